"""Exact distances and closest points of triangle pairs in blocks, and the pair-local
frame every batch kernel evaluates a pair in (split from
:mod:`~engine.kernels.geometry.triangle_batch`, which imports them; the layout of
triangle sets and frames is described there).

A pair (i, j) is evaluated in a frame whose origin is vertex 0 of its A triangle
(:func:`_pair`); points are shifted back to the input frame on output.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from engine.kernels.geometry.triangle_exact import exact_pair
from engine.kernels.jit import INLINE, JIT, sqrt

BLOCK = 256  # pairs per block of the batch kernels (and rows of :func:`point_rows`)


@njit(**INLINE)
def _frame(f, i):
    return (
        (f[0, i], f[1, i], f[2, i]),
        (f[3, i], f[4, i], f[5, i]),
        (f[6, i], f[7, i], f[8, i]),
        (f[9, i], f[10, i], f[11, i]),
        f[12, i] != 0,
    )


@njit(**INLINE)
def _pair(a, i, b, j):
    """Origin (A's vertex 0) and both triangles of pair (i, j) in its local frame."""
    ox, oy, oz = a[0, i], a[1, i], a[2, i]
    return (
        (ox, oy, oz),
        (ox - ox, oy - oy, oz - oz),
        (a[3, i] - ox, a[4, i] - oy, a[5, i] - oz),
        (a[6, i] - ox, a[7, i] - oy, a[8, i] - oz),
        (b[0, j] - ox, b[1, j] - oy, b[2, j] - oz),
        (b[3, j] - ox, b[4, j] - oy, b[5, j] - oz),
        (b[6, j] - ox, b[7, j] - oy, b[8, j] - oz),
    )


@njit(**JIT)
def exact_paired(a, fa, b, fb, m, one, dist):
    """Exact distance ``dist[t]`` of pairs (t, t), ``0 ≤ t < m``.

    Distances only: with point outputs too, LLVM's runtime overlap checks send
    the loop down its scalar path (10× slower). Closest points come from
    :func:`exact_point` for the pairs that need them. (The loop bodies of these
    kernels repeat a few lines on purpose: in a shared inlined helper that takes
    the arrays, the loop stops vectorising. Block kernels start at 0: with a
    run-time start the vectorised loop ran up to 5× slower.)
    """
    for t in range(m):
        o, a0, a1, a2, b0, b1, b2 = _pair(a, t, b, t)
        dist[t] = sqrt(exact_pair(a0, a1, a2, _frame(fa, t), b0, b1, b2, _frame(fb, t), one)[0])


@njit(**JIT)
def exact_rows(a, fa, i, b, fb, one, dist):
    """Exact distance ``dist[j]`` of pairs (i, j) for every j."""
    for j in range(b.shape[1]):
        o, a0, a1, a2, b0, b1, b2 = _pair(a, i, b, j)
        dist[j] = sqrt(exact_pair(a0, a1, a2, _frame(fa, i), b0, b1, b2, _frame(fb, j), one)[0])


@njit(**JIT)
def exact_points(a, fa, b, fb, m, one, d, pax, pay, paz, pbx, pby, pbz):
    """Exact distance ``d[t]`` and closest points ``(pax, pay, paz)[t]`` on A and ``(pbx,
    pby, pbz)[t]`` on B (input frame) of pairs (t, t), ``0 ≤ t < m``: :func:`exact_point`'s
    values, vectorised. Outputs: seven ``(≥ m,)`` rows of ``a``'s dtype placed as
    :func:`point_rows` places them (one 2-D output, or rows allocated one after another,
    keep LLVM on the scalar path or thrash the cache: as slow as ``exact_point``)."""
    for t in range(m):
        o, a0, a1, a2, b0, b1, b2 = _pair(a, t, b, t)
        d2, p, q = exact_pair(a0, a1, a2, _frame(fa, t), b0, b1, b2, _frame(fb, t), one)
        d[t] = sqrt(d2)
        pax[t], pay[t], paz[t] = p[0] + o[0], p[1] + o[1], p[2] + o[2]
        pbx[t], pby[t], pbz[t] = q[0] + o[0], q[1] + o[1], q[2] + o[2]


@njit(**JIT)
def point_rows(like):
    """Seven ``(BLOCK,)`` rows of ``like``'s dtype for :func:`exact_points`, in one
    allocation, the first on a 64-byte boundary and each 4 KiB + 64 bytes after the one
    before. Measured on the paper's grid (float64, AVX2), for 414 pairs a body pair: 4 KiB +
    64 bytes apart 65–80 µs; half that spacing, or rows placed as
    :mod:`~engine.kernels.geometry.triangle_paired` places its own, 100–175 µs (the
    scalar ``exact_point``'s speed)."""
    spacing = (4096 + 64) // like.itemsize
    line = 64 // like.itemsize
    flat = np.empty(6 * spacing + BLOCK + line, like.dtype)
    misaligned = np.int64(flat.ctypes.data % np.uint64(64))  # bytes past a boundary
    at = ((64 - misaligned) % 64) // like.itemsize
    return (
        flat[at : at + BLOCK],
        flat[at + spacing : at + spacing + BLOCK],
        flat[at + 2 * spacing : at + 2 * spacing + BLOCK],
        flat[at + 3 * spacing : at + 3 * spacing + BLOCK],
        flat[at + 4 * spacing : at + 4 * spacing + BLOCK],
        flat[at + 5 * spacing : at + 5 * spacing + BLOCK],
        flat[at + 6 * spacing : at + 6 * spacing + BLOCK],
    )


@njit(**JIT)
def exact_point(a, fa, i, b, fb, j, one):
    """Exact ``(distance, p, q)`` of one pair (i, j); points in the input frame."""
    o, a0, a1, a2, b0, b1, b2 = _pair(a, i, b, j)
    d2, p, q = exact_pair(a0, a1, a2, _frame(fa, i), b0, b1, b2, _frame(fb, j), one)
    return (
        sqrt(d2),
        (p[0] + o[0], p[1] + o[1], p[2] + o[2]),
        (q[0] + o[0], q[1] + o[1], q[2] + o[2]),
    )
