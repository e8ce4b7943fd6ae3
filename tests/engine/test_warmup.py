"""engine.warmup: parts, workers, the stamp of a completed warm-up, the collector's
thresholds while compiling, and the small scene's warm-up."""

from __future__ import annotations

import gc
import importlib
import os
import subprocess
import sys

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


#: Python run after a probe's set-up: every kernel dispatched for the first time in this
#: process from here on (loaded from the cache or compiled) is noted in ``dispatched``.
NOTE_DISPATCHES = """
import numba.core.dispatcher as dispatcher

dispatched = []
first_call = dispatcher.Dispatcher._compile_for_args


def noted(self, *args, **kwargs):
    dispatched.append(self.py_func.__qualname__)
    return first_call(self, *args, **kwargs)


dispatcher.Dispatcher._compile_for_args = noted
"""


def _dispatched(set_up: str, then: str) -> str:
    """In a fresh process: ``set_up``, then ``then``; the kernels ``then`` dispatched for
    the first time, as ``dispatched: name name …``."""
    probe = f"{set_up}\n{NOTE_DISPATCHES}\n{then}\nprint('dispatched:', ' '.join(dispatched))"
    found = subprocess.run(
        [sys.executable, "-c", probe], capture_output=True, text=True, timeout=600
    )
    assert found.returncode == 0, found.stderr[-3000:]
    return found.stdout.strip().splitlines()[-1]


def test_a_warmed_scene_process_loads_no_other_kernel_for_another_scene():
    """After :func:`engine.warm_scene` (a fresh process), building another scene of other
    meshes, stepping it with the default scheme and setting its state dispatch no kernel
    for the first time: the warm-up loaded all of them."""
    set_up = "import engine\nfrom engine import Scene, shapes\nengine.warm_scene()"
    then = """
scene = Scene(gravity=(0.0, 0.0, -9.81))
scene.add_plane(size=4.0, divisions=2)
scene.add_body(shapes.icosphere(2, radius=0.5), position=(0.0, 0.0, 0.52))
scene.add_body(shapes.box(), position=(1.0, 0.0, 0.51))
for _ in range(3):
    scene.step(1e-3)
scene.set_state(positions=scene.positions)
scene.step(1e-3)
"""
    assert _dispatched(set_up, then) == "dispatched:"


def test_the_sections_alone_dispatch_every_kernel_of_the_parts():
    """In a fresh process, every section of :data:`SECTIONS` run alone, then the parts: the
    parts dispatch no kernel for the first time (benchmarks/device/warm_wide.py compiles
    the sections in processes of their own and counts on it)."""
    set_up = """
import importlib
warmup = importlib.import_module("engine.warmup")
for name, function, arguments in warmup.SECTIONS:
    function(*arguments)
"""
    assert _dispatched(set_up, "for part in warmup.PARTS:\n    part()") == "dispatched:"
