"""engine.warmup: parts, workers, the stamp of a completed warm-up, and the collector's
thresholds while compiling."""

from __future__ import annotations

import gc
import importlib
import os

import numba
import pytest

from engine.errors import InvalidArgumentError

warmup_module = importlib.import_module("engine.warmup")  # engine.warmup is also the function


@pytest.fixture
def empty_cache(tmp_path, monkeypatch):
    """A kernel cache directory of its own (fake parts must not stamp the real one)."""
    monkeypatch.setattr(numba.config, "CACHE_DIR", str(tmp_path / "kernels-test"))
    return tmp_path / "kernels-test"


def test_parts_run_with_the_compile_thresholds_and_the_old_ones_come_back(monkeypatch, empty_cache):
    seen = []
    parts = tuple(lambda k=k: seen.append((k, gc.get_threshold())) for k in range(2))
    monkeypatch.setattr(warmup_module, "PARTS", parts)
    before = gc.get_threshold()
    assert before != warmup_module.COMPILE_GC_THRESHOLDS
    seconds = warmup_module.warmup(workers=1)
    assert seconds >= 0.0
    assert seen == [(k, warmup_module.COMPILE_GC_THRESHOLDS) for k in range(2)]
    assert gc.get_threshold() == before


def test_the_thresholds_come_back_when_a_part_fails(monkeypatch, empty_cache):
    def broken():
        raise RuntimeError("a part failed")

    monkeypatch.setattr(warmup_module, "PARTS", (broken,))
    before = gc.get_threshold()
    with pytest.raises(RuntimeError, match="a part failed"):
        warmup_module.warmup(workers=1)
    assert gc.get_threshold() == before
    assert not warmup_module.warm_stamp().exists()  # a failed warm-up is not warm


def test_a_completed_warm_up_stamps_its_cache_and_then_loads_in_one_process(
    monkeypatch, empty_cache
):
    monkeypatch.setattr(warmup_module, "PARTS", (lambda: None, lambda: None))
    assert warmup_module.default_workers() == min(2, os.cpu_count() or 1)
    assert not warmup_module.warm_stamp().exists()
    warmup_module.warmup(workers=1)
    stamp = warmup_module.warm_stamp()
    assert stamp.exists() and stamp.parent == empty_cache
    assert warmup_module.default_workers() == 1


def test_the_real_warm_up_leaves_the_stamp_of_the_real_cache():
    warmup_module.warmup(workers=1)  # the session's cache is warm: this loads every kernel
    assert warmup_module.warm_stamp().exists()
    assert warmup_module.default_workers() == 1


def test_the_stamp_names_the_warm_up_source_and_the_compiler(monkeypatch, empty_cache):
    first = warmup_module.warm_stamp()
    monkeypatch.setattr(numba, "__version__", numba.__version__ + ".other")
    assert warmup_module.warm_stamp() != first


@pytest.mark.parametrize("workers", [0, len(warmup_module.PARTS) + 1])
def test_a_worker_count_out_of_range_is_refused(workers):
    with pytest.raises(InvalidArgumentError, match="workers must be"):
        warmup_module.warmup(workers)
