"""Contact points from closest-point pairs, merged (the paper's implementation remark)."""

from __future__ import annotations

import numpy as np
from numba import njit

from engine.kernels.jit import BORROW, JIT

_f64 = np.float64


@njit(**JIT)
def contact_kernel(found, count, face_a, face_b, n_faces_b, keep_all, normals_a, setup, out):
    """Contacts of one body pair from the leaf pairs a search found; returns ``(m, k)``.

    ``found = (i, j, distance, point_a, point_b, status)`` as written by
    :func:`~engine.kernels.geometry.triangle_batch.listed_kernel` (``point_* (3, cap)``, in
    A's frame; the first ``count`` rows are used); ``face_a[i]``, ``face_b[j]`` map node
    indices to faces; ``keep_all`` keeps every row, else only ``status == 1``
    (certified contacts of the iterative kernel); ``normals_a (F, 3)`` float64 unit
    face normals of A. ``setup = (ε_a, ε_b, tiny, merge radius, rotation (3, 3),
    position (3,))``: leaf ε of each body, the gap below which the two closest
    points count as coincident, and A's pose.

    Writes ``out = (pairs (n, 2) int64, points, normals (n, 3), overlaps (n,))``
    (float64, world frame): the first ``m`` rows of ``pairs`` are the kept
    (face of A, face of B) pairs in lexicographic order (an empty ``pairs``: counted,
    not written); the first ``k`` rows of the others are the merged contacts. A contact
    lies on the closest-point segment p→q, weighted by the ε's; its normal is
    (q − p)/|q − p| (A's face normal when the points coincide); its overlap is
    ε_a + ε_b − d, clipped to [0, ε_a + ε_b]. Points closer than the merge radius are
    merged greedily, deepest first, into their average (overlaps averaged); a cluster's
    normal is its deepest member's (see :func:`_merge`).
    """
    node_i, node_j, distance, point_a, point_b, status = found
    ea, eb, tiny, radius, rotation, position = setup
    out_pairs, out_points, out_normals, out_overlaps = out
    n = count
    rows = np.empty(n, np.int64)
    keys = np.empty(n, np.int64)
    m = 0
    for t in range(n):
        if keep_all or status[t] == 1:
            rows[m] = t
            keys[m] = face_a[node_i[t]] * n_faces_b + face_b[node_j[t]]
            m += 1
    order = key_order(keys[:m])
    weight = 0.5 if ea + eb == 0 else ea / (ea + eb)
    points = np.empty((m, 3))
    normals = np.empty((m, 3))
    overlaps = np.empty(m)
    copies = np.empty(m)  # how many consecutive rows each distinct row stands for
    u = 0  # distinct rows so far
    # the values of the last distinct row, while it can stand for more (its points apart,
    # a merge radius above 0: a radius of 0 keeps every row a contact of its own)
    reusable = False
    last_d, a0, a1, a2 = _f64(0.0), _f64(0.0), _f64(0.0), _f64(0.0)
    b0, b1, b2 = _f64(0.0), _f64(0.0), _f64(0.0)
    write_pairs = out_pairs.shape[0] > 0
    for s in range(m):
        t = rows[order[s]]
        if write_pairs:
            out_pairs[s, 0], out_pairs[s, 1] = face_a[node_i[t]], face_b[node_j[t]]
        d = _f64(distance[t])
        p0, p1, p2 = _f64(point_a[0, t]), _f64(point_a[1, t]), _f64(point_a[2, t])
        q0, q1, q2 = _f64(point_b[0, t]), _f64(point_b[1, t]), _f64(point_b[2, t])
        if (
            reusable
            and d == last_d
            and p0 == a0
            and p1 == a1
            and p2 == a2
            and q0 == b0
            and q1 == b1
            and q2 == b2
        ):  # the same values as the row before: the same point, normal, overlap, cluster
            copies[u - 1] += 1.0
            continue
        reusable = False
        g0, g1, g2 = q0 - p0, q1 - p1, q2 - p2
        points[u, 0], points[u, 1], points[u, 2] = (
            p0 + weight * g0,
            p1 + weight * g1,
            p2 + weight * g2,
        )
        length = np.sqrt(g0 * g0 + g1 * g1 + g2 * g2)
        # decide on the points' own gap: a (float32) distance can be positive while
        # the two points round to the same coordinates
        if length > tiny:
            normals[u, 0], normals[u, 1], normals[u, 2] = (
                g0 / length,
                g1 / length,
                g2 / length,
            )
            reusable = radius > 0
            last_d, a0, a1, a2, b0, b1, b2 = d, p0, p1, p2, q0, q1, q2
        else:
            fa = face_a[node_i[t]]
            for c in range(3):
                normals[u, c] = normals_a[fa, c]
        overlaps[u] = min(max(ea + eb - d, 0.0), ea + eb)
        copies[u] = 1.0
        u += 1
    k = _merge(
        points[:u],
        normals[:u],
        overlaps[:u],
        copies[:u],
        radius,
        out_points,
        out_normals,
        out_overlaps,
    )
    for s in range(k):  # to the world frame
        p0, p1, p2 = out_points[s, 0], out_points[s, 1], out_points[s, 2]
        n0, n1, n2 = out_normals[s, 0], out_normals[s, 1], out_normals[s, 2]
        for c in range(3):
            r0, r1, r2 = rotation[c, 0], rotation[c, 1], rotation[c, 2]
            out_points[s, c] = r0 * p0 + r1 * p1 + r2 * p2 + position[c]
            out_normals[s, c] = r0 * n0 + r1 * n1 + r2 * n2
    return m, k


