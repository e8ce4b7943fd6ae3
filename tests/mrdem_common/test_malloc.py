"""The allocator setting takes effect on glibc: fresh large blocks stop costing page faults
(counted by the kernel, in a child process: the setting lasts for the process)."""

from __future__ import annotations

import platform
import subprocess
import sys

import pytest

from mrdem_common.malloc import keep_large_blocks

PROBE = """
import resource, sys
import numpy as np
from mrdem_common.malloc import keep_large_blocks
if sys.argv[1] == "tuned":
    assert keep_large_blocks()
def fresh():
    blocks = [np.ones(40_000) for _ in range(8)]  # 320 KB each: above glibc's 128 KiB default
    return sum(float(b[-1]) for b in blocks)
fresh()
before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
for _ in range(100):
    fresh()
print(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before)
"""


def _page_faults(mode: str) -> int:
    run = subprocess.run([sys.executable, "-c", PROBE, mode], capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    return int(run.stdout)


@pytest.mark.skipif(platform.libc_ver()[0] != "glibc", reason="mallopt is glibc's")
def test_large_blocks_are_reused_instead_of_mapped_again():
    assert keep_large_blocks() is True
    assert keep_large_blocks(64 * 2**20, 256 * 2**20) is True
    default, tuned = _page_faults("default"), _page_faults("tuned")
    assert default > 100 * 8 * 50  # 800 fresh blocks of 79 pages each, mapped anew
    assert tuned < default / 20  # the blocks are reused
