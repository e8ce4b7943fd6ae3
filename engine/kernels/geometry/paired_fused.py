"""The paired form on raw triangle arrays, preparation fused into the pair loop.

:func:`paired_raw_kernel` evaluates pairs ``(raw_a[t], raw_b[t])`` from flat views of the
caller's ``(n, 3, 3)`` arrays, a block of :data:`CHUNK` pairs per call, without the
block-buffer round trip of :mod:`~engine.kernels.geometry.triangle_paired`. Each triangle is
rotated (largest angle at vertex 0) and its frame computed in float64 by
:func:`load_prepared` (``triangle_paired.prepared_triangle``, the arithmetic of
``prepare_block``), then rounded to the kernel precision.

* :func:`iterative_block`: preparation, one sweep of the iterative kernel and its
  certificate in one loop, in registers;
* :func:`exact_block`: preparation (what the exact kernel reads: no inverse edge lengths
  nor conditioning, 4 divisions and 1 square root fewer per triangle) and the exact kernel
  in one loop;
* :func:`native_block` (``native=True``, the float32 one-sweep modes): the
  preparation in the kernel precision (:func:`load_native`) and face points rebuilt from
  their barycentrics (:func:`_closest_native`), so that a float32 frame's larger error
  (barycentrics off by ``ulp·κ²`` instead of ``ulp·κ``) costs convergence, never a bound.
  Not bit for bit with the block path; decisions, bounds and fallbacks as exact as there
  (tests/engine/geometry/test_triangle_paired_fused.py). Measured (512 pairs in cache,
  float32, 1 thread): 34–36 ns a pair with the float64 preparation, 20 without.

Each of these block loops runs 8 float32 lanes wide (AVX2), the float64 preparation in
pairs of registers.
Their only reduction is a bool ("every coordinate valid"): an int64 counter of invalid
triangles made LLVM cap the vector width at 4 (its widest reduction type sets the
largest width it tries), which cost 25 % (one sweep) and 10 % (exact, then split into a
float64 preparation loop at 4 lanes writing 38 work rows and an exact loop at 8); the
count is taken afterwards, only when some coordinate was invalid (:func:`_invalid`).

Results are written in place; points go to flat ``(3n,)`` views of the ``(n, 3)`` outputs
(constant stride 3; a 2-D output defeats LLVM's dependence analysis). Indices are unsigned
and loops bounded by the constant :data:`CHUNK`, so LLVM sees affine accesses that cannot
wrap; without that it refused to vectorise ("cannot identify array bounds", "too many SCEV
assumptions"). Results equal ``triangle_paired.paired_kernel``'s bit for bit: the same
operations on the same values, except float32 exact closest points on an AVX-512 machine,
where LLVM vectorises the two loops differently and a few points differ in their last bits
(docs/kernels.md; distances, bounds and statuses stay bit for bit). Hybrid fallbacks are
queued (their raw triangles copied) and resolved a block at a time by :func:`exact_block`.
One sweep only (the default): a runtime sweep count inside the pair loop would stop it from
vectorising, so the host sends other counts to the block-buffer path.
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
)
from engine.kernels.geometry.triangle_exact import exact_pair, segment_segment
from engine.kernels.geometry.triangle_iterative import (
    _edge_point,
    centroid,
    classify,
    separation_bounds,
    sweep,
)
from engine.kernels.geometry.triangle_paired import count_invalid, prepared_triangle
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
    triangles: with 3-D indexing LLVM needs run-time stride assumptions and gives up) prepared
    by :func:`~engine.kernels.geometry.triangle_paired.prepared_triangle` (the arithmetic of
    ``prepare_block``), in registers.

    Returns ``(ok, v0, v1, v2, frame, kappa)``: ``ok`` False when a coordinate is NaN or
    beyond ``±limit``; vertices (rotated) and the frame tuple of
    :func:`~engine.kernels.geometry.triangle_exact.triangle_frame` rounded to the float type
    of ``like`` (``valid`` a bool); ``kappa`` the conditioning (1 for slivers), likewise.
    """
    u = np.uint64(9 * k)  # unsigned: no wrap-around select, an affine index for LLVM
    p = (np.float64(src[u]), np.float64(src[u + U1]), np.float64(src[u + U2]))
    q = (np.float64(src[u + U3]), np.float64(src[u + U4]), np.float64(src[u + U5]))
    r = (np.float64(src[u + U6]), np.float64(src[u + U7]), np.float64(src[u + U8]))
    ok, v0, v1, v2, (n, g1, g2, il, valid), kappa = prepared_triangle(p, q, r, limit, tiny, 1.0)
    frame = (_round3(n, like), _round3(g1, like), _round3(g2, like), _round3(il, like), valid)
    rv = (_round3(v0, like), _round3(v1, like), _round3(v2, like))
    return ok, rv[0], rv[1], rv[2], frame, cast_like(kappa, like)


