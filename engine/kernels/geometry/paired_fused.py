"""The paired form on raw triangle arrays, preparation fused into the pair loop.

:func:`paired_raw_kernel` evaluates pairs ``(raw_a[t], raw_b[t])`` from flat views of the
caller's ``(n, 3, 3)`` arrays, a block of :data:`CHUNK` pairs per call, without the
block-buffer round trip of :mod:`~engine.kernels.geometry.triangle_paired`. Each triangle is
rotated (largest angle at vertex 0) and its frame computed in float64 by
:func:`load_prepared` (the arithmetic of ``triangle_paired.prepare_block``), then rounded to
the kernel precision.

* :func:`iterative_block`: preparation, one sweep of the iterative kernel and its
  certificate in one loop, in registers (4 lanes: the float64 preparation sets the width).
* :func:`exact_block`: the float64 preparation writes only what the exact kernel reads (no
  inverse edge lengths nor conditioning: 4 divisions and 1 square root fewer per
  triangle) to 38 work rows; the exact kernel then runs 8 float32 lanes wide.

Results are written in place; points go to flat ``(3n,)`` views of the ``(n, 3)`` outputs
(constant stride 3; a 2-D output defeats LLVM's dependence analysis). Indices are unsigned
and loops bounded by the constant :data:`CHUNK`, so LLVM sees affine accesses that cannot
wrap; without that it refused to vectorise ("cannot identify array bounds", "too many SCEV
assumptions"). Results equal ``triangle_paired.paired_kernel``'s bit for bit: the same
operations on the same values. Hybrid fallbacks are queued (their raw triangles copied) and
resolved a block at a time by :func:`exact_block`. One sweep only (the default): a runtime
sweep count inside the pair loop would stop it from vectorising, so the host sends other
counts to the block-buffer path.
"""

from __future__ import annotations

import numpy as np
from numba import njit, types
from numba.extending import intrinsic

from engine.kernels.geometry.triangle_batch import (
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
)
from engine.kernels.geometry.triangle_exact import exact_pair, triangle_frame
from engine.kernels.geometry.triangle_iterative import (
    centroid,
    classify,
    separation_bounds,
    sweep,
)
from engine.kernels.jit import INLINE, JIT, select, sqrt

CHUNK = 512
"""Pairs per block call (and capacity of the fallback queue)."""
U1, U2, U3, U4, U5, U6, U7, U8 = (np.uint64(i) for i in range(1, 9))


@intrinsic
def cast_like(typingctx, x, like):
    """``x`` rounded (or widened) to the float type of ``like``."""
    if not isinstance(x, types.Float) or not isinstance(like, types.Float):
        return None
    sig = like(x, like)

    def codegen(context, builder, signature, args):
        return context.cast(builder, args[0], signature.args[0], signature.return_type)

    return sig, codegen


@njit(**INLINE)
def _round3(v, like):
    return cast_like(v[0], like), cast_like(v[1], like), cast_like(v[2], like)


@njit(**INLINE)
def load_prepared(src, k, limit, tiny, like):
    """Triangle ``k`` of ``src (≥9k+9,)`` (float32 or float64; a flat view of ``(n, 3, 3)``
    triangles: with 3-D indexing LLVM needs run-time stride assumptions and gives up) prepared as
    :func:`~engine.kernels.geometry.triangle_paired.prepare_block` prepares it, in registers.

    Returns ``(ok, v0, v1, v2, frame, kappa)``: ``ok`` False when a coordinate is NaN or
    beyond ``±limit``; vertices (rotated) and the frame tuple of
    :func:`~engine.kernels.geometry.triangle_exact.triangle_frame` rounded to the float type
    of ``like`` (``valid`` a bool); ``kappa`` the conditioning (1 for slivers), likewise.
    """
    one = 1.0
    u = np.uint64(9 * k)  # unsigned: no wrap-around select, an affine index for LLVM
    x0, y0, z0 = np.float64(src[u]), np.float64(src[u + U1]), np.float64(src[u + U2])
    x1, y1, z1 = np.float64(src[u + U3]), np.float64(src[u + U4]), np.float64(src[u + U5])
    x2, y2, z2 = np.float64(src[u + U6]), np.float64(src[u + U7]), np.float64(src[u + U8])
    ok = (abs(x0) <= limit) & (abs(y0) <= limit) & (abs(z0) <= limit)
    ok = ok & (abs(x1) <= limit) & (abs(y1) <= limit) & (abs(z1) <= limit)
    ok = ok & (abs(x2) <= limit) & (abs(y2) <= limit) & (abs(z2) <= limit)
    p, q, r = (x0, y0, z0), (x1, y1, z1), (x2, y2, z2)
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
    n, g1, g2, il, valid = triangle_frame(v0, v1, v2, one, tiny)
    kappa = select(valid, _conditioning(v0, v1, v2, one, tiny), one)
    frame = (_round3(n, like), _round3(g1, like), _round3(g2, like), _round3(il, like), valid)
    rv = (_round3(v0, like), _round3(v1, like), _round3(v2, like))
    return ok, rv[0], rv[1], rv[2], frame, cast_like(kappa, like)


