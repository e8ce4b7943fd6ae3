"""The kernel cache key (engine/kernels/jit.py): a hash of every kernel source file, so that
an edit anywhere under engine/kernels — a helper inlined from a sibling folder included —
selects a fresh Numba cache directory instead of stale machine code."""

from __future__ import annotations

import shutil
from pathlib import Path

import numba
import numpy as np
import pytest

from engine.kernels import jit

KERNELS = Path(jit.__file__).parent


def copy_of_the_kernels(tmp_path: Path) -> Path:
    root = tmp_path / "kernels"
    shutil.copytree(KERNELS, root, ignore=shutil.ignore_patterns("__pycache__"))
    return root


def test_the_cache_directory_is_named_by_the_hash_of_these_sources():
    assert jit.source_hash(KERNELS) == jit.KERNEL_SOURCE_HASH
    assert numba.config.CACHE_DIR.endswith(f"kernels-{jit.KERNEL_SOURCE_HASH}")
    nested = sorted(p.relative_to(KERNELS).as_posix() for p in KERNELS.rglob("*.py"))
    assert any("/" in name for name in nested)  # the kernels live in sub-folders


def test_an_edit_in_any_kernel_folder_changes_the_hash(tmp_path):
    root = copy_of_the_kernels(tmp_path)
    original = jit.source_hash(root)
    assert original == jit.KERNEL_SOURCE_HASH
    for path in sorted(root.rglob("*.py")):
        text = path.read_bytes()
        path.write_bytes(text + b"\n")
        assert jit.source_hash(root) != original, path.relative_to(root)
        path.write_bytes(text)
    assert jit.source_hash(root) == original


def test_moving_or_adding_a_kernel_file_changes_the_hash(tmp_path):
    root = copy_of_the_kernels(tmp_path)
    original = jit.source_hash(root)
    rotation = root / "geometry" / "rotation.py"
    moved = root / "collision" / "rotation.py"
    rotation.rename(moved)
    assert jit.source_hash(root) != original
    moved.rename(rotation)
    assert jit.source_hash(root) == original
    (root / "dynamics" / "extra.py").write_text("X = 1\n")
    assert jit.source_hash(root) != original


def test_only_tail_masked_kernels_run_their_last_lanes_masked():
    """A ``tail_masked`` loop is compiled with masked (predicated) vector lanes and no
    scalar remainder; the same loop unmarked, compiled right after, keeps LLVM's scalar
    remainder (the option is set for the marked kernel's optimisation only). AVX-512
    hosts: mask registers make the masked lanes visible in the assembly."""
    if not jit.HOST_AVX512:
        pytest.skip("masked lanes are told apart by AVX-512 mask registers")

    def masked_scale(x, m, out):
        for t in range(m):
            out[t] = 2.5 * x[t]

    def plain_scale(x, m, out):
        for t in range(m):
            out[t] = 2.5 * x[t]

    signature = (numba.float64[::1], numba.int64, numba.float64[::1])
    options = {**jit.DISTINCT, "cache": False}
    masked = numba.njit(signature, **options)(jit.tail_masked(masked_scale))
    plain = numba.njit(signature, **options)(plain_scale)
    masked_asm = masked.inspect_asm(masked.signatures[0])
    plain_asm = plain.inspect_asm(plain.signatures[0])
    assert "{%k" in masked_asm and "vmulsd" not in masked_asm
    assert "vmulsd" in plain_asm
    x, out = np.arange(5.0), np.zeros(5)
    masked(x, 5, out)
    np.testing.assert_array_equal(out, 2.5 * x)


STACK_ROWS = 4
STACK_SIZE = 2 * STACK_ROWS  # a constant: an expression in the kernel is not one


@numba.njit
def _stacked(values, rows):
    """Sums of ``values`` in ``rows`` slots: a (STACK_ROWS, 2) buffer in the frame, replaced
    by a heap array when ``rows`` is larger."""
    buffer = numba.carray(jit.stack_buffer(STACK_SIZE, np.float64), (STACK_ROWS, 2))
    if rows > STACK_ROWS:
        buffer = np.empty((rows, 2))
    buffer[:rows] = 0.0
    for k in range(values.shape[0]):
        buffer[k % rows, 0] += values[k]
        buffer[k % rows, 1] += 1.0
    return buffer[:rows].copy()


@pytest.mark.parametrize("rows", [1, STACK_ROWS, STACK_ROWS + 3])
def test_a_stack_buffer_holds_what_is_written_and_can_be_replaced_by_a_heap_one(rows):
    values = np.arange(1.0, 23.0)
    got = _stacked(values, rows)
    for r in range(rows):
        np.testing.assert_array_equal(got[r], [values[r::rows].sum(), len(values[r::rows])])


def test_a_stack_buffer_needs_a_constant_positive_size():
    @numba.njit
    def sized(n):
        return numba.carray(jit.stack_buffer(n, np.float64), (1,))[0]

    with pytest.raises(numba.core.errors.TypingError):
        sized(4)
