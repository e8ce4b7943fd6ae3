"""The worker threads the kernels run on: one pool per requested thread count.

The kernels release the GIL (``nogil``), so host code splits a batch into chunks and runs
them on these threads; a pool per count keeps ``threads=k`` a bound on concurrency.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor, wait
from threading import Lock

__all__ = ["in_parts", "worker_pool"]

CPUS = os.cpu_count() or 1  # looked up once: os.cpu_count() costs µs per call

_pools: dict[int, ThreadPoolExecutor] = {}
_pools_lock = Lock()


def worker_pool(threads: int) -> ThreadPoolExecutor:
    """The pool of ``threads`` worker threads (created on first use, kept for the process)."""
    with _pools_lock:
        if threads not in _pools:
            _pools[threads] = ThreadPoolExecutor(
                max_workers=threads, thread_name_prefix=f"mrdem-kernel-{threads}"
            )
        return _pools[threads]


def in_parts(
    threads: int | None, rows: int, task: Callable[[int, int], object], least: int = 4096
) -> None:
    """Run ``task(start, stop)`` over ``range(rows)`` in contiguous parts, one per worker
    thread (``threads``; None: all cores), when there are ``least`` rows per thread or
    more; else one call on this thread. The first part runs on this thread while worker
    threads run the others (one hand-off fewer: each costs tens of µs, more where thread
    wake-ups are slow). ``task`` must write only its own rows (a kernel that releases the
    GIL); an exception in a part is raised here, after every part has ended."""
    threads = min(int(threads or CPUS), rows // max(least, 1))
    if threads <= 1:
        task(0, rows)
        return
    bounds = [rows * i // threads for i in range(threads + 1)]
    pool = worker_pool(threads)
    futures = [pool.submit(task, a, b) for a, b in zip(bounds[1:-1], bounds[2:], strict=True)]
    try:
        task(bounds[0], bounds[1])
    finally:
        wait(futures)
    for future in futures:
        future.result()
