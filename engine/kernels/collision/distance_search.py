"""Minimum distance between two posed meshes: one best-first branch and bound over their
surrogate trees, in one call (the kernel of :func:`engine.collision.proximity.mesh_distance`).

The query runs in body A's frame: B's node data are moved by the relative pose
``pose_a⁻¹ ∘ pose_b`` as they are read, B's triangles with the arithmetic of
:func:`~engine.kernels.collision.rigid.move_kernel` (the contact search's mover: the exact
kernel sees the same bits as there).

**Lower bounds** of a node pair (a, b), each below the distance of every pair of faces
they cover (g = surrogate ε − leaf ε, 0 for a leaf; every point of a covered face lies
within g of the node's triangle, see :mod:`engine.collision.proximity`):

1. spheres: ``|c_a − c_b| − r_a − r_b`` (bounding spheres of the covered faces; a pair
   is dropped on squared distances, without a square root);
2. boxes: the gap of the two nodes' oriented boxes on their 6 axes and the axis through
   their centres (:func:`~engine.kernels.collision.distance_bounds.box_gap`; for the
   children of an unfolded pair also the gaps on one box's three axes together,
   :func:`~engine.kernels.collision.distance_bounds.child_bounds`);
3. triangles: the exact distance of the two node triangles less ``g_a + g_b``
   (:func:`~engine.kernels.geometry.triangle_points.exact_points`, vectorised over up to
   a block of pairs, in the query precision, with the pairs' closest points); for a leaf
   pair, its exact distance.

Bounds 1 and 2 are cheap (a few dozen flops); 3 is an exact triangle distance, so it is
computed lazily: only for pairs that reach the top of the heap, a block at a time.

**Search.** A greedy descent (the child with the smallest sphere bound, down to a leaf
pair) gives a first upper bound: the best distance. Node pairs wait keyed on their lower
bound clamped at 0, each marked *refined* once it has bound 3: those with a positive key
in a binary heap, those with key 0 on a stack (pushed in entry order, so that the last
pushed pops first: while bounds are ≤ 0 the search runs depth first, nearest child
first, towards a crossing pair). The *top* pair is the stack's while it holds any (a key
of 0 is the least), else the heap's: the same order as one heap with ties popping the
latest entry first, without sifting entries tied at 0 through the heap. The top pair is
looked at; if its bound, less the rounding margin, exceeds the best distance the search
ends (every other bound is at least as large). Else:

* an unrefined leaf pair, or unrefined pair with a positive bound, is refined together
  with the next such pairs on top (up to ``POPS``): bound 3 in one vectorised call; a
  leaf pair is then a candidate (bound 3 is its exact distance: it lowers the best
  distance or is dropped), any other pair is pushed back with its new key, or dropped.
  A pair whose bound 3 cannot exceed the best distance (its node triangles' nearest
  vertex pair, less ``g_a + g_b``, does not: ``may_drop``) is not refined;
* any other pair (refined, or with a bound ≤ 0: the depth-first dive skips bound 3) is
  unfolded: its child pairs get bounds 1 and 2 (B's nodes moved into A's frame once per
  unfolding, ``place_node``; with at least ``WIDE`` of them, the bounds of the A nodes
  against all of them in one call, a vectorised loop each, ``child_bounds``: helpers of
  :mod:`~engine.kernels.collision.distance_bounds`), and those kept are pushed
  unrefined: those with a positive bound onto the heap as they come, then those with a
  bound ≤ 0 onto the stack, sorted, the largest bound first. In the dive (bound ≤ 0), a
  pair whose child pairs are all leaf pairs, at most ``POPS`` of them, has them evaluated
  with the exact kernel at once instead (no bounds, sort or later refinement: can × milk
  at −0.001 8 % faster in a timing loop over ``peers.py``'s poses, issue 15, eleventh step),
  together with the leaf pairs of the next pairs on the stack that are leaf pairs or have
  only leaf pairs as children, up to ``POPS`` in all (one masked vector iteration of the
  exact kernel: can × milk at −0.001 evaluates its 12 leaf pairs in 2 calls instead of 4,
  1.31–1.33 → 1.19–1.21 of Coal's time, issue 15, twelfth step).

The descent's pair is evaluated with
:func:`~engine.kernels.geometry.triangle_points.exact_point` (distance and closest points).
Every later exact distance comes with its pair's closest points from the same vectorised
call (``exact_points``, the scalar kernel's values bit for bit), so a closer pair found by
the search has its points at once: no second scalar ``exact_point`` at the end (can × milk
at −0.001: 3.57–3.62 → 3.17–3.19 µs a query in two of three rounds, issue 15,
thirteenth step). (Where the descent's pair is the answer, a query computes one exact
distance less: icospheres 80 at −0.01 in 2.2 µs instead of 2.5.)

A pair unfolds its node with the larger sphere (never a leaf), and the other node too if
it is a surrogate with a sphere at least ``BOTH`` times as large; when both unfold, each
child is first tested against the other node's sphere. (Unfolding both also in the
depth-first dive, bound ≤ 0, lets the box bounds of the finer child pairs pick the
crossing: on overlapping real meshes 15–30 % faster than unfolding one node there.)
The search also ends at a candidate of distance 0 (the meshes touch or intersect).
Measured on ``benchmarks/peers.py``, computing bound 3 lazily beat computing it for every
kept child pair (the previous search) on most near and overlapping cases; evaluating leaf
pairs once (not refined, pushed back, then evaluated with points), skipping refinements
that cannot drop a pair and moving B's nodes once per unfolding cut the far cases by
10–25 %. The per-pair helpers LLVM kept as calls by their size (``place_node``, ``_gap``,
``bound_placed``, ``may_drop``, ``_gather_b``: each call passes its arrays field by field)
are ``forceinline``: far and near cases 5–17 % faster (BENCHMARKS.md, issue 15, tenth step).
A second greedy descent guided by the box bounds, once run when the first found no
crossing of overlapping roots, is gone: on the peers' 40 poses it cost more where it
failed (can × milk overlapping: 15 %) than it saved where it found the crossing
(icospheres 320 at −0.01: 0.62 → 0.76–0.83 of Coal's time), and the geometric mean of the
40 ratios fell 1–3 % (issue 15, eleventh step). ``exact_points`` is
:func:`~engine.kernels.jit.tail_masked`: a refinement of 2 to 8 pairs is one vector
iteration.

A pair is dropped only when a bound exceeds the best candidate by more than ``margin``
(:func:`~engine.kernels.collision.batch.query_margin`: 256 ulp of the pair's scale, which
bounds the rounding of the bounds and of the exact kernel), so the result is the minimum
of the exact kernel (``exact_points``, whose distances are ``exact_point``'s) over every
face pair (A's rows, B's rows moved), bit for bit.

Node arrays of a tree (``N`` nodes, node order, root at row 0), row-major:

* ``rows (N, N_COLUMNS)`` float64 — per node: its prepared triangle (columns
  ``COORDS:COORDS + 9``) and frame (``FRAMES:FRAMES + 14``,
  :class:`~engine.geometry.triangle_set.TriangleSet`), body frame; the bounding sphere of
  the covered faces (centre ``CENTRE:CENTRE + 3``, radius ``RADIUS``); ``GAP`` g; then
  ``FIRST`` (first child), ``COUNT`` (child count, 0 for a leaf) and ``FACE`` (the face
  of a leaf, −1 for a surrogate), integers stored exactly; ``EXTENT`` the tree's largest
  absolute body-frame coordinate (every row; the rounding margin's scale); the node's box
  (columns ``BOX:BOX + 15``, :mod:`~engine.kernels.collision.distance_bounds`);
* ``prepared (N, ≥ 23)`` — A's triangles and frames (the same columns) in the query
  dtype: ``rows`` itself for float64.
"""

