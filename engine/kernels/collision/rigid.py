"""Per-query set-up of a body pair: moving prepared triangles rigidly, margins on ε.

:func:`move_kernel` is compiled without fast-math and is never inlined: the flat
search and the multiresolution search (moving B's nodes lazily, a level's newly
reached nodes at a time) both move B's triangles with it and must see identical
bits, whatever code LLVM generates around the call.
"""

from __future__ import annotations

from numba import njit

from engine.kernels.jit import EXACT_JIT, JIT


@njit(**EXACT_JIT)
def move_kernel(coords, frames, index, rotation, shift, coords_out, frames_out):
    """Move triangles ``index (k,)`` (int64) by ``x ↦ rotation @ x + shift``.

    ``coords (N, 9)`` and ``frames (N, 14)`` float64, row-major (see
    :mod:`~engine.kernels.geometry.triangle_batch`); frame vectors (normal, dual basis:
    columns 0–8) rotate, the scalars (columns 9–13) are copied. Results are
    rounded to the dtype of ``coords_out (N, 9)`` and ``frames_out (N, 14)``
    (rows not in ``index`` are left as they are).
    """
    r = rotation
    for t in range(index.shape[0]):
        i = index[t]
        for v in range(3):
            x, y, z = coords[i, 3 * v], coords[i, 3 * v + 1], coords[i, 3 * v + 2]
            for c in range(3):
                coords_out[i, 3 * v + c] = r[c, 0] * x + r[c, 1] * y + r[c, 2] * z + shift[c]
            x, y, z = frames[i, 3 * v], frames[i, 3 * v + 1], frames[i, 3 * v + 2]
            for c in range(3):
                frames_out[i, 3 * v + c] = r[c, 0] * x + r[c, 1] * y + r[c, 2] * z
        for c in range(9, 14):
            frames_out[i, c] = frames[i, c]


@njit(**JIT)
def margin_kernel(epsilon, face, margin, out):
    """``out[i] = epsilon[i] + margin`` for surrogates (``face[i] < 0``), else ``epsilon[i]``;
    rounded to the dtype of ``out``."""
    for i in range(epsilon.shape[0]):
        out[i] = epsilon[i] + (margin if face[i] < 0 else 0.0)
