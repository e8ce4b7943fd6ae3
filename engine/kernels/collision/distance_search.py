"""Minimum distance between two posed meshes: one best-first branch and bound over their
surrogate trees, in one call (the kernel of :func:`engine.collision.proximity.mesh_distance`).

The query runs in body A's frame: B's sphere centres are moved by the relative pose
``pose_a⁻¹ ∘ pose_b`` as they are read, B's triangles by
:func:`~engine.kernels.collision.rigid.move_kernel` (the contact search's mover, so the
exact kernel sees the bits it sees there) when their exact distance is evaluated.

**Lower bounds** of a node pair (a, b), every one below the distance of every pair of
covered faces (g = surrogate ε − leaf ε, 0 for a leaf; every point of a covered face lies
within g of the node's triangle, see :mod:`engine.collision.proximity`):

0. spheres: ``|c_a − c_b| − r_a − r_b`` (bounding spheres of the covered faces);
1. projection: the node triangles projected on the axis through the two centres, the gap
   between the two intervals less ``g_a + g_b`` (a separating-axis bound: 6 dot products);
2. surrogates (optional, ``refine``): the exact distance of the two node triangles less
   ``g_a + g_b``.

A leaf pair's last stage is its exact distance (:func:`~engine.kernels.geometry.
triangle_batch.exact_point`, in the query precision): a candidate for the minimum.

**Search.** A greedy descent (the child pair with the smallest sphere bound, down to a
leaf pair) gives a first upper bound. Then a binary heap of node pairs keyed on their
lower bound clamped at 0 (ties: the most recently pushed first, so that where bounds are
still ≤ 0 the search runs depth first, nearest child first, towards a crossing pair) is
popped: an entry whose bound, less the rounding margin, exceeds the best distance ends
the search (every other entry's bound is at least as large); otherwise its next bound
is computed, and the entry is pushed back when that bound exceeds the heap's top,
else processed at once (lazy evaluation: the cheap bound first). A surrogate pair past
its last bound stage is unfolded: the node with the larger g (a leaf never) is replaced
by its children, and a child pair enters the heap only if its sphere bound passes the
same test. The search also ends when a leaf pair has distance 0.

A pair is pruned only when a bound exceeds the best candidate by more than ``margin``
(:func:`~engine.kernels.collision.batch.query_margin`: 256 ulp of the pair's scale, which
bounds the rounding of the bounds and of the exact kernel), so the result is the minimum
of the exact kernel over every face pair, evaluated on the same moved triangles.

Arrays (``N`` nodes of a tree, node order, root at row 0):

* ``coords (N, 9)``, ``frames (N, 14)`` — the nodes' prepared triangles, row-major
  (:class:`~engine.geometry.distance.TriangleSet`): A's in the query dtype, B's in float64
  (body frame; moved into A's frame and rounded to the query dtype when evaluated);
* ``master (N, 9)`` float64 — A's triangles in float64 (the bounds' arithmetic);
* ``node (N, 5)`` float64 — bounding sphere centre (0–2) and radius (3) of the covered
  faces, g (4);
* ``tree (N, 3)`` int64 — first child, child count (0 for a leaf), face (−1 for a
  surrogate).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from engine.kernels.collision.batch import query_margin, relative_pose
from engine.kernels.geometry.triangle_batch import ZERO, exact_paired, exact_point
from engine.kernels.jit import EXACT_JIT, INLINE, JIT, sqrt

# Slots of ``out_i`` (int64) and ``out_f`` (float64) written by :func:`distance_kernel`.
OUT_FACE_A, OUT_FACE_B, OUT_PAIRS, OUT_EXACT, OUT_UNFOLDED, OUT_LARGEST, OUT_SPHERES = range(7)
N_OUT_I = 7
OUT_DISTANCE, OUT_POINT_A, OUT_POINT_B = 0, 1, 4  # distance, then two (3,) world points
N_OUT_F = 7
HEAP_START = 256  # initial capacity of the heap (doubled when full)


@njit(**JIT)
def _grown(array, size):
    """A copy of ``array (n,)`` with room for ``size > n`` entries."""
    out = np.empty(size, array.dtype)
    out[: array.shape[0]] = array
    return out


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


@njit(**JIT)
def _apart(ax, ay, az, bx, by, bz):
    """``b − a`` and its length."""
    dx, dy, dz = bx - ax, by - ay, bz - az
    return dx, dy, dz, sqrt(dx * dx + dy * dy + dz * dz)


@njit(**INLINE)
def _sphere_bound(a_node, i, b_node, j, r, s):
    """Sphere bound of the pair (i, j); ``r``, ``s`` as in :func:`_moved`."""
    cx = r[0] * b_node[j, 0] + r[1] * b_node[j, 1] + r[2] * b_node[j, 2] + s[0]
    cy = r[3] * b_node[j, 0] + r[4] * b_node[j, 1] + r[5] * b_node[j, 2] + s[1]
    cz = r[6] * b_node[j, 0] + r[7] * b_node[j, 1] + r[8] * b_node[j, 2] + s[2]
    length = _apart(a_node[i, 0], a_node[i, 1], a_node[i, 2], cx, cy, cz)[3]
    return length - a_node[i, 3] - b_node[j, 3]


@njit(**INLINE)
def _gather_a(a_coords, a_frames, i, k, ga, gfa):
    """Column ``k`` of ``ga (9, m)``, ``gfa (14, m)``: A's node ``i``."""
    for c in range(9):
        ga[c, k] = a_coords[i, c]
    for c in range(14):
        gfa[c, k] = a_frames[i, c]