from __future__ import annotations

import numpy as np
from numba import carray, njit

from engine.kernels.collision.batch import packed_relative_pose, query_margin
from engine.kernels.collision.distance_bounds import (  # noqa: F401 (columns re-exported)
    BOX,
    CENTRE,
    COORDS,
    COUNT,
    EXTENT,
    FACE,
    FIRST,
    FRAMES,
    GAP,
    N_BOX,
    PLACED,
    RADIUS,
    WIDE,
    bound_placed,
    child_bounds,
    far_placed,
    may_drop,
    node_bound,
    place_node,
    sphere_bound,
)
from engine.kernels.geometry.triangle_batch import ZERO
from engine.kernels.geometry.triangle_points import exact_point, exact_points
from engine.kernels.jit import BORROW, EXACT_BORROW, JIT, stack_buffer

N_COLUMNS = BOX + N_BOX
# Fields of the tuple returned by :func:`distance_kernel`.
OUT_DISTANCE, OUT_FACE_A, OUT_FACE_B, OUT_PAIRS, OUT_EXACT, OUT_UNFOLDED = range(6)
OUT_LARGEST, OUT_PRUNED = 6, 7
HEAP_START = 256  # initial capacity of the heap (doubled when full)
CHILDREN_START = 64  # initial capacity of an unfolded pair's child pairs (grown when needed)
BOTH = 0.5  # unfold both nodes of a pair when their spheres are this close in size
POPS = 8  # pairs refined together


