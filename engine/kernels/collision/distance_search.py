"""Minimum distance between two posed meshes: one best-first branch and bound over their
surrogate trees, in one call (the kernel of :func:`engine.collision.proximity.mesh_distance`).

The query runs in body A's frame: B's sphere centres are moved by the relative pose
``pose_a⁻¹ ∘ pose_b`` as they are read, and B's triangles when their exact distance is
evaluated, with the arithmetic of :func:`~engine.kernels.collision.rigid.move_kernel`
(the contact search's mover: the exact kernel sees the same bits as there).

**Lower bounds** of a node pair (a, b), each below the distance of every pair of faces
they cover (g = surrogate ε − leaf ε, 0 for a leaf; every point of a covered face lies
within g of the node's triangle, see :mod:`engine.collision.proximity`), cheapest first:

1. spheres: ``|c_a − c_b| − r_a − r_b`` (bounding spheres of the covered faces);
2. projection: the gap between the two node triangles projected on the axis through the
   two centres, less ``g_a + g_b`` (a separating axis: 6 dot products);
3. surrogates: the exact distance of the two node triangles less ``g_a + g_b``
   (:func:`~engine.kernels.geometry.triangle_batch.exact_paired`, vectorised over the
   children of a pair, in the query precision).

**Search.** A greedy descent (the child with the smallest sphere bound, down to a leaf
pair) gives a first upper bound: the best distance. A binary heap holds node pairs with
a surrogate, keyed on their lower bound clamped at 0; ties pop the most recently pushed
first, so that while bounds are ≤ 0 the search runs depth first, nearest child first,
towards a crossing pair. The top pair is popped; if its bound, less the rounding margin,
exceeds the best distance the search ends (every other bound is at least as large).
Else the pair is unfolded: its node with the larger sphere (never a leaf) is replaced by
its children, and when the pair's bound is positive (best first: nothing to gain from
going deep) the other node too if it is a surrogate with a sphere at least ``BOTH`` times
as large. Up to ``POPS`` pairs with a positive bound are popped and unfolded together
(one with a bound ≤ 0 alone: depth first), so that their child pairs get bound 3 in one
vectorised call. When both nodes unfold, each child is first tested against the other
node's sphere (bound 1), and only the children that pass are paired. Each child pair is
bounded by 1, 2 and 3 in turn and dropped at the first bound that exceeds the best
distance by more than the margin. A surviving leaf
pair gets its exact distance and closest points
(:func:`~engine.kernels.geometry.triangle_batch.exact_point`): a candidate; the others are
pushed, the largest bound first. The search also ends at a candidate of distance 0 (the
meshes touch or intersect). The unfolding rules and ``BOTH``, ``POPS`` gave the shortest
times on the cases of ``benchmarks/peers.py`` among those tried (the larger g, the
larger sphere; one node or both; one pair or 8 at a time).

A pair is dropped only when a bound exceeds the best candidate by more than ``margin``
(:func:`~engine.kernels.collision.batch.query_margin`: 256 ulp of the pair's scale, which
bounds the rounding of the bounds and of the exact kernel), so the result is the minimum
of ``exact_point`` over every face pair (A's rows, B's rows moved), bit for bit.

Node arrays of a tree (``N`` nodes, node order, root at row 0), row-major:

* ``rows (N, N_COLUMNS)`` float64 — per node: its prepared triangle (columns
  ``COORDS:COORDS + 9``) and frame (``FRAMES:FRAMES + 14``,
  :class:`~engine.geometry.distance.TriangleSet`), body frame; the bounding sphere of
  the covered faces (centre ``CENTRE:CENTRE + 3``, radius ``RADIUS``); ``GAP`` g; then
  ``FIRST`` (first child), ``COUNT`` (child count, 0 for a leaf) and ``FACE`` (the face
  of a leaf, −1 for a surrogate), integers stored exactly; ``EXTENT`` the tree's largest
  absolute body-frame coordinate (every row; the rounding margin's scale);
* ``prepared (N, ≥ 23)`` — A's triangles and frames (the same columns) in the query
  dtype: ``rows`` itself for float64.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from engine.kernels.collision.batch import query_margin, relative_pose
from engine.kernels.geometry.triangle_batch import ZERO, exact_paired, exact_point
from engine.kernels.jit import EXACT_JIT, INLINE, JIT, sqrt

# Columns of the node rows.
COORDS, FRAMES, CENTRE, RADIUS, GAP, FIRST, COUNT, FACE, EXTENT = 0, 9, 23, 26, 27, 28, 29, 30, 31
N_COLUMNS = 32
# Slots of ``out_i`` (int64) and ``out_f`` (float64) written by :func:`distance_kernel`.
OUT_FACE_A, OUT_FACE_B, OUT_PAIRS, OUT_EXACT, OUT_UNFOLDED, OUT_LARGEST, OUT_PRUNED = range(7)
N_OUT_I = 7
OUT_DISTANCE, OUT_POINT_A, OUT_POINT_B = 0, 1, 4  # the distance, then two (3,) points
N_OUT_F = 7
HEAP_START = 256  # initial capacity of the heap (doubled when full)
CHILDREN_START = 64  # initial capacity of the gathered child pairs (grown when needed)
BOTH = 0.5  # unfold both nodes of a pair when their spheres are this close in size
POPS = 8  # pairs unfolded together (their children's exact bounds in one vectorised call)


@njit(**JIT)
def _grown(array, size):
    """A copy of ``array (n,)`` with room for ``size > n`` entries."""
    out = np.empty(size, array.dtype)
    out[: array.shape[0]] = array
    return out


@njit(**JIT)
def _grown_rows(array, size):
    """A copy of ``array (k, n)`` with room for ``size > n`` columns."""
    out = np.empty((array.shape[0], size), array.dtype)
    out[:, : array.shape[1]] = array
    return out


@njit(**JIT)
def _gathered(m, dtype):
    """Buffers for ``m`` gathered pairs, one allocation: ``(A (9, m), A's frames (14, m),
    B (9, m), B's frames (14, m), distances (m,))``, C-contiguous views, ``dtype``."""
    g = np.empty((47, m), dtype)
    return g[0:9], g[9:23], g[23:32], g[32:46], g[46]


@njit(**JIT)
def _before(key_e, e, key_f, f):
    """Entry ``e`` pops before entry ``f``: smaller key, ties to the later entry."""
    return key_e < key_f or (key_e == key_f and e > f)


@njit(**INLINE)
def _push(heap, size, key, e):
    """Add entry ``e`` to the binary heap ``heap[:size]`` (int64) on ``key`` (float64);
    returns the new size."""
    k = size
    ke = key[e]
    while k > 0:
        parent = (k - 1) >> 1
        up = heap[parent]
        if not _before(ke, e, key[up], up):
            break
        heap[k] = up
        k = parent
    heap[k] = e
    return size + 1


@njit(**INLINE)
def _pop(heap, size, key):
    """Remove the top of ``heap[:size]`` (size > 0); returns the new size."""
    size -= 1
    last = heap[size]
    kl = key[last]
    k = 0
    while True:
        child = 2 * k + 1
        if child >= size:
            break
        c = heap[child]
        if child + 1 < size:
            d = heap[child + 1]
            if _before(key[d], d, key[c], c):
                child, c = child + 1, d
        if not _before(key[c], c, kl, last):
            break
        heap[k] = c
        k = child
    if size > 0:
        heap[k] = last
    return size


@njit(**EXACT_JIT)
def _moved(r, s, x, y, z):
    """``R x + s`` as :func:`~engine.kernels.collision.rigid.move_kernel` computes it (no
    contraction: the same bits); ``r`` the 9 entries of R row by row, ``s`` 3."""
    return (
        r[0] * x + r[1] * y + r[2] * z + s[0],
        r[3] * x + r[4] * y + r[5] * z + s[1],
        r[6] * x + r[7] * y + r[8] * z + s[2],
    )


@njit(**EXACT_JIT)
def _turned(r, x, y, z):
    """``R x`` as :func:`~engine.kernels.collision.rigid.move_kernel` computes it."""
    return (
        r[0] * x + r[1] * y + r[2] * z,
        r[3] * x + r[4] * y + r[5] * z,
        r[6] * x + r[7] * y + r[8] * z,
    )


@njit(**INLINE)
def _axis(a, i, b, j, r, s):
    """``(u, |u|)``: from the sphere centre of A's node ``i`` to that of B's node ``j``."""
    cx = r[0] * b[j, CENTRE] + r[1] * b[j, CENTRE + 1] + r[2] * b[j, CENTRE + 2] + s[0]
    cy = r[3] * b[j, CENTRE] + r[4] * b[j, CENTRE + 1] + r[5] * b[j, CENTRE + 2] + s[1]
    cz = r[6] * b[j, CENTRE] + r[7] * b[j, CENTRE + 1] + r[8] * b[j, CENTRE + 2] + s[2]
    ux, uy, uz = cx - a[i, CENTRE], cy - a[i, CENTRE + 1], cz - a[i, CENTRE + 2]
    return ux, uy, uz, sqrt(ux * ux + uy * uy + uz * uz)


@njit(**INLINE)
def _sphere(a, i, b, j, r, s):
    """Sphere bound of the pair (i, j)."""
    return _axis(a, i, b, j, r, s)[3] - a[i, RADIUS] - b[j, RADIUS]


@njit(**INLINE)
def _bounds(a, i, b, j, r, s, best, margin):
    """Sphere bound of the pair (i, j), then (unless that one drops the pair, ``bound −
    margin > best``) the larger of it and the projection bound."""
    ux, uy, uz, length = _axis(a, i, b, j, r, s)
    sphere = length - a[i, RADIUS] - b[j, RADIUS]
    if sphere - margin > best or not length > 0.0:
        return sphere
    ux, uy, uz = ux / length, uy / length, uz / length
    # u in B's frame (Rᵀu) and the shift's share, so that B's body-frame rows project
    vx = r[0] * ux + r[3] * uy + r[6] * uz
    vy = r[1] * ux + r[4] * uy + r[7] * uz
    vz = r[2] * ux + r[5] * uy + r[8] * uz
    offset = s[0] * ux + s[1] * uy + s[2] * uz
    a0 = a[i, 0] * ux + a[i, 1] * uy + a[i, 2] * uz
    a1 = a[i, 3] * ux + a[i, 4] * uy + a[i, 5] * uz
    a2 = a[i, 6] * ux + a[i, 7] * uy + a[i, 8] * uz
    b0 = b[j, 0] * vx + b[j, 1] * vy + b[j, 2] * vz + offset
    b1 = b[j, 3] * vx + b[j, 4] * vy + b[j, 5] * vz + offset
    b2 = b[j, 6] * vx + b[j, 7] * vy + b[j, 8] * vz + offset
    lo_a, hi_a = min(a0, min(a1, a2)), max(a0, max(a1, a2))
    lo_b, hi_b = min(b0, min(b1, b2)), max(b0, max(b1, b2))
    gap = max(lo_b - hi_a, lo_a - hi_b) - a[i, GAP] - b[j, GAP]
    return max(sphere, gap)


@njit(**INLINE)
def _gather_a(prepared, i, k, ga, gfa):
    """Column ``k`` of ``ga (9, m)``, ``gfa (14, m)``: A's node ``i``."""
    for c in range(9):
        ga[c, k] = prepared[i, COORDS + c]
    for c in range(14):
        gfa[c, k] = prepared[i, FRAMES + c]


@njit(**INLINE)
def _gather_b(b, j, r, s, k, gb, gfb):
    """Column ``k`` of ``gb (9, m)``, ``gfb (14, m)``: B's node ``j`` moved into A's frame
    as :func:`~engine.kernels.collision.rigid.move_kernel` moves it, rounded to their dtype."""
    for v in range(3):
        x, y, z = _moved(r, s, b[j, 3 * v], b[j, 3 * v + 1], b[j, 3 * v + 2])
        gb[3 * v, k], gb[3 * v + 1, k], gb[3 * v + 2, k] = x, y, z
        f = FRAMES + 3 * v
        x, y, z = _turned(r, b[j, f], b[j, f + 1], b[j, f + 2])
        gfb[3 * v, k], gfb[3 * v + 1, k], gfb[3 * v + 2, k] = x, y, z
    for c in range(9, 14):
        gfb[c, k] = b[j, FRAMES + c]


@njit(**INLINE)
def _copy_column(g, k0, k):
    """``g[:, k] = g[:, k0]``."""
    for c in range(g.shape[0]):
        g[c, k] = g[c, k0]


@njit(**JIT)
def _split_a(count_a, radius_a, count_b, radius_b):
    """Unfold A's node of a pair, not both leaves (child counts, sphere radii): the larger
    sphere."""
    return count_a > 0 and (count_b == 0 or radius_a >= radius_b)


@njit(**JIT)
def _unfolded(a, i, b, j, apart):
    """``(first, count)`` of A's, then of B's, nodes that replace the pair (i, j), not both
    leaves: the node with the larger sphere unfolds, and with ``apart`` (the pair's bound
    is positive: best first, not depth first) the other one too when it is a surrogate
    whose sphere is at least ``BOTH`` times as large; a node that stays is its own
    ``(i, 1)``."""
    ra, rb = a[i, RADIUS], b[j, RADIUS]
    split = _split_a(a[i, COUNT], ra, b[j, COUNT], rb)
    both = apart and a[i, COUNT] > 0 and b[j, COUNT] > 0 and min(ra, rb) >= BOTH * max(ra, rb)
    first_a, count_a, first_b, count_b = i, np.int64(1), j, np.int64(1)
    if split or both:
        first_a, count_a = np.int64(a[i, FIRST]), np.int64(a[i, COUNT])
    if not split or both:
        first_b, count_b = np.int64(b[j, FIRST]), np.int64(b[j, COUNT])
    return first_a, count_a, first_b, count_b


@njit(**JIT)
def distance_kernel(
    prepared_a, a, b, position_a, orientation_a, position_b, orientation_b, ulp, one, out_i, out_f
):
    """Minimum distance between body A (node rows ``a``, its triangles in the query dtype
    ``prepared_a``; see the module docstring) at ``position_a (3,)``, ``orientation_a
    (4,)`` (unit quaternion w, x, y, z) and body B (``b``) at ``position_b``,
    ``orientation_b``; ``ulp`` (float), ``one`` (1 in the query dtype): machine epsilon
    and unit of the query dtype.

    Writes ``out_i (N_OUT_I,)`` int64: the faces of A and of B attaining the minimum, node
    pairs bounded (the root's and every child pair's), exact evaluations of leaf pairs
    (``exact_point``), pairs unfolded, the largest heap, child pairs dropped by their
    sphere or projection bound; ``out_f (N_OUT_F,)`` float64: the distance (in the query
    dtype), then its closest points on A and on B, world frame.
    """
    ra, rotation, shift = relative_pose(position_a, orientation_a, position_b, orientation_b)
    margin = query_margin(a[0, EXTENT], b[0, EXTENT], shift, ulp)
    rr = rotation
    r = (rr[0, 0], rr[0, 1], rr[0, 2], rr[1, 0], rr[1, 1], rr[1, 2], rr[2, 0], rr[2, 1], rr[2, 2])
    s = (shift[0], shift[1], shift[2])
    dtype = prepared_a.dtype
    ga, gfa, gb, gfb, dist = _gathered(CHILDREN_START, dtype)
    pairs = exact = unfolded = pruned = ZERO

    # greedy descent (the larger sphere unfolds, to the child with the smallest sphere
    # bound): a first upper bound
    i, j = ZERO, ZERO
    while a[i, COUNT] > 0 or b[j, COUNT] > 0:
        split = _split_a(a[i, COUNT], a[i, RADIUS], b[j, COUNT], b[j, RADIUS])
        first = np.int64(a[i, FIRST]) if split else np.int64(b[j, FIRST])
        count = np.int64(a[i, COUNT]) if split else np.int64(b[j, COUNT])
        pick, low = first, np.inf
        for c in range(first, first + count):
            ci, cj = (c, j) if split else (i, c)
            bound = _sphere(a, ci, b, cj, r, s)
            if bound < low:
                pick, low = c, bound
        if split:
            i = pick
        else:
            j = pick
    _gather_a(prepared_a, i, ZERO, ga, gfa)
    _gather_b(b, j, r, s, ZERO, gb, gfb)
    d, p, q = exact_point(ga, gfa, ZERO, gb, gfb, ZERO, one)
    exact += 1
    best, best_i, best_j, best_p, best_q = np.float64(d), i, j, p, q

    # best-first search over the pairs with a surrogate
    entries = size = largest = ZERO
    pairs += 1
    search = best > 0.0 and (a[0, COUNT] > 0 or b[0, COUNT] > 0)
    room = HEAP_START if search else 1
    key = np.empty(room)
    ints = np.empty((3, room), np.int64)
    entry_a, entry_b, heap = ints[0], ints[1], ints[2]
    room = CHILDREN_START if search else 1
    child_low = np.empty(room)  # the gathered child pairs: bound, A's node, B's node
    child_ab = np.empty((2, room), np.int64)
    child_a, child_b = child_ab[0], child_ab[1]
    keep = np.empty((2, 8 if search else 1), np.int64)  # children kept by the parent test
    if search:
        key[0] = max(_sphere(a, ZERO, b, ZERO, r, s), 0.0)
        entry_a[0], entry_b[0] = 0, 0
        entries = 1
        size = _push(heap, size, key, ZERO)
        largest = 1
    while size > 0 and best > 0.0:
        # pop up to POPS pairs with a positive bound (one with a bound ≤ 0 alone: depth
        # first; fewer when their children would overflow the buffers), bound their
        # children with spheres and projections, gather the survivors
        m = popped = 0
        while size > 0 and popped < POPS:
            e = heap[0]
            if key[e] - margin > best or (popped > 0 and key[e] <= 0.0):
                break
            i, j = entry_a[e], entry_b[e]
            first_a, count_a, first_b, count_b = _unfolded(a, i, b, j, key[e] > 0.0)
            count = count_a * count_b
            if m + count > child_a.shape[0]:
                if m > 0:
                    break
                ga, gfa, gb, gfb, dist = _gathered(count, dtype)
                child_low = np.empty(count)
                child_ab = np.empty((2, count), np.int64)
                child_a, child_b = child_ab[0], child_ab[1]
            size = _pop(heap, size, key)
            popped += 1
            start = m
            if max(count_a, count_b) > keep.shape[1]:
                keep = np.empty((2, max(count_a, count_b)), np.int64)
            kept_a = kept_b = 0  # both unfold: each child against the other node's sphere
            for ci in range(first_a, first_a + count_a):
                if count_b > 1 and _sphere(a, ci, b, j, r, s) - margin > best:
                    pruned += count_b
                    continue
                keep[0, kept_a] = ci
                kept_a += 1
            for cj in range(first_b, first_b + count_b):
                if count_a > 1 and _sphere(a, i, b, cj, r, s) - margin > best:
                    pruned += kept_a
                    continue
                keep[1, kept_b] = cj
                kept_b += 1
            for ta in range(kept_a):
                ci = keep[0, ta]
                for tb in range(kept_b):
                    cj = keep[1, tb]
                    low = _bounds(a, ci, b, cj, r, s, best, margin)
                    if low - margin > best:
                        pruned += 1
                        continue
                    _gather_a(prepared_a, ci, m, ga, gfa)
                    if count_b == 1 and m > start:  # the same B node: moved once
                        _copy_column(gb, start, m)
                        _copy_column(gfb, start, m)
                    else:
                        _gather_b(b, cj, r, s, m, gb, gfb)
                    child_low[m], child_a[m], child_b[m] = low, ci, cj
                    m += 1
            pairs += count
        if popped == 0:
            break
        unfolded += popped
        if m == 0:
            continue
        # bound 3 on every gathered pair at once; candidates; the rest sorted, pushed
        exact_paired(ga, gfa, gb, gfb, m, one, dist)
        kept = 0
        for k in range(m):
            ci, cj = child_a[k], child_b[k]
            low = max(child_low[k], np.float64(dist[k]) - a[ci, GAP] - b[cj, GAP])
            if low - margin > best:
                continue
            if a[ci, COUNT] == 0 and b[cj, COUNT] == 0:  # a leaf pair: a candidate
                d, p, q = exact_point(ga, gfa, k, gb, gfb, k, one)
                exact += 1
                if d < best:
                    best, best_i, best_j, best_p, best_q = np.float64(d), ci, cj, p, q
                continue
            t = kept  # insertion, the largest bound first (ties pop the last pushed first)
            while t > 0 and child_low[t - 1] < low:
                child_low[t], child_a[t], child_b[t] = (
                    child_low[t - 1],
                    child_a[t - 1],
                    child_b[t - 1],
                )
                t -= 1
            child_low[t], child_a[t], child_b[t] = low, ci, cj
            kept += 1
        if entries + kept > key.shape[0]:
            key, ints = _grown(key, 2 * (entries + kept)), _grown_rows(ints, 2 * (entries + kept))
            entry_a, entry_b, heap = ints[0], ints[1], ints[2]
        for t in range(kept):
            if child_low[t] - margin > best:  # the best distance may have dropped since
                continue
            key[entries] = max(child_low[t], 0.0)
            entry_a[entries], entry_b[entries] = child_a[t], child_b[t]
            size = _push(heap, size, key, entries)
            entries += 1
        largest = max(largest, size)

    out_i[OUT_FACE_A], out_i[OUT_FACE_B] = np.int64(a[best_i, FACE]), np.int64(b[best_j, FACE])
    out_i[OUT_PAIRS], out_i[OUT_EXACT], out_i[OUT_UNFOLDED] = pairs, exact, unfolded
    out_i[OUT_LARGEST], out_i[OUT_PRUNED] = largest, pruned
    out_f[OUT_DISTANCE] = best
    pa = np.float64(best_p[0]), np.float64(best_p[1]), np.float64(best_p[2])
    pb = np.float64(best_q[0]), np.float64(best_q[1]), np.float64(best_q[2])
    for c in range(3):  # closest points to the world frame: x ↦ R_a x + p_a
        out_f[OUT_POINT_A + c] = ra[c, 0] * pa[0] + ra[c, 1] * pa[1] + ra[c, 2] * pa[2]
        out_f[OUT_POINT_A + c] += position_a[c]
        out_f[OUT_POINT_B + c] = ra[c, 0] * pb[0] + ra[c, 1] * pb[1] + ra[c, 2] * pb[2]
        out_f[OUT_POINT_B + c] += position_a[c]
