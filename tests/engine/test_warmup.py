"""engine.warmup: parts, workers, and the collector's thresholds while compiling."""

from __future__ import annotations

import gc
import importlib

import pytest

from engine.errors import InvalidArgumentError

warmup_module = importlib.import_module("engine.warmup")  # engine.warmup is also the function


def test_parts_run_with_the_compile_thresholds_and_the_old_ones_come_back(monkeypatch):
    seen = []
    parts = tuple(lambda k=k: seen.append((k, gc.get_threshold())) for k in range(2))
    monkeypatch.setattr(warmup_module, "PARTS", parts)
    before = gc.get_threshold()
    assert before != warmup_module.COMPILE_GC_THRESHOLDS
    seconds = warmup_module.warmup(workers=1)
    assert seconds >= 0.0
    assert seen == [(k, warmup_module.COMPILE_GC_THRESHOLDS) for k in range(2)]
    assert gc.get_threshold() == before


def test_the_thresholds_come_back_when_a_part_fails(monkeypatch):
    def broken():
        raise RuntimeError("a part failed")

    monkeypatch.setattr(warmup_module, "PARTS", (broken,))
    before = gc.get_threshold()
    with pytest.raises(RuntimeError, match="a part failed"):
        warmup_module.warmup(workers=1)
    assert gc.get_threshold() == before


@pytest.mark.parametrize("workers", [0, len(warmup_module.PARTS) + 1])
def test_a_worker_count_out_of_range_is_refused(workers):
    with pytest.raises(InvalidArgumentError, match="workers must be"):
        warmup_module.warmup(workers)