# sizes of the buffers a query keeps in its kernels' stack frames (``stack_buffer``)
GATHERED_ROWS = 47  # a gathered pair: A (9), A's frames (14), B (9), B's frames (14), distance
HEAP_INTS = 5 * HEAP_START
CHILD_INTS = 2 * CHILDREN_START
POPS_GATHERED = GATHERED_ROWS * POPS
LANES = 2 * POPS
KEEP_START = 8  # children of one node kept by the parent test (grown when needed)
KEEP_INTS = 2 * KEEP_START
PLACED_SIZE = PLACED * (KEEP_START + 1)
LOWS_SIZE = KEEP_START * (KEEP_START + 1)


@njit(**JIT)
def _gathered(g):
    """Views of ``g (47, m)`` (C-contiguous), the buffers for ``m`` gathered pairs:
    ``(A (9, m), A's frames (14, m), B (9, m), B's frames (14, m), distances (m,))``."""
    return g[0:9], g[9:23], g[23:32], g[32:46], g[46]


@njit(**JIT)
def _grown(key, ints, need):
    """Copies of the heap's ``key (n,)`` float64 and ``ints (5, n)`` int64 with room for
    ``2 need > n`` entries."""
    out_key = np.empty(2 * need)
    out_key[: key.shape[0]] = key
    out_ints = np.empty((5, 2 * need), np.int64)
    out_ints[:, : ints.shape[1]] = ints
    return out_key, out_ints


@njit(**BORROW)
def _before(key_e, e, key_f, f):
    """Entry ``e`` pops before entry ``f``: smaller key, ties to the later entry."""
    return key_e < key_f or (key_e == key_f and e > f)


@njit(**BORROW)
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


@njit(**BORROW)
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


@njit(**EXACT_BORROW)
def _moved(r, s, x, y, z):
    """``R x + s`` as :func:`~engine.kernels.collision.rigid.move_kernel` computes it (no
    contraction: the same bits); ``r`` the 9 entries of R row by row, ``s`` 3."""
    return (
        r[0] * x + r[1] * y + r[2] * z + s[0],
        r[3] * x + r[4] * y + r[5] * z + s[1],
        r[6] * x + r[7] * y + r[8] * z + s[2],
    )


@njit(**EXACT_BORROW)
def _turned(r, x, y, z):
    """``R x`` as :func:`~engine.kernels.collision.rigid.move_kernel` computes it."""
    return (
        r[0] * x + r[1] * y + r[2] * z,
        r[3] * x + r[4] * y + r[5] * z,
        r[6] * x + r[7] * y + r[8] * z,
    )


@njit(**BORROW)
def _gather_a(prepared, i, k, ga, gfa):
    """Column ``k`` of ``ga (9, m)``, ``gfa (14, m)``: A's node ``i``."""
    for c in range(9):
        ga[c, k] = prepared[i, COORDS + c]
    for c in range(14):
        gfa[c, k] = prepared[i, FRAMES + c]


@njit(**BORROW, forceinline=True)
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


@njit(**BORROW)
def _leaves(rows, first, count):
    """Nodes ``first … first + count − 1`` of ``rows`` are all leaves."""
    for node in range(first, first + count):  # noqa: SIM110 (a loop Numba compiles)
        if rows[node, COUNT] > 0:
            return False
    return True


