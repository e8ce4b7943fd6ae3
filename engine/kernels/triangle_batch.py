"""Loops over batches of triangle pairs (the kernels the host API calls).

Layout: a triangle set is ``coords (9, n)`` (rows x0 y0 z0 x1 … z2) plus
``frames (13, n)`` from :func:`frames_kernel` (rows: unit normal 0–2, dual basis
g1 3–5, g2 6–8, inverse squared edge lengths 9–11, valid flag 12). Every pair
is evaluated in a pair-local frame whose origin is vertex 0 of its A triangle.

LLVM vectorises a pair loop only when its loads are contiguous, so the
arithmetic kernels come in two shapes: ``*_rows`` (one A triangle against a
contiguous run of B triangles: streaming) and ``*_paired`` (column t of A
against column t of B). Arbitrary candidate lists are first gathered, a block
at a time, into paired buffers. The loop over Newton iterations sits *outside*
the loop over pairs (the paper's permutation), so the pair loop is innermost.
The form kernels (:func:`paired_kernel`, :func:`all_pairs_kernel`,
:func:`listed_kernel`) work on a half-open range ``[start, stop)`` so that the
host can split work across threads (every kernel releases the GIL).

Modes: ``EXACT`` (0), ``ITERATIVE`` (1), ``HYBRID`` (2). Status codes:
``NO_CONTACT`` (0), ``CONTACT`` (1), ``NOT_CONVERGED`` (2).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .jit import INLINE, JIT, select, sqrt
from .triangle_exact import exact_pair, triangle_frame
from .triangle_iterative import centroid, classify, separation_bounds, sweep

# np.int64 rather than int literals: a literal argument gives a callee another
# specialisation (and another few seconds of compilation) than a variable does.
EXACT, ITERATIVE, HYBRID = np.int64(0), np.int64(1), np.int64(2)
NO_CONTACT, CONTACT, NOT_CONVERGED = np.int64(0), np.int64(1), np.int64(2)
ZERO = np.int64(0)
BLOCK = 256
# Counter slots of the ``stats`` output (int64).
STAT_PAIRS, STAT_CULLED, STAT_ITERATIVE, STAT_FALLBACKS = 0, 1, 2, 3
N_STATS = 4


@njit(**JIT)
def frames_kernel(coords, frames, one, tiny):
    """Fill ``frames (13, n)`` from ``coords (9, n)``."""
    for i in range(coords.shape[1]):
        n, g1, g2, il, valid = triangle_frame(
            (coords[0, i], coords[1, i], coords[2, i]),
            (coords[3, i], coords[4, i], coords[5, i]),
            (coords[6, i], coords[7, i], coords[8, i]),
            one,
            tiny,
        )
        frames[0, i], frames[1, i], frames[2, i] = n
        frames[3, i], frames[4, i], frames[5, i] = g1
        frames[6, i], frames[7, i], frames[8, i] = g2
        frames[9, i], frames[10, i], frames[11, i] = il
        frames[12, i] = select(valid, one, one - one)


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


@njit(**INLINE)
def _extent(f, i, one):
    """Longest edge of triangle ``i`` (from its inverse squared edge lengths)."""
    return one / sqrt(min(f[9, i], min(f[10, i], f[11, i])))


@njit(**JIT)
def exact_paired(a, fa, b, fb, t0, t1, one, dist):
    """Exact distance ``dist[t]`` of pairs (t, t), ``t0 ≤ t < t1``.

    Distances only: with point outputs too, LLVM's runtime overlap checks send
    the loop down its scalar path (10× slower). Closest points come from
    :func:`exact_point` for the pairs that need them. (The loop bodies of these
    kernels repeat a few lines on purpose: in a shared inlined helper that takes
    the arrays, the loop stops vectorising.)
    """
    for t in range(t0, t1):
        o, a0, a1, a2, b0, b1, b2 = _pair(a, t, b, t)
        dist[t] = sqrt(exact_pair(a0, a1, a2, _frame(fa, t), b0, b1, b2, _frame(fb, t), one)[0])


@njit(**JIT)
def exact_rows(a, fa, i, b, fb, one, dist):
    """Exact distance ``dist[j]`` of pairs (i, j) for every j."""
    for j in range(b.shape[1]):
        o, a0, a1, a2, b0, b1, b2 = _pair(a, i, b, j)
        dist[j] = sqrt(exact_pair(a0, a1, a2, _frame(fa, i), b0, b1, b2, _frame(fb, j), one)[0])


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


@njit(**JIT)
def bound_rows(a, fa, i, b, fb, eps_i, eps_b, one, band_factor, margin):
    """``margin[j] = L − (ε + band)`` for pairs (i, j), L the centroid-axis lower bound.

    ``margin > 0`` certifies that the pair is not in contact.
    """
    for j in range(b.shape[1]):
        o, a0, a1, a2, b0, b1, b2 = _pair(a, i, b, j)
        ca, cb = centroid(a0, a1, a2, one), centroid(b0, b1, b2, one)
        low = separation_bounds(ca, cb, a0, a1, a2, b0, b1, b2, one)[1]
        band = band_factor * (low + _extent(fa, i, one) + _extent(fb, j, one))
        margin[j] = low - (eps_i + eps_b[j] + band)


@njit(**JIT)
def bound_paired(a, fa, b, fb, t0, t1, eps, one, band_factor, margin):
    """As :func:`bound_rows` for pairs (t, t) with contact distances ``eps[t]``."""
    for t in range(t0, t1):
        o, a0, a1, a2, b0, b1, b2 = _pair(a, t, b, t)
        ca, cb = centroid(a0, a1, a2, one), centroid(b0, b1, b2, one)
        low = separation_bounds(ca, cb, a0, a1, a2, b0, b1, b2, one)[1]
        band = band_factor * (low + _extent(fa, t, one) + _extent(fb, t, one))
        margin[t] = low - (eps[t] + band)


@njit(**JIT)
def iterate_paired(a, fa, b, fb, t0, t1, iterations, one, band_factor, scratch):
    """Iterative kernel on pairs (t, t), ``t0 ≤ t < t1 ≤ t0 + BLOCK``.

    Writes to column ``t - t0`` of ``scratch (9, BLOCK)``: p (rows 0–2) and q
    (3–5) in the pair-local frame, the certified upper and lower bounds (6, 7)
    and the rounding band (8).
    """
    for t in range(t0, t1):
        o, a0, a1, a2, b0, b1, b2 = _pair(a, t, b, t)
        k = t - t0
        scratch[3, k], scratch[4, k], scratch[5, k] = centroid(b0, b1, b2, one)
    for _ in range(iterations):
        for t in range(t0, t1):
            k = t - t0
            o, a0, a1, a2, b0, b1, b2 = _pair(a, t, b, t)
            q = (scratch[3, k], scratch[4, k], scratch[5, k])
            p, q = sweep(a0, a1, a2, _frame(fa, t), b0, b1, b2, _frame(fb, t), q, one)
            scratch[0, k], scratch[1, k], scratch[2, k] = p
            scratch[3, k], scratch[4, k], scratch[5, k] = q
    for t in range(t0, t1):
        k = t - t0
        o, a0, a1, a2, b0, b1, b2 = _pair(a, t, b, t)
        p = (scratch[0, k], scratch[1, k], scratch[2, k])
        q = (scratch[3, k], scratch[4, k], scratch[5, k])
        upper, lower = separation_bounds(p, q, a0, a1, a2, b0, b1, b2, one)
        scratch[6, k] = upper
        scratch[7, k] = lower
        scratch[8, k] = band_factor * (upper + _extent(fa, t, one) + _extent(fb, t, one))


@njit(**JIT)
def gather(src, idx, t0, m, dst):
    """``dst[:, k] = src[:, idx[t0 + k]]`` for ``k < m``."""
    for c in range(src.shape[0]):
        for k in range(m):
            dst[c, k] = src[c, idx[t0 + k]]


@njit(**JIT)
def paired_kernel(
    a,
    fa,
    b,
    fb,
    eps,
    start,
    stop,
    mode,
    iterations,
    rtol,
    one,
    band_factor,
    distance,
    lower,
    point_a,
    point_b,
    status,
    stats,
):
    """Distances of pairs ``(t, t)``, ``start ≤ t < stop``.

    Outputs ``distance, lower (n,)``, ``point_a, point_b (3, n)``, ``status (n,)``
    int8 (the first kernel's result before any fallback; for the exact kernel
    ``CONTACT`` when ``d ≤ eps[t]``), and ``stats (N_STATS,)`` int64, added to.
    """
    stats[STAT_PAIRS] += stop - start
    if mode == EXACT:
        for t in range(start, stop):
            d, p, q = exact_point(a, fa, t, b, fb, t, one)
            distance[t] = d
            lower[t] = d
            status[t] = select(d <= eps[t], CONTACT, NO_CONTACT)
            point_a[0, t], point_a[1, t], point_a[2, t] = p
            point_b[0, t], point_b[1, t], point_b[2, t] = q
        return
    scratch = np.empty((9, BLOCK), a.dtype)
    for t0 in range(start, stop, BLOCK):
        t1 = min(t0 + BLOCK, stop)
        iterate_paired(a, fa, b, fb, t0, t1, iterations, one, band_factor, scratch)
        stats[STAT_ITERATIVE] += t1 - t0
        for t in range(t0, t1):
            k = t - t0
            upper, low, band = scratch[6, k], scratch[7, k], scratch[8, k]
            st = classify(upper, low, eps[t], rtol * eps[t] + band, band)
            status[t] = st
            distance[t] = upper
            lower[t] = low
            for c in range(3):
                point_a[c, t] = scratch[c, k] + a[c, t]
                point_b[c, t] = scratch[3 + c, k] + a[c, t]
            if st == NOT_CONVERGED and mode == HYBRID:
                stats[STAT_FALLBACKS] += 1
                d, p, q = exact_point(a, fa, t, b, fb, t, one)
                distance[t] = d
                lower[t] = d
                point_a[0, t], point_a[1, t], point_a[2, t] = p
                point_b[0, t], point_b[1, t], point_b[2, t] = q


@njit(**JIT)
def _record(n, i, j, d, p, q, st, out_i, out_j, out_d, out_p, out_q, out_s):
    """Append one result if there is room; always return the new count."""
    if n < out_i.shape[0]:
        out_i[n] = i
        out_j[n] = j
        out_d[n] = d
        out_p[0, n], out_p[1, n], out_p[2, n] = p
        out_q[0, n], out_q[1, n], out_q[2, n] = q
        out_s[n] = st
    return n + 1


@njit(**JIT)
def workspace(a):
    """Block buffers: gathered pairs (A, its frames, B, its frames), their original
    indices and contact distances, scratch for the iterative kernel, distances."""
    f = a.dtype
    return (
        np.empty((9, BLOCK), f),
        np.empty((13, BLOCK), f),
        np.empty((9, BLOCK), f),
        np.empty((13, BLOCK), f),
        np.empty(BLOCK, np.int64),
        np.empty(BLOCK, np.int64),
        np.empty(BLOCK, f),
        np.empty((9, BLOCK), f),
        np.empty(BLOCK, f),
    )


@njit(**JIT)
def _resolve(
    m,
    mode,
    iterations,
    rtol,
    one,
    band_factor,
    work,
    n,
    out_i,
    out_j,
    out_d,
    out_p,
    out_q,
    out_s,
    stats,
):
    """Contacts among the ``m ≤ BLOCK`` pairs gathered in ``work``; returns the new count.

    ``EXACT``: the exact kernel on all. Otherwise the iterative kernel, and in
    ``HYBRID`` mode the exact kernel on its not-converged pairs.
    """
    ga, gfa, gb, gfb, gi, gj, geps, scratch, dist = work
    if mode == EXACT:
        exact_paired(ga, gfa, gb, gfb, ZERO, m, one, dist)
        for k in range(m):
            if dist[k] <= geps[k]:
                d, p, q = exact_point(ga, gfa, k, gb, gfb, k, one)
                n = _record(
                    n, gi[k], gj[k], d, p, q, CONTACT, out_i, out_j, out_d, out_p, out_q, out_s
                )
        return n
    iterate_paired(ga, gfa, gb, gfb, ZERO, m, iterations, one, band_factor, scratch)
    stats[STAT_ITERATIVE] += m
    for k in range(m):
        eps = geps[k]
        upper, low, band = scratch[6, k], scratch[7, k], scratch[8, k]
        st = classify(upper, low, eps, rtol * eps + band, band)
        if st == NOT_CONVERGED and mode == HYBRID:
            stats[STAT_FALLBACKS] += 1
            d, p, q = exact_point(ga, gfa, k, gb, gfb, k, one)
            if d <= eps:
                n = _record(
                    n, gi[k], gj[k], d, p, q, CONTACT, out_i, out_j, out_d, out_p, out_q, out_s
                )
        elif st != NO_CONTACT:
            o = (ga[0, k], ga[1, k], ga[2, k])
            p = (scratch[0, k] + o[0], scratch[1, k] + o[1], scratch[2, k] + o[2])
            q = (scratch[3, k] + o[0], scratch[4, k] + o[1], scratch[5, k] + o[2])
            n = _record(n, gi[k], gj[k], upper, p, q, st, out_i, out_j, out_d, out_p, out_q, out_s)
    return n


@njit(**JIT)
def all_pairs_kernel(
    a,
    fa,
    b,
    fb,
    eps_a,
    eps_b,
    start,
    stop,
    mode,
    iterations,
    rtol,
    one,
    band_factor,
    out_i,
    out_j,
    out_d,
    out_p,
    out_q,
    out_s,
    stats,
):
    """Contacts among all pairs ``(i, j)``, ``start ≤ i < stop``, every j (streamed).

    A pair is in contact when its distance is at most ``eps_a[i] + eps_b[j]``.
    Results go to ``out_* (capacity,)`` / ``(3, capacity)``; the return value is
    the number found, which may exceed the capacity (the host then re-runs with
    more room). ``ITERATIVE`` mode also returns not-converged pairs (status
    ``NOT_CONVERGED``: maybe in contact). Outside ``EXACT`` mode, pairs whose
    centroid-axis bound certifies "no contact" skip the iterative kernel.
    """
    nb = b.shape[1]
    n = ZERO
    work = workspace(a)
    ga, gfa, gb, gfb, gi, gj, geps = work[:7]
    margin = np.empty(nb, a.dtype)
    dist = np.empty(nb, a.dtype)
    cj = np.empty(nb, np.int64)
    for i in range(start, stop):
        stats[STAT_PAIRS] += nb
        if mode == EXACT:
            exact_rows(a, fa, i, b, fb, one, dist)
            for j in range(nb):
                if dist[j] <= eps_a[i] + eps_b[j]:
                    d, p, q = exact_point(a, fa, i, b, fb, j, one)
                    n = _record(n, i, j, d, p, q, CONTACT, out_i, out_j, out_d, out_p, out_q, out_s)
            continue
        bound_rows(a, fa, i, b, fb, eps_a[i], eps_b, one, band_factor, margin)
        m = 0
        for j in range(nb):
            cj[m] = j
            m += margin[j] <= 0
        stats[STAT_CULLED] += nb - m
        for t0 in range(0, m, BLOCK):
            k = min(BLOCK, m - t0)
            for c in range(9):
                ga[c, :k] = a[c, i]
            for c in range(13):
                gfa[c, :k] = fa[c, i]
            gather(b, cj, t0, k, gb)
            gather(fb, cj, t0, k, gfb)
            for s in range(k):
                gi[s] = i
                gj[s] = cj[t0 + s]
                geps[s] = eps_a[i] + eps_b[cj[t0 + s]]
            n = _resolve(
                k,
                mode,
                iterations,
                rtol,
                one,
                band_factor,
                work,
                n,
                out_i,
                out_j,
                out_d,
                out_p,
                out_q,
                out_s,
                stats,
            )
    return n


@njit(**JIT)
def listed_kernel(
    a,
    fa,
    b,
    fb,
    eps_a,
    eps_b,
    pair_i,
    pair_j,
    start,
    stop,
    mode,
    iterations,
    rtol,
    one,
    band_factor,
    out_i,
    out_j,
    out_d,
    out_p,
    out_q,
    out_s,
    stats,
):
    """Contacts among listed pairs ``(pair_i[t], pair_j[t])``, ``start ≤ t < stop``.

    Same outputs and return value as :func:`all_pairs_kernel`.
    """
    n = ZERO
    work = workspace(a)
    ga, gfa, gb, gfb, gi, gj, geps = work[:7]
    margin = np.empty(BLOCK, a.dtype)
    for t0 in range(start, stop, BLOCK):
        m = min(BLOCK, stop - t0)
        stats[STAT_PAIRS] += m
        gather(a, pair_i, t0, m, ga)
        gather(fa, pair_i, t0, m, gfa)
        gather(b, pair_j, t0, m, gb)
        gather(fb, pair_j, t0, m, gfb)
        for k in range(m):
            gi[k] = pair_i[t0 + k]
            gj[k] = pair_j[t0 + k]
            geps[k] = eps_a[gi[k]] + eps_b[gj[k]]
        if mode != EXACT:
            bound_paired(ga, gfa, gb, gfb, ZERO, m, geps, one, band_factor, margin)
            kept = 0
            for k in range(m):
                if margin[k] <= 0:
                    if kept != k:
                        ga[:, kept] = ga[:, k]
                        gfa[:, kept] = gfa[:, k]
                        gb[:, kept] = gb[:, k]
                        gfb[:, kept] = gfb[:, k]
                        gi[kept], gj[kept], geps[kept] = gi[k], gj[k], geps[k]
                    kept += 1
            stats[STAT_CULLED] += m - kept
            m = kept
        n = _resolve(
            m,
            mode,
            iterations,
            rtol,
            one,
            band_factor,
            work,
            n,
            out_i,
            out_j,
            out_d,
            out_p,
            out_q,
            out_s,
            stats,
        )
    return n
