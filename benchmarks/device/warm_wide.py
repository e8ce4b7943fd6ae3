"""Compile the kernels cold on a many-core machine in one process per warm-up section.

``engine.warmup()`` compiles in at most two processes (its two parts): on the 16-core
device machine, whose compiles run about twice as slow as the 2-vCPU VM's, that is minutes
of a lease. This script runs each of the warm-up's sections (``engine.warmup.SECTIONS``:
the batched and the single searches and the triangle sets per precision, two steps of each
scheme, the fits, ``mesh_distance``, the broad phase) in a spawned process of its own, all
at once (kernels two sections share are compiled twice, in parallel), all writing the
shared ``$NUMBA_CACHE_DIR``, then runs ``engine.warmup(1)`` here, which loads them (and
compiles anything they missed) and leaves the warm stamp. Measured on the 16-core machine
(BENCHMARKS.md, issue 18, ninth session; a first version of the sections, one step a
scheme): 100.5 s, then 2.2 s for the warm-up, against 282 s for ``engine.warmup(1)``.
Prints the seconds of each section. Used by ``benchmarks/device/run.sh``; no part of the
service.

    python3 benchmarks/device/warm_wide.py [--workers N]
"""

from __future__ import annotations

import argparse
import importlib
import multiprocessing
import os
import time
from concurrent.futures import ProcessPoolExecutor

import engine

SECTIONS = importlib.import_module("engine.warmup").SECTIONS  # (engine.warmup: the function)


def _run(index: int) -> tuple[str, float]:
    name, function, arguments = SECTIONS[index]
    start = time.perf_counter()
    function(*arguments)
    return name, time.perf_counter() - start


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--workers", type=int, default=min(len(SECTIONS), os.cpu_count() or 1))
    args = parser.parse_args()
    start = time.perf_counter()
    context = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(args.workers, mp_context=context) as pool:
        for name, seconds in pool.map(_run, range(len(SECTIONS))):
            print(f"{name}: {seconds:.1f} s", flush=True)
    wide = time.perf_counter() - start
    loaded = engine.warmup(1)
    print(f"{len(SECTIONS)} sections in {args.workers} processes: {wide:.1f} s")
    print(f"then warmup(1): {loaded:.1f} s")


if __name__ == "__main__":
    main()
