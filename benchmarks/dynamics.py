"""Benchmark of the rigid-body dynamics against the paper (issue 4, point 7).

Run: ``.venv/bin/python benchmarks/dynamics.py [--quick]``. Prints tables and writes
``bench-results/dynamics.json``. Time step ``dt = 1e-3`` throughout: the paper gives none;
the contact spring of two unit spheres (K_s = 1,000, halo 0.01 each) has ω ≈ 310 rad/s,
so ω·dt ≈ 0.3 (a contact lasts about ten steps) and the explicit scheme is stable, and
all schemes run with the same dt, as in the paper.

1. **Particle–particle and particle–plane** (1,224-triangle unit spheres, the paper's
   Tables "Picard iterations" and "implicit comparison count", and the explicit
   comparison count): 100 steps per scheme (explicit, implicit-surrogate, multiscale)
   and per leaf kernel (hybrid; exact, the paper's "comparison-based"); the flat
   ``implicit`` scheme (every triangle pair in every Picard iteration; hybrid only) over
   the same 100 steps (``--quick``: 6 steps from 5 steps before the first contact, from
   the implicit-surrogate trajectory), beside implicit-surrogate on the same steps. Per
   step: Picard iterations, comparisons, iterative evaluations, fallbacks,
   sphere-pruned node pairs, wall time; non-converged steps; multiscale / explicit time.
   Particle–particle starts at t = 0 (contact from step ~30 to ~40). Particle–plane
   (tilt 20°, drop 0.1): the free fall before the first contact is skipped with explicit
   steps (no contact: every scheme moves the sphere identically), the 100 steps start 5
   steps before the first contact and cover the impact, a hop and rolling.
2. **Scale differences** (80-triangle unit sphere against one scaled 2, 4, 8 with 80 or
   80·scale² triangles): per step over the contact phase (steps with leaf contacts).
3. **Grid of spheres at rest** (1,224 triangles, spacing 1.0195): time per implicit step
   for growing grids, time per body pair, resident memory (peak per run); the paper's
   24,576 spheres are built first (geometry memory counted from the objects, RSS on a
   fresh heap) and searched once (one explicit step), and the implicit step time is
   **extrapolated** linearly in the body pairs from each measured grid.
"""

from __future__ import annotations

import argparse
import gc
import json
import math
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import engine  # noqa: E402
from engine import scenarios  # noqa: E402
from engine.collision.configuration import SEARCH_COUNTERS  # noqa: E402
from engine.trees.tree import _ARRAYS as TREE_ARRAYS  # noqa: E402

OUT = ROOT / "bench-results"
DT = 1e-3
TILT, DROP = 20.0, 0.1
LEAD = 5  # steps before the first contact where a window starts
GRID_SPACING = 1.0195
# The grid's spheres share one orientation that puts ordinary vertices (six triangles) on
# the grid axes: neighbours meet vertex to vertex, halos overlapping by 2.5 % of their
# reach. "aligned" (unrotated UV spheres: the 36-triangle pole fans face each other along
# z, 1,296 touching leaf pairs per such contact) is measured on the full grid as well.
GRID_ORIENTATIONS = "vertices"
PAPER_GRID_SHAPE = (32, 32, 24)  # 24,576 spheres

# ---------------------------------------------------------------- the paper's numbers
# Table "Picard iterations" (average per step over 100 steps):
# (comparison-based, iterative/hybrid).
PAPER_PICARD = {
    "particle-particle": {"single": (4.6, 4.9), "multiscale": (6.2, 6.2)},
    "particle-plane": {"single": (7.1, 7.1), "multiscale": (13.0, 13.1)},
}
# Table "implicit comparison count", totals over 100 steps: comparison-based
# (#comparisons, runtime), hybrid (#comparisons = fallbacks, #iterative, runtime). The
# caption says "time per time step"; the runtimes are kept as printed.
PAPER_IMPLICIT = {
    "particle-particle": {
        "implicit": (6.89e8, 1.69e2, 8.78e5, 7.34e8, 7.44e1),
        "implicit-surrogate": (3.97e6, 1.08, 7.14e4, 3.70e6, 7.20e-1),
        "multiscale": (1.82e6, 7.70e-1, 2.25e4, 1.70e6, 4.70e-1),
    },
    "particle-plane": {
        "implicit": (4.43e8, 9.61e1, 1.11e7, 4.43e8, 4.41e1),
        "implicit-surrogate": (3.59e6, 4.80e-1, 3.44e5, 3.42e6, 2.20e-1),
        "multiscale": (3.50e6, 4.90e-1, 3.11e5, 3.35e6, 1.90e-1),
    },
}
# Table "explicit comparison count", per step, hierarchy: comparison-based (#comparisons,
# seconds), hybrid (#iterative, seconds, #fallbacks).
PAPER_EXPLICIT = {
    "particle-particle": ((8.20e3, 2.60e-2), (7.64e3, 1.80e-2, 1.44e2)),
    "particle-plane": ((5.27e3, 7.68e-2), (5.03e3, 4.00e-2, 4.96e2)),
}
# Tables "different scale" (80 triangles both) and "different triangles" (80·scale²),
# per implicit step: iterations, #comparisons (hybrid: fallbacks), #iterative, seconds.
PAPER_SCALE = {
    False: {
        1: (13, 15.9, 145, 8.72e-2),
        2: (13, 19.3, 127, 6.80e-2),
        4: (18, 43.1, 178, 1.00e-1),
        8: (14, 41.0, 98.2, 6.82e-2),
    },
    True: {
        1: (13, 15.9, 145, 8.72e-2),
        2: (19, 41.8, 505, 2.25e-1),
        4: (20, 46.6, 588, 2.60e-1),
        8: (17, 38.0, 544, 2.40e-1),
    },
}
# Table "24,576 particles", per step per core: comparison-based (#comparisons, seconds),
# hybrid (#fallbacks, #iterative, seconds); memory 3.87 GiB.
PAPER_GRID = {
    "implicit-surrogate": (2.49e6, 470.0, 2.92e2, 2.49e6, 377.0),
    "multiscale": (9.08e5, 230.0, 1.09e2, 1.06e6, 213.0),
    "memory_gib": 3.87,
}
ISSUE_TARGETS = {
    "multiscale_over_explicit_particle_particle": 2.0,
    "paper_multiscale_over_explicit": 4.0,
    "grid_implicit_step_seconds_2_cores": 5.0,
    "grid_geometry_memory_mib": 200.0,
}