@njit(**JIT)
def _split_a(count_a, radius_a, count_b, radius_b):
    """Unfold A's node of a pair, not both leaves (child counts, sphere radii): the larger
    sphere."""
    return count_a > 0 and (count_b == 0 or radius_a >= radius_b)


@njit(**BORROW)
def _unfolded(a, i, b, j):
    """``(first, count)`` of A's, then of B's, nodes that replace the pair (i, j), not both
    leaves: the node with the larger sphere unfolds, and the other one too when it is a
    surrogate whose sphere is at least ``BOTH`` times as large; a node that stays is its
    own ``(i, 1)``."""
    ra, rb = a[i, RADIUS], b[j, RADIUS]
    split = _split_a(a[i, COUNT], ra, b[j, COUNT], rb)
    both = a[i, COUNT] > 0 and b[j, COUNT] > 0 and min(ra, rb) >= BOTH * max(ra, rb)
    first_a, count_a, first_b, count_b = i, np.int64(1), j, np.int64(1)
    if split or both:
        first_a, count_a = np.int64(a[i, FIRST]), np.int64(a[i, COUNT])
    if not split or both:
        first_b, count_b = np.int64(b[j, FIRST]), np.int64(b[j, COUNT])
    return first_a, count_a, first_b, count_b


@njit(**BORROW)
def _to_world(ra, pose, p):
    """``R_a p + p_a`` (a body-frame point of A to the world frame) as three floats; ``ra``
    row by row (9), ``pose (7,)``: the position first."""
    return (
        ra[0] * p[0] + ra[1] * p[1] + ra[2] * p[2] + pose[0],
        ra[3] * p[0] + ra[4] * p[1] + ra[5] * p[2] + pose[1],
        ra[6] * p[0] + ra[7] * p[1] + ra[8] * p[2] + pose[2],
    )


