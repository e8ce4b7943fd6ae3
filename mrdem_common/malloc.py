"""glibc's allocator kept from returning large blocks to the system after each use.

By default glibc serves every allocation above 128 KiB (adjusting up to 32 MiB) with a fresh
``mmap`` and gives it back with ``munmap`` when freed, so a process that makes and drops
arrays of a few hundred KiB on every request pays a page fault for every 4 KiB page of each,
every time. On the 2-vCPU VMs of BENCHMARKS.md a page fault costs microseconds: encoding a
1,000-pair contact answer (900 KB of msgpack) took 1.24 ms that way and 0.12 ms with the
thresholds below, which keep such blocks in the heap for reuse (the heap is trimmed once
more than ``trim_threshold`` bytes at its top are free).
"""

from __future__ import annotations

import ctypes
import ctypes.util

__all__ = ["keep_large_blocks"]

M_TRIM_THRESHOLD = -1  # glibc's mallopt parameters (malloc.h)
M_MMAP_THRESHOLD = -3


def keep_large_blocks(mmap_threshold: int = 32 * 2**20, trim_threshold: int = 128 * 2**20) -> bool:
    """Serve blocks below ``mmap_threshold`` bytes from the heap and trim the heap only past
    ``trim_threshold`` free bytes (``mallopt``); whether it took effect (False where the C
    library is not glibc)."""
    name = ctypes.util.find_library("c")
    if name is None:
        return False
    try:
        mallopt = ctypes.CDLL(name).mallopt
    except (OSError, AttributeError):
        return False
    mallopt.argtypes, mallopt.restype = [ctypes.c_int, ctypes.c_int], ctypes.c_int
    return bool(mallopt(M_MMAP_THRESHOLD, mmap_threshold)) and bool(
        mallopt(M_TRIM_THRESHOLD, trim_threshold)
    )
