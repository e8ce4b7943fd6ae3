"""Thread scaling of the paper's sphere grid: steps at 1, 2, 4, 8, 16 threads (issue 15, point 4).

Run: ``.venv/bin/python benchmarks/grid_threads.py [--threads 16 4 8 2 1]
[--orientations vertices aligned] [--steps 3] [--shape 32 32 24]``. Prints a table per run
and a summary, writes ``bench-results/grid_threads.json``.

One process: a small grid of each orientation is stepped first so that every kernel is
compiled (or loaded from Numba's cache) before anything is timed; then, for each thread
count in the order given and each orientation, a fresh scene
(:func:`engine.scenarios.sphere_grid`, 1,224-triangle UV spheres, implicit-surrogate,
dt = 1e-3) is stepped ``--steps`` times. Step 0 builds the pair lists; later steps reuse
them. The summary gives the median of the later steps, the speed-up over the smallest
thread count run and the parallel efficiency from 4 threads to each larger count,
``(t_4 · 4) / (t_n · n)``.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from common import machine  # noqa: E402

from engine import scenarios  # noqa: E402

OUT = ROOT / "bench-results"
DT = 1e-3
TRIANGLES = 1224
SPACING = 1.0195


def grid(shape: tuple[int, int, int], orientations: str, threads: int):
    scene = scenarios.sphere_grid(
        shape=shape,
        triangles=TRIANGLES,
        spacing=SPACING,
        scheme="implicit-surrogate",
        orientations=orientations,
    )
    scene.threads = threads
    return scene


def run(shape, orientations: str, threads: int, steps: int) -> list[dict]:
    scene = grid(shape, orientations, threads)
    rows = []
    for index in range(steps):
        row = scene.step(DT)
        rows.append(
            {
                "step": index,
                "seconds": row.seconds,
                "picard_iterations": row.picard_iterations,
                "comparisons": row.comparisons,
                "contacts": row.contacts,
            }
        )
    return rows


def summary(results: list[dict]) -> list[dict]:
    """Median later step, speed-up and efficiency from 4 threads, per orientation."""
    table = []
    for orientations in dict.fromkeys(r["orientations"] for r in results):
        mine = sorted(
            (r for r in results if r["orientations"] == orientations), key=lambda r: r["threads"]
        )
        steady = {
            r["threads"]: statistics.median(s["seconds"] for s in r["steps"][1:]) for r in mine
        }
        base = mine[0]["threads"]
        for r in mine:
            n = r["threads"]
            row = {
                "orientations": orientations,
                "threads": n,
                "first_step_s": r["steps"][0]["seconds"],
                "steady_step_s": steady[n],
                "speedup": steady[base] / steady[n] * 1.0,
                "speedup_over_threads": base,
            }
            if 4 in steady and n >= 4:
                row["efficiency_from_4"] = steady[4] * 4 / (steady[n] * n)
            table.append(row)
    return table


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--threads", type=int, nargs="+", default=[16, 4, 8, 2, 1])
    parser.add_argument("--orientations", nargs="+", default=["vertices", "aligned"])
    parser.add_argument("--steps", type=int, default=3)
    parser.add_argument("--shape", type=int, nargs=3, default=(32, 32, 24), metavar="N")
    args = parser.parse_args()
    if args.steps < 2:
        parser.error("--steps must be at least 2 (step 0 builds the pair lists)")
    host = machine()
    print(
        f"{host.get('cpu', '?')}, {host['cores']} cores, ISA {host.get('vector_isa', '?')}, "
        f"LLVM CPU {host['llvm_cpu']}; numba {host['numba']}, numpy {host['numpy']}"
    )
    start = time.perf_counter()
    for orientations in args.orientations:
        run((4, 4, 4), orientations, max(args.threads), 2)
    warmup = time.perf_counter() - start
    print(f"warm-up (compile or cache load): {warmup:.1f} s", flush=True)
    results = []
    for threads in args.threads:
        for orientations in args.orientations:
            steps = run(tuple(args.shape), orientations, threads, args.steps)
            results.append({"orientations": orientations, "threads": threads, "steps": steps})
            seconds = " ".join(f"{s['seconds']:.3f}" for s in steps)
            print(f"{orientations:>9} {threads:3d} threads: {seconds} s", flush=True)
    table = summary(results)
    print(
        f"\n{'orientation':>11} {'threads':>7} {'first s':>8} {'steady s':>8} {'speed-up':>8}"
        f" {'eff. from 4':>11}"
    )
    for row in table:
        efficiency = row.get("efficiency_from_4")
        print(
            f"{row['orientations']:>11} {row['threads']:7d} {row['first_step_s']:8.3f}"
            f" {row['steady_step_s']:8.3f} {row['speedup']:8.2f}"
            f" {'' if efficiency is None else f'{efficiency:.0%}':>11}"
        )
    OUT.mkdir(exist_ok=True)
    setup = vars(args) | {"dt": DT, "warmup_seconds": warmup, "machine": host}
    target = OUT / "grid_threads.json"
    target.write_text(json.dumps({"setup": setup, "runs": results, "summary": table}, indent=2))
    print(f"wrote {target}")


if __name__ == "__main__":
    main()
