"""Everyday scenes: mrdem's rigid-body scene engine against MuJoCo, and checks of its contact
law (friction on a ramp, the gentle start of overlapping bodies).

Run: ``.venv/bin/python benchmarks/scenes.py [--quick] [--skip-large] [--schemes ...]``
(needs MuJoCo, ``pip install -e .[bench]``, and ../shared/meshes; ``--help`` lists the
options). Prints a table per section; writes ``bench-results/scenes.json`` with the machine
(CPU, avx2/avx512f of /proc/cpuinfo, cores, MuJoCo version). ``--quick``: 0.2 s piles
without the flat ``implicit`` scheme (0.5–1 s a step on the pile; it is never run on the
large pile unless ``--large-schemes`` names it), a 64-body "large" pile, short ramps.

1. **pile**: 48 bodies (3 layers of 4×4, lemon and bread alternating, 800 kg/m³, seeded
   random orientations, ε = 2 mm) dropped into a 40 cm bin (floor and four walls are
   planes), ``Scene(sleep=True)``, ``PaperSpring(friction, damping)``, ``--seconds`` per
   scheme at its dt; MuJoCo (:func:`mujoco_scenes.mujoco_pile`: convex hulls, its own soft
   contacts, the same friction) on the same bodies and bin at the default scheme's dt and
   at 2 ms. Per run: wall time per simulated second, ms per step (all steps; the last 20 %:
   the settled pile), mean Picard iterations, steps unconverged, tunnelling warnings, steps
   split into sub-steps (``Scene(substeps=True)`` unless ``--no-substeps``),
   contacts at the end, the largest overlap over the run (fraction of the reach ε_a + ε_b;
   1 = surfaces touch or cross) and the steps that reached 1, MuJoCo's largest penetration,
   kinetic energy and bodies asleep at the end, bodies escaped (centre of mass outside the
   bin or below the floor), mrdem's wall time per simulated second over each MuJoCo run's.
2. **large pile**: the same with ``--large`` bodies (n×n per layer, n = round(∛N), layers
   as needed) in a bin of n·10 cm (``--skip-large``: left out).
3. **ramp**: a 20×20×10 cm, 4 kg box at rest on a plane tilted by each angle, μ = 0.6 and
   0.3, default scheme, dt 0.5 ms: its acceleration down the slope over the second half (a
   quadratic fit) against Coulomb's g(sin θ − μ cos θ) when it slides (relative error), the
   creep speed over the second half when it should stick.
4. **overlap**: a 4 g, 2 cm box started 40 % of its reach into a plane, for each
   ``separation_speed`` and scheme: the largest upward speed, at release and over the run.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
import warnings
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from common import machine  # noqa: E402
from mujoco_scenes import mujoco_pile  # noqa: E402

import engine  # noqa: E402
from engine import DEFAULT_SCHEME, SCHEMES, Mesh, PaperSpring, Pose, Scene  # noqa: E402
from engine.geometry.shapes import box  # noqa: E402

OUT = ROOT / "bench-results"
MESH_DIR = ROOT.parent / "shared" / "meshes"  # the meshes of ../shared (see its README)
PILE_MESHES = ("lemon", "bread")  # alternating in the layout
GRAVITY = 9.81

# the pile's layout: 9.3 cm grid, layers 9 cm apart from 6 cm up
SPACING, LAYER_HEIGHT, FIRST_LAYER_Z = 0.093, 0.09, 0.06
HALF_WIDTH_PER_COLUMN = 0.05  # 4 columns: the 40 cm bin
PILE_EPSILON, PILE_DENSITY = 0.002, 800.0
MUJOCO_OWN_DT = 2e-3
SETTLED_FRACTION = 0.2  # the last 20 % of a run's steps: the settled pile
CROSSING = 1.0 - 1e-9  # overlap / reach at which surfaces touch or cross (it is at most 1)
PILE_SCHEMES = ("explicit", "implicit", "implicit-midpoint")
FLAT = "implicit"  # the flat search in every Picard iteration: 0.5–1 s a step on the pile

# the ramp and the overlapping start (issue 16)
RAMP_BOX, RAMP_MASS, RAMP_EPSILON, RAMP_GAP, RAMP_DT = (0.2, 0.2, 0.1), 4.0, 0.002, 0.0039, 5e-4
OVERLAP_EDGE, OVERLAP_MASS, OVERLAP_EPSILON, OVERLAP_PLANE_EPSILON = 0.02, 0.004, 0.001, 0.0005
OVERLAP_DEPTH = 0.4  # fraction of the reach the box starts inside the plane
OVERLAP_DT = {"explicit": 1e-4}  # others 5e-4: explicit needs ω·dt < 2 on this stiff contact
OVERLAP_SPEEDS = (0.5, 0.1, math.inf)


@dataclass(frozen=True)
class PileLayout:
    """Bodies in layers of ``columns × columns``; ``bodies``: (mesh index, centre of mass
    (3,), unit quaternion (4,) w, x, y, z); the bin: walls at x, y = ±half_width, square
    planes of side ``wall_size`` (walls reach that high), ``divisions`` per side."""

    columns: int
    layers: int
    half_width: float
    wall_size: float
    divisions: int
    bodies: list


def pile_layout(count: int, seed: int = 0) -> PileLayout:
    """``count`` bodies on an n×n grid per layer (n = round(∛count), the 48-body pile's 4),
    meshes alternating, orientations from ``default_rng(seed)`` drawn in placing order."""
    n = max(1, round(count ** (1 / 3)))
    layers = math.ceil(count / (n * n))
    rng = np.random.default_rng(seed)
    offsets = (np.arange(n) - (n - 1) / 2) * SPACING
    bodies = []
    for k in range(count):
        layer, i, j = k // (n * n), (k // n) % n, k % n
        q = rng.normal(size=4)
        position = np.array([offsets[i], offsets[j], FIRST_LAYER_Z + LAYER_HEIGHT * layer])
        bodies.append((k % len(PILE_MESHES), position, q / np.linalg.norm(q)))
    half_width = HALF_WIDTH_PER_COLUMN * n
    top = 2 * FIRST_LAYER_Z + LAYER_HEIGHT * (layers - 1)  # the top layer, with headroom
    return PileLayout(n, layers, half_width, max(3 * half_width, 2 * top), n, bodies)


def apart(layout: PileLayout, meshes: list[Mesh], seed: int = 1) -> PileLayout:
    """``layout`` with the orientation of every body that touches another at the start
    (within ε_a + ε_b) drawn again from ``default_rng(seed)`` until none does, so that the
    largest overlap of a run is the drop's, not the placing's (the 512-body layout put
    two loaves 54 % of their reach into each other; the 48-body one is unchanged)."""
    rng = np.random.default_rng(seed)
    bodies = list(layout.bodies)
    for _ in range(100):
        scene = Scene()
        for mesh_index, position, q in bodies:
            mesh = meshes[mesh_index]
            scene.add_body(mesh, position=position, orientation=q, epsilon=PILE_EPSILON)
        found = scene.contacts(scene.positions, scene.orientations)
        counts = np.diff(found.offsets)
        touching = sorted({int(b) for (_, b), n in zip(found.bodies, counts, strict=True) if n})
        if not touching:
            return replace(layout, bodies=bodies)
        for k in touching:
            q = rng.normal(size=4)
            bodies[k] = (bodies[k][0], bodies[k][1], q / np.linalg.norm(q))
    raise RuntimeError("could not place the pile's bodies apart in 100 draws")


def load_meshes() -> list[Mesh]:
    """The pile's meshes (:data:`PILE_MESHES`) from :data:`MESH_DIR`, read with trimesh."""
    import trimesh

    meshes = []
    for name in PILE_MESHES:
        tm = trimesh.load(MESH_DIR / f"{name}.stl", force="mesh")
        meshes.append(Mesh(np.asarray(tm.vertices, dtype=np.float64), np.asarray(tm.faces)))
    return meshes


def build_pile(
    layout: PileLayout, meshes: list[Mesh], model: PaperSpring, substeps: bool = False
) -> Scene:
    """The layout's bodies in its bin (floor first, then the four walls, then the bodies);
    ``substeps``: a step that would move a surface by more than its ε is split."""
    scene = Scene(sleep=True, contact_model=model, substeps=substeps)
    h, size, eps = layout.half_width, layout.wall_size, PILE_EPSILON
    scene.add_plane(size=size, divisions=layout.divisions, epsilon=eps)
    for point, normal in (
        ((h, 0, size / 2), (-1, 0, 0)),
        ((-h, 0, size / 2), (1, 0, 0)),
        ((0, h, size / 2), (0, -1, 0)),
        ((0, -h, size / 2), (0, 1, 0)),
    ):
        scene.add_plane(
            point=point, normal=normal, size=size, divisions=layout.divisions, epsilon=eps
        )
    for mesh_index, position, q in layout.bodies:
        scene.add_body(
            meshes[mesh_index], position=position, orientation=q, density=PILE_DENSITY, epsilon=eps
        )
    return scene


def escaped(positions: np.ndarray, half_width: float) -> int:
    """Centres of mass outside |x|, |y| ≤ half_width or below z = 0."""
    out = (np.abs(positions[:, :2]) > half_width).any(axis=1) | (positions[:, 2] < 0)
    return int(out.sum())


def run_mrdem_pile(
    layout, meshes, model, scheme: str, dt: float, seconds: float, substeps: bool
) -> dict:
    """Step the pile ``seconds`` with ``scheme`` at ``dt``; the section's figures."""
    scene = build_pile(layout, meshes, model, substeps)
    steps = max(1, round(seconds / dt))
    step_s, iterations = np.empty(steps), np.empty(steps)
    largest_overlap, unconverged, crossing, split = 0.0, 0, 0, 0
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", engine.TunnellingWarning)
        for s in range(steps):
            start = time.perf_counter()
            stats = scene.step(dt, scheme)
            step_s[s] = time.perf_counter() - start
            iterations[s] = stats.picard_iterations
            largest_overlap = max(largest_overlap, stats.max_overlap)
            unconverged += not stats.converged
            crossing += stats.max_overlap >= CROSSING
            split += stats.substeps > 1
    free = ~scene.fixed
    tail = step_s[-max(1, int(steps * SETTLED_FRACTION)) :]
    return {
        "engine": "mrdem",
        "scheme": scheme,
        "dt": dt,
        "steps": steps,
        "wall_total_s": float(step_s.sum()),
        "wall_per_simulated_second_s": float(step_s.sum()) / (steps * dt),
        "ms_per_step": 1e3 * float(step_s.mean()),
        "settled_ms_per_step": 1e3 * float(tail.mean()),
        "picard_mean": float(iterations.mean()),
        "unconverged_steps": unconverged,
        "tunnelling_warnings": sum(
            issubclass(w.category, engine.TunnellingWarning) for w in caught
        ),
        "contacts_end": stats.contacts,
        "max_overlap_run": largest_overlap,
        "crossing_steps": crossing,
        "substepped_steps": split,
        "kinetic_energy_end_j": scene.kinetic_energy(),
        "sleeping_end": stats.sleeping,
        "escaped": escaped(scene.positions[free], layout.half_width),
        "mass_total_kg": float(scene.masses[free].sum()),
    }


def mujoco_bodies(layout: PileLayout, scene: Scene) -> list:
    """The layout's bodies as :func:`mujoco_pile` takes them: the pose of each mesh frame
    (mrdem places centres of mass: origin = position − R·centre)."""
    free = np.flatnonzero(~scene.fixed)
    out = []
    for (mesh_index, position, _), b in zip(layout.bodies, free, strict=True):
        pose = Pose(position, scene.orientations[b])
        out.append((mesh_index, pose.apply(-scene.centers[b][None])[0], pose.orientation))
    return out


def run_mujoco_pile(layout, meshes, scene, dt: float, seconds: float, friction: float) -> dict:
    """The same pile in MuJoCo (``scene``: the mrdem pile, for the mesh-frame poses)."""
    r = mujoco_pile(
        [(np.asarray(m.vertices, np.float64), np.asarray(m.faces)) for m in meshes],
        mujoco_bodies(layout, scene),
        density=PILE_DENSITY,
        half_width=layout.half_width,
        wall_height=layout.wall_size,
        dt=dt,
        seconds=seconds,
        friction=friction,
    )
    same = ("steps", "wall_total_s", "wall_per_simulated_second_s", "kinetic_energy_end_j")
    return {
        "engine": "mujoco",
        "scheme": r["integrator"],
        "dt": dt,
        **{k: r[k] for k in (*same, "escaped", "mass_total_kg", "settled", "warnings")},
        "ms_per_step": 1e3 * r["wall_total_s"] / max(1, r["steps"]),
        "median_ms_per_step": 1e3 * r["wall_per_step_s"],  # no per-step times: no settled
        "contacts_end": r["contacts"],
        "penetration_run_mm": 1e3 * r["largest_penetration_run_m"],  # impacts: transient
        "penetration_end_mm": 1e3 * r["largest_penetration_m"],
    }


def pile_section(
    count: int, schemes: dict, seconds: float, model: PaperSpring, substeps: bool, seed: int = 0
) -> dict:
    """mrdem with each ``schemes`` entry (scheme → dt) and MuJoCo at the default scheme's
    dt and at its own 2 ms, on a pile of ``count`` bodies; the ratios of wall time per
    simulated second (mrdem over each MuJoCo run)."""
    meshes = load_meshes()
    layout = apart(pile_layout(count, seed), meshes)
    rows = []
    for scheme, dt in schemes.items():
        rows.append(run_mrdem_pile(layout, meshes, model, scheme, dt, seconds, substeps))
        print(f"  {scheme} dt {dt:g}: {rows[-1]['wall_total_s']:.1f} s", flush=True)
    reference = build_pile(layout, meshes, model)
    reference_dt = schemes.get(DEFAULT_SCHEME, min(schemes.values()))
    mujoco = {}
    for dt in sorted({reference_dt, MUJOCO_OWN_DT}):
        mujoco[dt] = run_mujoco_pile(layout, meshes, reference, dt, seconds, model.friction)
        rows.append(mujoco[dt])
        print(f"  MuJoCo dt {dt:g}: {mujoco[dt]['wall_total_s']:.1f} s", flush=True)
    same_dt = mujoco[reference_dt]
    for row in rows:
        if row["engine"] == "mrdem":
            cost = row["wall_per_simulated_second_s"]
            row["ratio_mujoco_same_dt"] = cost / same_dt["wall_per_simulated_second_s"]
            row["ratio_mujoco_own_dt"] = cost / mujoco[MUJOCO_OWN_DT]["wall_per_simulated_second_s"]
    return {
        "bodies": count,
        "columns": layout.columns,
        "layers": layout.layers,
        "half_width_m": layout.half_width,
        "wall_size_m": layout.wall_size,
        "seconds": seconds,
        "mujoco_reference_dt": reference_dt,
        "runs": rows,
    }


def ramp_run(angle: float, mu: float, seconds: float, damping: float) -> dict:
    """The box released at rest on a plane tilted by ``angle`` degrees (friction ``mu``)."""
    theta = math.radians(angle)
    scene = Scene(contact_model=PaperSpring(friction=mu, damping=damping))
    normal = np.array([0.0, -math.sin(theta), math.cos(theta)])
    scene.add_plane(normal=normal, size=4.0, divisions=2, epsilon=RAMP_EPSILON)
    q = (math.cos(theta / 2), math.sin(theta / 2), 0.0, 0.0)  # about x, by θ
    position = normal * (RAMP_BOX[2] / 2 + RAMP_GAP)
    scene.add_body(
        box(RAMP_BOX), position=position, orientation=q, mass=RAMP_MASS, epsilon=RAMP_EPSILON
    )
    steps = max(4, round(seconds / RAMP_DT))
    down = np.array([0.0, -math.cos(theta), -math.sin(theta)])  # down the slope
    along, iterations = np.empty(steps), np.empty(steps)
    start = time.perf_counter()
    for s in range(steps):
        iterations[s] = scene.step(RAMP_DT).picard_iterations
        along[s] = scene.positions[1] @ down
    wall = time.perf_counter() - start
    t = np.arange(1, steps + 1) * RAMP_DT
    half = slice(steps // 2, None)
    accel = 2 * float(np.polyfit(t[half], along[half], 2)[0])
    coulomb = max(0.0, GRAVITY * (math.sin(theta) - mu * math.cos(theta)))
    slides = coulomb > 0
    speed = (along[-1] - along[steps // 2]) / (t[-1] - t[steps // 2])
    return {
        "angle_deg": angle,
        "friction": mu,
        "slides": slides,
        "acceleration_m_s2": accel,
        "coulomb_m_s2": coulomb,
        "relative_error": (accel - coulomb) / coulomb if slides else None,
        "creep_mm_s": None if slides else 1e3 * float(speed),
        "moved_mm": 1e3 * float(along[-1]),
        "picard_mean": float(iterations.mean()),
        "ms_per_step": 1e3 * wall / steps,
    }


def overlap_run(speed: float, scheme: str, seconds: float) -> dict:
    """The small box started ``OVERLAP_DEPTH`` of its reach into a plane, let go at
    ``separation_speed=speed`` (the default, undamped law): its largest upward speed until
    it first leaves the plane (the release) and over the whole run (bounces included)."""
    scene = Scene(separation_speed=speed)
    scene.add_plane(size=1.0, divisions=2, epsilon=OVERLAP_PLANE_EPSILON)
    reach = OVERLAP_EPSILON + OVERLAP_PLANE_EPSILON
    z = OVERLAP_EDGE / 2 + reach - OVERLAP_DEPTH * reach
    scene.add_body(
        box((OVERLAP_EDGE,) * 3), position=(0, 0, z), mass=OVERLAP_MASS, epsilon=OVERLAP_EPSILON
    )
    dt = OVERLAP_DT.get(scheme, 5e-4)
    steps = max(1, round(seconds / dt))
    fastest = release = -math.inf
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", engine.TunnellingWarning)
        for _ in range(steps):
            contacts = scene.step(dt, scheme).contacts
            fastest = max(fastest, float(scene.velocities[1, 2]))
            if release == -math.inf and contacts == 0:  # its first free flight
                release = fastest
    return {
        "separation_speed": speed,
        "scheme": scheme,
        "dt": dt,
        "steps": steps,
        "release_speed_m_s": release if release > -math.inf else None,
        "largest_upward_speed_m_s": fastest,
        "release_over_cap": release / speed if math.isfinite(speed) and release > 0 else None,
        "run_over_cap": fastest / speed if math.isfinite(speed) else None,
        "z_end_mm": 1e3 * float(scene.positions[1, 2]),
        "tunnelling_warnings": len(caught),
    }


def print_table(title: str, rows: list[dict], columns: list[tuple[str, str, str]]) -> None:
    """``rows`` under ``title`` as aligned columns of (header, key, format); None: "—"."""
    cells = [
        [("—" if r.get(key) is None else format(r[key], fmt)) for _, key, fmt in columns]
        for r in rows
    ]
    widths = [max(len(h), *(len(c[i]) for c in cells)) for i, (h, _, _) in enumerate(columns)]
    print(f"\n{title}")
    print("  ".join(h.rjust(w) for (h, _, _), w in zip(columns, widths, strict=True)))
    for c in cells:
        print("  ".join(v.rjust(w) for v, w in zip(c, widths, strict=True)))


# fmt: off
PILE_COLUMNS = [  # (header, key, format)
    ("engine", "engine", "s"), ("scheme", "scheme", "s"), ("dt", "dt", "g"),
    ("wall/sim s", "wall_per_simulated_second_s", ".2f"), ("ms/step", "ms_per_step", ".3f"),
    ("settled ms/step", "settled_ms_per_step", ".3f"), ("Picard", "picard_mean", ".2f"),
    ("unconv", "unconverged_steps", "d"), ("tunnel", "tunnelling_warnings", "d"),
    ("split", "substepped_steps", "d"),
    ("contacts", "contacts_end", "d"), ("max overlap", "max_overlap_run", ".3f"),
    ("crossing", "crossing_steps", "d"), ("MJ pen mm", "penetration_run_mm", ".2f"),
    ("KE J", "kinetic_energy_end_j", ".2e"), ("asleep", "sleeping_end", "d"),
    ("escaped", "escaped", "d"), ("÷MJ same dt", "ratio_mujoco_same_dt", ".1f"),
    ("÷MJ 2 ms", "ratio_mujoco_own_dt", ".1f"),
]
RAMP_COLUMNS = [
    ("μ", "friction", "g"), ("angle °", "angle_deg", "g"), ("slides", "slides", ""),
    ("accel m/s²", "acceleration_m_s2", ".4f"), ("Coulomb m/s²", "coulomb_m_s2", ".4f"),
    ("rel err", "relative_error", ".2%"), ("creep mm/s", "creep_mm_s", ".4f"),
    ("moved mm", "moved_mm", ".3f"), ("Picard", "picard_mean", ".2f"),
    ("ms/step", "ms_per_step", ".3f"),
]
OVERLAP_COLUMNS = [
    ("cap m/s", "separation_speed", "g"), ("scheme", "scheme", "s"), ("dt", "dt", "g"),
    ("release m/s", "release_speed_m_s", ".4f"), ("÷ cap", "release_over_cap", ".2f"),
    ("run max m/s", "largest_upward_speed_m_s", ".4f"), ("÷ cap", "run_over_cap", ".2f"),
    ("z end mm", "z_end_mm", ".3f"), ("tunnelling warnings", "tunnelling_warnings", "d"),
]
# fmt: on


def print_pile(title: str, section: dict) -> None:
    """One pile section's table."""
    head = (
        f"{title}: {section['bodies']} bodies ({section['columns']}×{section['columns']}"
        f" × {section['layers']} layers), bin ±{section['half_width_m']:g} m,"
        f" {section['seconds']:g} s simulated; ÷MJ: mrdem's wall/sim s over MuJoCo's"
        f" (dt {section['mujoco_reference_dt']:g}, 2 ms)"
    )
    print_table(head, section["runs"], PILE_COLUMNS)


def machine_info() -> dict:
    """:func:`common.machine` plus the avx2/avx512f flags of /proc/cpuinfo and MuJoCo."""
    import mujoco

    info = machine()
    flags: set[str] = set()
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name") and "cpu" not in info:
                    info["cpu"] = line.split(":", 1)[1].strip()
                if line.startswith("flags"):
                    flags = set(line.split(":", 1)[1].split())
                    break
    except OSError:
        pass
    info["cpuinfo_isa"] = {flag: flag in flags for flag in ("avx2", "avx512f")}
    info["mujoco"] = mujoco.__version__
    return info


def _plain(value):
    """``value`` with numpy scalars as Python ones and non-finite floats as strings
    ("inf"): strict JSON."""
    if isinstance(value, dict):
        return {k: _plain(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_plain(v) for v in value]
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return str(value)
    return value


def parse_args(argv=None) -> argparse.Namespace:
    """The command line (see ``--help``)."""
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--quick", action="store_true", help="short smoke run (0.2 s, 64-body pile)")
    p.add_argument("--seconds", type=float, help="simulated s of the piles (3.0; quick 0.2)")
    p.add_argument(
        "--schemes",
        nargs="+",
        choices=SCHEMES,
        metavar="SCHEME",
        help="pile, overlap (explicit implicit implicit-midpoint; --quick piles: no implicit)",
    )
    p.add_argument(
        "--large-schemes",
        nargs="+",
        choices=SCHEMES,
        metavar="SCHEME",
        help="large pile (default: the pile's without the flat implicit)",
    )
    p.add_argument("--dt-explicit", type=float, default=5e-4)
    p.add_argument(
        "--dt-implicit", type=float, default=5e-4, help="also implicit-surrogate, multiscale"
    )
    p.add_argument("--dt-midpoint", type=float, default=5e-4)
    p.add_argument("--damping", type=float, default=0.3, help="normal damping ratio ζ")
    p.add_argument("--friction", type=float, default=0.5, help="Coulomb μ of the piles")
    p.add_argument(
        "--seed",
        type=int,
        default=0,
        help="seed of the piles' orientations (the pile is chaotic: compare several)",
    )
    p.add_argument(
        "--stiffness",
        type=float,
        default=1000.0,
        help="the piles' spring constant K_s (PaperSpring, default the paper's 1000)",
    )
    p.add_argument("--large", type=int, help="bodies of the large pile (512; quick 64)")
    p.add_argument("--skip-large", action="store_true")
    p.add_argument(
        "--no-substeps",
        dest="substeps",
        action="store_false",
        help="never split a step whose surfaces would move more than ε (Scene(substeps=False))",
    )
    p.add_argument("--angles", type=float, nargs="+", default=[10, 20, 25, 30, 35])
    p.add_argument("--ramp-seconds", type=float, help="simulated s per ramp (1.0; quick 0.2)")
    p.add_argument("--output", type=Path, default=OUT / "scenes.json")
    args = p.parse_args(argv)
    if args.seconds is None:
        args.seconds = 0.2 if args.quick else 3.0
    if args.large is None:
        args.large = 64 if args.quick else 512
    if args.ramp_seconds is None:
        args.ramp_seconds = 0.2 if args.quick else 1.0
    args.overlap_schemes = args.schemes or list(PILE_SCHEMES)
    if args.schemes is None:
        args.schemes = [s for s in PILE_SCHEMES if not (args.quick and s == FLAT)]
    if args.large_schemes is None:
        args.large_schemes = [s for s in args.schemes if s != FLAT]
    return args


def main(argv=None) -> None:
    """Run the sections, print their tables, write the JSON."""
    args = parse_args(argv)
    wall = time.perf_counter()
    print(f"warm-up (compile or load kernels) {engine.warmup():.1f} s", flush=True)
    dts = {"explicit": args.dt_explicit, "implicit-midpoint": args.dt_midpoint}
    schemes = {s: dts.get(s, args.dt_implicit) for s in args.schemes}
    large_schemes = {s: dts.get(s, args.dt_implicit) for s in args.large_schemes}
    model = PaperSpring(friction=args.friction, damping=args.damping, stiffness=args.stiffness)
    results: dict = {
        "settings": {k: (str(v) if isinstance(v, Path) else v) for k, v in vars(args).items()},
        "machine": machine_info(),
        "contact_model": {k: getattr(model, k) for k in ("friction", "damping", "stiffness")},
    }

    print("pile:", flush=True)
    results["pile"] = pile_section(48, schemes, args.seconds, model, args.substeps, args.seed)
    print_pile("pile", results["pile"])
    if not args.skip_large:
        print(f"\nlarge pile ({args.large} bodies):", flush=True)
        results["large_pile"] = pile_section(
            args.large, large_schemes, args.seconds, model, args.substeps, args.seed
        )
        print_pile("large pile", results["large_pile"])

    results["ramp"] = [
        ramp_run(angle, mu, args.ramp_seconds, args.damping)
        for mu in (0.6, 0.3)
        for angle in args.angles
    ]
    print_table(
        f"ramp: {RAMP_MASS:g} kg box, {DEFAULT_SCHEME} at dt {RAMP_DT:g},"
        f" {args.ramp_seconds:g} s; fits over the second half, accel down the slope",
        results["ramp"],
        RAMP_COLUMNS,
    )

    overlap_seconds = 0.05 if args.quick else 0.2
    results["overlap"] = [
        overlap_run(speed, scheme, overlap_seconds)
        for speed in OVERLAP_SPEEDS
        for scheme in args.overlap_schemes
    ]
    print_table(
        f"overlap: {1e3 * OVERLAP_MASS:g} g box {OVERLAP_DEPTH:.0%} of its reach into a plane,"
        f" {overlap_seconds:g} s; the largest upward speed against separation_speed",
        results["overlap"],
        OVERLAP_COLUMNS,
    )

    results["seconds"] = time.perf_counter() - wall
    args.output.parent.mkdir(parents=True, exist_ok=True)
    args.output.write_text(json.dumps(_plain(results), indent=2))
    print(f"\ntotal {results['seconds']:.0f} s; wrote {args.output}")


if __name__ == "__main__":
    main()