@njit(**INLINE)
def load_native(src, k, limit, tiny, one):
    """Triangle ``k`` of ``src`` (as :func:`load_prepared`) prepared in the float type of
    ``one`` (``limit``, ``tiny`` of that type too) from its coordinates rounded to it: the
    same steps as :func:`load_prepared`, without float64 (float32 division and square root
    run 8 lanes wide, float64 ones 4, at about twice the cost per instruction)."""
    u = np.uint64(9 * k)  # unsigned: no wrap-around select, an affine index for LLVM
    p = (cast_like(src[u], one), cast_like(src[u + U1], one), cast_like(src[u + U2], one))
    q = (cast_like(src[u + U3], one), cast_like(src[u + U4], one), cast_like(src[u + U5], one))
    r = (cast_like(src[u + U6], one), cast_like(src[u + U7], one), cast_like(src[u + U8], one))
    return prepared_triangle(p, q, r, limit, tiny, one)


@njit(**INLINE)
def _closest_native(x, v0, v1, v2, frame, one):
    """``triangle_iterative.closest_on_triangle`` with the face point rebuilt from its
    barycentrics, ``v0 + u·e1 + s·e2``, instead of ``x − h·n``: the point then lies in the
    triangle up to the rounding of that sum whatever the error of the frame, so ``U`` stays
    an upper bound when the frame was computed in float32 (its barycentrics err by about
    ``ulp·κ²`` rather than ``ulp·κ``; a wrong inside test now only costs convergence)."""
    zero = one - one
    n, g1, g2, il, valid = frame
    wx, wy, wz = x[0] - v0[0], x[1] - v0[1], x[2] - v0[2]
    u = wx * g1[0] + wy * g1[1] + wz * g1[2]
    s = wx * g2[0] + wy * g2[1] + wz * g2[2]
    inside = valid & (u >= zero) & (s >= zero) & (u + s <= one)
    e1 = (v1[0] - v0[0], v1[1] - v0[1], v1[2] - v0[2])
    e2 = (v2[0] - v0[0], v2[1] - v0[1], v2[2] - v0[2])
    e3 = (v2[0] - v1[0], v2[1] - v1[1], v2[2] - v1[2])
    best, point = _edge_point(x, v0, e1, il[0], one)
    start, direction = v0, e1
    d2, c = _edge_point(x, v1, e3, il[1], one)
    best, point, start, direction = select(
        d2 < best, (d2, c, v1, e3), (best, point, start, direction)
    )
    d2, c = _edge_point(x, v0, e2, il[2], one)
    best, point, start, direction = select(
        d2 < best, (d2, c, v0, e2), (best, point, start, direction)
    )
    face = (
        v0[0] + u * e1[0] + s * e2[0],
        v0[1] + u * e1[1] + s * e2[1],
        v0[2] + u * e1[2] + s * e2[2],
    )
    return select(inside, face, point), not inside, start, direction


@njit(**INLINE)
def _sweep_native(a0, a1, a2, fa, b0, b1, b2, fb, q, one):
    """``triangle_iterative.sweep`` with :func:`_closest_native`."""
    p, a_edge, sa, da = _closest_native(q, a0, a1, a2, fa, one)
    q, b_edge, sb, db = _closest_native(p, b0, b1, b2, fb, one)
    rx, ry, rz = p[0] - q[0], p[1] - q[1], p[2] - q[2]
    d2 = rx * rx + ry * ry + rz * rz
    d2n, pn, qn = segment_segment(sa, da, sb, db, one)
    take = a_edge & b_edge & (d2n < d2)
    return select(take, (pn, qn), (p, q))


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


