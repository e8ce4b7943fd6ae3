"""Oriented boxes of surrogate-tree nodes and their distance bound (the node bound of
:func:`~engine.kernels.collision.distance_search.distance_kernel`).

A node's box (:attr:`~engine.trees.views.TreeViews.distance_boxes`; the contact search's
:attr:`~engine.trees.views.TreeViews.boxes` are the same boxes grown by the leaf ε) holds
every vertex of every face it covers: axes are the eigenvectors of the covered vertices'
second moments about the node's sphere centre (principal axes, computed on the host from
:func:`box_moments`) or the body axes, whichever box is smaller, extents the range of the
vertices along each axis (:func:`box_extents`). A triangle is the convex hull of its
vertices, so the box holds the covered faces. Projected on any unit axis ``u``, box A spans
``u·c_A ± Σ_k h_k |u·a_k|`` (centre ``c``, unit axes ``a_k``, half-extents ``h_k``), so the
gap of the two spans is a lower bound on the distance of any point of A's faces to any
of B's; :func:`box_gap` takes the largest gap over the 6 box axes and the axis through
the two centres. :func:`place_box` moves a B box into A's frame once and
:func:`placed_gap` bounds it against A's nodes (the same arithmetic as :func:`box_gap`).
:func:`child_bounds` (the children of an unfolded pair, vectorised) also takes the gaps on
one box's three axes together (:func:`_axes_gap`): the axes are orthonormal, so a point
whose projections on them clear gaps g₀, g₁, g₂ ≥ 0 lies at least √(g₀² + g₁² + g₂²)
away; where two boxes sit diagonally apart that is up to √3 times the largest gap. (On
``benchmarks/peers.py``'s far poses of real meshes it drops 3–11 % of the node pairs and
5–16 % of the time; in the scalar bounds, where pairs are few, its arithmetic cost more
than it saved.)

Node rows (``(N, ≥ BOX + 15)`` float64, the distance search's row layout): columns
``BOX:BOX + 3`` centre, ``BOX + 3:BOX + 12`` the three axes (row-major, axis k at
``BOX + 3 + 3k``), ``BOX + 12:BOX + 15`` half-extents, body frame.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from engine.kernels.jit import BORROW, DISTINCT, JIT, select, sqrt, tail_masked

# Columns of the node rows (:mod:`~engine.kernels.collision.distance_search` documents them).
COORDS, FRAMES, CENTRE, RADIUS, GAP, FIRST, COUNT, FACE, EXTENT = 0, 9, 23, 26, 27, 28, 29, 30, 31
BOX = 32  # first box column of the node rows
AXES, HALF = BOX + 3, BOX + 12
N_BOX = 15
N_PLACED = 15  # rows of a placed box (:func:`place_box`)
WIDE = 4  # B's children from which their bounds are computed in one vectorised loop
PLACED = N_PLACED + 4  # rows of the placed B nodes of an unfolded pair: box, sphere


@njit(**JIT)
def box_moments(triangles, face, parent, centre, second):
    """Add to ``second (N, 3, 3)`` float64, for every node, ``Σ (x − c)(x − c)ᵀ`` over the
    vertices ``x`` of its covered faces (``c = centre[node] (N, 3)``).

    ``triangles (N, 3, 3)`` float64 node triangles, ``face (N,)`` int64 (−1 for
    surrogates), ``parent (N,)`` int64 (−1 for the root)."""
    for leaf in range(face.shape[0]):
        if face[leaf] < 0:
            continue
        node = leaf
        while node >= 0:
            for v in range(3):
                d0 = triangles[leaf, v, 0] - centre[node, 0]
                d1 = triangles[leaf, v, 1] - centre[node, 1]
                d2 = triangles[leaf, v, 2] - centre[node, 2]
                second[node, 0, 0] += d0 * d0
                second[node, 0, 1] += d0 * d1
                second[node, 0, 2] += d0 * d2
                second[node, 1, 1] += d1 * d1
                second[node, 1, 2] += d1 * d2
                second[node, 2, 2] += d2 * d2
            node = parent[node]
    for node in range(face.shape[0]):
        second[node, 1, 0] = second[node, 0, 1]
        second[node, 2, 0] = second[node, 0, 2]
        second[node, 2, 1] = second[node, 1, 2]


@njit(**JIT)
def box_extents(triangles, face, parent, axes, low, high):
    """``low, high (N, 3)`` float64 (filled with +inf, −inf by the caller): per node, the
    least and largest ``axes[node, k] · x`` over the vertices ``x`` of its covered faces
    (``axes (N, 3, 3)``, axis k in row k; other arguments as :func:`box_moments`)."""
    for leaf in range(face.shape[0]):
        if face[leaf] < 0:
            continue
        node = leaf
        while node >= 0:
            for v in range(3):
                x, y, z = triangles[leaf, v, 0], triangles[leaf, v, 1], triangles[leaf, v, 2]
                for k in range(3):
                    p = axes[node, k, 0] * x + axes[node, k, 1] * y + axes[node, k, 2] * z
                    low[node, k] = min(low[node, k], p)
                    high[node, k] = max(high[node, k], p)
            node = parent[node]


@njit(**BORROW)
def _turn(r, x, y, z):
    return (
        r[0] * x + r[1] * y + r[2] * z,
        r[3] * x + r[4] * y + r[5] * z,
        r[6] * x + r[7] * y + r[8] * z,
    )


@njit(**BORROW)
def _dot(p, q):
    return p[0] * q[0] + p[1] * q[1] + p[2] * q[2]


@njit(**BORROW, forceinline=True)
def _gap(a, i, c, u, v, t, hb):
    """:func:`box_gap` of A's node ``i`` and a box placed in A's frame: centre ``c``, unit
    axes ``u, v, t``, half-extents ``hb`` (tuples of 3)."""
    d = (c[0] - a[i, BOX], c[1] - a[i, BOX + 1], c[2] - a[i, BOX + 2])
    ha = (a[i, HALF], a[i, HALF + 1], a[i, HALF + 2])
    p = (a[i, AXES], a[i, AXES + 1], a[i, AXES + 2])
    q = (a[i, AXES + 3], a[i, AXES + 4], a[i, AXES + 5])
    w = (a[i, AXES + 6], a[i, AXES + 7], a[i, AXES + 8])
    c00, c01, c02 = abs(_dot(p, u)), abs(_dot(p, v)), abs(_dot(p, t))
    c10, c11, c12 = abs(_dot(q, u)), abs(_dot(q, v)), abs(_dot(q, t))
    c20, c21, c22 = abs(_dot(w, u)), abs(_dot(w, v)), abs(_dot(w, t))
    da0, da1, da2 = abs(_dot(p, d)), abs(_dot(q, d)), abs(_dot(w, d))
    db0, db1, db2 = abs(_dot(u, d)), abs(_dot(v, d)), abs(_dot(t, d))
    gap = da0 - ha[0] - (hb[0] * c00 + hb[1] * c01 + hb[2] * c02)
    gap = max(gap, da1 - ha[1] - (hb[0] * c10 + hb[1] * c11 + hb[2] * c12))
    gap = max(gap, da2 - ha[2] - (hb[0] * c20 + hb[1] * c21 + hb[2] * c22))
    gap = max(gap, db0 - hb[0] - (ha[0] * c00 + ha[1] * c10 + ha[2] * c20))
    gap = max(gap, db1 - hb[1] - (ha[0] * c01 + ha[1] * c11 + ha[2] * c21))
    gap = max(gap, db2 - hb[2] - (ha[0] * c02 + ha[1] * c12 + ha[2] * c22))
    length2 = _dot(d, d)
    spread = ha[0] * da0 + ha[1] * da1 + ha[2] * da2 + hb[0] * db0 + hb[1] * db1 + hb[2] * db2
    length = sqrt(length2)
    centres = (length2 - spread) / length if length > 0.0 else -np.inf
    return max(gap, centres)


@njit(**BORROW)
def _axes_gap(a0, a1, a2, b0, b1, b2):
    """The box bound of the gaps ``a0, a1, a2`` of two boxes' spans on A's three axes and
    ``b0, b1, b2`` on B's: the largest, or where positive gaps lie on two or three axes
    of one box, the root of their squares' sum (the axes are orthonormal: a point of the
    Minkowski difference whose projection on each of them is at least its gap is at least
    that far from the origin), whichever is larger. (Boxes that overlap on every axis keep
    their largest, negative, gap: the depth-first dive orders child pairs by it.)"""
    gap = max(max(max(a0, a1), a2), max(max(b0, b1), b2))
    pa0, pa1, pa2 = max(a0, 0.0), max(a1, 0.0), max(a2, 0.0)
    pb0, pb1, pb2 = max(b0, 0.0), max(b1, 0.0), max(b2, 0.0)
    across = max(pa0 * pa0 + pa1 * pa1 + pa2 * pa2, pb0 * pb0 + pb1 * pb1 + pb2 * pb2)
    return max(gap, select(across > 0.0, sqrt(across), -np.inf))


@njit(**BORROW)
def box_gap(a, i, b, j, r, s):
    """Lower bound on the distance between the faces covered by A's node ``i`` (rows
    ``a``) and B's node ``j`` (rows ``b``, moved by ``x ↦ R x + s``, ``r`` the 9 entries of
    R row by row, ``s`` 3): the largest gap of the two boxes projected on A's 3 axes, B's 3
    axes and the axis through the centres (−inf for that one when the centres coincide)."""
    cx, cy, cz = _turn(r, b[j, BOX], b[j, BOX + 1], b[j, BOX + 2])
    c = (cx + s[0], cy + s[1], cz + s[2])
    u = _turn(r, b[j, AXES], b[j, AXES + 1], b[j, AXES + 2])
    v = _turn(r, b[j, AXES + 3], b[j, AXES + 4], b[j, AXES + 5])
    t = _turn(r, b[j, AXES + 6], b[j, AXES + 7], b[j, AXES + 8])
    return _gap(a, i, c, u, v, t, (b[j, HALF], b[j, HALF + 1], b[j, HALF + 2]))


@njit(**BORROW, forceinline=True)
def place_box(b, j, r, s, placed, k):
    """Column ``k`` of ``placed (≥ N_PLACED, m)`` float64: B's node ``j`` box moved by ``x ↦
    R x + s`` (as :func:`box_gap` moves it): rows 0:3 centre, 3:12 the three axes, 12:15
    half-extents."""
    placed[0, k], placed[1, k], placed[2, k] = _turn(r, b[j, BOX], b[j, BOX + 1], b[j, BOX + 2])
    placed[0, k] += s[0]
    placed[1, k] += s[1]
    placed[2, k] += s[2]
    for axis in range(3):
        x, y, z = b[j, AXES + 3 * axis], b[j, AXES + 3 * axis + 1], b[j, AXES + 3 * axis + 2]
        placed[3 + 3 * axis, k], placed[4 + 3 * axis, k], placed[5 + 3 * axis, k] = _turn(
            r, x, y, z
        )
    for c in range(3):
        placed[12 + c, k] = b[j, HALF + c]


@njit(**BORROW)
def placed_gap(a, i, placed, k):
    """:func:`box_gap` of A's node ``i`` and the box in column ``k`` of ``placed`` (from
    :func:`place_box`)."""
    c = (placed[0, k], placed[1, k], placed[2, k])
    u = (placed[3, k], placed[4, k], placed[5, k])
    v = (placed[6, k], placed[7, k], placed[8, k])
    t = (placed[9, k], placed[10, k], placed[11, k])
    return _gap(a, i, c, u, v, t, (placed[12, k], placed[13, k], placed[14, k]))


@njit(**BORROW)
def sphere_bound(a, i, b, j, r, s):
    """Sphere bound of the pair (i, j)."""
    cx = r[0] * b[j, CENTRE] + r[1] * b[j, CENTRE + 1] + r[2] * b[j, CENTRE + 2] + s[0]
    cy = r[3] * b[j, CENTRE] + r[4] * b[j, CENTRE + 1] + r[5] * b[j, CENTRE + 2] + s[1]
    cz = r[6] * b[j, CENTRE] + r[7] * b[j, CENTRE + 1] + r[8] * b[j, CENTRE + 2] + s[2]
    ux, uy, uz = cx - a[i, CENTRE], cy - a[i, CENTRE + 1], cz - a[i, CENTRE + 2]
    return sqrt(ux * ux + uy * uy + uz * uz) - a[i, RADIUS] - b[j, RADIUS]


@njit(**BORROW)
def sphere_far(a, i, b, j, r, s, limit):
    """``(far, d2)``: the sphere bound of the pair (i, j) exceeds ``limit`` (tested on
    squares, no square root), and the squared distance of the centres."""
    cx = r[0] * b[j, CENTRE] + r[1] * b[j, CENTRE + 1] + r[2] * b[j, CENTRE + 2] + s[0]
    cy = r[3] * b[j, CENTRE] + r[4] * b[j, CENTRE + 1] + r[5] * b[j, CENTRE + 2] + s[1]
    cz = r[6] * b[j, CENTRE] + r[7] * b[j, CENTRE + 1] + r[8] * b[j, CENTRE + 2] + s[2]
    ux, uy, uz = cx - a[i, CENTRE], cy - a[i, CENTRE + 1], cz - a[i, CENTRE + 2]
    d2 = ux * ux + uy * uy + uz * uz
    reach = limit + a[i, RADIUS] + b[j, RADIUS]
    return reach >= 0.0 and d2 > reach * reach, d2


@njit(**BORROW)
def node_bound(a, i, b, j, r, s, best, margin):
    """Bound 1 of the pair (i, j), then (unless that one drops the pair, ``bound − margin
    > best``: then +inf) the larger of bounds 1 and 2."""
    far, d2 = sphere_far(a, i, b, j, r, s, best + margin)
    if far:
        return np.inf
    sphere = sqrt(d2) - a[i, RADIUS] - b[j, RADIUS]
    return max(sphere, box_gap(a, i, b, j, r, s))


@njit(**BORROW, forceinline=True)
def place_node(b, j, r, s, placed, k):
    """Column ``k`` of ``placed (PLACED, m)``: B's node ``j`` moved into A's frame, its box
    (:func:`~engine.kernels.collision.distance_bounds.place_box`) then its sphere (centre,
    radius)."""
    place_box(b, j, r, s, placed, k)
    x, y, z = b[j, CENTRE], b[j, CENTRE + 1], b[j, CENTRE + 2]
    placed[N_PLACED, k] = r[0] * x + r[1] * y + r[2] * z + s[0]
    placed[N_PLACED + 1, k] = r[3] * x + r[4] * y + r[5] * z + s[1]
    placed[N_PLACED + 2, k] = r[6] * x + r[7] * y + r[8] * z + s[2]
    placed[N_PLACED + 3, k] = b[j, RADIUS]


@njit(**BORROW)
def far_placed(a, i, placed, k, limit):
    """``(far, d2)`` of :func:`sphere_far` for A's node ``i`` and the placed B node ``k``."""
    ux = placed[N_PLACED, k] - a[i, CENTRE]
    uy = placed[N_PLACED + 1, k] - a[i, CENTRE + 1]
    uz = placed[N_PLACED + 2, k] - a[i, CENTRE + 2]
    d2 = ux * ux + uy * uy + uz * uz
    reach = limit + a[i, RADIUS] + placed[N_PLACED + 3, k]
    return reach >= 0.0 and d2 > reach * reach, d2


