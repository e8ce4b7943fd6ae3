"""Shared helpers of the benchmark scripts."""

from __future__ import annotations

import os
import platform
import subprocess
import time


def best_time(fn, repeat: int = 5) -> float:
    """Minimum wall time of ``repeat`` calls of ``fn`` (after one warm-up call)."""
    fn()
    times = []
    for _ in range(repeat):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return min(times)


def per_call(fn, calls: int = 200, repeat: int = 7) -> float:
    """Seconds per call of ``fn``: the best of ``repeat`` loops of ``calls`` calls (for
    calls of microseconds, where one call's timing is mostly noise)."""
    fn()
    best = float("inf")
    for _ in range(repeat):
        start = time.perf_counter()
        for _ in range(calls):
            fn()
        best = min(best, (time.perf_counter() - start) / calls)
    return best


def pareto_front(rows: list[dict], cost: str, error: str | tuple[str, ...]) -> list[dict]:
    """The rows no other row beats in ``cost`` and every ``error`` (lower is better): a row
    is dominated by one at most as costly and at most as wrong in every error, and better
    in one of them."""
    keys = (cost, *((error,) if isinstance(error, str) else error))
    return [
        r
        for r in rows
        if not any(all(o[k] <= r[k] for k in keys) and any(o[k] < r[k] for k in keys) for o in rows)
    ]


def machine() -> dict:
    """CPU model, vector ISA and versions of the run."""
    import llvmlite.binding as llvm
    import numba
    import numpy as np

    info = {"python": platform.python_version(), "numpy": np.__version__}

    info["numba"] = numba.__version__
    info["llvm_cpu"] = llvm.get_host_cpu_name()
    info["cores"] = os.cpu_count()
    try:
        lscpu = subprocess.run(["lscpu"], capture_output=True, text=True, check=True).stdout
        for line in lscpu.splitlines():
            if line.startswith("Model name:"):
                info["cpu"] = line.split(":", 1)[1].strip()
            if line.startswith("Flags:"):
                flags = set(line.split(":", 1)[1].split())
                isa = [f for f in ("avx2", "fma", "avx512f", "avx512vl", "avx512dq") if f in flags]
                info["vector_isa"] = " ".join(isa)
    except (OSError, subprocess.CalledProcessError):
        info["cpu"] = platform.processor()
    return info