@njit(**JIT)
def exact_block(ra, rb, m, limit, tiny, one, eps, distance, lower, status, pa, pb):
    """Exact distance and closest points of pairs ``(ra[k], rb[k])``, ``k < m ≤ CHUNK``.

    ``ra, rb (≥9m,)`` float32 or float64 raw triangles (flat, as :func:`load_prepared`);
    ``limit``, ``tiny`` float64 (as :func:`load_prepared`); ``one`` 1 in the kernel dtype;
    ``eps (≥m,)`` contact distances. Writes ``distance, lower (≥m,)`` (the exact distance),
    ``status (≥m,)`` int8 (contact when ``d ≤ eps``), ``pa, pb (≥3m,)`` the points on A
    and B (x, y, z per pair). Returns the number of invalid triangles (int64).

    One loop, 8 float32 lanes (two AVX2 registers for each float64 value of the
    preparation, whose inverse edge lengths and conditioning LLVM drops: the exact kernel
    does not read them).
    """
    good = True  # a bool reduction: an int64 counter would cap the loop at 4 lanes
    for k in range(min(m, CHUNK)):  # a constant bound proves 9k cannot wrap (LLVM vectorises)
        oka, a0, a1, a2, fa, _ = load_prepared(ra, k, limit, tiny, one)
        okb, b0, b1, b2, fb, _ = load_prepared(rb, k, limit, tiny, one)
        good = good & oka & okb
        o, a0, a1, a2, b0, b1, b2 = _local(a0, a1, a2, b0, b1, b2)
        d2, p, q = exact_pair(a0, a1, a2, fa, b0, b1, b2, fb, one)
        d = sqrt(d2)
        distance[k] = d
        lower[k] = d
        status[k] = select(d <= eps[k], CONTACT, NO_CONTACT)
        u = np.uint64(3 * k)  # unsigned: no wrap-around select, an affine index for LLVM
        pa[u], pa[u + U1], pa[u + U2] = p[0] + o[0], p[1] + o[1], p[2] + o[2]
        pb[u], pb[u + U1], pb[u + U2] = q[0] + o[0], q[1] + o[1], q[2] + o[2]
    return _invalid(good, ra, rb, m, limit)


@njit(**JIT)
def _invalid(good, ra, rb, m, limit):
    """Invalid triangles among the first ``m`` of ``ra`` and of ``rb`` (0 when ``good``)."""
    if good:
        return ZERO
    return count_invalid(ra[: 9 * m], limit) + count_invalid(rb[: 9 * m], limit)


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
    good = True  # a bool reduction: an int64 counter would cap the loop at 4 lanes
    for k in range(min(m, CHUNK)):  # a constant bound proves 9k cannot wrap (LLVM vectorises)
        oka, a0, a1, a2, fa, ka = load_prepared(ra, k, limit, tiny, one)
        okb, b0, b1, b2, fb, kb = load_prepared(rb, k, limit, tiny, one)
        good = good & oka & okb
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
    return _invalid(good, ra, rb, m, limit)


@njit(**JIT)
def native_block(ra, rb, m, limit, tiny, consts, eps, distance, lower, status, pa, pb):
    """:func:`iterative_block` with the preparation in the kernel precision
    (:func:`load_native`) and :func:`_sweep_native`; ``limit``, ``tiny`` in the kernel
    dtype. The certificate and its rounding band are unchanged: ``U`` and ``L`` are bounds
    whatever the frame, and the band covers the exact kernel's own rounding.
    """
    one, rtol, band_factor = consts
    good = True  # a bool reduction: an int64 counter would cap the loop at 4 lanes
    for k in range(min(m, CHUNK)):  # a constant bound proves 9k cannot wrap (LLVM vectorises)
        oka, a0, a1, a2, fa, ka = load_native(ra, k, limit, tiny, one)
        okb, b0, b1, b2, fb, kb = load_native(rb, k, limit, tiny, one)
        good = good & oka & okb
        o, a0, a1, a2, b0, b1, b2 = _local(a0, a1, a2, b0, b1, b2)
        q = centroid(b0, b1, b2, one)
        p, q = _sweep_native(a0, a1, a2, fa, b0, b1, b2, fb, q, one)
        upper, low = separation_bounds(p, q, a0, a1, a2, b0, b1, b2, one)
        band = band_factor * (upper + _extent(fa[3], one) + _extent(fb[3], one)) * max(ka, kb)
        e = eps[k]
        status[k] = classify(upper, low, e, rtol * e + band, band)
        distance[k] = upper
        lower[k] = low
        u = np.uint64(3 * k)  # unsigned: no wrap-around select, an affine index for LLVM
        pa[u], pa[u + U1], pa[u + U2] = p[0] + o[0], p[1] + o[1], p[2] + o[2]
        pb[u], pb[u + U1], pb[u + U2] = q[0] + o[0], q[1] + o[1], q[2] + o[2]
    return _invalid(good, ra, rb, m, np.float64(limit))


@njit(**JIT)
def _copy_triangle(src, i, dst, c):
    """Triangle ``i`` of the flat ``src`` to slot ``c`` of the flat ``dst``."""
    for r in range(9):
        dst[9 * c + r] = src[9 * i + r]


