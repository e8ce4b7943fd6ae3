"""What warm starts across time steps save (issue 6): comparisons and time per step of a
resting and of a rolling contact, warm against restarting every step at the roots.

* multiscale: fronts kept from the last step (``MultiscaleSearch.warm``) against fronts
  rebuilt from the two roots each step (the paper's Algorithm 6 as published);
* implicit-surrogate: the pair cache's lists (``Scene(skin=0.5)``, the default until issue
  15's seventh step) against a traversal from the roots in every Picard iteration
  (``skin=0``).

Scenes (1,280-triangle sphere, ε = 1 % of the diameter, dt = 1e-3): **resting** — the sphere
settled on a flat plane (300 steps to settle first); **rolling** — the sphere rolling down
the 20° plane of the paper's particle-on-plane scenario (measured after it has landed).
Writes ``bench-results/warmstart.json``.

    .venv/bin/python benchmarks/warmstart.py
"""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import engine  # noqa: E402
from engine import PaperSpring, Scene, shapes  # noqa: E402

OUT = ROOT / "bench-results"
DT = 1e-3
MEASURE = 100


def scene(kind: str, scheme: str, skin: float) -> Scene:
    model = PaperSpring(damping=0.3, friction=0.5)
    s = Scene(scheme=scheme, contact_model=model, skin=skin, max_halvings=2)
    ball = shapes.icosphere(3, radius=0.5)
    if kind == "resting":
        s.add_plane(size=4.0, divisions=8, epsilon=0.01)  # halos of 0.01 given, as measured
        s.add_body(ball, position=(0.0, 0.0, 0.5 + 0.019), epsilon=0.01)
        return s
    theta = math.radians(20.0)
    normal = np.array([math.sin(theta), 0.0, math.cos(theta)])
    downhill = np.array([math.cos(theta), 0.0, -math.sin(theta)])
    s.add_plane(normal=normal, size=8.0, divisions=16, epsilon=0.01)
    s.add_body(ball, position=normal * (0.5 + 0.019) - 2.0 * downhill, epsilon=0.01)
    return s


def measure(kind: str, scheme: str, warm: bool) -> dict:
    s = scene(kind, scheme, 0.5 if (warm or scheme == "multiscale") else 0.0)
    if scheme == "multiscale":
        s.multiscale.warm = warm
    for _ in range(300 if kind == "resting" else 150):  # settle / land and start rolling
        s.step(DT)
    rows = [s.step(DT) for _ in range(MEASURE)]
    return {
        "kind": kind,
        "scheme": scheme,
        "warm": warm,
        "comparisons": float(np.mean([r.comparisons for r in rows])),
        "iterative": float(np.mean([r.iterative for r in rows])),
        "picard_iterations": float(np.mean([r.picard_iterations for r in rows])),
        "evaluations": float(np.mean([r.evaluations for r in rows])),
        "unfoldings": float(np.mean([r.unfoldings for r in rows])),
        "ms_per_step": 1e3 * float(np.mean([r.seconds for r in rows])),
        "non_converged": int(sum(not r.converged for r in rows)),
        "contacts": float(np.mean([r.contacts for r in rows])),
        "speed": float(np.linalg.norm(s.velocities[-1])),
    }


def main() -> None:
    OUT.mkdir(exist_ok=True)
    engine.warmup()
    rows = []
    print(
        f"{'contact':8s} {'scheme':19s} {'start':>6s} {'comparisons':>12s} {'iterative':>10s}"
        f" {'Picard':>7s} {'searches':>9s} {'unfold':>7s} {'ms/step':>8s} {'n-conv':>7s}"
        f" {'saving':>8s}"
    )
    for kind in ("resting", "rolling"):
        for scheme in ("multiscale", "implicit-surrogate"):
            cold = measure(kind, scheme, warm=False)
            warm = measure(kind, scheme, warm=True)
            warm["comparisons_saving"] = cold["comparisons"] / max(warm["comparisons"], 1e-9)
            warm["time_saving"] = cold["ms_per_step"] / warm["ms_per_step"]
            for r in (cold, warm):
                rows.append(r)
                saving = f"{r['comparisons_saving']:7.1f}x" if "comparisons_saving" in r else ""
                print(
                    f"{kind:8s} {scheme:19s} {'warm' if r['warm'] else 'roots':>6s}"
                    f" {r['comparisons']:12.1f} {r['iterative']:10.1f}"
                    f" {r['picard_iterations']:7.2f} {r['evaluations']:9.2f}"
                    f" {r['unfoldings']:7.1f} {r['ms_per_step']:8.3f} {r['non_converged']:7d}"
                    f" {saving:>8s}",
                    flush=True,
                )
    (OUT / "warmstart.json").write_text(json.dumps({"dt": DT, "steps": MEASURE, "rows": rows}))
    print(f"wrote {OUT / 'warmstart.json'}")


if __name__ == "__main__":
    main()
