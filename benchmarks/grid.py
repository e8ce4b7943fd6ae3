"""Steps of the paper's sphere grid, timed one by one (issue 15, point 4).

Run: ``.venv/bin/python benchmarks/grid.py [--shape 32 32 24] [--orientations vertices]
[--steps 3] [--threads 2] [--scheme implicit-surrogate]``. Prints a table and writes
``bench-results/grid.json``.

The scene is :func:`engine.scenarios.sphere_grid` (1,224-triangle UV spheres, centres 1.0195
apart, no gravity, at rest; ``"vertices"``: every sphere turned so that ordinary vertices
face the grid axes, ``"aligned"``: unrotated, pole fans face to face). Per step, dt = 1e-3:
wall seconds (``scene.step``'s own ``seconds``), process CPU seconds (all threads), Picard
iterations, contact evaluations, listed leaf pairs, body pairs, triangle comparisons,
merged contacts. The first step builds the pair lists; later steps reuse them.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from engine import scenarios  # noqa: E402

OUT = ROOT / "bench-results"
DT = 1e-3


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--shape", type=int, nargs=3, default=(32, 32, 24), metavar="N")
    parser.add_argument("--orientations", default="vertices", choices=("vertices", "aligned"))
    parser.add_argument("--steps", type=int, default=3)
    parser.add_argument("--threads", type=int, default=None, help="default: Numba's")
    parser.add_argument("--scheme", default="implicit-surrogate")
    args = parser.parse_args()
    start = time.perf_counter()
    scene = scenarios.sphere_grid(
        shape=tuple(args.shape),
        triangles=1224,
        spacing=1.0195,
        scheme=args.scheme,
        orientations=args.orientations,
    )
    scene.threads = args.threads
    built = time.perf_counter() - start
    print(f"{len(scene)} bodies built in {built:.2f} s; {args.orientations}, {args.scheme}")
    print(f"{'step':>4} {'wall s':>8} {'CPU s':>8} {'Picard':>6} {'evals':>5} {'comparisons':>12}")
    rows = []
    for index in range(args.steps):
        cpu = time.process_time()
        row = scene.step(DT)
        cpu = time.process_time() - cpu
        rows.append(
            {
                "step": index,
                "seconds": row.seconds,
                "cpu_seconds": cpu,
                "picard_iterations": row.picard_iterations,
                "evaluations": row.evaluations,
                "listed": row.listed,
                "body_pairs": row.body_pairs,
                "comparisons": row.comparisons,
                "contacts": row.contacts,
                "converged": bool(row.converged),
            }
        )
        print(
            f"{index:4d} {row.seconds:8.3f} {cpu:8.3f} {row.picard_iterations:6d}"
            f" {row.evaluations:5d} {row.comparisons:12,}"
        )
    OUT.mkdir(exist_ok=True)
    setup = vars(args) | {"dt": DT, "bodies": len(scene), "build_seconds": built}
    setup["cpus"] = os.cpu_count()
    target = OUT / "grid.json"
    target.write_text(json.dumps({"setup": setup, "steps": rows}, indent=2))
    print(f"wrote {target}")


if __name__ == "__main__":
    main()
