"""Triangle preparation and the paired distance form, from raw vertex arrays.

Preparation (what :class:`~engine.geometry.triangle_set.TriangleSet` holds): each triangle's
vertices are rotated (orientation kept) so that vertex 0 sits opposite its longest edge
(the first longest, as ``numpy.argmax`` picks it), and its frame (rows of
:func:`~engine.kernels.geometry.triangle_batch.frames_kernel`) is computed in float64 from
the float64 coordinates, then both are rounded to the kernel precision. The same pass
validates the coordinates: it counts triangles with a coordinate that is not finite or
beyond ``limit`` (the host then reports the first one).

The paired form (:func:`paired_kernel`) prepares pairs a block at a time into block
buffers (or copies blocks of prepared sets) and evaluates them there, so nothing of size
``n`` but the results is written. Closest points are vectorised:
:func:`~engine.kernels.geometry.triangle_points.exact_points` stores distance and points
into seven one-dimensional rows (with one two-dimensional output LLVM gives up on the
loop: "unsafe indirect dependence"), placed as :func:`workspace` says. Hybrid fallbacks
are queued across blocks and resolved a full block at a time by the same loop. Results equal
:func:`~engine.kernels.geometry.triangle_batch.paired_kernel`'s on sets prepared from the
same triangles, bit for bit.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from engine.kernels.geometry.triangle_batch import (
    BLOCK,
    CONTACT,
    EXACT,
    HYBRID,
    NO_CONTACT,
    NOT_CONVERGED,
    STAT_FALLBACKS,
    STAT_ITERATIVE,
    STAT_PAIRS,
    ZERO,
    _conditioning,
    copy_columns,
    iterate_paired,
)
from engine.kernels.geometry.triangle_exact import triangle_frame
from engine.kernels.geometry.triangle_iterative import classify
from engine.kernels.geometry.triangle_points import exact_points
from engine.kernels.jit import INLINE, JIT, select


@njit(**INLINE)
def prepared_triangle(p, q, r, limit, tiny, one):
    """One triangle prepared in registers, in the float type of ``one`` (1 in it): the
    arithmetic of every preparation (:func:`prepare_block` here and
    ``paired_fused.load_prepared`` in float64; ``paired_fused.load_native`` in the kernel
    precision).

    ``p, q, r`` the vertices as ``(x, y, z)`` tuples; ``limit``, ``tiny`` (as
    :func:`prepare_block`), all of the type of ``one``. Returns ``(ok, v0, v1, v2, frame,
    kappa)``: ``ok`` False when a coordinate is NaN or beyond ``±limit``; the vertices
    rotated (orientation kept) so that ``v0`` sits opposite the first longest edge; the
    :func:`~engine.kernels.geometry.triangle_exact.triangle_frame` tuple of the rotated
    triangle; ``kappa`` its conditioning (1 for slivers). Values a caller does not use
    (the inverse edge lengths, ``kappa``) cost nothing: LLVM drops them.
    """
    ok = (abs(p[0]) <= limit) & (abs(p[1]) <= limit) & (abs(p[2]) <= limit)
    ok = ok & (abs(q[0]) <= limit) & (abs(q[1]) <= limit) & (abs(q[2]) <= limit)
    ok = ok & (abs(r[0]) <= limit) & (abs(r[1]) <= limit) & (abs(r[2]) <= limit)
    ax, ay, az = r[0] - q[0], r[1] - q[1], r[2] - q[2]
    bx, by, bz = p[0] - r[0], p[1] - r[1], p[2] - r[2]
    cx, cy, cz = q[0] - p[0], q[1] - p[1], q[2] - p[2]
    l0 = ax * ax + ay * ay + az * az  # squared length of the edge opposite vertex 0
    l1 = bx * bx + by * by + bz * bz
    l2 = cx * cx + cy * cy + cz * cz
    first0 = (l0 >= l1) & (l0 >= l2)
    first1 = ~first0 & (l1 >= l2)
    v0 = select(first0, p, select(first1, q, r))
    v1 = select(first0, q, select(first1, r, p))
    v2 = select(first0, r, select(first1, p, q))
    frame = triangle_frame(v0, v1, v2, one, tiny)
    kappa = select(frame[4], _conditioning(v0, v1, v2, one, tiny), one)
    return ok, v0, v1, v2, frame, kappa


@njit(**JIT)
def prepare_block(src, m, limit, tiny, coords, frames):
    """Prepare triangles ``src[k]``, ``k < m``, into column ``k`` of ``coords (9, ≥m)`` and
    ``frames (14, ≥m)`` (the dtype of those two). (Columns start at 0: with a run-time
    offset the loop runs 4× slower.)

    ``src (≥m, 3, 3)`` float32 or float64; ``limit`` float64, the largest admissible
    coordinate magnitude; ``tiny`` float64, the sliver threshold on sin² (64 ulp of the
    kernel precision). Returns the number of triangles with a coordinate that is NaN or
    beyond ``±limit`` (int64); their columns hold garbage.
    """
    one = 1.0
    good = True  # a bool reduction: an int64 counter would cap the loop at 4 lanes
    for k in range(m):
        p = (np.float64(src[k, 0, 0]), np.float64(src[k, 0, 1]), np.float64(src[k, 0, 2]))
        q = (np.float64(src[k, 1, 0]), np.float64(src[k, 1, 1]), np.float64(src[k, 1, 2]))
        r = (np.float64(src[k, 2, 0]), np.float64(src[k, 2, 1]), np.float64(src[k, 2, 2]))
        ok, v0, v1, v2, (n, g1, g2, il, valid), kappa = prepared_triangle(p, q, r, limit, tiny, one)
        good = good & ok
        coords[0, k], coords[1, k], coords[2, k] = v0
        coords[3, k], coords[4, k], coords[5, k] = v1
        coords[6, k], coords[7, k], coords[8, k] = v2
        frames[13, k] = kappa
        frames[0, k], frames[1, k], frames[2, k] = n
        frames[3, k], frames[4, k], frames[5, k] = g1
        frames[6, k], frames[7, k], frames[8, k] = g2
        frames[9, k], frames[10, k], frames[11, k] = il
        frames[12, k] = select(valid, one, one - one)
    if good:
        return ZERO
    bad = ZERO
    for k in range(m):
        for c in range(9):
            if not abs(np.float64(src[k, c // 3, c % 3])) <= limit:
                bad += 1
                break
    return bad


@njit(**JIT)
def count_invalid(flat, limit):
    """Triangles of ``flat (9n,)`` (float32 or float64, 9 coordinates each) with a coordinate
    that is NaN or beyond ``±limit`` (int64): the slow path of the fused pair loops, which
    only reduce "all valid"."""
    bad = ZERO
    for k in range(len(flat) // 9):
        ok = True
        for c in range(9):
            ok = ok & (abs(np.float64(flat[9 * k + c])) <= limit)
        bad += select(ok, ZERO, np.int64(1))
    return bad


@njit(**JIT)
def prepare_kernel(raw, start, stop, limit, tiny, coords, frames):
    """Prepare triangles ``raw[t]``, ``start ≤ t < stop``, into columns ``t`` of
    ``coords (9, n)`` and ``frames (14, n)`` (one float dtype).

    ``raw (n, 3, 3)`` float32 or float64; ``limit``, ``tiny`` as :func:`prepare_block`.
    Returns the number of invalid triangles in the range (int64).
    """
    gc = np.empty((9, BLOCK), coords.dtype)
    gf = np.empty((14, BLOCK), coords.dtype)
    bad = ZERO
    for t0 in range(start, stop, BLOCK):
        t1 = min(t0 + BLOCK, stop)
        m = t1 - t0
        bad += prepare_block(raw[t0:t1], m, limit, tiny, gc, gf)
        _put_columns(gc, m, coords, t0)
        _put_columns(gf, m, frames, t0)
    return bad


@njit(**JIT)
def _put_columns(src, m, dst, t0):
    """``dst[:, t0 + k] = src[:, k]`` for ``k < m``."""
    for c in range(src.shape[0]):
        row = dst[c, t0 : t0 + m]
        for k in range(m):
            row[k] = src[c, k]


@njit(**JIT)
def transpose_kernel(src, start, stop, dst):
    """``dst[t, c] = src[c, t]`` for ``start ≤ t < stop``: ``src (k, n)``, ``dst (n, k)``."""
    for t in range(start, stop):
        for c in range(src.shape[0]):
            dst[t, c] = src[c, t]


@njit(**JIT)
def workspace(like):
    """Buffers of :func:`paired_kernel`, floats of the dtype of ``like``: ``(101, BLOCK)``
    rows (0–45 a block of pairs: coords and frames of A, of B; 46–54 the iterative kernel's
    scratch; 55–100 the queue of fallback pairs), and the seven output rows of
    :func:`~engine.kernels.geometry.triangle_points.exact_points`.

    The output rows lie 4 KiB plus an irregular multiple of 64 bytes apart in one
    allocation. Measured (AVX2, float32, 256 pairs): with the seven rows of a 2-D array, or
    seven arrays allocated one after another, the vectorised loop ran at 200–370 ns a pair
    (as slow as the scalar ``exact_point``); with rows placed like this, 45 ns.
    """
    f = like.dtype
    page = 4096 // like.itemsize
    pad = 64 // like.itemsize
    flat = np.empty(7 * page + 7 * pad + BLOCK, f)
    out = []
    for r in range(7):
        at = r * page + ((r * 37) % 7) * pad
        out.append(flat[at : at + BLOCK])
    rows = (out[0], out[1], out[2], out[3], out[4], out[5], out[6])
    return np.empty((101, BLOCK), f), rows


@njit(**JIT)
def _fetch(side, raw, coords, frames, t0, m, limit, tiny, gc, gf):
    """Block ``[t0, t0 + m)`` of one side into ``gc``, ``gf``: prepared from ``raw`` when
    ``side`` is 0, copied from the prepared ``coords``, ``frames`` otherwise. Returns the
    number of invalid raw triangles."""
    if side == 0:
        return prepare_block(raw[t0 : t0 + m], m, limit, tiny, gc, gf)
    copy_columns(coords, t0, m, gc)
    copy_columns(frames, t0, m, gf)
    return ZERO


@njit(**JIT)
def _resolve_queue(c, one, qa, qfa, qb, qfb, qt, res, distance, lower, point_a, point_b):
    """Exact distance and points of the ``c`` queued pairs, written to rows ``qt[k]``;
    ``res`` seven ``(BLOCK,)`` work arrays."""
    r0, r1, r2, r3, r4, r5, r6 = res
    exact_points(qa, qfa, qb, qfb, c, one, r0, r1, r2, r3, r4, r5, r6)
    for k in range(c):
        t = qt[k]
        distance[t] = r0[k]
        lower[t] = r0[k]
        point_a[t, 0], point_a[t, 1], point_a[t, 2] = r1[k], r2[k], r3[k]
        point_b[t, 0], point_b[t, 1], point_b[t, 2] = r4[k], r5[k], r6[k]


@njit(**JIT)
def paired_kernel(
    a_in, b_in, eps, start, stop, params, limit, distance, lower, point_a, point_b, status, stats
):
    """Distances of pairs ``(t, t)``, ``start ≤ t < stop``, each side raw or prepared.

    ``a_in = (side, raw, coords, frames)``: ``side`` 0 for raw triangles ``raw (n, 3, 3)``
    (float32 or float64; prepared here, block by block), 1 for a prepared set ``coords
    (9, n)``, ``frames (14, n)``; the arrays of the other kind may be empty. Likewise
    ``b_in``. ``eps (n,)`` contact distances and every float output in the kernel dtype;
    ``params = (mode, iterations, rtol, one, band_factor)``; ``limit`` float64 (as
    :func:`prepare_block`). Outputs ``distance, lower (n,)``, ``point_a, point_b (n, 3)``,
    ``status (n,)`` int8, as in :func:`~engine.kernels.geometry.triangle_batch.paired_kernel`;
    ``stats (N_STATS,)`` int64, added to. Returns the number of invalid raw triangles
    (outputs are then meaningless).
    """
    mode, iterations, rtol, one, band_factor = params
    side_a, raw_a, coords_a, frames_a = a_in
    side_b, raw_b, coords_b, frames_b = b_in
    tiny = np.float64(band_factor)
    ws, res = workspace(eps)
    ga, gfa, gb, gfb = ws[0:9], ws[9:23], ws[23:32], ws[32:46]
    scratch = ws[46:55]
    qa, qfa, qb, qfb = ws[55:64], ws[64:78], ws[78:87], ws[87:101]
    r0, r1, r2, r3, r4, r5, r6 = res
    qt = np.empty(BLOCK, np.int64)
    bad = ZERO
    c = ZERO
    stats[STAT_PAIRS] += stop - start
    for t0 in range(start, stop, BLOCK):
        t1 = min(t0 + BLOCK, stop)
        m = t1 - t0
        bad += _fetch(side_a, raw_a, coords_a, frames_a, t0, m, limit, tiny, ga, gfa)
        bad += _fetch(side_b, raw_b, coords_b, frames_b, t0, m, limit, tiny, gb, gfb)
        if mode == EXACT:
            exact_points(ga, gfa, gb, gfb, m, one, r0, r1, r2, r3, r4, r5, r6)
            for k in range(m):
                t = t0 + k
                d = r0[k]
                distance[t] = d
                lower[t] = d
                status[t] = select(d <= eps[t], CONTACT, NO_CONTACT)
                point_a[t, 0], point_a[t, 1], point_a[t, 2] = r1[k], r2[k], r3[k]
                point_b[t, 0], point_b[t, 1], point_b[t, 2] = r4[k], r5[k], r6[k]
            continue
        iterate_paired(ga, gfa, gb, gfb, m, iterations, one, band_factor, scratch)
        stats[STAT_ITERATIVE] += m
        for k in range(m):
            t = t0 + k
            upper, low, band = scratch[6, k], scratch[7, k], scratch[8, k]
            st = classify(upper, low, eps[t], rtol * eps[t] + band, band)
            status[t] = st
            distance[t] = upper
            lower[t] = low
            ox, oy, oz = ga[0, k], ga[1, k], ga[2, k]
            point_a[t, 0], point_a[t, 1], point_a[t, 2] = (
                scratch[0, k] + ox,
                scratch[1, k] + oy,
                scratch[2, k] + oz,
            )
            point_b[t, 0], point_b[t, 1], point_b[t, 2] = (
                scratch[3, k] + ox,
                scratch[4, k] + oy,
                scratch[5, k] + oz,
            )
            if st == NOT_CONVERGED and mode == HYBRID:
                stats[STAT_FALLBACKS] += 1
                for r in range(9):
                    qa[r, c] = ga[r, k]
                    qb[r, c] = gb[r, k]
                for r in range(14):
                    qfa[r, c] = gfa[r, k]
                    qfb[r, c] = gfb[r, k]
                qt[c] = t
                c += 1
                if c == BLOCK:
                    _resolve_queue(
                        c, one, qa, qfa, qb, qfb, qt, res, distance, lower, point_a, point_b
                    )
                    c = ZERO
    if c > 0:
        _resolve_queue(c, one, qa, qfa, qb, qfb, qt, res, distance, lower, point_a, point_b)
    return bad
