"""Shared helpers of the benchmark scripts."""

from __future__ import annotations

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