@njit(**INLINE)
def _local(a0, a1, a2, b0, b1, b2):
    """Origin (``a0``) and both triangles in the pair-local frame, as ``triangle_points._pair``."""
    ox, oy, oz = a0
    return (
        (ox, oy, oz),
        (ox - ox, oy - oy, oz - oz),
        (a1[0] - ox, a1[1] - oy, a1[2] - oz),
        (a2[0] - ox, a2[1] - oy, a2[2] - oz),
        (b0[0] - ox, b0[1] - oy, b0[2] - oz),
        (b1[0] - ox, b1[1] - oy, b1[2] - oz),
        (b2[0] - ox, b2[1] - oy, b2[2] - oz),
    )


@njit(**INLINE)
def _extent(il, one):
    """Longest edge, from the inverse squared edge lengths (as ``triangle_batch._extent``)."""
    return one / sqrt(min(il[0], min(il[1], il[2])))


@njit(**INLINE)
def _get(ws, r, k):
    """Vertices and exact-kernel frame of the triangle in rows ``r … r + 18`` of ``ws``."""
    v0 = (ws[r, k], ws[r + 1, k], ws[r + 2, k])
    v1 = (ws[r + 3, k], ws[r + 4, k], ws[r + 5, k])
    v2 = (ws[r + 6, k], ws[r + 7, k], ws[r + 8, k])
    n = (ws[r + 9, k], ws[r + 10, k], ws[r + 11, k])
    g1 = (ws[r + 12, k], ws[r + 13, k], ws[r + 14, k])
    g2 = (ws[r + 15, k], ws[r + 16, k], ws[r + 17, k])
    return v0, v1, v2, (n, g1, g2, n, ws[r + 18, k] != 0)