@njit(**JIT)
def _resolve(c, lim, queue, distance, lower, pa, pb):
    """Exact distance and points of the ``c`` queued pairs into their rows ``qt[k]``."""
    limit, tiny, one = lim
    qa, qb, qt, qe, qd, ql, qs, qpa, qpb = queue
    exact_block(
        qa[: 9 * c], qb[: 9 * c], c, limit, tiny, one, qe[:c], qd[:c], ql[:c], qs[:c], qpa, qpb
    )
    for k in range(c):
        t = qt[k]
        distance[t] = qd[k]
        lower[t] = qd[k]
        for s in range(3):
            pa[3 * t + s] = qpa[3 * k + s]
            pb[3 * t + s] = qpb[3 * k + s]


@njit(**JIT)
def _fallback_queue(raw_a, raw_b, dt):
    """The queue of not-converged pairs: raw triangles, rows, and :func:`exact_block`'s
    inputs and outputs (``dt`` the kernel dtype), :data:`CHUNK` slots each."""
    return (
        np.empty(9 * CHUNK, raw_a.dtype),
        np.empty(9 * CHUNK, raw_b.dtype),
        np.empty(CHUNK, np.int64),
        np.zeros(CHUNK, dt),
        np.empty(CHUNK, dt),
        np.empty(CHUNK, dt),
        np.empty(CHUNK, np.int8),
        np.empty(3 * CHUNK, dt),
        np.empty(3 * CHUNK, dt),
    )


@njit(**JIT)
def _enqueue(raw_a, raw_b, t0, t1, c, lim, queue, distance, lower, pa, pb, status, stats):
    """Queue the not-converged pairs of rows ``[t0, t1)`` after the ``c`` queued ones,
    resolving the queue whenever it is full; returns the new count."""
    qa, qb, qt = queue[0], queue[1], queue[2]
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
    return c


@njit(**JIT)
def paired_raw_kernel(
    raw_a, raw_b, eps, start, stop, params, limit, native, distance, lower, pa, pb, status, stats
):
    """Distances of pairs ``(raw_a[t], raw_b[t])``, ``start ≤ t < stop``, one sweep.

    ``raw_a, raw_b (9n,)`` float32 or float64 (one dtype; flat views of ``(n, 3, 3)``);
    ``eps (n,)`` and every float output in the kernel dtype;
    ``params = (mode, iterations, rtol, one, band_factor)`` (``iterations`` is taken as 1);
    ``limit`` float64, the largest admissible coordinate; ``native`` (one-sweep modes only:
    iterative, hybrid): prepare in the kernel precision (:func:`native_block`) instead of
    float64. Hybrid fallbacks are resolved by :func:`exact_block` (float64 preparation)
    either way: they equal the exact kernel's results bit for bit.
    Outputs ``distance, lower (n,)``, ``pa, pb (3n,)`` (flat views of ``(n, 3)`` points),
    ``status (n,)`` int8, as in ``triangle_paired.paired_kernel``; ``stats (N_STATS,)``
    int64, added to. Returns the number of invalid triangles (outputs are then meaningless).
    """
    mode, iterations, rtol, one, band_factor = params
    tiny = np.float64(band_factor)
    lim = (limit, tiny, one)
    consts = (one, rtol, band_factor)
    limit_k = cast_like(limit, one)  # (coordinate_limit of float32 is a float32 value)
    queue = _fallback_queue(raw_a, raw_b, eps.dtype)
    bad = ZERO
    c = ZERO
    stats[STAT_PAIRS] += stop - start
    for t0 in range(start, stop, CHUNK):
        t1 = min(t0 + CHUNK, stop)
        ra, rb, e = raw_a[9 * t0 : 9 * t1], raw_b[9 * t0 : 9 * t1], eps[t0:t1]
        out = (
            distance[t0:t1],
            lower[t0:t1],
            status[t0:t1],
            pa[3 * t0 : 3 * t1],
            pb[3 * t0 : 3 * t1],
        )
        if mode == EXACT:
            bad += exact_block(ra, rb, t1 - t0, limit, tiny, one, e, *out)
            continue
        if native:
            bad += native_block(ra, rb, t1 - t0, limit_k, band_factor, consts, e, *out)
        else:
            bad += iterative_block(ra, rb, t1 - t0, limit, tiny, consts, e, *out)
        stats[STAT_ITERATIVE] += t1 - t0
        if mode == HYBRID:
            c = _enqueue(
                raw_a, raw_b, t0, t1, c, lim, queue, distance, lower, pa, pb, status, stats
            )
    if c > 0:
        _resolve(c, lim, queue, distance, lower, pa, pb)
        stats[STAT_FALLBACKS] += c
    return bad