COUNTERS = (*SEARCH_COUNTERS, "evaluations")


# ---------------------------------------------------------------- helpers
def rss_mib(field: str = "VmRSS") -> float:
    """Resident memory of this process (``VmRSS``, or ``VmHWM`` for the peak), MiB."""
    with open("/proc/self/status") as status:
        for line in status:
            if line.startswith(field + ":"):
                return int(line.split()[1]) / 1024
    return float("nan")


PEAKS: list[float] = []


def reset_peak_rss() -> bool:
    """Reset this process's peak resident memory (``VmHWM``; Linux ``clear_refs``), after
    noting the peak so far in ``PEAKS``."""
    PEAKS.append(rss_mib("VmHWM"))
    try:
        with open("/proc/self/clear_refs", "w") as refs:
            refs.write("5")
        return True
    except OSError:
        return False


def restore(scene, state) -> None:
    scene.set_state(state.positions, state.orientations, state.velocities, state.angular_velocities)
    scene.time = state.time


def run(scene, steps: int, dt: float = DT, states: list | None = None) -> list:
    """``steps`` steps of ``scene``; their StepStats (and the state after each one, into
    ``states``, when given)."""
    rows = []
    for _ in range(steps):
        rows.append(scene.step(dt))
        if states is not None:
            states.append(scene.state)
    return rows


def first_contact(rows) -> int | None:
    return next((i for i, r in enumerate(rows) if r.contacts > 0), None)


def summary(rows) -> dict:
    """Per-step means of a run's StepStats, plus totals and counts."""
    contact = [r for r in rows if r.contacts > 0]
    out = {
        "steps": len(rows),
        "picard_iterations": float(np.mean([r.picard_iterations for r in rows])),
        "picard_iterations_contact": (
            float(np.mean([r.picard_iterations for r in contact])) if contact else None
        ),
        "max_picard_iterations": max(r.picard_iterations for r in rows),
        "seconds": float(np.mean([r.seconds for r in rows])),
        "seconds_contact": float(np.mean([r.seconds for r in contact])) if contact else None,
        "seconds_total": float(sum(r.seconds for r in rows)),
        "non_converged": sum(not r.converged for r in rows),
        "non_converged_steps": [i for i, r in enumerate(rows) if not r.converged],
        "halvings": sum(r.halvings for r in rows),
        "contact_steps": len(contact),
        "first_contact": first_contact(rows),
        "max_overlap": max(r.max_overlap for r in rows),
        "max_contacts": max(r.contacts for r in rows),
    }
    for name in COUNTERS:
        out[name] = float(np.mean([getattr(r, name) for r in rows]))
        out[name + "_total"] = int(sum(getattr(r, name) for r in rows))
    return out


def state_difference(a, b) -> dict:
    return {
        "position": float(np.abs(a.positions - b.positions).max()),
        "velocity": float(np.abs(a.velocities - b.velocities).max()),
        "angular_velocity": float(np.abs(a.angular_velocities - b.angular_velocities).max()),
    }


def fmt(x, width: int = 9) -> str:
    if x is None:
        return "-".rjust(width)
    if isinstance(x, int | np.integer) or (abs(x) >= 1e3 or (0 < abs(x) < 1e-2)):
        return f"{x:{width}.3g}"
    return f"{x:{width}.2f}"


def ms(seconds):
    return None if seconds is None else seconds * 1e3


def plane_normal() -> np.ndarray:
    theta = math.radians(TILT)
    return np.array([math.sin(theta), 0.0, math.cos(theta)])


def plane_scene(scheme: str):
    """``scenarios.particle_on_plane`` with the benchmark's tilt and drop."""
    return scenarios.particle_on_plane(triangles=1224, tilt_degrees=TILT, drop=DROP, scheme=scheme)


def plane_physics(scene) -> dict:
    ball = int(np.flatnonzero(~scene.fixed)[0])
    plane = int(np.flatnonzero(scene.fixed)[0])
    n = plane_normal()
    v, w = scene.velocities[ball], scene.angular_velocities[ball]
    tangential = v - (v @ n) * n
    contact_point_velocity = tangential + np.cross(w, -0.5 * n)  # surface point on the plane
    return {
        "height_over_plane": float(n @ (scene.positions[ball] - scene.positions[plane]) - 0.5),
        "speed": float(np.linalg.norm(v)),
        "normal_velocity": float(v @ n),
        "slip_velocity": float(np.linalg.norm(contact_point_velocity)),
        "kinetic_energy": scene.kinetic_energy(),
    }