@njit(**INLINE)
def _gather_b(b_coords, b_frames, j, r, s, k, gb, gfb):
    """Column ``k`` of ``gb (9, m)``, ``gfb (14, m)``: B's node ``j`` moved into A's frame
    as :func:`~engine.kernels.collision.rigid.move_kernel` moves it, rounded to their dtype."""
    for v in range(3):
        x, y, z = _moved(r, s, b_coords[j, 3 * v], b_coords[j, 3 * v + 1], b_coords[j, 3 * v + 2])
        gb[3 * v, k], gb[3 * v + 1, k], gb[3 * v + 2, k] = x, y, z
        x, y, z = _turned(r, b_frames[j, 3 * v], b_frames[j, 3 * v + 1], b_frames[j, 3 * v + 2])
        gfb[3 * v, k], gfb[3 * v + 1, k], gfb[3 * v + 2, k] = x, y, z
    for c in range(9, 14):
        gfb[c, k] = b_frames[j, c]


@njit(**JIT)
def _split_a(count_a, gap_a, count_b, gap_b):
    """Unfold A's node of a pair, not both leaves (child counts, g): the larger g."""
    return count_a > 0 and (count_b == 0 or gap_a >= gap_b)


@njit(**JIT)
def distance_kernel(
    a_coords,
    a_frames,
    a_master,
    a_node,
    a_tree,
    b_coords,
    b_frames,
    b_node,
    b_tree,
    position_a,
    orientation_a,
    position_b,
    orientation_b,
    extent_a,
    extent_b,
    ulp,
    one,
    out_i,
    out_f,
):
    """Minimum distance between body A (its nodes at ``position_a (3,)``, ``orientation_a
    (4,)``) and body B (see the module docstring for the node arrays).

    ``extent_a``, ``extent_b`` (float): largest body-frame coordinate of each tree (the
    rounding margin's scale); ``ulp`` (float): machine epsilon of the query dtype, the
    dtype of ``a_coords``, ``a_frames`` and of ``one``; ``refine`` (bool): evaluate the
    (unused) .

    Writes ``out_i (N_OUT_I,)`` int64: faces of A and B attaining the minimum, node pairs
    that entered the heap, exact evaluations, pairs unfolded, largest heap, child pairs
    pruned by their spheres; ``out_f (N_OUT_F,)`` float64: the distance, then its closest
    points on A and on B in the world frame.
    """
    ra, rotation, shift = relative_pose(position_a, orientation_a, position_b, orientation_b)
    margin = query_margin(extent_a, extent_b, shift, ulp)
    rr = rotation
    r = (rr[0, 0], rr[0, 1], rr[0, 2], rr[1, 0], rr[1, 1], rr[1, 2], rr[2, 0], rr[2, 1], rr[2, 2])
    s = (shift[0], shift[1], shift[2])
    dtype = a_coords.dtype
    cap = 16  # gathered child pairs (columns), grown to the largest child count met
    ga, gfa = np.empty((9, cap), dtype), np.empty((14, cap), dtype)
    gb, gfb = np.empty((9, cap), dtype), np.empty((14, cap), dtype)
    dist = np.empty(cap, dtype)
    child_low = np.empty(cap)
    child_index = np.empty(cap, np.int64)
    pairs = exact = unfolded = largest = pruned = ZERO

    # greedy descent (the child with the smallest sphere bound): a first upper bound
    i, j = ZERO, ZERO
    while a_tree[i, 1] > 0 or b_tree[j, 1] > 0:
        split = _split_a(a_tree[i, 1], a_node[i, 4], b_tree[j, 1], b_node[j, 4])
        first, count = (a_tree[i, 0], a_tree[i, 1]) if split else (b_tree[j, 0], b_tree[j, 1])
        pick, low = first, np.inf
        for c in range(first, first + count):
            bound = (
                _sphere_bound(a_node, c, b_node, j, r, s)
                if split
                else _sphere_bound(a_node, i, b_node, c, r, s)
            )
            if bound < low:
                pick, low = c, bound
        if split:
            i = pick
        else:
            j = pick
    _gather_a(a_coords, a_frames, i, ZERO, ga, gfa)
    _gather_b(b_coords, b_frames, j, r, s, ZERO, gb, gfb)
    d, p, q = exact_point(ga, gfa, ZERO, gb, gfb, ZERO, one)
    exact += 1
    best, best_i, best_j, best_p, best_q = np.float64(d), i, j, p, q

    # best-first search over pairs with a surrogate (leaf pairs are resolved as they are met)
    size = HEAP_START
    key = np.empty(size)
    entry_a = np.empty(size, np.int64)
    entry_b = np.empty(size, np.int64)
    heap = np.empty(size, np.int64)
    entries = ZERO
    size = ZERO
    pairs += 1
    if a_tree[0, 1] > 0 or b_tree[0, 1] > 0:
        key[0] = max(_sphere_bound(a_node, 0, b_node, 0, r, s), 0.0)
        entry_a[0], entry_b[0] = 0, 0
        entries = 1
        size = _push(heap, size, key, ZERO)
        largest = 1
    while size > 0 and best > 0.0:
        e = heap[0]
        if key[e] - margin > best:
            break
        size = _pop(heap, size, key)
        i, j = entry_a[e], entry_b[e]
        # unfold the node with the larger g; bound the children
        unfolded += 1
        split = _split_a(a_tree[i, 1], a_node[i, 4], b_tree[j, 1], b_node[j, 4])
        first, count = (a_tree[i, 0], a_tree[i, 1]) if split else (b_tree[j, 0], b_tree[j, 1])
        if count > child_index.shape[0]:
            ga, gfa = np.empty((9, count), dtype), np.empty((14, count), dtype)
            gb, gfb = np.empty((9, count), dtype), np.empty((14, count), dtype)
            dist, child_low = np.empty(count, dtype), np.empty(count)
            child_index = np.empty(count, np.int64)
        m = 0
        for c in range(first, first + count):
            low = (
                _sphere_bound(a_node, c, b_node, j, r, s)
                if split
                else _sphere_bound(a_node, i, b_node, c, r, s)
            )
            if low - margin > best:
                pruned += 1
                continue
            if split:
                _gather_a(a_coords, a_frames, c, m, ga, gfa)
                _gather_b(b_coords, b_frames, j, r, s, m, gb, gfb)
            else:
                _gather_a(a_coords, a_frames, i, m, ga, gfa)
                _gather_b(b_coords, b_frames, c, r, s, m, gb, gfb)
            child_low[m], child_index[m] = low, c
            m += 1
        pairs += m
        exact_paired(ga, gfa, gb, gfb, m, one, dist)
        kept = 0
        for k in range(m):
            c = child_index[k]
            ci, cj = (c, j) if split else (i, c)
            low = max(child_low[k], np.float64(dist[k]) - a_node[ci, 4] - b_node[cj, 4])
            if low - margin > best:
                continue
            if a_tree[ci, 1] == 0 and b_tree[cj, 1] == 0:  # a leaf pair: a candidate
                d, p, q = exact_point(ga, gfa, k, gb, gfb, k, one)
                exact += 1
                if d < best:
                    best, best_i, best_j, best_p, best_q = np.float64(d), ci, cj, p, q
                continue
            t = kept  # insertion, the largest bound first (ties pop the last pushed first)
            while t > 0 and child_low[t - 1] < low:
                child_low[t], child_index[t] = child_low[t - 1], child_index[t - 1]
                t -= 1
            child_low[t], child_index[t] = low, c
            kept += 1
        if entries + kept > key.shape[0]:
            grow = 2 * (entries + kept)
            key, heap = _grown(key, grow), _grown(heap, grow)
            entry_a, entry_b = _grown(entry_a, grow), _grown(entry_b, grow)
        for t in range(kept):
            if child_low[t] - margin > best:  # best may have dropped since
                continue
            c = child_index[t]
            key[entries] = max(child_low[t], 0.0)
            entry_a[entries], entry_b[entries] = (c, j) if split else (i, c)
            size = _push(heap, size, key, entries)
            entries += 1
        largest = max(largest, size)

    out_i[OUT_FACE_A], out_i[OUT_FACE_B] = a_tree[best_i, 2], b_tree[best_j, 2]
    out_i[OUT_PAIRS], out_i[OUT_EXACT], out_i[OUT_UNFOLDED] = pairs, exact, unfolded
    out_i[OUT_LARGEST], out_i[OUT_SPHERES] = largest, pruned
    out_f[OUT_DISTANCE] = best
    pa = np.float64(best_p[0]), np.float64(best_p[1]), np.float64(best_p[2])
    pb = np.float64(best_q[0]), np.float64(best_q[1]), np.float64(best_q[2])
    for c in range(3):  # closest points to the world frame: x ↦ R_a x + p_a
        out_f[OUT_POINT_A + c] = ra[c, 0] * pa[0] + ra[c, 1] * pa[1] + ra[c, 2] * pa[2]
        out_f[OUT_POINT_A + c] += position_a[c]
        out_f[OUT_POINT_B + c] = ra[c, 0] * pb[0] + ra[c, 1] * pb[1] + ra[c, 2] * pb[2]
        out_f[OUT_POINT_B + c] += position_a[c]