RADIX_FROM = 128
"""Keys from which :func:`key_order` sorts by radix rather than by ``np.argsort``'s
quicksort (the traversal's 1,296 leaf pairs of the paper's pole-to-pole grid pair, in runs
of about 8: :func:`~engine.kernels.collision.pair_lists.by_faces`, keys and copies
included, took 13.7 µs with the quicksort and 6.0 µs with the radix sort on the AVX-512 VM
of BENCHMARKS.md; 128 is a round number, the crossover was not measured)."""
RADIX_BITS = 11  # most bits per radix pass


@njit(**JIT)
def key_order(keys):
    """``np.argsort(keys)`` of distinct ``keys (m,)`` int64, without a sort when they are
    already in order or come as two sorted runs (the pair cache keeps its lists sorted by
    faces, and a listed query reports its uncertain pairs, then its sure contacts, each in
    list order): the identity, or one linear merge; else :func:`_radix_order` from
    ``RADIX_FROM`` keys (non-negative ones, as face-pair keys are), ``np.argsort`` below.
    Distinct keys have one sorted order, so this is ``np.argsort``'s permutation whichever
    way it is found."""
    m = keys.shape[0]
    cut = 0
    for t in range(1, m):
        if keys[t] < keys[t - 1]:
            if cut > 0:
                if m >= RADIX_FROM and keys.min() >= 0:
                    return _radix_order(keys)
                return np.argsort(keys)
            cut = t
    order = np.empty(m, np.int64)
    if cut == 0:
        for t in range(m):
            order[t] = t
        return order
    i, j = 0, cut
    for s in range(m):
        if j == m or (i < cut and keys[i] < keys[j]):
            order[s] = i
            i += 1
        else:
            order[s] = j
            j += 1
    return order