def pair_physics(scene, initial) -> dict:
    linear, _ = scene.momentum()
    before = np.linalg.norm(initial.velocities[1] - initial.velocities[0])
    after = np.linalg.norm(scene.velocities[1] - scene.velocities[0])
    return {
        "restitution": float(after / before),
        "momentum": float(np.linalg.norm(linear)),
        "kinetic_energy": scene.kinetic_energy(),
        "speed": float(np.linalg.norm(scene.velocities, axis=1).max()),
    }


# ---------------------------------------------------------------- 1. two scenarios
def scenario_runs(name: str, steps: int, flat_steps: int, kernels: tuple[str, ...]) -> dict:
    """All schemes on one scenario from one starting state; see the module docstring."""
    if name == "particle-particle":

        def build(scheme):
            return scenarios.particle_particle(
                triangles=1224, speed=0.5, offset=0.0, gap=0.05, scheme=scheme
            )

        start = build("explicit").state
        lead_in = 0
    else:
        build = plane_scene
        probe = build("explicit")
        states = [probe.state]
        lead_rows = run(probe, 1000, states=states)  # free fall, explicit
        hit = first_contact(lead_rows)
        if hit is None:
            raise RuntimeError("the sphere never reached the plane in 1,000 steps")
        lead_in = max(0, hit - LEAD)
        start = states[lead_in]
    runs, finals, trajectories = {}, {}, {}
    for scheme in ("explicit", "implicit-surrogate", "multiscale"):
        for kernel in kernels:
            scene = build(scheme)
            scene.kernel = kernel
            restore(scene, start)
            states = [scene.state]
            rows = run(scene, steps, states=states)
            key = f"{scheme} {kernel}"
            physics = pair_physics(scene, start) if name == "particle-particle" else None
            runs[key] = {
                "scheme": scheme,
                "kernel": kernel,
                **summary(rows),
                "physics": physics or plane_physics(scene),
            }
            finals[key], trajectories[key] = scene.state, states
    # the flat search on a short window from the implicit-surrogate trajectory
    reference = runs["implicit-surrogate hybrid"]
    window = 0 if flat_steps >= steps else max(0, (reference["first_contact"] or 0) - LEAD)
    scene = build("implicit")
    restore(scene, trajectories["implicit-surrogate hybrid"][window])
    rows = run(scene, flat_steps)
    same = build("implicit-surrogate")
    restore(same, trajectories["implicit-surrogate hybrid"][window])
    same_rows = run(same, flat_steps)
    runs["implicit hybrid"] = {
        "scheme": "implicit",
        "kernel": "hybrid",
        "window": [window, window + flat_steps],
        **summary(rows),
        "implicit_surrogate_same_window": summary(same_rows),
        "state_difference_to_implicit_surrogate": state_difference(scene.state, same.state),
    }
    agreement = {
        "implicit-surrogate vs multiscale (hybrid)": state_difference(
            finals["implicit-surrogate hybrid"], finals["multiscale hybrid"]
        ),
        "implicit-surrogate vs explicit (hybrid)": state_difference(
            finals["implicit-surrogate hybrid"], finals["explicit hybrid"]
        ),
    }
    if "exact" in kernels:
        agreement["implicit-surrogate hybrid vs exact"] = state_difference(
            finals["implicit-surrogate hybrid"], finals["implicit-surrogate exact"]
        )
        agreement["multiscale vs implicit-surrogate (exact)"] = state_difference(
            finals["implicit-surrogate exact"], finals["multiscale exact"]
        )
    ex, ms = runs["explicit hybrid"], runs["multiscale hybrid"]
    ratio = {
        "all_steps": ms["seconds"] / ex["seconds"],
        "contact_steps": (
            ms["seconds_contact"] / ex["seconds_contact"]
            if ms["seconds_contact"] and ex["seconds_contact"]
            else None
        ),
        "implicit_surrogate_over_explicit": runs["implicit-surrogate hybrid"]["seconds"]
        / ex["seconds"],
    }
    ratio["repeated"] = repeated_ratio(build, start, steps)
    return {
        "scenario": name,
        "dt": DT,
        "steps": steps,
        "lead_in_steps": lead_in,
        "start_time": start.time,
        "runs": runs,
        "agreement": agreement,
        "multiscale_over_explicit": ratio,
    }


TIMING_REPEATS = 7


def repeated_ratio(build, start, steps: int) -> dict:
    """The multiscale / explicit step-time ratio (hybrid) from ``TIMING_REPEATS`` runs of
    each, interleaved (explicit, multiscale, explicit, …) so that both see the same load:
    the ratio of the medians and of the fastest runs (a shared machine's noise only ever
    slows a run down)."""
    times: dict[str, list[float]] = {"explicit": [], "multiscale": []}
    for _ in range(TIMING_REPEATS):
        for scheme, out in times.items():
            scene = build(scheme)
            restore(scene, start)
            out.append(summary(run(scene, steps))["seconds"])
    ex, ms = np.array(times["explicit"]), np.array(times["multiscale"])
    return {
        "runs": TIMING_REPEATS,
        "explicit_ms": (ex * 1e3).tolist(),
        "multiscale_ms": (ms * 1e3).tolist(),
        "median_ratio": float(np.median(ms) / np.median(ex)),
        "min_ratio": float(ms.min() / ex.min()),
    }


