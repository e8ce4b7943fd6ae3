"""Oriented bounding boxes of tree nodes: the separating-axis test of two boxes with a margin.

A box row is ``(15,)`` float64, as :attr:`~engine.trees.views.TreeViews.boxes` writes them
(body frame): centre (columns 0–2), three orthonormal unit axes (3–5, 6–8, 9–11) and the
half-extents along them (12–14). The traversal places B's rows into A's frame once per node
and query (:func:`place_row`), then :func:`separated` tests a node pair after its bounding
spheres have passed: two convex sets are disjoint by more than ``margin`` when some axis
separates their projections by more than ``margin`` (the 15 axes of two boxes: 3 + 3 face
normals and 9 edge cross products; a cross product of unit vectors is no longer than 1, so
its unnormalised gap exceeding ``margin`` is a true gap of more than ``margin``).

LLVM inlines both helpers wherever they are used (``forceinline``: by their size it had
kept them called functions, and a call, with its arrays passed field by field, cost about
as much as the work; inlined, near queries of icospheres are 1–3 µs faster, BENCHMARKS.md,
issue 15, tenth step). The
bounds-only search (:func:`bounds_apart`) is compiled without fast-math and called, not
inlined: one body, free of contraction wherever it lands, serves the host's early-out
(:func:`~engine.kernels.collision.pair_query.roots_apart`) and the query kernel's own
(:func:`~engine.kernels.collision.pair_query.pair_query`), so both reach the same outcome
for the same bounds, pose and margin. :func:`place_box` and :func:`box_apart` are the
helpers as called functions (the same no-fast-math bits as the search).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from engine.kernels.jit import BORROW, EXACT_BORROW, EXACT_JIT, JIT

BOX_COLUMNS = 15  # centre (3), axes (3 × 3, one per row), half-extents (3)
TABLE_COLUMNS = 21  # a box (15), a sphere: centre (3), radius; first child, child count
SEARCH_BUDGET = 256  # node pairs a bounds-only search tests before it gives up


@njit(**BORROW, forceinline=True)
def place_row(boxes_b, j, rotation, shift, placed_b, done):
    """B's box row ``j`` of ``boxes_b (N, 15)`` float64 moved into A's frame by
    ``x ↦ rotation x + shift`` (``rotation (3, 3)``, ``shift (3,)`` float64), into
    ``placed_b[j]`` (``placed_b (N, 15)`` float64), unless ``done[j]`` (``(N,)`` bool,
    then set)."""
    if not done[j]:
        for r in range(3):
            r0, r1, r2 = rotation[r, 0], rotation[r, 1], rotation[r, 2]
            placed_b[j, r] = r0 * boxes_b[j, 0] + r1 * boxes_b[j, 1] + r2 * boxes_b[j, 2] + shift[r]
            placed_b[j, 3 + r] = r0 * boxes_b[j, 3] + r1 * boxes_b[j, 4] + r2 * boxes_b[j, 5]
            placed_b[j, 6 + r] = r0 * boxes_b[j, 6] + r1 * boxes_b[j, 7] + r2 * boxes_b[j, 8]
            placed_b[j, 9 + r] = r0 * boxes_b[j, 9] + r1 * boxes_b[j, 10] + r2 * boxes_b[j, 11]
            placed_b[j, 12 + r] = boxes_b[j, 12 + r]
        done[j] = True


@njit(**EXACT_BORROW)
def place_box(boxes_b, j, rotation, shift, placed_b, done):
    """:func:`place_row` as a called function (arguments as there)."""
    place_row(boxes_b, j, rotation, shift, placed_b, done)


@njit(**BORROW, forceinline=True)
def separated(boxes_a, i, placed_b, j, margin):
    """True when A's box row ``i`` of ``boxes_a (Na, 15)`` and B's placed row ``j`` of
    ``placed_b (Nb, 15)`` (both float64, A's frame) are apart by more than ``margin``
    along one of their 15 separating axes (``margin`` float64 ≥ 0; see the module). A's
    face normals come first, each with the row of B's axes in A's box coordinates it
    needs, so a pair that one of them separates costs a third of the test."""
    dx = placed_b[j, 0] - boxes_a[i, 0]
    dy = placed_b[j, 1] - boxes_a[i, 1]
    dz = placed_b[j, 2] - boxes_a[i, 2]
    b0x, b0y, b0z = placed_b[j, 3], placed_b[j, 4], placed_b[j, 5]
    b1x, b1y, b1z = placed_b[j, 6], placed_b[j, 7], placed_b[j, 8]
    b2x, b2y, b2z = placed_b[j, 9], placed_b[j, 10], placed_b[j, 11]
    ha0, ha1, ha2 = boxes_a[i, 12], boxes_a[i, 13], boxes_a[i, 14]
    hb0, hb1, hb2 = placed_b[j, 12], placed_b[j, 13], placed_b[j, 14]
    # A's face normals: the centres' offset and B's axes in A's box coordinates, a row at
    # a time
    a00, a01, a02 = boxes_a[i, 3], boxes_a[i, 4], boxes_a[i, 5]
    t0 = a00 * dx + a01 * dy + a02 * dz
    r00 = a00 * b0x + a01 * b0y + a02 * b0z
    r01 = a00 * b1x + a01 * b1y + a02 * b1z
    r02 = a00 * b2x + a01 * b2y + a02 * b2z
    e00, e01, e02 = abs(r00), abs(r01), abs(r02)
    if abs(t0) > ha0 + hb0 * e00 + hb1 * e01 + hb2 * e02 + margin:
        return True
    a10, a11, a12 = boxes_a[i, 6], boxes_a[i, 7], boxes_a[i, 8]
    t1 = a10 * dx + a11 * dy + a12 * dz
    r10 = a10 * b0x + a11 * b0y + a12 * b0z
    r11 = a10 * b1x + a11 * b1y + a12 * b1z
    r12 = a10 * b2x + a11 * b2y + a12 * b2z
    e10, e11, e12 = abs(r10), abs(r11), abs(r12)
    if abs(t1) > ha1 + hb0 * e10 + hb1 * e11 + hb2 * e12 + margin:
        return True
    a20, a21, a22 = boxes_a[i, 9], boxes_a[i, 10], boxes_a[i, 11]
    t2 = a20 * dx + a21 * dy + a22 * dz
    r20 = a20 * b0x + a21 * b0y + a22 * b0z
    r21 = a20 * b1x + a21 * b1y + a22 * b1z
    r22 = a20 * b2x + a21 * b2y + a22 * b2z
    e20, e21, e22 = abs(r20), abs(r21), abs(r22)
    if abs(t2) > ha2 + hb0 * e20 + hb1 * e21 + hb2 * e22 + margin:
        return True
    # B's face normals
    if abs(t0 * r00 + t1 * r10 + t2 * r20) > ha0 * e00 + ha1 * e10 + ha2 * e20 + hb0 + margin:
        return True
    if abs(t0 * r01 + t1 * r11 + t2 * r21) > ha0 * e01 + ha1 * e11 + ha2 * e21 + hb1 + margin:
        return True
    if abs(t0 * r02 + t1 * r12 + t2 * r22) > ha0 * e02 + ha1 * e12 + ha2 * e22 + hb2 + margin:
        return True
    # edge cross products a_k × b_l
    if abs(t2 * r10 - t1 * r20) > ha1 * e20 + ha2 * e10 + hb1 * e02 + hb2 * e01 + margin:
        return True
    if abs(t2 * r11 - t1 * r21) > ha1 * e21 + ha2 * e11 + hb0 * e02 + hb2 * e00 + margin:
        return True
    if abs(t2 * r12 - t1 * r22) > ha1 * e22 + ha2 * e12 + hb0 * e01 + hb1 * e00 + margin:
        return True
    if abs(t0 * r20 - t2 * r00) > ha0 * e20 + ha2 * e00 + hb1 * e12 + hb2 * e11 + margin:
        return True
    if abs(t0 * r21 - t2 * r01) > ha0 * e21 + ha2 * e01 + hb0 * e12 + hb2 * e10 + margin:
        return True
    if abs(t0 * r22 - t2 * r02) > ha0 * e22 + ha2 * e02 + hb0 * e11 + hb1 * e10 + margin:
        return True
    if abs(t1 * r00 - t0 * r10) > ha0 * e10 + ha1 * e00 + hb1 * e22 + hb2 * e21 + margin:
        return True
    if abs(t1 * r01 - t0 * r11) > ha0 * e11 + ha1 * e01 + hb0 * e22 + hb2 * e20 + margin:
        return True
    return abs(t1 * r02 - t0 * r12) > ha0 * e12 + ha1 * e02 + hb0 * e21 + hb1 * e20 + margin


@njit(**EXACT_BORROW)
def box_apart(boxes_a, i, placed_b, j, margin):
    """:func:`separated` as a called function (arguments as there)."""
    return separated(boxes_a, i, placed_b, j, margin)


@njit(**EXACT_JIT)
def bounds_apart(table_a, table_b, rotation, shift, margin, budget):
    """True when the node bounds alone show that no leaf pair of two bodies is within
    ``margin`` (float64) of contact: ``table_* (N, 21)`` float64 rows per node, body frames,
    each a box (columns 0–14, as in the module), a sphere (15–17 centre, 18 radius), the
    first child (19) and the child count (20, 0 for a leaf); B's frame maps to A's by ``x ↦
    rotation x + shift``. A depth-first search from the root pair drops every pair whose
    spheres or boxes are apart by more than ``margin`` and replaces every other by the
    pairs of its larger node's children (larger sphere; a leaf stands for itself), the
    child pair whose spheres overlap most searched first. False as soon as a pair of two
    leaves remains or more than ``budget`` pairs were tested: bodies in contact end after
    about one descent, and the order cannot change the outcome (it is True exactly when the
    whole search tree, whatever its order, holds no leaf pair and at most ``budget`` pairs). The
    outcome is monotone in ``margin``: with a smaller one every pair dropped is dropped
    too, so a search that ends True within the budget ends True with any smaller margin."""
    stack = np.empty((budget + 1, 2), np.int64)
    placed = np.empty((1, 19))
    # one test site (each inlined copy of the box test costs compile time): the root pair
    # is tested as the one "child" of an A side whose children are [0, 1)
    i, j, side_a, first, count = 0, 0, True, 0, 1
    top, tests = 0, 0
    while True:
        closest, nearest = top, np.inf  # the kept child pair whose spheres overlap most
        if side_a:
            _place(table_b, j, rotation, shift, placed)
        for c in range(first, first + count):
            tests += 1
            if tests > budget:
                return False
            ci, cj = i, j
            if side_a:
                ci = c
            else:
                cj = c
                _place(table_b, c, rotation, shift, placed)
            if not _row_pair_apart(table_a, ci, placed, 0, margin):
                key = _overlap(table_a, ci, placed)
                if key < nearest:
                    closest, nearest = top, key
                stack[top, 0], stack[top, 1] = ci, cj
                top += 1
        if top > 0 and closest < top - 1:  # popped next
            for col in range(2):
                stack[closest, col], stack[top - 1, col] = stack[top - 1, col], stack[closest, col]
        if top == 0:
            return True
        top -= 1
        i, j = stack[top, 0], stack[top, 1]
        count_a, count_b = np.int64(table_a[i, 20]), np.int64(table_b[j, 20])
        if count_a == 0 and count_b == 0:
            return False  # two leaves that may touch
        side_a = count_a > 0 and (count_b == 0 or table_a[i, 18] >= table_b[j, 18])
        first = np.int64(table_a[i, 19]) if side_a else np.int64(table_b[j, 19])
        count = count_a if side_a else count_b


@njit(**BORROW)
def _overlap(rows_a, i, placed):
    """``|c_a − c_b|² − (r_a + r_b)²`` (float64) of the spheres of row ``i`` of ``rows_a``
    and ``placed[0]`` (:func:`bounds_apart`'s layout, A's frame): smaller where they
    overlap more, the order in which the search goes on."""
    dx = rows_a[i, 15] - placed[0, 15]
    dy = rows_a[i, 16] - placed[0, 16]
    dz = rows_a[i, 17] - placed[0, 17]
    reach = rows_a[i, 18] + placed[0, 18]
    return dx * dx + dy * dy + dz * dz - reach * reach


@njit(**BORROW)
def _place(table_b, j, rotation, shift, out):
    """B's node ``j`` (its box and sphere, columns 0–18 of ``table_b``) moved into A's frame,
    into ``out[0]`` (``(1, 19)`` float64)."""
    for r in range(3):
        out[0, r] = (
            rotation[r, 0] * table_b[j, 0]
            + rotation[r, 1] * table_b[j, 1]
            + rotation[r, 2] * table_b[j, 2]
            + shift[r]
        )
        out[0, 15 + r] = (
            rotation[r, 0] * table_b[j, 15]
            + rotation[r, 1] * table_b[j, 16]
            + rotation[r, 2] * table_b[j, 17]
            + shift[r]
        )
    for c in range(3, 12, 3):
        for r in range(3):
            out[0, c + r] = (
                rotation[r, 0] * table_b[j, c]
                + rotation[r, 1] * table_b[j, c + 1]
                + rotation[r, 2] * table_b[j, c + 2]
            )
    for c in (12, 13, 14, 18):
        out[0, c] = table_b[j, c]


@njit(**BORROW)
def _row_pair_apart(rows_a, i, placed, j, margin):
    """Rows ``i`` of ``rows_a`` and ``j`` of ``placed`` (:func:`bounds_apart`'s layout, A's
    frame; box, then sphere) apart by more than ``margin``: their spheres, else their
    boxes."""
    dx = rows_a[i, 15] - placed[j, 15]
    dy = rows_a[i, 16] - placed[j, 16]
    dz = rows_a[i, 17] - placed[j, 17]
    reach = rows_a[i, 18] + placed[j, 18] + margin
    if dx * dx + dy * dy + dz * dz > reach * reach:
        return True
    return separated(rows_a, i, placed, j, margin)


@njit(**JIT)
def box_set_up(boxes_a, boxes_b, rotation, shift):
    """``(boxed, placed, done)`` for a query with node boxes ``boxes_* (N, 15)`` float64
    (``(0, 15)``: none, then ``boxed`` is False and the buffers empty): ``placed (Nb, 15)``
    float64 and ``done (Nb,)`` bool as :func:`place_box` fills them, B's root placed."""
    boxed = boxes_a.shape[0] > 0 and boxes_b.shape[0] > 0
    nb = boxes_b.shape[0] if boxed else 0
    placed_b = np.empty((nb, BOX_COLUMNS))
    done = np.zeros(nb, np.bool_)
    if boxed:
        place_box(boxes_b, 0, rotation, shift, placed_b, done)
    return boxed, placed_b, done
