"""The hot paths of a query and a step, timed directly: for A/B runs of two checkouts.

Run it alternately on two trees in one sitting, each in a fresh process with warm kernel
caches, to see whether a change moved a path (BENCHMARKS.md, "Engine layout")::

    PYTHONPATH=/path/to/before .venv/bin/python benchmarks/paths.py --label before
    PYTHONPATH=.               .venv/bin/python benchmarks/paths.py --label after

Times: medians of many calls (queries, steady steps), the best of 5 batches. Uses only the
public API, so any checkout since the batch API runs it. Prints one JSON line and appends it
to ``bench-results/paths.json``.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

import engine
from engine import Pose, Scene, build_tree, find_contacts, find_contacts_batch, scenarios, shapes

OUT = Path(__file__).resolve().parents[1] / "bench-results" / "paths.json"
IDENTITY = np.array([1.0, 0.0, 0.0, 0.0])


def median_us(call, n: int = 300) -> float:
    call()
    times = []
    for _ in range(n):
        start = time.perf_counter()
        call()
        times.append(time.perf_counter() - start)
    return float(np.median(times)) * 1e6


def step_ms(scene: Scene, steps: int, scheme: str | None = None) -> float:
    """Median wall time of ``steps`` steps after one unmeasured step."""
    scene.step(1e-3, scheme)
    times = []
    for _ in range(steps):
        start = time.perf_counter()
        scene.step(1e-3, scheme)
        times.append(time.perf_counter() - start)
    return float(np.median(times)) * 1e3


def measure() -> dict:
    out: dict[str, float] = {}
    tree = build_tree(shapes.icosphere(3), 0.01, seed=0)  # 1,280 triangles
    origin = Pose([0.0, 0.0, 0.0], IDENTITY)
    for gap in (1.0, 0.02, -0.01):
        other = Pose([2.0 + gap, 0.0, 0.0], IDENTITY)
        out[f"query_gap_{gap:+.2f}_us"] = median_us(
            lambda o=other: find_contacts(tree, origin, tree, o)
        )
    rng = np.random.default_rng(1)
    k = 1000
    quats = rng.normal(size=(k, 4))
    quats /= np.linalg.norm(quats, axis=1)[:, None]
    dirs = rng.normal(size=(k, 3))
    dirs /= np.linalg.norm(dirs, axis=1)[:, None]
    centres = dirs * (2.0 + rng.uniform(-0.05, 0.02, size=(k, 1)))
    items = [(tree, origin, tree, Pose(centres[i], quats[i])) for i in range(k)]
    find_contacts_batch(items, threads=1)
    best = np.inf
    for _ in range(5):
        start = time.perf_counter()
        find_contacts_batch(items, threads=1)
        best = min(best, time.perf_counter() - start)
    out["batch_1000_pairs_1_thread_us_per_pair"] = best / k * 1e6

    pile = Scene()  # default scheme: implicit midpoint
    ball = shapes.icosphere(2, radius=0.5)
    pile.add_bodies(ball, [[x, y, 0.5] for x in range(3) for y in range(3)], epsilon=0.01)
    pile.add_plane(epsilon=0.001)
    out["nine_balls_on_a_plane_step_ms"] = step_ms(pile, 150)

    plane = scenarios.particle_on_plane()
    for _ in range(150):  # down to the plane
        plane.step(1e-3, "explicit")
    for scheme in ("explicit", "implicit-surrogate", "multiscale"):
        out[f"particle_on_plane_{scheme}_step_ms"] = step_ms(plane, 30, scheme)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--label", default="", help="a name for this run (e.g. before, after)")
    args = parser.parse_args()
    row = {"label": args.label, "engine": str(Path(engine.__file__).parent), **measure()}
    print(json.dumps(row))
    OUT.parent.mkdir(exist_ok=True)
    rows = json.loads(OUT.read_text()) if OUT.exists() else []
    OUT.write_text(json.dumps([*rows, row], indent=1))


if __name__ == "__main__":
    main()