def paper_row(scenario: str, scheme: str, kernel: str) -> dict:
    """The paper's per-step numbers for one of our runs (None where it has none)."""
    row = dict.fromkeys(("picard", "comparisons", "iterative", "fallbacks", "seconds"))
    exact = kernel == "exact"
    if scheme == "explicit":
        comp, hyb = PAPER_EXPLICIT[scenario]
        row["picard"] = 1
        if exact:
            row["comparisons"], row["seconds"] = comp
        else:
            row["iterative"], row["seconds"], row["fallbacks"] = hyb
        return row
    level = "multiscale" if scheme == "multiscale" else "single"
    row["picard"] = PAPER_PICARD[scenario][level][0 if exact else 1]
    comp, comp_t, fallbacks, iterative, hyb_t = PAPER_IMPLICIT[scenario][scheme]
    if exact:
        row["comparisons"], row["seconds"] = comp / 100, comp_t
    else:
        row["fallbacks"], row["iterative"], row["seconds"] = fallbacks / 100, iterative / 100, hyb_t
    return row


def print_scenario(result: dict) -> None:
    name = result["scenario"]
    print(
        f"\n== {name}: dt {result['dt']:g}, {result['steps']} steps"
        f" (flat implicit: {result['runs']['implicit hybrid']['steps']} steps from step"
        f" {result['runs']['implicit hybrid']['window'][0]}), lead-in"
        f" {result['lead_in_steps']} explicit steps (t0 = {result['start_time']:.3f} s);"
        " per step, paper in brackets (paper comparisons: totals / 100)"
    )
    print(
        f"{'scheme':19s}{'kernel':7s}{'Picard':>7s}{'[paper]':>8s}{'contact':>8s}"
        f"{'comparisons':>12s}{'[paper]':>10s}{'iterative':>10s}{'[paper]':>10s}"
        f"{'fallbacks':>10s}{'[paper]':>10s}{'pruned':>10s}{'ms/step':>9s}{'ms/cstep':>9s}"
        f"{'[paper]':>9s}"
        f"{'non-conv':>9s}{'contact steps':>17s}{'max ovl':>8s}"
    )
    print(
        "  ([paper] after ms/cstep: explicit, ms per step; implicit schemes, the paper's"
        " runtime as printed x 1e3 — its caption says time per time step, the unit is unclear)"
    )
    for key, r in result["runs"].items():
        p = paper_row(name, r["scheme"], r["kernel"])
        cstep = r["seconds_contact"] * 1e3 if r["seconds_contact"] else None
        print(
            f"{r['scheme']:19s}{r['kernel']:7s}{r['picard_iterations']:7.2f}{fmt(p['picard'], 8)}"
            f"{fmt(r['picard_iterations_contact'], 8)}"
            f"{r['comparisons']:12.4g}{fmt(p['comparisons'], 10)}"
            f"{r['iterative']:10.4g}{fmt(p['iterative'], 10)}"
            f"{r['fallbacks']:10.4g}{fmt(p['fallbacks'], 10)}{r['sphere_pruned']:10.4g}"
            f"{r['seconds'] * 1e3:9.3f}{fmt(cstep, 9)}{fmt(ms(p['seconds']), 9)}"
            f"{r['non_converged']:9d}"
            f"{r['contact_steps']:8d} from {str(r['first_contact']):>3s}"
            f"{r['max_overlap']:8.3f}"
        )
        if key == "implicit hybrid":
            s = r["implicit_surrogate_same_window"]
            d = r["state_difference_to_implicit_surrogate"]
            print(
                f"{'  implicit-surrogate, same window':33s}{s['picard_iterations']:7.2f}"
                f"{'':16s}{s['comparisons']:12.4g}{'':10s}{s['iterative']:10.4g}{'':10s}"
                f"{s['fallbacks']:10.4g}{'':10s}{s['sphere_pruned']:10.4g}"
                f"{s['seconds'] * 1e3:9.3f}{'':9s}{s['non_converged']:9d}"
                f"   flat vs surrogate after the window: |dx| {d['position']:.2e},"
                f" |dv| {d['velocity']:.2e}, |dw| {d['angular_velocity']:.2e}"
            )
    ratio = result["multiscale_over_explicit"]
    contact = ratio["contact_steps"]
    print(
        f"multiscale / explicit step time (hybrid): {ratio['all_steps']:.1f}x over all steps,"
        f" {contact:.1f}x over contact steps (issue: <= 2x, paper: <= 4x);"
        f" implicit-surrogate / explicit: {ratio['implicit_surrogate_over_explicit']:.1f}x"
        if contact
        else f"multiscale / explicit step time (hybrid): {ratio['all_steps']:.1f}x"
    )
    rep = ratio["repeated"]
    print(
        f"multiscale / explicit step time (hybrid), {rep['runs']} interleaved runs of each:"
        f" median {np.median(rep['multiscale_ms']):.3f} / {np.median(rep['explicit_ms']):.3f} ms"
        f" = {rep['median_ratio']:.2f}x, fastest {min(rep['multiscale_ms']):.3f} /"
        f" {min(rep['explicit_ms']):.3f} ms = {rep['min_ratio']:.2f}x (issue: <= 2x)"
    )
    for label, d in result["agreement"].items():
        print(
            f"final states, {label}: max |dx| {d['position']:.2e}, |dv| {d['velocity']:.2e},"
            f" |dw| {d['angular_velocity']:.2e}"
        )
    for key, r in result["runs"].items():
        ph = r.get("physics")
        if not ph:
            continue
        if name == "particle-particle":
            print(
                f"physics {key:25s}: restitution {ph['restitution']:.3f}, |momentum|"
                f" {ph['momentum']:.1e}, kinetic energy {ph['kinetic_energy']:.4f},"
                f" max speed {ph['speed']:.3f}"
            )
        else:
            print(
                f"physics {key:25s}: height over plane {ph['height_over_plane']:+.4f},"
                f" speed {ph['speed']:.3f} (normal {ph['normal_velocity']:+.3f}), slip"
                f" {ph['slip_velocity']:.3f}, kinetic energy {ph['kinetic_energy']:.4f}"
            )


