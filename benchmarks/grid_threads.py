"""Thread scaling of the paper's sphere grid: steps at 1, 2, 4, 8, 16 threads (issue 15, point 4).

Run: ``.venv/bin/python benchmarks/grid_threads.py [--threads 16 4 8 2 1]
[--orientations vertices aligned] [--steps 3] [--shape 32 32 24] [--phases]``. Prints a
table per run and a summary, writes ``bench-results/grid_threads.json``.

One process: a small grid (125 bodies, enough for the broad phase's cell grid) of each
orientation is stepped first so that every kernel is compiled (or loaded from Numba's
cache) before anything is timed; then, for each thread
count in the order given and each orientation, a fresh scene
(:func:`engine.scenarios.sphere_grid`, 1,224-triangle UV spheres, implicit-surrogate,
dt = 1e-3) is stepped ``--steps`` times. Step 0 builds the pair lists; later steps reuse
them. The summary gives the median of the later steps, the speed-up over the smallest
thread count run and the parallel efficiency from 4 threads to each larger count,
``(t_4 · 4) / (t_n · n)``.

``--phases`` also times, per step, the batch kernel's chunks as the worker threads run
them (by wrapping ``engine.collision.batch``'s kernel entry point, in this process only):
``parallel s`` is the summed wall time from an evaluation's first chunk start to its
last chunk end, ``serial s`` the rest of the step (host work between the kernels),
``busy`` the chunks' summed time over that wall time (threads kept busy; equal to the
thread count when balanced), ``chunk s`` the summed chunk time (grows with the thread
count when cores slow each other down: memory, frequency, allocation).
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import threading
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


class ChunkClock:
    """Start and end (perf_counter) of every batch-kernel chunk, from any thread."""

    def __init__(self) -> None:
        from engine.collision import batch

        self.module, self.kernel = batch.kb, batch.kb.batch_kernel
        self.spans: list[tuple[float, float]] = []
        self._lock = threading.Lock()

    def __enter__(self):
        kernel = self.kernel

        def timed(*args):
            start = time.perf_counter()
            result = kernel(*args)
            end = time.perf_counter()
            with self._lock:
                self.spans.append((start, end))
            return result

        self.module.batch_kernel = timed
        return self

    def __exit__(self, *exc) -> None:
        self.module.batch_kernel = self.kernel

    def phases(self, wall: float) -> dict:
        """Parallel and serial seconds of a step of ``wall`` seconds. An evaluation's
        chunks run back to back on the workers; between evaluations none runs, so the
        spans group into evaluations where a chunk starts after all before it ended."""
        parallel, group_start, group_end = 0.0, None, None
        for start, end in sorted(self.spans):
            if group_end is None or start > group_end:
                if group_end is not None:
                    parallel += group_end - group_start
                group_start, group_end = start, end
            group_end = max(group_end, end)
        if group_end is not None:
            parallel += group_end - group_start
        chunks = sum(e - s for s, e in self.spans)
        return {
            "parallel_s": parallel,
            "serial_s": wall - parallel,
            "chunk_s": chunks,
            "busy": chunks / parallel if parallel > 0 else 0.0,
            "chunks": len(self.spans),
        }


def run(shape, orientations: str, threads: int, steps: int, phases: bool = False) -> list[dict]:
    scene = grid(shape, orientations, threads)
    rows = []
    for index in range(steps):
        clock = ChunkClock() if phases else None
        if clock is None:
            row = scene.step(DT)
        else:
            with clock:
                row = scene.step(DT)
        rows.append(
            {
                "step": index,
                "seconds": row.seconds,
                "picard_iterations": row.picard_iterations,
                "comparisons": row.comparisons,
                "contacts": row.contacts,
            }
            | ({} if clock is None else clock.phases(row.seconds))
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
                "speedup": steady[base] / steady[n],
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
    parser.add_argument("--phases", action="store_true", help="time the kernel chunks too")
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
        run((5, 5, 5), orientations, max(args.threads), 2)  # > 64 bodies: the grid broad phase
    warmup = time.perf_counter() - start
    print(f"warm-up (compile or cache load): {warmup:.1f} s", flush=True)
    results = []
    for threads in args.threads:
        for orientations in args.orientations:
            steps = run(tuple(args.shape), orientations, threads, args.steps, args.phases)
            results.append({"orientations": orientations, "threads": threads, "steps": steps})
            seconds = " ".join(f"{s['seconds']:.3f}" for s in steps)
            print(f"{orientations:>9} {threads:3d} threads: {seconds} s", flush=True)
            for s in steps if args.phases else ():
                print(
                    f"    step {s['step']}: parallel {s['parallel_s']:.3f} s, serial"
                    f" {s['serial_s']:.3f} s, chunk {s['chunk_s']:.3f} s, busy {s['busy']:.1f}"
                    f" of {threads} ({s['chunks']} chunks)",
                    flush=True,
                )
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