@njit(**BORROW, forceinline=True)
def bound_placed(a, i, placed, k, best, margin):
    """:func:`node_bound` for A's node ``i`` and the placed B node ``k``."""
    far, d2 = far_placed(a, i, placed, k, best + margin)
    if far:
        return np.inf
    sphere = sqrt(d2) - a[i, RADIUS] - placed[N_PLACED + 3, k]
    return max(sphere, placed_gap(a, i, placed, k))


@njit(**DISTINCT)
@tail_masked
def child_bounds(a, nodes, m, placed, n, out):
    """``out[k, t]`` (``0 ≤ k < m``, ``0 ≤ t < n``): the larger of bounds 1 and 2 of A's
    node ``nodes[k]`` and the placed B node ``t`` (:func:`place_node`), bound 2 with the
    gaps on one box's three axes taken together (:func:`_axes_gap`: at least
    :func:`placed_gap`); for each A node one loop over the columns, vectorised. (All the
    A children of an unfolding in one call: can × milk at −0.001 1.22 → 1.15 of Coal's
    time, issue 15, twelfth step. ``_bounds_row`` is ``tail_masked`` as well: LLVM
    vectorises its loop when it compiles it, before inlining. ``DISTINCT``: ``out`` shares
    no memory with the inputs, and the loop runs without runtime overlap checks: can × milk
    at −0.001 2.75–2.81 → 2.64–2.69 µs in the kernel. Two A nodes a loop, their chains
    interleaved, was slower: 2.78–3.01 → 3.14–3.33 µs.)"""
    for k in range(m):
        _bounds_row(a, nodes[k], placed, n, out, k)