@njit(**JIT)
def _radix_order(keys):
    """The stable ascending order of ``keys (m ≥ 1,)`` int64, all ≥ 0: a least-significant-digit
    radix sort, as few passes of at most ``RADIX_BITS`` bits as the largest key needs (each
    pass a count, a prefix sum and a scatter of the keys with their rows)."""
    m = keys.shape[0]
    top = keys.max()
    bits = 0
    while bits < 63 and (top >> bits) > 0:
        bits += 1
    passes = max(1, (bits + RADIX_BITS - 1) // RADIX_BITS)
    digit = max(1, (bits + passes - 1) // passes)
    mask = (1 << digit) - 1
    order, key = np.arange(m), keys.copy()
    other, other_key = np.empty(m, np.int64), np.empty(m, np.int64)
    start = np.empty(mask + 2, np.int64)
    for p in range(passes):
        shift = p * digit
        start[:] = 0
        for t in range(m):
            start[((key[t] >> shift) & mask) + 1] += 1
        for d in range(mask + 1):
            start[d + 1] += start[d]
        for t in range(m):
            d = (key[t] >> shift) & mask
            s = start[d]
            other[s], other_key[s] = order[t], key[t]
            start[d] = s + 1
        order, other = other, order
        key, other_key = other_key, key
    return order


@njit(**JIT)
def _merge(points, normals, overlaps, copies, radius, out_points, out_normals, out_overlaps):
    """Greedy merging (see :func:`contact_kernel`) into the ``out_*`` rows; returns the count.

    ``points, normals (m, 3)``, ``overlaps (m,)`` float64 in, each row standing for
    ``copies (m,)`` float64 equal rows (an average weighs it so; with ``radius > 0`` the
    copies would all join its cluster); ``out_*`` the same, first ``k`` rows written. A
    point joins the nearest cluster whose first (deepest) point lies within ``radius``; a
    cluster becomes the average of its points and of its overlaps, and takes the
    normal of its deepest member (the first in the stable order of decreasing overlap): the
    direction of the two bodies' least distance there. An average of the members' normals
    would mix in leaf pairs that only touch across an internal edge of a flat region (two
    coplanar triangles of a face, a plane's diagonal): a triangle just past that edge has its
    closest point on it, at distance √(h² + s²) for a lateral offset s, and a normal tilted
    by s/h, where the flat surface it belongs to has none. That tilt grows with the offset:
    averaged in, it is a negative lateral stiffness (a box resting over a plane's diagonal was
    pushed off it and, with the regularised friction, crept 1.8 mm in 100 s). Such a pair is
    never the deepest of its cluster when a triangle of the flat region lies under it
    (distance h < √(h² + s²)).
    """
    m = points.shape[0]
    order = _deepest_first(overlaps)
    label = np.empty(m, np.int64)
    first = np.empty((m, 3))  # each cluster's first point
    k = 0
    limit = radius * radius
    for t in range(m):
        s = order[t]
        if t > 0 and limit > 0 and _same_point(points, s, order[t - 1]):
            # the point before it, again: it joined the nearest cluster (the set of
            # clusters is the same now), or started one, now at distance 0 < limit: this
            # one joins the same
            label[s] = label[order[t - 1]]
            continue
        best, best_d2 = -1, limit
        for c in range(k):
            d2 = 0.0
            for x in range(3):
                d2 += (first[c, x] - points[s, x]) ** 2
            if d2 < best_d2:
                best, best_d2 = c, d2
        if best < 0:
            for x in range(3):
                first[k, x] = points[s, x]
            best = k
            k += 1
        label[s] = best
    count = np.zeros(k)
    out_points[:k] = 0.0
    out_overlaps[:k] = 0.0
    for t in range(m):
        s = order[t]
        c = label[s]
        if count[c] == 0:  # the deepest member
            for x in range(3):
                out_normals[c, x] = normals[s, x]
        w = copies[s]
        count[c] += w
        out_overlaps[c] += w * overlaps[s]
        for x in range(3):
            out_points[c, x] += w * points[s, x]
    for c in range(k):
        out_overlaps[c] /= count[c]
        for x in range(3):
            out_points[c, x] /= count[c]
    return k


@njit(**JIT)
def _deepest_first(overlaps):
    """``np.argsort(-overlaps, kind="mergesort")`` (stable) of ``overlaps (m,)``, without a
    sort when they already come in non-increasing order (the identity)."""
    m = overlaps.shape[0]
    for t in range(m):
        if overlaps[t] != overlaps[t] or (t > 0 and overlaps[t] > overlaps[t - 1]):
            return np.argsort(-overlaps, kind="mergesort")
    return np.arange(m)


@njit(**BORROW)
def _same_point(points, s, u):
    return (
        points[s, 0] == points[u, 0]
        and points[s, 1] == points[u, 1]
        and points[s, 2] == points[u, 2]
    )
