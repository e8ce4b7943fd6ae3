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


def pareto_front(rows: list[dict], cost: str, error: str) -> list[dict]:
    """The rows no other row beats in both ``cost`` and ``error`` (lower is better)."""
    return [
        r
        for r in rows
        if not any(
            o[cost] <= r[cost]
            and o[error] <= r[error]
            and (o[cost] < r[cost] or o[error] < r[error])
            for o in rows
        )
    ]