@njit(**DISTINCT, forceinline=True)
@tail_masked
def _bounds_row(a, i, placed, n, out, k):
    """Row ``k`` of :func:`child_bounds`: A's node ``i``."""
    ox, oy, oz, rad = a[i, CENTRE], a[i, CENTRE + 1], a[i, CENTRE + 2], a[i, RADIUS]
    bx, by, bz = a[i, BOX], a[i, BOX + 1], a[i, BOX + 2]
    h0, h1, h2 = a[i, BOX + 12], a[i, BOX + 13], a[i, BOX + 14]
    p0, p1, p2 = a[i, BOX + 3], a[i, BOX + 4], a[i, BOX + 5]
    q0, q1, q2 = a[i, BOX + 6], a[i, BOX + 7], a[i, BOX + 8]
    w0, w1, w2 = a[i, BOX + 9], a[i, BOX + 10], a[i, BOX + 11]
    for t in range(n):
        ux = placed[N_PLACED, t] - ox
        uy = placed[N_PLACED + 1, t] - oy
        uz = placed[N_PLACED + 2, t] - oz
        sphere = sqrt(ux * ux + uy * uy + uz * uz) - rad - placed[N_PLACED + 3, t]
        d0, d1, d2 = placed[0, t] - bx, placed[1, t] - by, placed[2, t] - bz
        u0, u1, u2 = placed[3, t], placed[4, t], placed[5, t]
        v0, v1, v2 = placed[6, t], placed[7, t], placed[8, t]
        t0, t1, t2 = placed[9, t], placed[10, t], placed[11, t]
        g0, g1, g2 = placed[12, t], placed[13, t], placed[14, t]
        c00 = abs(p0 * u0 + p1 * u1 + p2 * u2)
        c01 = abs(p0 * v0 + p1 * v1 + p2 * v2)
        c02 = abs(p0 * t0 + p1 * t1 + p2 * t2)
        c10 = abs(q0 * u0 + q1 * u1 + q2 * u2)
        c11 = abs(q0 * v0 + q1 * v1 + q2 * v2)
        c12 = abs(q0 * t0 + q1 * t1 + q2 * t2)
        c20 = abs(w0 * u0 + w1 * u1 + w2 * u2)
        c21 = abs(w0 * v0 + w1 * v1 + w2 * v2)
        c22 = abs(w0 * t0 + w1 * t1 + w2 * t2)
        da0 = abs(p0 * d0 + p1 * d1 + p2 * d2)
        da1 = abs(q0 * d0 + q1 * d1 + q2 * d2)
        da2 = abs(w0 * d0 + w1 * d1 + w2 * d2)
        db0 = abs(u0 * d0 + u1 * d1 + u2 * d2)
        db1 = abs(v0 * d0 + v1 * d1 + v2 * d2)
        db2 = abs(t0 * d0 + t1 * d1 + t2 * d2)
        gap = _axes_gap(
            da0 - h0 - (g0 * c00 + g1 * c01 + g2 * c02),
            da1 - h1 - (g0 * c10 + g1 * c11 + g2 * c12),
            da2 - h2 - (g0 * c20 + g1 * c21 + g2 * c22),
            db0 - g0 - (h0 * c00 + h1 * c10 + h2 * c20),
            db1 - g1 - (h0 * c01 + h1 * c11 + h2 * c21),
            db2 - g2 - (h0 * c02 + h1 * c12 + h2 * c22),
        )
        length2 = d0 * d0 + d1 * d1 + d2 * d2
        spread = h0 * da0 + h1 * da1 + h2 * da2 + g0 * db0 + g1 * db1 + g2 * db2
        length = sqrt(length2)
        centres = select(length > 0.0, (length2 - spread) / length, -np.inf)
        out[k, t] = max(max(gap, centres), sphere)


@njit(**BORROW, forceinline=True)
def may_drop(a, i, b, j, r, s, limit):
    """Bound 3 of the internal pair (i, j) may exceed ``limit``: the nearest of the two
    node triangles' vertex pairs (an upper bound on their distance), less ``g_a + g_b``,
    does. (A heuristic only: it decides whether bound 3 is worth computing.)"""
    near = np.inf
    for w in range(3):
        x, y, z = b[j, COORDS + 3 * w], b[j, COORDS + 3 * w + 1], b[j, COORDS + 3 * w + 2]
        bx = r[0] * x + r[1] * y + r[2] * z + s[0]
        by = r[3] * x + r[4] * y + r[5] * z + s[1]
        bz = r[6] * x + r[7] * y + r[8] * z + s[2]
        for v in range(3):
            ux = bx - a[i, COORDS + 3 * v]
            uy = by - a[i, COORDS + 3 * v + 1]
            uz = bz - a[i, COORDS + 3 * v + 2]
            near = min(near, ux * ux + uy * uy + uz * uz)
    return sqrt(near) - a[i, GAP] - b[j, GAP] > limit