@njit(**JIT)
def _search(prepared_a, a, b, r, s, margin, best, best_i, best_j, one):
    """Best-first search from the roots' pair, given the descents' ``best`` distance (> 0)
    of the leaf pair (``best_i``, ``best_j``); returns ``(best, best_i, best_j, pairs,
    exact, unfolded, largest, pruned, best_p, best_q)``, the last two the closest points
    (query dtype, A's frame) of the pair the search found, if it found a closer one than
    the descent's (else zeros)."""
    pairs = exact = unfolded = pruned = ZERO
    # every buffer in this frame (stack_buffer: no allocation, release or reference
    # counts; one grown past its start is replaced by an np.empty one)
    key = carray(stack_buffer(HEAP_START, np.float64), (HEAP_START,))
    # per entry: A's node, B's node, refined; the heap; the stack
    ints = carray(stack_buffer(HEAP_INTS, np.int64), (5, HEAP_START))
    entry_a, entry_b, refined, heap, stack = ints[0], ints[1], ints[2], ints[3], ints[4]
    gathered = stack_buffer(POPS_GATHERED, prepared_a.dtype)
    ga, gfa, gb, gfb, dist = _gathered(carray(gathered, (GATHERED_ROWS, POPS)))
    batch = carray(stack_buffer(POPS, np.int64), (POPS,))  # the entries refined together
    # the leaf pairs evaluated together in the dive
    lane = carray(stack_buffer(LANES, np.int64), (2, POPS))
    # closest points of the pairs refined together (exact_points: separate rows), so that
    # the answer's need no scalar exact_point at the end
    pax = carray(stack_buffer(POPS, prepared_a.dtype), (POPS,))
    pay = carray(stack_buffer(POPS, prepared_a.dtype), (POPS,))
    paz = carray(stack_buffer(POPS, prepared_a.dtype), (POPS,))
    pbx = carray(stack_buffer(POPS, prepared_a.dtype), (POPS,))
    pby = carray(stack_buffer(POPS, prepared_a.dtype), (POPS,))
    pbz = carray(stack_buffer(POPS, prepared_a.dtype), (POPS,))
    zero = one - one  # the query dtype's 0
    best_p = best_q = (zero, zero, zero)  # the answer's points, once the search finds it
    # child pairs of an unfolded pair: bound, A's, B's
    child_low = carray(stack_buffer(CHILDREN_START, np.float64), (CHILDREN_START,))
    child = carray(stack_buffer(CHILD_INTS, np.int64), (2, CHILDREN_START))
    # children kept by the parent test
    keep = carray(stack_buffer(KEEP_INTS, np.int64), (2, KEEP_START))
    # B's nodes of an unfolded pair, moved (+ B's parent)
    placed = carray(stack_buffer(PLACED_SIZE, np.float64), (PLACED, KEEP_START + 1))
    # bounds of the A children against them
    lows = carray(stack_buffer(LOWS_SIZE, np.float64), (KEEP_START, KEEP_START + 1))
    key[0] = max(node_bound(a, ZERO, b, ZERO, r, s, np.inf, margin), 0.0)
    entry_a[0], entry_b[0], refined[0] = 0, 0, 0
    entries = size = depth = ZERO
    if key[0] > 0.0:
        size = _push(heap, size, key, ZERO)
    else:
        stack[0], depth = 0, 1
    pairs, largest = ZERO + 1, ZERO + 1
    while (depth > 0 or size > 0) and best > 0.0:
        e = stack[depth - 1] if depth > 0 else heap[0]
        if key[e] - margin > best:
            break
        i, j = entry_a[e], entry_b[e]
        leaf = a[i, COUNT] == 0 and b[j, COUNT] == 0
        unsure = refined[e] == 0 and not leaf and key[e] > 0.0
        if unsure and not may_drop(a, i, b, j, r, s, best + margin):
            refined[e] = 1  # bound 3 cannot drop it: unfold it now
        if refined[e] == 0 and (leaf or key[e] > 0.0):
            # bound 3 for up to POPS unrefined pairs from the top; a leaf pair is then a
            # candidate, any other pushed back with its new key or dropped
            m = 0
            while (depth > 0 or size > 0) and m < POPS:
                e = stack[depth - 1] if depth > 0 else heap[0]
                i, j = entry_a[e], entry_b[e]
                if key[e] - margin > best or refined[e] != 0:
                    break
                if a[i, COUNT] > 0 or b[j, COUNT] > 0:
                    if key[e] <= 0.0:
                        break
                    if m > 0 and not may_drop(a, i, b, j, r, s, best + margin):
                        refined[e] = 1
                        break
                if depth > 0:
                    depth -= 1
                else:
                    size = _pop(heap, size, key)
                _gather_a(prepared_a, i, m, ga, gfa)
                _gather_b(b, j, r, s, m, gb, gfb)
                batch[m] = e
                m += 1
            exact_points(ga, gfa, gb, gfb, m, one, dist, pax, pay, paz, pbx, pby, pbz)
            for k in range(m):
                e = batch[k]
                i, j = entry_a[e], entry_b[e]
                d = np.float64(dist[k])
                if a[i, COUNT] == 0 and b[j, COUNT] == 0:
                    exact += 1
                    if d < best:
                        best, best_i, best_j = d, i, j
                        best_p, best_q = (pax[k], pay[k], paz[k]), (pbx[k], pby[k], pbz[k])
                    continue
                low = max(key[e], d - a[i, GAP] - b[j, GAP])
                if low - margin > best:
                    continue
                key[e], refined[e] = low, 1  # (low ≥ the key popped, > 0)
                size = _push(heap, size, key, e)
            continue
        # unfold the pair (never a leaf pair: those are candidates once refined); its child
        # pairs get bounds 1 and 2 and are pushed unrefined (in the dive, leaf pairs get
        # their exact distances at once)
        if depth > 0:
            depth -= 1
        else:
            size = _pop(heap, size, key)
        unfolded += 1
        first_a, count_a, first_b, count_b = _unfolded(a, i, b, j)
        count = count_a * count_b
        pairs += count
        if (
            key[e] <= 0.0
            and count <= POPS
            and _leaves(a, first_a, count_a)
            and _leaves(b, first_b, count_b)
        ):
            # the dive reached a pair whose child pairs are all leaf pairs: their exact
            # distances in one call, instead of bounds, a sort and a refinement later,
            # with those of the next pairs on the stack that are leaf pairs or have only
            # leaf pairs as children, up to POPS (one vector iteration, tail_masked)
            m = 0
            while True:
                for k in range(count):
                    lane[0, m], lane[1, m] = first_a + k // count_b, first_b + k % count_b
                    _gather_a(prepared_a, lane[0, m], m, ga, gfa)
                    _gather_b(b, lane[1, m], r, s, m, gb, gfb)
                    m += 1
                if depth == 0:
                    break
                f = stack[depth - 1]
                i, j = entry_a[f], entry_b[f]
                if a[i, COUNT] == 0 and b[j, COUNT] == 0:
                    if m == POPS:
                        break
                    first_a, count_a, first_b, count_b, count = i, ZERO + 1, j, ZERO + 1, 1
                else:
                    first_a, count_a, first_b, count_b = _unfolded(a, i, b, j)
                    count = count_a * count_b
                    if (
                        m + count > POPS
                        or not _leaves(a, first_a, count_a)
                        or not _leaves(b, first_b, count_b)
                    ):
                        break
                    unfolded += 1
                    pairs += count
                depth -= 1
            exact_points(ga, gfa, gb, gfb, m, one, dist, pax, pay, paz, pbx, pby, pbz)
            exact += m
            for k in range(m):
                d = np.float64(dist[k])
                if d < best:
                    best, best_i, best_j = d, lane[0, k], lane[1, k]
                    best_p, best_q = (pax[k], pay[k], paz[k]), (pbx[k], pby[k], pbz[k])
            continue
        if count > child_low.shape[0]:
            child_low = np.empty(count)
            child = np.empty((2, count), np.int64)
        if max(count_a, count_b) > keep.shape[1]:
            keep = np.empty((2, max(count_a, count_b)), np.int64)
            placed = np.empty((PLACED, max(count_a, count_b) + 1))
            lows = np.empty((max(count_a, count_b), max(count_a, count_b) + 1))
        limit = best + margin
        for t in range(count_b):  # B's nodes moved once
            place_node(b, first_b + t, r, s, placed, t)
        kept_a = kept_b = 0  # both unfold: each child against the other node's sphere
        if count_a > 1 and count_b > 1:
            place_node(b, j, r, s, placed, count_b)
            for ci in range(first_a, first_a + count_a):
                if far_placed(a, ci, placed, count_b, limit)[0]:
                    pruned += count_b
                    continue
                keep[0, kept_a] = ci
                kept_a += 1
            for t in range(count_b):
                if far_placed(a, i, placed, t, limit)[0]:  # (B's child t placed above)
                    pruned += kept_a
                    continue
                keep[1, kept_b] = t
                kept_b += 1
        else:
            for ci in range(first_a, first_a + count_a):
                keep[0, kept_a] = ci
                kept_a += 1
            for t in range(count_b):
                keep[1, kept_b] = t
                kept_b += 1
        if entries + 1 + count > key.shape[0]:
            key, ints = _grown(key, ints, entries + 1 + count)
            entry_a, entry_b, refined, heap, stack = ints[0], ints[1], ints[2], ints[3], ints[4]
        # survivors with a positive bound are pushed as they come (their keys order them);
        # those with a bound ≤ 0 (keys tied at 0: the last pushed pops first) are sorted,
        # the largest bound first, and pushed after them
        kept = 0
        wide = count_b >= WIDE
        if wide:
            child_bounds(a, keep[0], kept_a, placed, count_b, lows)
        for ta in range(kept_a):
            ci = keep[0, ta]
            for tb in range(kept_b):
                t = keep[1, tb]
                if wide:
                    low = lows[ta, t]
                else:
                    low = bound_placed(a, ci, placed, t, best, margin)
                if low - margin > best:
                    pruned += 1
                    continue
                cj = first_b + t
                if low > 0.0:
                    entries += 1
                    key[entries] = low
                    entry_a[entries], entry_b[entries], refined[entries] = ci, cj, 0
                    size = _push(heap, size, key, entries)
                    continue
                u = kept
                while u > 0 and child_low[u - 1] < low:
                    child_low[u] = child_low[u - 1]
                    child[0, u], child[1, u] = child[0, u - 1], child[1, u - 1]
                    u -= 1
                child_low[u], child[0, u], child[1, u] = low, ci, cj
                kept += 1
        for t in range(kept):
            entries += 1
            key[entries] = 0.0
            entry_a[entries], entry_b[entries], refined[entries] = child[0, t], child[1, t], 0
            stack[depth] = entries
            depth += 1
        largest = max(largest, size + depth)
    return best, best_i, best_j, pairs, exact, unfolded, largest, pruned, best_p, best_q


