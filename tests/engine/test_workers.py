"""Worker threads: a range split into parts, each row written once, errors raised."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest

from engine.workers import in_parts


@pytest.mark.parametrize("threads", [None, 1, 2, 3, 8])
@pytest.mark.parametrize("rows", [0, 1, 7, 100, 1000])
def test_parts_cover_every_row_once(threads, rows):
    seen = np.zeros(rows, np.int64)
    calls = []

    def task(a: int, b: int) -> None:
        calls.append((a, b, threading.current_thread().name))
        seen[a:b] += 1

    in_parts(threads, rows, task, least=10)
    np.testing.assert_array_equal(seen, np.ones(rows, np.int64))
    parts = sorted(c[:2] for c in calls)
    assert parts[0][0] == 0 and parts[-1][1] == rows
    assert all(p[1] == q[0] for p, q in zip(parts[:-1], parts[1:], strict=True))  # contiguous
    expected = max(1, min(threads or 10**9, rows // 10))
    if threads is not None:
        assert len(calls) == expected
    first = next(c for c in calls if c[0] == 0)
    assert first[2] == threading.current_thread().name  # the first part: no hand-off
    others = [c for c in calls if c[0] > 0]
    assert all(c[2].startswith("mrdem-kernel-") for c in others)


@pytest.mark.parametrize("failing", ["first", "other"])
def test_an_error_in_a_part_is_raised_to_the_caller_after_every_part_ended(failing):
    ended = []

    def task(a: int, b: int) -> None:
        if (a == 0) == (failing == "first"):
            raise ValueError(f"part {a}:{b}")
        time.sleep(0.05)
        ended.append(a)

    with pytest.raises(ValueError, match="part"):
        in_parts(4, 400, task, least=10)
    assert len(ended) == (3 if failing == "first" else 1)
