"""Loops over batches of triangle pairs (the kernels the host API calls).

Layout: a triangle set is ``coords (9, n)`` (rows x0 y0 z0 x1 … z2) plus
``frames (14, n)`` from :func:`frames_kernel` (rows: unit normal 0–2, dual basis
g1 3–5, g2 6–8, inverse squared edge lengths 9–11, valid flag 12, conditioning
κ = 1/sin θ of the angle at vertex 0, 13).

Rounding band: the inside test of a face errs by about ``ulp·|w|·κ``, so every
band around ε is ``64 ulp · (scale of the pair) · max(κ_A, κ_B)``: hybrid and
exact decide alike even for poorly shaped triangles (which then fall back to
the exact kernel more often). Every pair
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

:func:`iterate_paired`, :func:`bound_paired` and :func:`bound_rows` are ``DISTINCT``
(:mod:`engine.kernels.jit`): the arrays they write must share no memory with the arrays
they read (separate buffers, or disjoint rows of one).

Modes: ``EXACT`` (0), ``ITERATIVE`` (1), ``HYBRID`` (2). Status codes:
``NO_CONTACT`` (0), ``CONTACT`` (1), ``NOT_CONVERGED`` (2).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from engine.kernels.geometry.triangle_exact import triangle_frame
from engine.kernels.geometry.triangle_iterative import centroid, classify, separation_bounds, sweep
from engine.kernels.geometry.triangle_points import (
    BLOCK,
    _frame,
    _pair,
    certified_points,
    copy_columns,
    exact_point,
    exact_rows,
    gather_coords,
    gather_rows,
    point_rows,
    vertex_point,
)
from engine.kernels.jit import BORROW, DISTINCT, INLINE, JIT, select, sqrt, tail_masked

# np.int64 rather than int literals: a literal argument gives a callee another
# specialisation (and another few seconds of compilation) than a variable does.
EXACT, ITERATIVE, HYBRID = np.int64(0), np.int64(1), np.int64(2)
NO_CONTACT, CONTACT, NOT_CONVERGED = np.int64(0), np.int64(1), np.int64(2)
ZERO = np.int64(0)
# Counter slots of the ``stats`` output (int64).
STAT_PAIRS, STAT_CULLED, STAT_ITERATIVE, STAT_FALLBACKS = 0, 1, 2, 3
STAT_SPHERES = 4  # node pairs pruned by bounding spheres (the traversal only)
N_STATS = 5


@njit(**JIT)
def frames_kernel(coords, frames, one, tiny):
    """Fill ``frames (14, n)`` from ``coords (9, n)``."""
    for i in range(coords.shape[1]):
        v0 = (coords[0, i], coords[1, i], coords[2, i])
        v1 = (coords[3, i], coords[4, i], coords[5, i])
        v2 = (coords[6, i], coords[7, i], coords[8, i])
        n, g1, g2, il, valid = triangle_frame(v0, v1, v2, one, tiny)
        frames[13, i] = select(valid, _conditioning(v0, v1, v2, one, tiny), one)
        frames[0, i], frames[1, i], frames[2, i] = n
        frames[3, i], frames[4, i], frames[5, i] = g1
        frames[6, i], frames[7, i], frames[8, i] = g2
        frames[9, i], frames[10, i], frames[11, i] = il
        frames[12, i] = select(valid, one, one - one)


@njit(**INLINE)
def _conditioning(v0, v1, v2, one, tiny):
    """κ = 1/sin θ of the angle at ``v0``, at most 1/√tiny (θ → 0 or 180°: no plane)."""
    x1, y1, z1 = v1[0] - v0[0], v1[1] - v0[1], v1[2] - v0[2]
    x2, y2, z2 = v2[0] - v0[0], v2[1] - v0[1], v2[2] - v0[2]
    cx, cy, cz = y1 * z2 - z1 * y2, z1 * x2 - x1 * z2, x1 * y2 - y1 * x2
    lengths = (x1 * x1 + y1 * y1 + z1 * z1) * (x2 * x2 + y2 * y2 + z2 * z2)
    sin2 = (cx * cx + cy * cy + cz * cz) / select(lengths > one - one, lengths, one)
    return one / sqrt(max(sin2, tiny))


@njit(**INLINE)
def _extent(f, i, one):
    """Longest edge of triangle ``i`` (from its inverse squared edge lengths)."""
    return one / sqrt(min(f[9, i], min(f[10, i], f[11, i])))


@njit(**DISTINCT)
def bound_rows(a, fa, i, b, fb, eps_i, eps_b, one, band_factor, margin):
    """``margin[j] = L − (ε + band)`` for pairs (i, j), L the centroid-axis lower bound.

    ``margin > 0`` certifies that the pair is not in contact.
    """
    for j in range(b.shape[1]):
        o, a0, a1, a2, b0, b1, b2 = _pair(a, i, b, j)
        ca, cb = centroid(a0, a1, a2, one), centroid(b0, b1, b2, one)
        low = separation_bounds(ca, cb, a0, a1, a2, b0, b1, b2, one)[1]
        kappa = max(fa[13, i], fb[13, j])
        band = band_factor * (low + _extent(fa, i, one) + _extent(fb, j, one)) * kappa
        margin[j] = low - (eps_i + eps_b[j] + band)


@njit(**INLINE)
def _longest_edge(v0, v1, v2):
    x1, y1, z1 = v1[0] - v0[0], v1[1] - v0[1], v1[2] - v0[2]
    x2, y2, z2 = v2[0] - v0[0], v2[1] - v0[1], v2[2] - v0[2]
    x3, y3, z3 = v2[0] - v1[0], v2[1] - v1[1], v2[2] - v1[2]
    e1 = x1 * x1 + y1 * y1 + z1 * z1
    e2 = x2 * x2 + y2 * y2 + z2 * z2
    e3 = x3 * x3 + y3 * y3 + z3 * z3
    return sqrt(max(e1, max(e2, e3)))


@njit(**DISTINCT)
@tail_masked
def bound_paired(a, b, m, eps, one, band_factor, margin):
    """As :func:`bound_rows` for pairs (t, t) with contact distances ``eps[t]``.

    Needs coordinates only, so a candidate list can be culled before the
    frames of its survivors are gathered; κ comes from the coordinates (never
    below the frames' κ: ``band_factor`` doubles as the sliver threshold).
    """
    for t in range(m):
        o, a0, a1, a2, b0, b1, b2 = _pair(a, t, b, t)
        ca, cb = centroid(a0, a1, a2, one), centroid(b0, b1, b2, one)
        low = separation_bounds(ca, cb, a0, a1, a2, b0, b1, b2, one)[1]
        kappa = max(
            _conditioning(a0, a1, a2, one, band_factor), _conditioning(b0, b1, b2, one, band_factor)
        )
        band = band_factor * (low + _longest_edge(a0, a1, a2) + _longest_edge(b0, b1, b2)) * kappa
        margin[t] = low - (eps[t] + band)


@njit(**DISTINCT)
@tail_masked
def iterate_paired(a, fa, b, fb, m, iterations, one, band_factor, scratch):
    """Iterative kernel on pairs (t, t), ``0 ≤ t < m ≤ BLOCK``.

    Writes to column ``t`` of ``scratch (9, BLOCK)``: p (rows 0–2) and q
    (3–5) in the pair-local frame, the certified upper and lower bounds (6, 7)
    and the rounding band (8).
    """
    for t in range(m):
        o, a0, a1, a2, b0, b1, b2 = _pair(a, t, b, t)
        k = t
        scratch[3, k], scratch[4, k], scratch[5, k] = centroid(b0, b1, b2, one)
    for _ in range(iterations):
        for t in range(m):
            k = t
            o, a0, a1, a2, b0, b1, b2 = _pair(a, t, b, t)
            q = (scratch[3, k], scratch[4, k], scratch[5, k])
            p, q = sweep(a0, a1, a2, _frame(fa, t), b0, b1, b2, _frame(fb, t), q, one)
            scratch[0, k], scratch[1, k], scratch[2, k] = p
            scratch[3, k], scratch[4, k], scratch[5, k] = q
    for t in range(m):
        k = t
        o, a0, a1, a2, b0, b1, b2 = _pair(a, t, b, t)
        p = (scratch[0, k], scratch[1, k], scratch[2, k])
        q = (scratch[3, k], scratch[4, k], scratch[5, k])
        upper, lower = separation_bounds(p, q, a0, a1, a2, b0, b1, b2, one)
        scratch[6, k] = upper
        scratch[7, k] = lower
        kappa = max(fa[13, t], fb[13, t])
        scratch[8, k] = band_factor * (upper + _extent(fa, t, one) + _extent(fb, t, one)) * kappa


@njit(**JIT)
def pair_bounds(pairs):
    """``(min, max of column 0, max of column 1)`` of a non-empty ``(k, 2)`` int64 array."""
    lo, hi0, hi1 = pairs[0, 0], pairs[0, 0], pairs[0, 1]
    for t in range(pairs.shape[0]):
        i, j = pairs[t, 0], pairs[t, 1]
        lo = min(lo, min(i, j))
        hi0 = max(hi0, i)
        hi1 = max(hi1, j)
    return lo, hi0, hi1


@njit(**JIT)
def paired_kernel(
    a, fa, b, fb, eps, start, stop, params, distance, lower, point_a, point_b, status, stats
):
    """Distances of pairs ``(t, t)``, ``start ≤ t < stop``.

    Outputs ``distance, lower (n,)``, ``point_a, point_b (3, n)``, ``status (n,)``
    int8 (the first kernel's result before any fallback; for the exact kernel
    ``CONTACT`` when ``d ≤ eps[t]``), and ``stats (N_STATS,)`` int64, added to.
    ``params = (mode, iterations, rtol, one, band_factor)``.
    """
    mode, iterations, rtol, one, band_factor = params
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
    ga, gfa, gb, gfb = workspace(a)[:4]
    scratch = np.empty((9, BLOCK), a.dtype)
    for t0 in range(start, stop, BLOCK):
        t1 = min(t0 + BLOCK, stop)
        m = t1 - t0
        copy_columns(a, t0, m, ga)
        copy_columns(fa, t0, m, gfa)
        copy_columns(b, t0, m, gb)
        copy_columns(fb, t0, m, gfb)
        iterate_paired(ga, gfa, gb, gfb, m, iterations, one, band_factor, scratch)
        stats[STAT_ITERATIVE] += m
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


@njit(**BORROW)
def _record(n, i, j, d, p, q, st, out_i, out_j, out_d, out_p, out_q, out_s):
    """Append one result to the arrays of ``out`` if there is room; always return the
    new count.

    ``out = (i (cap,), j (cap,), distance (cap,), point_a (3, cap), point_b (3, cap),
    status (cap,))``, unpacked by the caller outside its loop (a tuple item taken
    inside the loop costs reference counting on every pair).
    """
    if n < out_i.shape[0]:
        out_i[n] = i
        out_j[n] = j
        out_d[n] = d
        out_p[0, n], out_p[1, n], out_p[2, n] = p
        out_q[0, n], out_q[1, n], out_q[2, n] = q
        out_s[n] = st
    return n + 1


@njit(**JIT)
def result_buffers(capacity, like):
    """Result buffers of the contact forms (the ``out`` of :func:`_record`) with room for
    ``capacity`` results, floats of the dtype of ``like``."""
    dtype = like.dtype
    return (
        np.empty(capacity, np.int64),
        np.empty(capacity, np.int64),
        np.empty(capacity, dtype),
        np.empty((3, capacity), dtype),
        np.empty((3, capacity), dtype),
        np.empty(capacity, np.int8),
    )


@njit(**JIT)
def workspace(a):
    """Block buffers: gathered pairs (A, its frames, B, its frames), their original
    indices and contact distances, scratch for the iterative kernel, distances, two
    :func:`point_rows` (``rows`` and ``final`` of
    :func:`~engine.kernels.geometry.triangle_points.certified_points`), and ``closest
    (1,)`` float64, +∞: :func:`_resolve` lowers it to the least ``d − ε`` of the pairs it
    resolves (d the iterative kernel's upper bound, a distance between two points of
    the triangles, and the exact distance of every pair given points; ε the pair's
    contact distance)."""
    f = a.dtype
    return (
        np.empty((9, BLOCK), f),
        np.empty((14, BLOCK), f),
        np.empty((9, BLOCK), f),
        np.empty((14, BLOCK), f),
        np.empty(BLOCK, np.int64),
        np.empty(BLOCK, np.int64),
        np.empty(BLOCK, f),
        np.empty((9, BLOCK), f),
        np.empty(BLOCK, f),
        point_rows(a),
        point_rows(a),
        np.full(1, np.inf),
    )


@njit(**BORROW)
def _resolve(m, params, work, n, out, stats):
    """Contacts among the ``m ≤ BLOCK`` pairs gathered in ``work``; returns the new count.

    ``params = (mode, iterations, rtol, one, band_factor)``. ``EXACT``: every pair's
    contact distance and closest points, as a contact records them (below). Otherwise the
    iterative kernel; in ``HYBRID`` mode it only decides (certified "no contact" is final),
    and every pair in contact or not converged gets them too (``stats[STAT_FALLBACKS]``
    counts the not-converged ones): the contacts are the exact search's, bit for bit. (The
    iterate's points are *a* pair at a distance within the tolerance, not the closest
    pair: for parallel faces or edges they can lie a triangle apart, and near touching the
    direction q − p is the iteration's noise.) ``ITERATIVE`` records the iterate's bound
    and points.

    A contact records :func:`~engine.kernels.geometry.triangle_points.certified_points`:
    the two stored vertices and their distance where the vertex–vertex certificate holds,
    else the exact kernel's (vectorised ``exact_points``); a pair is in contact when that
    distance is at most its ε (a pair the iterative kernel certifies in contact is kept
    whatever it is: it is ≤ the certified upper bound ≤ ε). The pairs that need points are
    moved to the front of the block, in order (``work``'s columns are overwritten), so
    contacts are recorded in the order of the block. ``work``'s ``closest`` is lowered
    (see :func:`workspace`).
    """
    mode, iterations, rtol, one, band_factor = params
    ga, gfa, gb, gfb, gi, gj, geps, scratch, dist, rows, final, closest = work
    v0, v1, v2, v3, v4, v5, v6 = final
    out_i, out_j, out_d, out_p, out_q, out_s = out
    c = ZERO  # pairs that need points, moved to columns 0 … c − 1
    least = closest[0]
    if mode == EXACT:
        c = m
        for k in range(m):
            dist[k] = one - one  # in contact when its distance is within ε
    else:
        iterate_paired(ga, gfa, gb, gfb, m, iterations, one, band_factor, scratch)
        stats[STAT_ITERATIVE] += m
        for k in range(m):
            eps = geps[k]
            upper, low, band = scratch[6, k], scratch[7, k], scratch[8, k]
            least = min(least, np.float64(upper) - np.float64(eps))
            st = classify(upper, low, eps, rtol * eps + band, band)
            if mode == HYBRID:
                if st == NO_CONTACT:
                    continue
                if st == NOT_CONVERGED:
                    stats[STAT_FALLBACKS] += 1
                # certified contact: kept whatever its distance; not converged: kept if the
                # distance is within ε
                dist[c] = select(st == CONTACT, one, one - one)
                if c < k:
                    _move_column(ga, gfa, gb, gfb, gi, gj, geps, k, c)
                c += 1
            elif st != NO_CONTACT:
                o = (ga[0, k], ga[1, k], ga[2, k])
                p = (scratch[0, k] + o[0], scratch[1, k] + o[1], scratch[2, k] + o[2])
                q = (scratch[3, k] + o[0], scratch[4, k] + o[1], scratch[5, k] + o[2])
                n = _record(
                    n, gi[k], gj[k], upper, p, q, st, out_i, out_j, out_d, out_p, out_q, out_s
                )
    if c > 0:
        certified_points(ga, gfa, gb, gfb, c, one, final, rows)
        for k in range(c):
            least = min(least, np.float64(v0[k]) - np.float64(geps[k]))
            if dist[k] != 0 or v0[k] <= geps[k]:
                p, q = (v1[k], v2[k], v3[k]), (v4[k], v5[k], v6[k])
                n = _record(
                    n, gi[k], gj[k], v0[k], p, q, CONTACT, out_i, out_j, out_d, out_p, out_q, out_s
                )
    closest[0] = least
    return n


@njit(**BORROW, forceinline=True)
def _move_column(ga, gfa, gb, gfb, gi, gj, geps, k, c):
    """Column ``k`` of a gathered block (both sides' coordinates and frames, indices,
    contact distance) into column ``c``."""
    for r in range(9):
        ga[r, c] = ga[r, k]
        gb[r, c] = gb[r, k]
    for r in range(14):
        gfa[r, c] = gfa[r, k]
        gfb[r, c] = gfb[r, k]
    gi[c], gj[c], geps[c] = gi[k], gj[k], geps[k]


@njit(**BORROW)
def _flush(rm, c, params, work, n, out, stats):
    """Gather the ``c`` queued candidates (``work`` indices gi, gj) and resolve them.

    ``rm = (a, frames of a, b, frames of b)`` as row-major arrays.
    """
    a_rm, fa_rm, b_rm, fb_rm = rm
    ga, gfa, gb, gfb, gi, gj = work[:6]
    gather_rows(a_rm, fa_rm, gi, c, ga, gfa)
    gather_rows(b_rm, fb_rm, gj, c, gb, gfb)
    return _resolve(c, params, work, n, out, stats)


@njit(**JIT)
def all_pairs_kernel(a, fa, b, fb, rm, eps_a, eps_b, start, stop, params, out, stats):
    """Contacts among all pairs ``(i, j)``, ``start ≤ i < stop``, every j (streamed).

    A pair is in contact when its distance is at most ``eps_a[i] + eps_b[j]``; a contact
    records :func:`~engine.kernels.geometry.triangle_points.certified_points`' values (in
    ``EXACT`` mode :func:`vertex_point`, else ``exact_point``, on the pairs whose exact
    distance is within ε plus a rounding allowance, then decided on the recorded distance,
    as :func:`_resolve` decides).
    ``rm`` holds row-major copies of (a, fa, b, fb) for gathering; ``params`` and
    ``out`` are as in :func:`_resolve` and :func:`_record`. Returns the number of
    results, which may exceed the capacity of ``out`` (the host then re-runs with
    more room). ``ITERATIVE`` mode also returns not-converged pairs (status
    ``NOT_CONVERGED``: maybe in contact). Outside ``EXACT`` mode, pairs whose
    centroid-axis bound certifies "no contact" are dropped; the rest are queued
    across rows and resolved a full block at a time.
    """
    mode, one, band_factor = params[0], params[3], params[4]
    nb = b.shape[1]
    n = ZERO
    work = workspace(a)
    queue_i, queue_j, queue_eps = work[4], work[5], work[6]
    out_i, out_j, out_d, out_p, out_q, out_s = out
    margin = np.empty(nb, a.dtype)
    dist = np.empty(nb, a.dtype)
    h = one / (one + one)
    h4 = (h * h) * (h * h)
    ulp16 = (h4 * h4) * (h4 * h4)  # 2⁻¹⁶
    c = ZERO
    for i in range(start, stop):
        stats[STAT_PAIRS] += nb
        if mode == EXACT:
            exact_rows(a, fa, i, b, fb, one, dist)
            for j in range(nb):
                reach = eps_a[i] + eps_b[j]
                # the certified distance is the exact one up to a few ulp of the pair's scale
                allowance = (dist[j] + _extent(fa, i, one) + _extent(fb, j, one)) * ulp16
                if dist[j] <= reach + allowance:
                    d, p, q = vertex_point(a, i, b, j, one)
                    if not d >= 0:
                        d, p, q = exact_point(a, fa, i, b, fb, j, one)
                    if d <= reach:
                        n = _record(
                            n, i, j, d, p, q, CONTACT, out_i, out_j, out_d, out_p, out_q, out_s
                        )
            continue
        bound_rows(a, fa, i, b, fb, eps_a[i], eps_b, one, band_factor, margin)
        kept = ZERO
        for j in range(nb):
            if margin[j] <= 0:
                kept += 1
                queue_i[c], queue_j[c], queue_eps[c] = i, j, eps_a[i] + eps_b[j]
                c += 1
                if c == BLOCK:
                    n = _flush(rm, c, params, work, n, out, stats)
                    c = ZERO
        stats[STAT_CULLED] += nb - kept
    if c > 0:
        n = _flush(rm, c, params, work, n, out, stats)
    return n


@njit(**JIT)
def listed_workspace(a):
    """Buffers of :func:`listed_kernel`: :func:`workspace`, then gathered coordinates
    of A and B, contact distances and bound margins of one block."""
    f = a.dtype
    return (
        workspace(a),
        np.empty((9, BLOCK), f),
        np.empty((9, BLOCK), f),
        np.empty(BLOCK, f),
        np.empty(BLOCK, f),
    )


@njit(**BORROW)
def listed_kernel(rm, eps_a, eps_b, pairs, start, stop, params, buffers, out, n, stats):
    """Contacts among listed pairs ``pairs[t] = (i, j)`` (int64), ``start ≤ t < stop``.

    Same arguments and return value as :func:`all_pairs_kernel`, except that
    results are appended to ``out`` after its first ``n`` entries, and that the
    caller passes the :func:`listed_workspace` ``buffers`` (so that a traversal
    calling this per level allocates them once). Outside ``EXACT`` mode each
    block of pairs is culled on gathered coordinates; survivors are queued and
    resolved a full block at a time.
    """
    a_rm, b_rm = rm[0], rm[2]
    mode, one, band_factor = params[0], params[3], params[4]
    work, ca, cb, ceps, margin = buffers
    queue_i, queue_j, queue_eps = work[4], work[5], work[6]
    c = ZERO
    for t0 in range(start, stop, BLOCK):
        m = min(BLOCK, stop - t0)
        stats[STAT_PAIRS] += m
        for k in range(m):
            ceps[k] = eps_a[pairs[t0 + k, 0]] + eps_b[pairs[t0 + k, 1]]
        if mode == EXACT:
            for k in range(m):
                margin[k] = -one
        else:
            gather_coords(a_rm, pairs, 0, t0, m, ca)
            gather_coords(b_rm, pairs, 1, t0, m, cb)
            bound_paired(ca, cb, m, ceps, one, band_factor, margin)
        kept = ZERO
        for k in range(m):
            if margin[k] <= 0:
                kept += 1
                queue_i[c], queue_j[c], queue_eps[c] = pairs[t0 + k, 0], pairs[t0 + k, 1], ceps[k]
                c += 1
                if c == BLOCK:
                    n = _flush(rm, c, params, work, n, out, stats)
                    c = ZERO
        stats[STAT_CULLED] += m - kept
    if c > 0:
        n = _flush(rm, c, params, work, n, out, stats)
    return n
