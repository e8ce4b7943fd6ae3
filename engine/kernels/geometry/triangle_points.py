"""Exact distances and closest points of triangle pairs in blocks, and the pair-local
frame every batch kernel evaluates a pair in (split from
:mod:`~engine.kernels.geometry.triangle_batch`, which imports them; the layout of
triangle sets and frames is described there).

A pair (i, j) is evaluated in a frame whose origin is vertex 0 of its A triangle
(:func:`_pair`); points are shifted back to the input frame on output.

It also holds the block gathers (:func:`gather_rows`, :func:`gather_coords`,
:func:`copy_columns`; re-exported by ``triangle_batch``) and the vertex–vertex certificate
(:func:`vertex_pair`): the points a contact records (:func:`certified_points`).

:func:`exact_paired`, :func:`exact_rows`, :func:`exact_points` and :func:`vertex_points`
are ``DISTINCT`` (:mod:`engine.kernels.jit`): the arrays they write must share no memory
with the arrays they read (separate buffers, or disjoint rows of one).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from engine.kernels.geometry.triangle_exact import exact_pair
from engine.kernels.jit import BORROW, DISTINCT, INLINE, JIT, select, sqrt, tail_masked

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


@njit(**DISTINCT)
@tail_masked
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


@njit(**DISTINCT)
def exact_rows(a, fa, i, b, fb, one, dist):
    """Exact distance ``dist[j]`` of pairs (i, j) for every j."""
    for j in range(b.shape[1]):
        o, a0, a1, a2, b0, b1, b2 = _pair(a, i, b, j)
        dist[j] = sqrt(exact_pair(a0, a1, a2, _frame(fa, i), b0, b1, b2, _frame(fb, j), one)[0])


@njit(**DISTINCT)
@tail_masked
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


@njit(**BORROW)
def exact_point(a, fa, i, b, fb, j, one):
    """Exact ``(distance, p, q)`` of one pair (i, j); points in the input frame."""
    o, a0, a1, a2, b0, b1, b2 = _pair(a, i, b, j)
    d2, p, q = exact_pair(a0, a1, a2, _frame(fa, i), b0, b1, b2, _frame(fb, j), one)
    return (
        sqrt(d2),
        (p[0] + o[0], p[1] + o[1], p[2] + o[2]),
        (q[0] + o[0], q[1] + o[1], q[2] + o[2]),
    )


@njit(**INLINE)
def _closer(best, d2, p, q):
    """``best = (d², p, q)`` replaced by the candidate when it is strictly closer."""
    return select(d2 < best[0], (d2, p, q), best)


@njit(**INLINE)
def _dist2(p, q):
    x, y, z = q[0] - p[0], q[1] - p[1], q[2] - p[2]
    return x * x + y * y + z * z


@njit(**INLINE)
def _kkt(v, p, g, gg, tau2, sign):
    """Vertex ``v`` of the triangle whose vertex ``p`` is chosen: ``sign·(v − p)·g <
    −τ|v − p||g|`` (strictly on the far side of the plane through p normal to g, by an angle
    margin), or v = p."""
    x, y, z = v[0] - p[0], v[1] - p[1], v[2] - p[2]
    dot = sign * (x * g[0] + y * g[1] + z * g[2])
    ee = x * x + y * y + z * z
    return (ee == sign - sign) | ((dot < sign - sign) & (dot * dot > tau2 * ee * gg))


@njit(**INLINE)
def vertex_pair(a0, a1, a2, b0, b1, b2, one):
    """The vertex–vertex certificate of one triangle pair (vertices as 3-tuples, any frame).

    Takes the closest of the 9 vertex pairs ``(a_k, b_l)`` (the first on ties) and
    ``g = b_l − a_k``; certifies it when ``|g| > 0``, every other vertex of A satisfies
    ``(a_m − a_k)·g < −τ|a_m − a_k||g|`` and every other vertex of B ``(b_m − b_l)·g >
    τ|b_m − b_l||g|`` (a vertex equal to the chosen one passes), ``τ = 2⁻¹⁰ ≈ 1e-3``.
    This is the KKT condition of the distance between two convex hulls with a margin: the
    plane through a_k normal to g supports A, the one through b_l supports B, so ``(a_k,
    b_l)`` is the unique closest pair of the two triangles, exactly; the rounding of the
    differences (a few ulp, relative) is far inside the margin. Near-degenerate cases
    (parallel faces or edges, a vertex over a face or an edge, touching or crossing
    triangles, ties) fail the margin and are refused.

    Returns ``(d, p, q)``: ``d = |g|`` and the two stored vertices ``p = a_k``, ``q = b_l``
    where certified, ``d = −1`` where refused (NaN input is refused). The exact kernel
    returns the same pair up to its own rounding (it works in a frame at A's vertex 0):
    within a few ulp of the coordinates for the points and of the pair's scale for the
    distance (~1e-17 on the paper's grid), so a certified value is a deliberate rounding
    change of the exact kernel's, not a different answer.
    """
    zero = one - one
    h = one / (one + one)
    h2 = h * h
    h8 = (h2 * h2) * (h2 * h2)
    tau2 = (h8 * h8) * (h2 * h2)  # τ² = 2⁻²⁰
    best = (_dist2(a0, b0), a0, b0)
    best = _closer(best, _dist2(a0, b1), a0, b1)
    best = _closer(best, _dist2(a0, b2), a0, b2)
    best = _closer(best, _dist2(a1, b0), a1, b0)
    best = _closer(best, _dist2(a1, b1), a1, b1)
    best = _closer(best, _dist2(a1, b2), a1, b2)
    best = _closer(best, _dist2(a2, b0), a2, b0)
    best = _closer(best, _dist2(a2, b1), a2, b1)
    best = _closer(best, _dist2(a2, b2), a2, b2)
    gg, p, q = best
    g = (q[0] - p[0], q[1] - p[1], q[2] - p[2])
    ok = (gg > zero) & _kkt(a0, p, g, gg, tau2, one) & _kkt(a1, p, g, gg, tau2, one)
    ok = ok & _kkt(a2, p, g, gg, tau2, one) & _kkt(b0, q, g, gg, tau2, -one)
    ok = ok & _kkt(b1, q, g, gg, tau2, -one) & _kkt(b2, q, g, gg, tau2, -one)
    return select(ok, sqrt(select(ok, gg, one)), -one), p, q


@njit(**INLINE)
def _vertices(a, i):
    return (a[0, i], a[1, i], a[2, i]), (a[3, i], a[4, i], a[5, i]), (a[6, i], a[7, i], a[8, i])


@njit(**BORROW)
def vertex_point(a, i, b, j, one):
    """:func:`vertex_pair` of pair (i, j) of triangle sets ``a (9, na)``, ``b (9, nb)``."""
    a0, a1, a2 = _vertices(a, i)
    b0, b1, b2 = _vertices(b, j)
    return vertex_pair(a0, a1, a2, b0, b1, b2, one)


@njit(**DISTINCT)
@tail_masked
def vertex_points(a, b, m, one, d, pax, pay, paz, pbx, pby, pbz):
    """:func:`vertex_pair` of pairs (t, t), ``0 ≤ t < m``, vectorised; outputs as
    :func:`exact_points`' (``d[t] = −1``: refused, points then meaningless)."""
    for t in range(m):
        a0, a1, a2 = _vertices(a, t)
        b0, b1, b2 = _vertices(b, t)
        dt, p, q = vertex_pair(a0, a1, a2, b0, b1, b2, one)
        d[t] = dt
        pax[t], pay[t], paz[t] = p
        pbx[t], pby[t], pbz[t] = q


@njit(**BORROW)
def certified_points(a, fa, b, fb, m, one, final, rows):
    """Distance and closest points of pairs (t, t), ``0 ≤ t < m``, as a contact records
    them: :func:`vertex_pair`'s where it certifies the pair, else :func:`exact_points`'.

    ``final`` and ``rows``: two :func:`point_rows`; the results go to ``final`` (column t
    for pair t); the refused pairs' columns of ``a, fa, b, fb`` are moved to the front, in
    order (the others are overwritten), and their exact values pass through ``rows``.
    """
    d, pax, pay, paz, pbx, pby, pbz = final
    r0, r1, r2, r3, r4, r5, r6 = rows
    vertex_points(a, b, m, one, d, pax, pay, paz, pbx, pby, pbz)
    e = 0
    for t in range(m):
        if not d[t] >= 0:
            if e < t:
                for c in range(9):
                    a[c, e] = a[c, t]
                    b[c, e] = b[c, t]
                for c in range(14):
                    fa[c, e] = fa[c, t]
                    fb[c, e] = fb[c, t]
            e += 1
    if e == 0:
        return
    exact_points(a, fa, b, fb, e, one, r0, r1, r2, r3, r4, r5, r6)
    e = 0
    for t in range(m):
        if not d[t] >= 0:
            d[t], pax[t], pay[t], paz[t] = r0[e], r1[e], r2[e], r3[e]
            pbx[t], pby[t], pbz[t] = r4[e], r5[e], r6[e]
            e += 1


@njit(**BORROW)
def gather_rows(coords, frames, idx, m, coords_out, frames_out):
    """``coords_out[:, k] = coords[idx[k]]``, ``frames_out[:, k] = frames[idx[k]]``,
    ``k < m``: a triangle's row-major coordinates (9) and frame (14), unrolled."""
    for k in range(m):
        i = idx[k]
        for c in range(9):
            coords_out[c, k] = coords[i, c]
        for c in range(14):
            frames_out[c, k] = frames[i, c]


@njit(**BORROW)
def copy_columns(src, t0, m, dst):
    """``dst[:, k] = src[:, t0 + k]`` for ``k < m`` (an explicit loop compiles faster
    than Numba's generic slice assignment)."""
    for c in range(src.shape[0]):
        for k in range(m):
            dst[c, k] = src[c, t0 + k]


@njit(**BORROW)
def gather_coords(src, pairs, side, t0, m, dst):
    """``dst[:, k] = src[pairs[t0 + k, side], :]``: coordinates, unrolled."""
    for k in range(m):
        i = pairs[t0 + k, side]
        dst[0, k], dst[1, k], dst[2, k] = src[i, 0], src[i, 1], src[i, 2]
        dst[3, k], dst[4, k], dst[5, k] = src[i, 3], src[i, 4], src[i, 5]
        dst[6, k], dst[7, k], dst[8, k] = src[i, 6], src[i, 7], src[i, 8]