# ---------------------------------------------------------------- 2. scale differences
def scale_study(scales, max_steps: int) -> list[dict]:
    rows = []
    print(
        "\n== scale differences: 80-triangle unit sphere vs a sphere scaled s (80 or 80 s²"
        " triangles), head-on at 0.5 each, dt 1e-3; per step over the contact phase"
        " (steps with leaf contacts), paper in brackets (hybrid: #tri. comp. = fallbacks)"
    )
    print(
        f"{'refine':7s}{'scale':>6s}{'tris':>6s} {'scheme':19s}{'Picard':>7s}{'[paper]':>8s}"
        f"{'fallbacks':>10s}{'[paper]':>8s}{'iterative':>10s}{'[paper]':>8s}"
        f"{'comparisons':>12s}{'ms/step':>9s}{'[paper]':>8s}{'steps':>6s}{'from':>5s}"
        f"{'non-conv':>9s}{'ovl@0':>7s}{'max ovl':>8s}  small v / large v"
    )
    for refine in (False, True):
        for scale in scales:
            for scheme in ("implicit-surrogate", "multiscale"):
                scene = scenarios.scale_difference(
                    scale=scale, refine=refine, speed=0.5, scheme=scheme
                )
                steps, quiet = [], 0
                while len(steps) < max_steps:
                    steps.append(scene.step(DT))
                    touched = first_contact(steps) is not None
                    quiet = quiet + 1 if steps[-1].contacts == 0 else 0
                    if touched and quiet >= 5:
                        break
                contact = [r for r in steps if r.contacts > 0]
                s = summary(contact) if contact else summary(steps)
                paper = PAPER_SCALE[refine].get(scale)
                row = {
                    "refine": refine,
                    "scale": scale,
                    "triangles": 80 * scale**2 if refine else 80,
                    "scheme": scheme,
                    "steps_run": len(steps),
                    "first_contact": first_contact(steps),
                    "overlap_first_step": steps[0].max_overlap,
                    "non_converged_all": sum(not r.converged for r in steps),
                    "final_velocities": scene.velocities[:, 0].tolist(),
                    "contact_phase": s,
                    "paper": paper,
                }
                rows.append(row)
                p = paper or (None,) * 4
                print(
                    f"{str(refine):7s}{scale:6d}{row['triangles']:6d} {scheme:19s}"
                    f"{s['picard_iterations']:7.1f}{fmt(p[0], 8)}"
                    f"{s['fallbacks']:10.1f}{fmt(p[1], 8)}{s['iterative']:10.1f}"
                    f"{fmt(p[2], 8)}{s['comparisons']:12.1f}{s['seconds'] * 1e3:9.2f}"
                    f"{fmt(p[3] * 1e3 if p[3] else None, 8)}{s['steps']:6d}"
                    f"{str(row['first_contact']):>5s}{row['non_converged_all']:9d}"
                    f"{row['overlap_first_step']:7.2f}{s['max_overlap']:8.2f}"
                    f"  {row['final_velocities'][0]:+.3f} / {row['final_velocities'][1]:+.3f}"
                )
    return rows


# ---------------------------------------------------------------- 3. the grid
def array_bytes(obj, seen: set) -> int:
    """Bytes of the numpy arrays reachable from ``obj`` (containers and objects'
    attributes), each underlying buffer counted once."""
    if id(obj) in seen:
        return 0
    seen.add(id(obj))
    if isinstance(obj, np.ndarray):
        base = obj
        while isinstance(base.base, np.ndarray):
            base = base.base
        if base is not obj:
            return array_bytes(base, seen)
        return obj.nbytes
    if isinstance(obj, dict):
        return sum(array_bytes(v, seen) for v in obj.values())
    if isinstance(obj, list | tuple | set):
        return sum(array_bytes(v, seen) for v in obj)
    if hasattr(obj, "__dict__") and not isinstance(obj, type):
        return array_bytes(vars(obj), seen)
    return 0


STATE_ARRAYS = (
    "positions",
    "orientations",
    "velocities",
    "angular_velocities",
    "masses",
    "inertia",
    "inverse_inertia",
    "centers",
    "tree_index",
    "fixed",
    "external_forces",
)


def geometry_bytes(scene) -> dict:
    """Memory of a scene's geometry from its objects: the shared trees' own arrays, what
    is cached on them (prepared node sets, normals, spheres, the mesh), the batched
    search's tree bank, and the per-body state arrays."""
    seen: set = set()
    own = sum(array_bytes(getattr(t, name), seen) for t in scene.trees for name in TREE_ARRAYS)
    cached = sum(array_bytes(vars(t), seen) for t in scene.trees)
    bank = array_bytes(scene._bank, seen) if scene._bank is not None else 0
    state = sum(array_bytes(getattr(scene, name), seen) for name in STATE_ARRAYS)
    return {
        "tree_arrays": own,
        "tree_caches": cached,
        "tree_bank": bank,
        "body_state": state,
        "body_state_per_body": state / len(scene),
        "total": own + cached + bank + state,
    }


