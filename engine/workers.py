"""The worker threads the kernels run on: one pool per requested thread count.

The kernels release the GIL (``nogil``), so host code splits a batch into chunks and runs
them on these threads; a pool per count keeps ``threads=k`` a bound on concurrency.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from threading import Lock

__all__ = ["worker_pool"]

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