@njit(**JIT)
def distance_kernel(prepared_a, a, b, pose_a, pose_b, points):
    """Minimum distance between body A (node rows ``a``, its triangles in the query dtype
    ``prepared_a`` (float32 or float64); see the module docstring) at ``pose_a (7,)``
    float64 (position, then unit quaternion w, x, y, z) and body B (``b``) at ``pose_b``.

    Writes ``points (2, 3)`` float64: the closest points on A then on B, world frame (an
    output the host allocates: a returned tuple of arrays or of nested tuples costs more
    to box). Returns a tuple of scalars (fields ``OUT_*``): the distance (float64, computed
    in the query dtype), the faces of A and of B attaining it, then int64 counters: node
    pairs bounded (the root's and every child pair's), exact distances of leaf pairs
    evaluated, pairs unfolded, the largest front (heap and stack), child pairs dropped by
    their sphere or box bound.
    """
    # one pair, for the descents, in this frame
    one_pair = carray(stack_buffer(GATHERED_ROWS, prepared_a.dtype), (GATHERED_ROWS, 1))
    ga, gfa, gb, gfb, dist = _gathered(one_pair)
    dist[0] = 1
    one = dist[0]  # (the query dtype's 1, no array made for it)
    ulp = np.float64(np.nextafter(one, one + one) - one)  # the query dtype's epsilon
    # (tuples: relative_pose's bits without its four arrays, 0.1 µs a query)
    ra, r, s = packed_relative_pose(pose_a, pose_b)
    margin = query_margin(a[0, EXTENT], b[0, EXTENT], s, ulp)

    # a greedy descent (the larger sphere unfolds, to the child with the smallest sphere
    # bound): a first upper bound, its pair's closest points kept
    i, j = ZERO, ZERO
    while a[i, COUNT] > 0 or b[j, COUNT] > 0:
        split = _split_a(a[i, COUNT], a[i, RADIUS], b[j, COUNT], b[j, RADIUS])
        first = np.int64(a[i, FIRST]) if split else np.int64(b[j, FIRST])
        count = np.int64(a[i, COUNT]) if split else np.int64(b[j, COUNT])
        pick, low = first, np.inf
        for c in range(first, first + count):
            ci, cj = (c, j) if split else (i, c)
            bound = sphere_bound(a, ci, b, cj, r, s)
            if bound < low:
                pick, low = c, bound
        if split:
            i = pick
        else:
            j = pick
    # (gathered: exact_point's C-layout, int64 specialisation, the one the flat search
    # compiles; its distance is exact_points', bit for bit)
    _gather_a(prepared_a, i, ZERO, ga, gfa)
    _gather_b(b, j, r, s, ZERO, gb, gfb)
    d, p, q = exact_point(ga, gfa, ZERO, gb, gfb, ZERO, one)
    best, best_i, best_j, exact = np.float64(d), i, j, ZERO + 1

    pairs, unfolded, largest, pruned = ZERO + 1, ZERO, ZERO, ZERO  # the roots' pair
    if best > 0.0 and (a[0, COUNT] > 0 or b[0, COUNT] > 0):
        found = _search(prepared_a, a, b, r, s, margin, best, best_i, best_j, one)
        best, best_i, best_j, pairs, searched, unfolded, largest, pruned = found[:8]
        exact += searched
        if best_i != i or best_j != j:  # the search found a closer pair, with its points
            p, q = found[8], found[9]
    pa = np.float64(p[0]), np.float64(p[1]), np.float64(p[2])
    pb = np.float64(q[0]), np.float64(q[1]), np.float64(q[2])
    points[0, 0], points[0, 1], points[0, 2] = _to_world(ra, pose_a, pa)
    points[1, 0], points[1, 1], points[1, 2] = _to_world(ra, pose_a, pb)
    face_a, face_b = np.int64(a[best_i, FACE]), np.int64(b[best_j, FACE])
    return best, face_a, face_b, pairs, exact, unfolded, largest, pruned