def grid_run(shape, scheme: str, steps: int) -> dict:
    gc.collect()
    reset = reset_peak_rss()
    before = rss_mib()
    start = time.perf_counter()
    scene = scenarios.sphere_grid(
        shape=shape,
        triangles=1224,
        spacing=GRID_SPACING,
        scheme=scheme,
        orientations=GRID_ORIENTATIONS,
    )
    build = time.perf_counter() - start
    built = rss_mib()
    start = time.perf_counter()  # one search: the tree bank and the trees' caches
    scene.contacts(scene.positions, scene.orientations)
    warm = time.perf_counter() - start
    rows = run(scene, steps)
    after = rss_mib()
    s = summary(rows)
    pairs = rows[0].body_pairs
    row = {
        "shape": list(shape),
        "spheres": len(scene),
        "scheme": scheme,
        "body_pairs": pairs,
        "build_seconds": build,
        "first_search_seconds": warm,
        "rss_before_mib": before,
        "rss_built_mib": built,
        "rss_after_steps_mib": after,
        "peak_rss_mib": rss_mib("VmHWM") if reset else None,
        "geometry": geometry_bytes(scene),
        "per_step": [
            {
                "seconds": r.seconds,
                "picard_iterations": r.picard_iterations,
                "evaluations": r.evaluations,
                "converged": r.converged,
                "comparisons": r.comparisons,
                "iterative": r.iterative,
                "fallbacks": r.fallbacks,
                "contacts": r.contacts,
                "max_overlap": r.max_overlap,
            }
            for r in rows
        ],
        **s,
        "seconds_per_body_pair": s["seconds"] / pairs,
        "seconds_per_body_pair_iteration": s["seconds"] / pairs / s["picard_iterations"],
        "kinetic_energy_after": scene.kinetic_energy(),
        "max_speed_after": float(np.linalg.norm(scene.velocities, axis=1).max()),
    }
    del scene
    gc.collect()
    return row


def print_grid_row(r: dict) -> None:
    iters = "/".join(str(x["picard_iterations"]) for x in r["per_step"])
    print(
        f"{'x'.join(map(str, r['shape'])):>9s}{r['spheres']:7d} {r['scheme']:19s}"
        f"{r['body_pairs']:7d}{r['steps']:6d}{iters:>9s}{r['non_converged']:7d}"
        f"{r['comparisons']:12.4g}{r['iterative']:12.4g}{r['fallbacks']:10.4g}"
        f"{r['seconds']:9.3f}{r['seconds_per_body_pair'] * 1e3:10.3f} "
        f"{r['seconds_per_body_pair_iteration'] * 1e6:10.1f}"
        f"{r['peak_rss_mib'] or float('nan'):8.0f}{r['geometry']['total'] / 2**20:8.2f}"
        f"{r['build_seconds']:7.2f}"
        f"{r['max_speed_after']:8.3f}"
    )


def grid_study(plan: dict, budget: float) -> dict:
    """Growing grids per scheme; a scheme stops growing when the next grid's steps would
    take more than ``budget`` seconds (estimated from the last grid's time per pair)."""
    print(
        f"\n== grid of 1,224-triangle spheres, orientations {GRID_ORIENTATIONS!r}, spacing"
        f" {GRID_SPACING} (no gravity, at rest),"
        f" dt 1e-3, threads {os.cpu_count()}; per step (first steps from rest); peakRSS: peak"
        " resident MiB of the process during the run (build + steps)"
    )
    print(
        f"{'grid':>9s}{'bodies':>7s} {'scheme':19s}{'pairs':>7s}{'steps':>6s}{'Picard':>9s} "
        f"{'n-conv':>6s}{'comparisons':>12s}{'iterative':>12s}{'fallbacks':>10s}"
        f"{'s/step':>9s}{'ms/pair':>10s}{'us/pair/it':>11s}"
        f"{'peakRSS':>8s}{'geomMiB':>8s}{'build':>7s}{'vmax':>8s}"
    )
    rows = []
    for scheme, (shapes, steps) in plan.items():
        per_pair = None
        for shape in shapes:
            n = int(np.prod(shape))
            estimate = 3 * n * per_pair * steps if per_pair else 0.0  # ~3 pairs per sphere
            if estimate > budget:
                print(
                    f"{'x'.join(map(str, shape)):>9s}{n:7d} {scheme:19s} skipped: about"
                    f" {estimate:.0f} s estimated (budget {budget:.0f} s)"
                )
                break
            row = grid_run(shape, scheme, steps)
            rows.append(row)
            print_grid_row(row)
            per_pair = row["seconds_per_body_pair"]
    return {"rows": rows}


