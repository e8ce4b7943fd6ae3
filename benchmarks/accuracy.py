"""Time stepping, run time against error (issue 6): dt × scheme on the paper's
particle–particle and particle-on-plane scenarios, against a tiny-dt reference.

The reference is the explicit scheme at dt = 2e-5 (explicit and implicit Euler converge to
the same solution as dt → 0). Error: the largest distance of any body's centre from the
reference's at checkpoints every 0.02 s, and the final velocity difference. A run whose state
leaves the reference by more than the scene's size (or turns non-finite) is marked unstable.
Prints the table and the Pareto front (time against position error), writes
``bench-results/accuracy.json`` and, with matplotlib, ``bench-results/accuracy.png``.

    .venv/bin/python benchmarks/accuracy.py [scenario ...]   (default: all)
"""

from __future__ import annotations

import json
import sys
import time
import warnings
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from common import pareto_front  # noqa: E402

import engine  # noqa: E402
from engine import TunnellingWarning, scenarios  # noqa: E402

OUT = ROOT / "bench-results"
CHECK = 0.02
REFERENCE_DT = 2e-5
DTS = (5e-5, 1e-4, 2e-4, 5e-4, 1e-3, 2e-3, 4e-3)
SCHEMES = ("explicit", "implicit-surrogate", "implicit-midpoint", "multiscale")


def box_stack(scheme: str):
    """Two unit boxes resting on a plane (on the edge of their halos), damped, with friction:
    the stiff resting contact where explicit Euler needs a small dt."""
    from engine import PaperSpring, Scene, shapes

    scene = Scene(scheme=scheme, contact_model=PaperSpring(damping=0.5, friction=0.5))
    scene.add_plane(size=6.0, divisions=2, epsilon=0.01)
    box = shapes.box()
    eps = 0.01 * box.diameter  # halos given: the measured figures used 1 % of the diameter
    low = 0.5 + 0.998 * (0.01 + eps)
    scene.add_body(box, position=(0.0, 0.0, low), epsilon=eps)
    scene.add_body(box, position=(0.1, 0.05, low + 1.0 + 0.998 * 2 * eps), epsilon=eps)
    scene.set_state(velocities=[[0.0, 0.0, 0.0], [0.05, 0.0, -0.05], [0.0, 0.0, 0.0]])
    return scene


SCENARIOS = {
    # name: (builder, simulated seconds)
    "box-stack": (box_stack, 0.32),
    "particle-particle": (lambda s: scenarios.particle_particle(triangles=320, scheme=s), 0.16),
    "particle-plane": (lambda s: scenarios.particle_on_plane(triangles=320, scheme=s), 0.32),
}


def trajectory(name: str, scheme: str, dt: float) -> tuple[np.ndarray, np.ndarray, float, dict]:
    build, span = SCENARIOS[name]
    scene = build(scheme)
    per_check = round(CHECK / dt)
    checks, seconds, non_converged = [], 0.0, 0
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", TunnellingWarning)
        for _ in range(round(span / CHECK)):
            for _ in range(per_check):
                start = time.perf_counter()
                row = scene.step(dt)
                seconds += time.perf_counter() - start
                non_converged += not row.converged
            checks.append(scene.positions.copy())
    return np.array(checks), scene.velocities.copy(), seconds, {"non_converged": non_converged}


def main() -> None:
    names = sys.argv[1:] or list(SCENARIOS)
    OUT.mkdir(exist_ok=True)
    engine.warmup()
    results = {}
    for name in names:
        ref_x, ref_v, ref_s, _ = trajectory(name, "explicit", REFERENCE_DT)
        print(f"\n== {name}: reference explicit dt {REFERENCE_DT:g} ({ref_s:.1f} s)")
        print(
            f"{'scheme':19s}{'dt':>8s}{'seconds':>10s}{'pos err':>11s}{'vel err':>11s}"
            f"{'n-conv':>8s}  stable"
        )
        rows = []
        for scheme in SCHEMES:
            for dt in DTS:
                x, v, seconds, extra = trajectory(name, scheme, dt)
                finite = bool(np.isfinite(x).all() and np.isfinite(v).all())
                error = float(np.linalg.norm(x - ref_x, axis=2).max()) if finite else np.inf
                verr = float(np.linalg.norm(v - ref_v, axis=1).max()) if finite else np.inf
                row = {
                    "scheme": scheme,
                    "dt": dt,
                    "seconds": seconds,
                    "position_error": error,
                    "velocity_error": verr,
                    "stable": finite and error < 0.5,
                    **extra,
                }
                rows.append(row)
                print(
                    f"{scheme:19s}{dt:8.0e}{seconds:10.3f}{error:11.2e}{verr:11.2e}"
                    f"{extra['non_converged']:8d}  {'yes' if row['stable'] else 'NO'}",
                    flush=True,
                )
        front = pareto_front([r for r in rows if r["stable"]], "seconds", "position_error")
        print("Pareto front (time against position error):")
        for r in sorted(front, key=lambda r: r["seconds"]):
            seconds, error = r["seconds"], r["position_error"]
            print(f"  {r['scheme']:19s} dt {r['dt']:g}: {seconds:.3f} s, {error:.2e}")
        results[name] = {"reference_seconds": ref_s, "rows": rows, "pareto": front}
    target = OUT / (
        "accuracy.json" if len(names) == len(SCENARIOS) else f"accuracy-{'-'.join(names)}.json"
    )
    target.write_text(json.dumps(results, indent=2, default=float))
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        print("matplotlib missing: no PNG")
        return
    fig, axes = plt.subplots(1, len(results), figsize=(11, 4.5))
    for ax, (name, result) in zip(np.atleast_1d(axes), results.items(), strict=True):
        for scheme in SCHEMES:
            pts = [r for r in result["rows"] if r["scheme"] == scheme and r["stable"]]
            ax.loglog(
                [r["seconds"] for r in pts], [r["position_error"] for r in pts], "o-", label=scheme
            )
            for r in pts:
                ax.annotate(f"{r['dt']:g}", (r["seconds"], r["position_error"]), fontsize=6)
        ax.set_title(name)
        ax.set_xlabel("run time (s)")
        ax.set_ylabel("max position error")
        ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(target.with_suffix(".png"), dpi=120)
    print(f"wrote {target} and {target.with_suffix('.png').name}")


if __name__ == "__main__":
    main()