@njit(**JIT)
def exact_block(ra, rb, m, limit, tiny, one, eps, ws, distance, lower, status, pa, pb):
    """Exact distance and closest points of pairs ``(ra[k], rb[k])``, ``k < m ≤ CHUNK``.

    ``ra, rb (≥9m,)`` float32 or float64 raw triangles (flat, as :func:`load_prepared`);
    ``limit``, ``tiny`` float64 (as :func:`load_prepared`); ``one`` 1 in the kernel dtype;
    ``eps (≥m,)`` contact distances; ``ws (38, ≥m)`` work rows in the kernel dtype.
    Writes ``distance, lower (≥m,)`` (the exact distance), ``status (≥m,)`` int8 (contact
    when ``d ≤ eps``), ``pa, pb (≥3m,)`` the points on A and B (x, y, z per pair).
    Returns the number of invalid triangles (int64).

    Two loops: the float64 preparation (4 lanes of AVX2) writes what the exact kernel reads
    (vertices, normal, dual basis, validity: 19 rows a side) to ``ws``; the exact kernel
    then runs in the kernel precision (8 float32 lanes). One fused loop ran at the width of
    its widest type, 4 lanes, and was no faster.
    """
    bad = ZERO
    zero = one - one
    for k in range(min(m, CHUNK)):  # a constant bound proves 9k cannot wrap (LLVM vectorises)
        oka, a0, a1, a2, fa, _ = load_prepared(ra, k, limit, tiny, one)
        okb, b0, b1, b2, fb, _ = load_prepared(rb, k, limit, tiny, one)
        bad += select(oka, ZERO, np.int64(1)) + select(okb, ZERO, np.int64(1))
        ws[0, k], ws[1, k], ws[2, k] = a0
        ws[3, k], ws[4, k], ws[5, k] = a1
        ws[6, k], ws[7, k], ws[8, k] = a2
        ws[9, k], ws[10, k], ws[11, k] = fa[0]
        ws[12, k], ws[13, k], ws[14, k] = fa[1]
        ws[15, k], ws[16, k], ws[17, k] = fa[2]
        ws[18, k] = select(fa[4], one, zero)
        ws[19, k], ws[20, k], ws[21, k] = b0
        ws[22, k], ws[23, k], ws[24, k] = b1
        ws[25, k], ws[26, k], ws[27, k] = b2
        ws[28, k], ws[29, k], ws[30, k] = fb[0]
        ws[31, k], ws[32, k], ws[33, k] = fb[1]
        ws[34, k], ws[35, k], ws[36, k] = fb[2]
        ws[37, k] = select(fb[4], one, zero)
    for k in range(min(m, CHUNK)):
        a0, a1, a2, fa = _get(ws, 0, k)
        b0, b1, b2, fb = _get(ws, 19, k)
        o, a0, a1, a2, b0, b1, b2 = _local(a0, a1, a2, b0, b1, b2)
        d2, p, q = exact_pair(a0, a1, a2, fa, b0, b1, b2, fb, one)
        d = sqrt(d2)
        distance[k] = d
        lower[k] = d
        status[k] = select(d <= eps[k], CONTACT, NO_CONTACT)
        u = np.uint64(3 * k)  # unsigned: no wrap-around select, an affine index for LLVM
        pa[u], pa[u + U1], pa[u + U2] = p[0] + o[0], p[1] + o[1], p[2] + o[2]
        pb[u], pb[u + U1], pb[u + U2] = q[0] + o[0], q[1] + o[1], q[2] + o[2]
    return bad


@njit(**JIT)
def iterative_block(ra, rb, m, limit, tiny, consts, eps, distance, lower, status, pa, pb):
    """One sweep of the iterative kernel and its certificate on pairs ``(ra[k], rb[k])``,
    ``k < m ≤ CHUNK``: the values of ``triangle_batch.iterate_paired`` and ``classify``.

    ``consts = (one, rtol, band_factor)`` in the kernel dtype; other arguments as
    :func:`exact_block`. Writes the upper bound to ``distance``, the certified lower bound
    to ``lower``, the three-valued result to ``status``, the sweep's points to ``pa, pb``.
    Returns the number of invalid triangles (int64).
    """
    one, rtol, band_factor = consts
    bad = ZERO
    for k in range(min(m, CHUNK)):  # a constant bound proves 9k cannot wrap (LLVM vectorises)
        oka, a0, a1, a2, fa, ka = load_prepared(ra, k, limit, tiny, one)
        okb, b0, b1, b2, fb, kb = load_prepared(rb, k, limit, tiny, one)
        bad += select(oka, ZERO, np.int64(1)) + select(okb, ZERO, np.int64(1))
        o, a0, a1, a2, b0, b1, b2 = _local(a0, a1, a2, b0, b1, b2)
        q = centroid(b0, b1, b2, one)
        p, q = sweep(a0, a1, a2, fa, b0, b1, b2, fb, q, one)
        upper, low = separation_bounds(p, q, a0, a1, a2, b0, b1, b2, one)
        band = band_factor * (upper + _extent(fa[3], one) + _extent(fb[3], one)) * max(ka, kb)
        e = eps[k]
        status[k] = classify(upper, low, e, rtol * e + band, band)
        distance[k] = upper
        lower[k] = low
        u = np.uint64(3 * k)  # unsigned: no wrap-around select, an affine index for LLVM
        pa[u], pa[u + U1], pa[u + U2] = p[0] + o[0], p[1] + o[1], p[2] + o[2]
        pb[u], pb[u + U1], pb[u + U2] = q[0] + o[0], q[1] + o[1], q[2] + o[2]
    return bad


@njit(**JIT)
def _copy_triangle(src, i, dst, c):
    """Triangle ``i`` of the flat ``src`` to slot ``c`` of the flat ``dst``."""
    for r in range(9):
        dst[9 * c + r] = src[9 * i + r]