def full_grid(search: bool) -> dict:
    """The paper's 24,576 spheres: build, geometry memory, RSS; one explicit step (one
    search of every body pair) when ``search``."""
    gc.collect()
    before = rss_mib()
    start = time.perf_counter()
    scene = scenarios.sphere_grid(
        shape=PAPER_GRID_SHAPE,
        triangles=1224,
        spacing=GRID_SPACING,
        scheme="explicit",
        orientations=GRID_ORIENTATIONS,
    )
    build = time.perf_counter() - start
    built = rss_mib()
    start = time.perf_counter()
    _, pairs = scene.configuration(scene.positions, scene.orientations)
    broad = time.perf_counter() - start
    out = {
        "shape": list(PAPER_GRID_SHAPE),
        "spheres": len(scene),
        "body_pairs": len(pairs),
        "build_seconds": build,
        "broad_phase_seconds": broad,
        "rss_before_mib": before,
        "rss_built_mib": built,
    }
    scene.bank  # noqa: B018 -- builds the tree bank (counted as geometry)
    if search:
        reset_peak_rss()
        stats = scene.step(DT, "explicit")
        out["explicit_step"] = {
            "seconds": stats.seconds,
            "comparisons": stats.comparisons,
            "iterative": stats.iterative,
            "fallbacks": stats.fallbacks,
            "contacts": stats.contacts,
            "body_pairs": stats.body_pairs,
        }
        out["rss_after_step_mib"] = rss_mib()
        out["peak_rss_step_mib"] = rss_mib("VmHWM")
    out["geometry"] = geometry_bytes(scene)
    del scene
    gc.collect()
    if search:
        out["implicit_steps"] = {
            o: full_grid_implicit(IMPLICIT_FULL_STEPS, o) for o in (GRID_ORIENTATIONS, "aligned")
        }
    return out


IMPLICIT_FULL_STEPS = 3


def full_grid_implicit(steps: int, orientations: str) -> dict:
    """``steps`` implicit-surrogate steps of the paper's grid, measured (fresh scene)."""
    gc.collect()
    reset_peak_rss()
    scene = scenarios.sphere_grid(
        shape=PAPER_GRID_SHAPE,
        triangles=1224,
        spacing=GRID_SPACING,
        scheme="implicit-surrogate",
        orientations=orientations,
    )
    rows = []
    for _ in range(steps):
        r = scene.step(DT)
        rows.append(
            {
                "seconds": r.seconds,
                "picard_iterations": r.picard_iterations,
                "evaluations": r.evaluations,
                "listed": r.listed,
                "converged": r.converged,
                "comparisons": r.comparisons,
                "contacts": r.contacts,
                "body_pairs": r.body_pairs,
            }
        )
        print(f"  full grid ({orientations}) implicit-surrogate step: {rows[-1]}", flush=True)
    out = {
        "orientations": orientations,
        "steps": rows,
        "pair_cache_mib": scene.pair_cache.nbytes / 2**20,
        "peak_rss_mib": rss_mib("VmHWM"),
        "threads": os.cpu_count(),
    }
    del scene
    gc.collect()
    return out


def extrapolate(grid: dict, full: dict) -> dict:
    """Implicit step time at 24,576 spheres, linear in the body pairs, from every grid
    measured per scheme: over all its steps, and over the steps after the first (warm
    starts: pair lists, fronts)."""
    out = {}
    for scheme in ("implicit-surrogate", "multiscale"):
        rows = [r for r in grid["rows"] if r["scheme"] == scheme]
        entries = []
        for r in rows:
            entry = {
                "from_grid": r["shape"],
                "from_body_pairs": r["body_pairs"],
                "picard_iterations": r["picard_iterations"],
                "converged": r["non_converged"] == 0,
                "seconds_per_body_pair": r["seconds_per_body_pair"],
                "extrapolated_seconds": r["seconds_per_body_pair"] * full["body_pairs"],
                "threads": os.cpu_count(),
            }
            later = [x["seconds"] for x in r["per_step"][1:]]
            if later:
                entry["extrapolated_seconds_after_first"] = (
                    float(np.mean(later)) / r["body_pairs"] * full["body_pairs"]
                )
            entries.append(entry)
        if entries:
            out[scheme] = entries
    return out


def print_full(full: dict, estimate: dict) -> None:
    g = full["geometry"]
    print(
        f"\n== paper grid {'x'.join(map(str, full['shape']))} = {full['spheres']:,} spheres"
        f" (built first, on a fresh heap): {full['body_pairs']:,} body pairs (broad phase"
        f" {full['broad_phase_seconds']:.2f} s), build {full['build_seconds']:.1f} s, RSS"
        f" {full['rss_before_mib']:.0f} -> {full['rss_built_mib']:.0f} MiB"
        + (
            f" -> {full['rss_after_step_mib']:.0f} MiB after one explicit step (peak"
            f" {full['peak_rss_step_mib']:.0f} MiB)"
            if "rss_after_step_mib" in full
            else ""
        )
    )
    print(
        f"geometry memory (from the objects): {g['total'] / 2**20:.2f} MiB = shared tree"
        f" {g['tree_arrays'] / 2**20:.3f} MiB + its caches {g['tree_caches'] / 2**20:.3f} MiB"
        f" + tree bank {g['tree_bank'] / 2**20:.3f} MiB + body state"
        f" {g['body_state'] / 2**20:.2f} MiB ({g['body_state_per_body']:.0f} B per body)"
        f" (issue: <= 200 MiB; paper 3.87 GiB)"
    )
    if "explicit_step" in full:
        e = full["explicit_step"]
        print(
            f"measured: one explicit step (one search of all {e['body_pairs']:,} pairs)"
            f" {e['seconds']:.2f} s, {e['comparisons']:.3g} comparisons, {e['iterative']:.3g}"
            f" iterative, {e['fallbacks']:.3g} fallbacks, {e['contacts']:,} contacts"
        )
    for orientations, m in full.get("implicit_steps", {}).items():
        print(
            f"MEASURED implicit-surrogate steps of the full grid ({orientations}) on"
            f" {m['threads']} threads (pair cache {m['pair_cache_mib']:.0f} MiB, process peak"
            f" {m['peak_rss_mib']:.0f} MiB):"
        )
        for i, r in enumerate(m["steps"]):
            print(
                f"  step {i}: {r['seconds']:.2f} s, {r['picard_iterations']} Picard iterations,"
                f" {r['evaluations']} searches ({r['listed']:,} pair searches from the"
                f" lists), converged {r['converged']}, {r['comparisons']:.3g} comparisons"
            )
    for scheme, entries in estimate.items():
        paper = PAPER_GRID[scheme]
        print(
            f"EXTRAPOLATION (linear in body pairs, not measured) {scheme}, one implicit step"
            f" of {full['body_pairs']:,} pairs on {entries[0]['threads']} threads (issue:"
            f" <= 5 s on 2 cores; paper {paper[1]:.0f} s comparison-based / {paper[4]:.0f} s"
            " hybrid per step per core):"
        )
        for x in entries:
            note = "" if x["converged"] else " (Picard NOT converged: iteration cap)"
            print(
                f"  from {'x'.join(map(str, x['from_grid'])):>9s} ({x['from_body_pairs']:5d}"
                f" pairs, {x['picard_iterations']:.1f} Picard iterations{note}):"
                f" {x['seconds_per_body_pair'] * 1e3:8.3f} ms per pair ->"
                f" {x['extrapolated_seconds']:9.1f} s"
                + (
                    f" (steps after the first: {x['extrapolated_seconds_after_first']:.1f} s)"
                    if "extrapolated_seconds_after_first" in x
                    else ""
                )
            )