@njit(**JIT)
def _resolve(c, lim, queue, distance, lower, pa, pb):
    """Exact distance and points of the ``c`` queued pairs into their rows ``qt[k]``."""
    limit, tiny, one = lim
    qa, qb, qt, qe, qd, ql, qs, qpa, qpb, ws = queue
    exact_block(
        qa[: 9 * c], qb[: 9 * c], c, limit, tiny, one, qe[:c], ws, qd[:c], ql[:c], qs[:c], qpa, qpb
    )
    for k in range(c):
        t = qt[k]
        distance[t] = qd[k]
        lower[t] = qd[k]
        for s in range(3):
            pa[3 * t + s] = qpa[3 * k + s]
            pb[3 * t + s] = qpb[3 * k + s]


@njit(**JIT)
def paired_raw_kernel(
    raw_a, raw_b, eps, start, stop, params, limit, distance, lower, pa, pb, status, stats
):
    """Distances of pairs ``(raw_a[t], raw_b[t])``, ``start ≤ t < stop``, one sweep.

    ``raw_a, raw_b (9n,)`` float32 or float64 (one dtype; flat views of ``(n, 3, 3)``);
    ``eps (n,)`` and every float output in the kernel dtype;
    ``params = (mode, iterations, rtol, one, band_factor)`` (``iterations`` is taken as 1);
    ``limit`` float64, the largest admissible coordinate.
    Outputs ``distance, lower (n,)``, ``pa, pb (3n,)`` (flat views of ``(n, 3)`` points),
    ``status (n,)`` int8, as in ``triangle_paired.paired_kernel``; ``stats (N_STATS,)``
    int64, added to. Returns the number of invalid triangles (outputs are then meaningless).
    """
    mode, iterations, rtol, one, band_factor = params
    tiny = np.float64(band_factor)
    lim = (limit, tiny, one)
    consts = (one, rtol, band_factor)
    dt = eps.dtype
    queue = (
        np.empty(9 * CHUNK, raw_a.dtype),
        np.empty(9 * CHUNK, raw_b.dtype),
        np.empty(CHUNK, np.int64),
        np.zeros(CHUNK, dt),
        np.empty(CHUNK, dt),
        np.empty(CHUNK, dt),
        np.empty(CHUNK, np.int8),
        np.empty(3 * CHUNK, dt),
        np.empty(3 * CHUNK, dt),
        np.empty((38, CHUNK + 16), dt),  # (padded rows: no 4 KiB aliasing between them)
    )
    qa, qb, qt, ws = queue[0], queue[1], queue[2], queue[9]
    bad = ZERO
    c = ZERO
    stats[STAT_PAIRS] += stop - start
    for t0 in range(start, stop, CHUNK):
        t1 = min(t0 + CHUNK, stop)
        m = t1 - t0
        out = (
            distance[t0:t1],
            lower[t0:t1],
            status[t0:t1],
            pa[3 * t0 : 3 * t1],
            pb[3 * t0 : 3 * t1],
        )
        if mode == EXACT:
            bad += exact_block(
                raw_a[9 * t0 : 9 * t1],
                raw_b[9 * t0 : 9 * t1],
                m,
                limit,
                tiny,
                one,
                eps[t0:t1],
                ws,
                *out,
            )
            continue
        bad += iterative_block(
            raw_a[9 * t0 : 9 * t1], raw_b[9 * t0 : 9 * t1], m, limit, tiny, consts, eps[t0:t1], *out
        )
        stats[STAT_ITERATIVE] += m
        if mode != HYBRID:
            continue
        for t in range(t0, t1):
            if status[t] == NOT_CONVERGED:
                _copy_triangle(raw_a, t, qa, c)
                _copy_triangle(raw_b, t, qb, c)
                qt[c] = t
                c += 1
                if c == CHUNK:
                    _resolve(c, lim, queue, distance, lower, pa, pb)
                    stats[STAT_FALLBACKS] += c
                    c = ZERO
    if c > 0:
        _resolve(c, lim, queue, distance, lower, pa, pb)
        stats[STAT_FALLBACKS] += c
    return bad