# ---------------------------------------------------------------- main
def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="shorter runs, smaller grids")
    args = parser.parse_args()
    quick = args.quick
    OUT.mkdir(exist_ok=True)
    wall = time.perf_counter()
    warm = engine.warmup()
    print(f"warm-up (compile or load kernels) {warm:.1f} s; dt {DT:g}; cores {os.cpu_count()}")
    steps = 40 if quick else 100
    flat_steps = 6 if quick else steps  # the flat search is cheap enough for all steps here
    kernels = ("hybrid",) if quick else ("hybrid", "exact")
    results: dict = {
        "settings": {
            "dt": DT,
            "steps": steps,
            "flat_steps": flat_steps,
            "kernels": kernels,
            "quick": quick,
            "cpu_count": os.cpu_count(),
            "python": platform.python_version(),
            "tilt_degrees": TILT,
            "drop": DROP,
        },
        "paper": {
            "picard": PAPER_PICARD,
            "implicit_totals_100_steps": PAPER_IMPLICIT,
            "explicit_per_step": PAPER_EXPLICIT,
            "scale": {str(k): v for k, v in PAPER_SCALE.items()},
            "grid": PAPER_GRID,
        },
        "issue_targets": ISSUE_TARGETS,
    }
    # the paper's grid first, while the heap is fresh (its RSS growth is then its own)
    section = time.perf_counter()
    full = full_grid(search=not quick)
    full_seconds = time.perf_counter() - section
    section = time.perf_counter()
    results["scenarios"] = []
    for name in ("particle-particle", "particle-plane"):
        result = scenario_runs(name, steps, flat_steps, kernels)
        results["scenarios"].append(result)
        print_scenario(result)
    print(f"(section 1: {time.perf_counter() - section:.0f} s)")

    section = time.perf_counter()
    results["scale"] = scale_study((1, 2) if quick else (1, 2, 4, 8), 120 if quick else 200)
    print(f"(section 2: {time.perf_counter() - section:.0f} s)")

    section = time.perf_counter()
    if quick:
        plan = {
            "explicit": ([(2, 2, 2), (4, 4, 4)], 2),
            "implicit-surrogate": ([(2, 2, 2), (4, 4, 4)], 2),
            "multiscale": ([(2, 2, 2)], 1),
        }
        budget = 20.0
    else:
        grids = [(4, 4, 4), (8, 8, 8), (12, 12, 12), (16, 16, 12), (20, 20, 16), (24, 24, 18)]
        plan = {
            "explicit": (grids, 2),
            "implicit-surrogate": (grids, 2),
            "multiscale": ([(2, 2, 2), (3, 3, 3), (4, 4, 4), (5, 5, 5)], 3),
        }
        budget = 60.0
    grid = grid_study(plan, budget)
    estimate = extrapolate(grid, full)
    print_full(full, estimate)
    results["grid"] = {**grid, "paper_grid": full, "extrapolation": estimate}
    print(f"(section 3: {time.perf_counter() - section + full_seconds:.0f} s)")

    results["seconds"] = time.perf_counter() - wall
    results["peak_rss_mib"] = max([rss_mib("VmHWM"), *PEAKS])
    (OUT / "dynamics.json").write_text(json.dumps(results, indent=2, default=_json))
    print(
        f"total {results['seconds']:.0f} s, peak RSS {results['peak_rss_mib']:.0f} MiB;"
        f" wrote {OUT / 'dynamics.json'}"
    )


def _json(value):
    if isinstance(value, np.integer):
        return int(value)
    if isinstance(value, np.floating):
        return float(value)
    if isinstance(value, np.ndarray):
        return value.tolist()
    raise TypeError(f"not JSON serialisable: {type(value).__name__}")


if __name__ == "__main__":
    main()
