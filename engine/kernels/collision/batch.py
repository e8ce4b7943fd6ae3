"""Many body pairs in one call: poses, margins and one :func:`query_kernel` per pair.

Trees live in a *bank* (:class:`NodeBank`): every node array of several trees
concatenated, with each tree's node and face offsets in a :class:`TreeTable`. A tree's
rows are a contiguous slice of the bank, and its child indices are local to that slice,
so a query sees exactly the arrays a single query sees (the same compiled
``query_kernel`` runs both). The host passes the body pairs (:class:`PairQueries`), the
search parameters (:class:`QueryParams`) and the kept leaf-pair lists
(:class:`PairLists`) as named records too, and gets a :class:`BatchResult` back.

The pose helpers are compiled without fast-math, so the single-pair host path,
which calls them too, moves B by bit-identical rotations and shifts.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit

from engine.kernels.collision.contact_merge import contact_kernel
from engine.kernels.collision.pair_lists import (
    by_faces,
    listed_contacts,
    listed_scratch,
    reference_distances,
)
from engine.kernels.collision.traversal import query_kernel, roots_apart
from engine.kernels.geometry.rotation import rotation_entries
from engine.kernels.geometry.triangle_batch import (
    ITERATIVE,
    N_STATS,
    STAT_FALLBACKS,
    STAT_ITERATIVE,
    STAT_PAIRS,
    STAT_SPHERES,
    listed_workspace,
)
from engine.kernels.jit import EXACT_BORROW, EXACT_JIT, JIT

MARGIN_ULPS = 256.0
SQRT3 = np.sqrt(3.0)
# Columns of the per-query counters written by :func:`batch_kernel`.
COUNT_DEPTH, COUNT_UNFOLDINGS, COUNT_ITERATIVE, COUNT_FALLBACKS, COUNT_COMPARISONS = range(5)
COUNT_SPHERES, COUNT_LISTED = 5, 6
N_COUNTS = 7


class NodeBank(NamedTuple):
    """Node arrays of several trees concatenated (``N`` nodes, ``F`` faces in all); the
    rows of tree ``t`` are given by :class:`TreeTable`, child indices are local to them."""

    coords: np.ndarray  # (N, 9) query precision: prepared triangles, row-major
    frames: np.ndarray  # (N, 14) query precision: their frames
    master_coords: np.ndarray  # (N, 9) float64: the same in float64 (B is moved from them)
    master_frames: np.ndarray  # (N, 14) float64
    epsilon: np.ndarray  # (N,) float64: ε of each node
    epsilon_query: np.ndarray  # (N,) query precision: the same, rounded (a leaf's ε there)
    face: np.ndarray  # (N,) int32: a leaf's face (local to its tree), −1 for a surrogate
    first_child: np.ndarray  # (N,) int32: local row of a surrogate's first child
    child_count: np.ndarray  # (N,) int32
    face_normals: np.ndarray  # (F, 3) float64: unit face normals
    spheres: np.ndarray  # (N, 4) float64: bounding sphere (centre, radius) of each node
    boxes: np.ndarray  # (N, 15) float64: oriented bounding box of each node (as ``spheres``)


class TreeTable(NamedTuple):
    """One entry per tree of a :class:`NodeBank` (``T`` trees)."""

    node_offset: np.ndarray  # (T,) int64: first row of the tree's nodes
    node_count: np.ndarray  # (T,) int64
    face_offset: np.ndarray  # (T,) int64: first row of the tree's face normals
    face_count: np.ndarray  # (T,) int64
    leaf_epsilon: np.ndarray  # (T,) float64
    bounding_radius: np.ndarray  # (T,) float64
    extent: np.ndarray  # (T,) float64: largest body-frame coordinate (max-norm)
    radius: np.ndarray  # (T,) float64: largest body-frame distance from the origin


class PairQueries(NamedTuple):
    """``k`` body pairs: trees by bank position and poses (world frame)."""

    tree_a: np.ndarray  # (k,) int64
    tree_b: np.ndarray  # (k,) int64
    position_a: np.ndarray  # (k, 3) float64
    orientation_a: np.ndarray  # (k, 4) float64 unit quaternions (w, x, y, z)
    position_b: np.ndarray  # (k, 3) float64
    orientation_b: np.ndarray  # (k, 4) float64


@njit(**EXACT_JIT)
def unit_orientations(orientations, unit):
    """``unit (n, 4)``: each of ``orientations (n, 4)`` float64 divided
    by its norm as ``q / np.linalg.norm(q)`` rounds it (the sum of squares in numpy's
    order). Returns the first body whose orientation's norm is not within 1e-6 of 1 (NaN
    included), else −1."""
    for i in range(orientations.shape[0]):
        q0, q1, q2, q3 = (
            orientations[i, 0],
            orientations[i, 1],
            orientations[i, 2],
            orientations[i, 3],
        )
        norm = np.sqrt(q0 * q0 + q1 * q1 + q2 * q2 + q3 * q3)
        if not abs(norm - 1.0) <= 1e-6:
            return i
        unit[i, 0], unit[i, 1], unit[i, 2], unit[i, 3] = q0 / norm, q1 / norm, q2 / norm, q3 / norm
    return -1


@njit(**EXACT_JIT)
def gather_queries(pairs, tree_index, origins, unit, first, last, out):
    """Write rows ``first:last`` of ``out`` (:class:`PairQueries`) for body ``pairs (k, 2)``
    int64: each body's tree ``tree_index (n,)`` int64, origin ``origins (n, 3)`` and unit
    orientation ``unit (n, 4)`` float64 (:func:`unit_orientations`). One pass instead of
    numpy's six gathers (on the paper's 24,576-sphere grid, with the norms, 2.3 ms of
    serial host work per evaluation before it; now run in parts on the worker threads)."""
    for t in range(first, last):
        a, b = pairs[t, 0], pairs[t, 1]
        out.tree_a[t], out.tree_b[t] = tree_index[a], tree_index[b]
        for c in range(3):
            out.position_a[t, c] = origins[a, c]
            out.position_b[t, c] = origins[b, c]
        for c in range(4):
            out.orientation_a[t, c] = unit[a, c]
            out.orientation_b[t, c] = unit[b, c]


class QueryParams(NamedTuple):
    """Search parameters shared by every query of a call (see :func:`query_kernel`)."""

    surrogate: tuple  # (mode, iterations, rtol, one, band) for pairs with a surrogate
    leaf: tuple  # the same for leaf pairs
    keep_all: bool  # keep every leaf pair found, else only the certified ones (status 1)
    ulp: float  # machine epsilon of the query precision (for the margin)
    tiny: float  # gap below which two closest points coincide, per unit bounding radius
    keep_pairs: bool  # write the (face of A, face of B) pairs, else only count them


class PairLists(NamedTuple):
    """Leaf-pair lists kept between calls (``m`` entries, a Verlet list per body pair)."""

    skin: float  # s relative to ε_a + ε_b; 0: no lists
    slot: np.ndarray  # (k,) int64: entry of each query, −1 for none
    rotations: np.ndarray  # (m, 3, 3) float64: reference pose of B relative to A
    shifts: np.ndarray  # (m, 3) float64
    offsets: np.ndarray  # (m + 1,) int64: entry e owns near[offsets[e]:offsets[e + 1]]
    near: np.ndarray  # (L, 2) int64: leaf node pairs (local rows of A, of B)
    distances: np.ndarray  # (L,) float64: each pair's exact distance at the reference pose


class BatchResult(NamedTuple):
    """Ragged (CSR) results of queries ``start … stop − 1`` (``k = stop − start``)."""

    pair_offsets: np.ndarray  # (k + 1,) int64
    pairs: np.ndarray  # (p, 2) int64: (face of A, face of B)
    contact_offsets: np.ndarray  # (k + 1,) int64
    points: np.ndarray  # (c, 3) float64, world frame
    normals: np.ndarray  # (c, 3) float64, unit, from A to B
    overlaps: np.ndarray  # (c,) float64
    near_offsets: np.ndarray  # (k + 1,) int64: the queries' new lists
    near: np.ndarray  # (L, 2) int64
    near_distances: np.ndarray  # (L,) float64: their exact distances at the reference pose
    rotations: np.ndarray  # (k, 3, 3) float64: each list's reference pose
    shifts: np.ndarray  # (k, 3) float64


@njit(**EXACT_JIT)
def relative_pose(position_a, orientation_a, position_b, orientation_b):
    """``(R_a, R, s)``: A's rotation and the map ``x ↦ R x + s`` from B's frame to A's
    (``R = R_aᵀ R_b``, ``s = R_aᵀ (p_b − p_a)``); positions (3,), orientations (4,)
    unit quaternions, results (3, 3), (3, 3), (3,) float64."""
    ra, rotation, shift = relative_entries(
        (position_a[0], position_a[1], position_a[2]),
        (orientation_a[0], orientation_a[1], orientation_a[2], orientation_a[3]),
        (position_b[0], position_b[1], position_b[2]),
        (orientation_b[0], orientation_b[1], orientation_b[2], orientation_b[3]),
    )
    ra_out, rotation_out, shift_out = np.empty((3, 3)), np.empty((3, 3)), np.empty(3)
    for k in range(9):
        ra_out[k // 3, k % 3] = ra[k]
        rotation_out[k // 3, k % 3] = rotation[k]
    for k in range(3):
        shift_out[k] = shift[k]
    return ra_out, rotation_out, shift_out


@njit(**EXACT_BORROW)
def packed_relative_pose(pose_a, pose_b):
    """:func:`relative_pose` of two poses ``(7,)`` float64 (position, then quaternion) as
    tuples ``(R_a (9,), R (9,), s (3,))``, matrices row by row: the same bits, no array
    made."""
    return relative_entries(
        (pose_a[0], pose_a[1], pose_a[2]),
        (pose_a[3], pose_a[4], pose_a[5], pose_a[6]),
        (pose_b[0], pose_b[1], pose_b[2]),
        (pose_b[3], pose_b[4], pose_b[5], pose_b[6]),
    )


@njit(**EXACT_BORROW)
def relative_entries(position_a, orientation_a, position_b, orientation_b):
    """The arithmetic of :func:`relative_pose` on tuples (positions 3, quaternions 4):
    ``(R_a, R, s)`` as tuples of 9, 9 and 3 floats, matrices row by row."""
    ra = rotation_entries(orientation_a[0], orientation_a[1], orientation_a[2], orientation_a[3])
    rb = rotation_entries(orientation_b[0], orientation_b[1], orientation_b[2], orientation_b[3])
    d = (
        position_b[0] - position_a[0],
        position_b[1] - position_a[1],
        position_b[2] - position_a[2],
    )
    return (
        ra,
        (
            _transposed_product(ra, rb, 0, 0),
            _transposed_product(ra, rb, 0, 1),
            _transposed_product(ra, rb, 0, 2),
            _transposed_product(ra, rb, 1, 0),
            _transposed_product(ra, rb, 1, 1),
            _transposed_product(ra, rb, 1, 2),
            _transposed_product(ra, rb, 2, 0),
            _transposed_product(ra, rb, 2, 1),
            _transposed_product(ra, rb, 2, 2),
        ),
        (_turned_back(ra, d, 0), _turned_back(ra, d, 1), _turned_back(ra, d, 2)),
    )


@njit(**EXACT_BORROW)
def _transposed_product(ra, rb, i, j):
    """``(R_aᵀ R_b)[i, j]`` of two row-major 9-tuples."""
    return ra[i] * rb[j] + ra[3 + i] * rb[3 + j] + ra[6 + i] * rb[6 + j]


@njit(**EXACT_BORROW)
def _turned_back(ra, d, i):
    """``(R_aᵀ d)[i]`` of a row-major 9-tuple and a 3-tuple."""
    return ra[i] * d[0] + ra[3 + i] * d[1] + ra[6 + i] * d[2]


@njit(**EXACT_JIT)
def query_margin(extent_a, extent_b, shift, ulp):
    """Safety margin on surrogate ε: ``MARGIN_ULPS`` ulp of the pair's scale, which
    bounds every coordinate in A's frame (B's shift plus both bodies' largest body-frame
    coordinates; a rotation stretches a max-norm by at most √3)."""
    length = np.sqrt(shift[0] * shift[0] + shift[1] * shift[1] + shift[2] * shift[2])
    return MARGIN_ULPS * ulp * 2.0 * (SQRT3 * (extent_a + extent_b) + length)


@njit(**JIT)
def count_totals(counts, out):
    """``out (N_COUNTS,)`` int64: the columns of ``counts (k, N_COUNTS)`` int64 summed."""
    out[:] = 0
    for q in range(counts.shape[0]):
        for j in range(N_COUNTS):
            out[j] += counts[q, j]


@njit(**JIT)
def batch_kernel(bank, trees, queries, params, lists, start, stop, counts, levels):
    """Contacts of body pairs ``start ≤ q < stop``; returns a :class:`BatchResult`.

    ``bank`` (:class:`NodeBank`) holds the trees' nodes, ``trees`` (:class:`TreeTable`)
    where each tree's rows are, ``queries`` (:class:`PairQueries`) the ``k`` body pairs
    and ``params`` (:class:`QueryParams`) the search parameters (see
    :func:`~engine.kernels.collision.traversal.query_kernel`).

    ``lists`` (:class:`PairLists`): with ``skin > 0`` each query keeps a list of its
    leaf pairs within ε_a + ε_b + s, s = skin·(ε_a + ε_b) (leaf ε), found at a reference
    pose of B relative to A, with their exact distances there. Query q uses the list of
    entry ``slot[q]`` (−1: none) instead of a traversal while B's points have moved by
    less than s relative to A since its reference pose (:func:`motion_bound`, plus the
    query's margin), evaluating only the listed pairs that may be in contact now
    (:func:`listed_contacts`); else it traverses with every ε grown by s/2 and starts a
    new list (its pairs' exact distances as the traversal recorded them; in ``ITERATIVE``
    mode, which records bounds, :func:`reference_distances`).

    Writes ``counts (stop − start, N_COUNTS)`` int64 and ``levels (stop − start, L)``
    int64 (pairs evaluated per level), every entry: they may come uninitialised. In the
    result, query ``start + t`` owns rows ``pair_offsets[t]:pair_offsets[t + 1]`` of
    ``pairs``, likewise for contacts and its new list (empty without a skin, and for a
    query that used its cached list: that list stays valid as it is), whose reference
    pose is ``rotations[t], shifts[t]``.
    """
    k = stop - start
    pair_offsets = np.zeros(k + 1, np.int64)
    contact_offsets = np.zeros(k + 1, np.int64)
    near_offsets = np.zeros(k + 1, np.int64)
    rotations = np.empty((k, 3, 3))
    shifts = np.empty((k, 3))
    # a listed query's face pairs are a subset of its list: room for all of them at once
    # (touched only where written), so a chunk of the aligned grid (~2 M rows) does not
    # grow by doubling (each copy and page fault of 16-byte rows cost as much as the rows)
    # Without ``keep_pairs`` the pairs are counted only: the buffer stays empty, and
    # ``contact_kernel`` writes no pair into an empty one (a scene step reads the count; on
    # the "aligned" grid the pairs were 256 MB an evaluation, and ``contact_kernel``, which
    # wrote them, 43 % of a steady step's samples).
    room = 64 if params.keep_pairs else 0
    most = 0  # the longest list: listed queries share buffers of its size
    for t in range(k):
        e = lists.slot[start + t] if lists.slot.shape[0] > 0 else -1
        if e >= 0:
            size = lists.offsets[e + 1] - lists.offsets[e]
            most = max(most, size)
            if params.keep_pairs:
                room += size
    pairs = np.empty((room, 2), np.int64)
    near_out = np.empty((64, 2), np.int64)
    near_distances = np.empty(64)
    points = np.empty((64, 3))
    normals_out = np.empty((64, 3))
    overlaps = np.empty(64)
    stats = np.zeros(N_STATS, np.int64)
    local = np.full(max(1, int(trees.node_count.max())), -1, np.int64)  # listed_contacts'
    buffers = listed_workspace(bank.coords)
    listed_buffers = listed_scratch(most, bank.coords)
    found = listed_buffers[11]
    face_b = listed_buffers[9]
    for t in range(k):
        q = start + t
        ta, tb = queries.tree_a[q], queries.tree_b[q]
        a0, a1 = trees.node_offset[ta], trees.node_offset[ta] + trees.node_count[ta]
        b0, b1 = trees.node_offset[tb], trees.node_offset[tb] + trees.node_count[tb]
        position_a = queries.position_a[q]
        rot_a, rotation, shift = relative_pose(
            position_a, queries.orientation_a[q], queries.position_b[q], queries.orientation_b[q]
        )
        extent_b = trees.extent[tb]
        margin = query_margin(trees.extent[ta], extent_b, shift, params.ulp)
        ea, eb = trees.leaf_epsilon[ta], trees.leaf_epsilon[tb]
        tiny = params.tiny * max(trees.bounding_radius[ta], trees.bounding_radius[tb])
        setup = (ea, eb, tiny, min(ea, eb), rot_a, position_a)
        f0, f1 = trees.face_offset[ta], trees.face_offset[ta] + trees.face_count[ta]
        contact = (trees.face_count[tb], params.keep_all, bank.face_normals[f0:f1], setup)
        stats[:] = 0
        levels[t, :] = 0
        skin = lists.skin
        reach = skin * (ea + eb)
        inflate = 0.5 * reach if skin > 0.0 else 0.0  # a traversal grows every ε by s/2
        e = lists.slot[q]
        drift = 0.0
        if skin > 0.0 and e >= 0:
            drift = motion_bound(
                lists.rotations[e], lists.shifts[e], rotation, shift, trees.radius[tb]
            )
        listed = skin > 0.0 and e >= 0 and drift + margin < reach
        p0, c0, n0 = pair_offsets[t], contact_offsets[t], near_offsets[t]
        if listed and lists.offsets[e + 1] == lists.offsets[e]:
            # an empty list: no leaf pair of the two bodies within reach (a far wall)
            depth, unfoldings, n1, p1, c1 = 0, 0, n0, p0, c0
            rotations[t], shifts[t] = lists.rotations[e], lists.shifts[e]
        elif listed:
            l0, l1 = lists.offsets[e], lists.offsets[e + 1]
            n = listed_contacts(
                bank,
                (a0, a1, b0),
                (rotation, shift),
                lists.near[l0:l1],
                lists.distances[l0:l1],
                drift + 2.0 * margin,
                params.leaf,
                (local, buffers, listed_buffers),
                stats,
            )
            depth, unfoldings, n1 = 0, 0, n0  # a kept list stays put
            rotations[t], shifts[t] = lists.rotations[e], lists.shifts[e]
            if params.keep_pairs:
                pairs = _grow(pairs, p0, p0 + n)
            points, normals_out, overlaps = (
                _grow(points, c0, c0 + n),
                _grow(normals_out, c0, c0 + n),
                _grow(overlaps, c0, c0 + n),
            )
            out = (pairs[min(p0, pairs.shape[0]) :], points[c0:], normals_out[c0:], overlaps[c0:])
            face_a = bank.face[a0:a1]
            m, c = 0, 0
            if n > 0:
                m, c = contact_kernel(
                    found, n, face_a, face_b, contact[0], contact[1], contact[2], setup, out
                )
            p1, c1 = p0 + m, c0 + c
        elif roots_apart(
            bank.spheres[a0:a1],
            bank.boxes[a0:a1],
            bank.spheres[b0:b1],
            bank.boxes[b0:b1],
            rotation,
            shift,
            margin + 2.0 * inflate,
        ):  # the traversal's first test, without its set-up: nothing near, an empty list
            stats[STAT_SPHERES] += 1
            depth, unfoldings, n1, p1, c1 = 0, 0, n0, p0, c0
            rotations[t], shifts[t] = rotation, shift
        else:
            body_a = (  # query_kernel's body layout; A in the query precision
                bank.coords[a0:a1],
                bank.frames[a0:a1],
                bank.epsilon[a0:a1],
                bank.face[a0:a1],
                bank.first_child[a0:a1],
                bank.child_count[a0:a1],
                bank.spheres[a0:a1],
                bank.boxes[a0:a1],
            )
            body_b = (  # B from float64, moved into A's frame by the query
                bank.master_coords[b0:b1],
                bank.master_frames[b0:b1],
                bank.epsilon[b0:b1],
                bank.face[b0:b1],
                bank.first_child[b0:b1],
                bank.child_count[b0:b1],
                bank.spheres[b0:b1],
                bank.boxes[b0:b1],
            )
            depth, unfoldings, result, near, distances = query_kernel(
                body_a,
                body_b,
                (rotation, shift),
                margin,
                inflate,
                params.surrogate,
                params.leaf,
                contact,
                stats,
                levels[t],
            )
            rotations[t], shifts[t] = rotation, shift
            found_pairs, pts, nrm, ovl = result
            p1, c1 = p0 + found_pairs.shape[0], c0 + pts.shape[0]
            n1 = n0 + (near.shape[0] if skin > 0.0 else 0)
            if params.keep_pairs:
                pairs = _grow(pairs, p0, p1)
                pairs[p0:p1] = found_pairs
            points, normals_out, overlaps = (
                _grow(points, c0, c1),
                _grow(normals_out, c0, c1),
                _grow(overlaps, c0, c1),
            )
            points[c0:c1] = pts
            normals_out[c0:c1] = nrm
            overlaps[c0:c1] = ovl
            if n1 > n0:
                near, distances = by_faces(
                    near, distances, bank.face[a0:a1], bank.face[b0:b1], trees.face_count[tb]
                )
                near_out = _grow(near_out, n0, n1)
                near_distances = _grow(near_distances, n0, n1)
                near_out[n0:n1] = near
                if params.leaf[0] == ITERATIVE:  # the traversal recorded bounds, not distances
                    reference_distances(
                        bank,
                        (a0, b0),
                        (rotation, shift),
                        near,
                        params.leaf[3],
                        (local, buffers),
                        near_distances[n0:n1],
                    )
                else:  # the exact distances the traversal recorded them with
                    near_distances[n0:n1] = distances
        pair_offsets[t + 1], contact_offsets[t + 1], near_offsets[t + 1] = p1, c1, n1
        counts[t, COUNT_DEPTH] = depth
        counts[t, COUNT_UNFOLDINGS] = unfoldings
        counts[t, COUNT_ITERATIVE] = stats[STAT_ITERATIVE]
        counts[t, COUNT_FALLBACKS] = stats[STAT_FALLBACKS]
        counts[t, COUNT_COMPARISONS] = stats[STAT_PAIRS]
        counts[t, COUNT_SPHERES] = stats[STAT_SPHERES]
        counts[t, COUNT_LISTED] = 1 if listed else 0
    n_pairs, n_contacts, n_near = pair_offsets[k], contact_offsets[k], near_offsets[k]
    return BatchResult(
        pair_offsets,
        pairs[: min(n_pairs, pairs.shape[0])],
        contact_offsets,
        points[:n_contacts],
        normals_out[:n_contacts],
        overlaps[:n_contacts],
        near_offsets,
        near_out[:n_near],
        near_distances[:n_near],
        rotations,
        shifts,
    )


ORTHOGONALITY = 1e-14
"""Allowance for rotation matrices that are orthogonal only to rounding (entries off by a
few ulp): added to ‖R − R₀‖₂ in :func:`motion_bound`."""


@njit(**EXACT_JIT)
def motion_bound(rotation_0, shift_0, rotation, shift, radius_b):
    """Upper bound on how far any point of B (within ``radius_b`` of B's frame origin)
    moved relative to A between the poses ``x ↦ R₀x + s₀`` and ``x ↦ Rx + s``:
    ‖R − R₀‖₂·radius + |s − s₀|. For two rotations R − R₀ = (Q − I)·R₀, Q = R·R₀ᵀ a turn by
    θ, whose singular values are 2·sin(θ/2) twice and 0: the spectral norm is the
    Frobenius norm over √2, taken entry by entry (small turns lose no accuracy), plus
    :data:`ORTHOGONALITY` for the matrices' rounding: R₀ and R must be rotations of unit
    quaternions to rounding (every path to the batch renormalises them:
    ``check_quaternions``, :func:`unit_orientations`; a quaternion of norm 1 + 1e-8 would
    need more). (The bound was ‖R − R₀‖_F·√3·extent,
    up to 2.4 times larger: lists of turning bodies were renewed that much sooner.)"""
    frobenius = 0.0
    for i in range(3):
        for j in range(3):
            d = rotation[i, j] - rotation_0[i, j]
            frobenius += d * d
    turn = np.sqrt(0.5 * frobenius) + ORTHOGONALITY
    d0, d1, d2 = shift[0] - shift_0[0], shift[1] - shift_0[1], shift[2] - shift_0[2]
    return turn * radius_b + np.sqrt(d0 * d0 + d1 * d1 + d2 * d2)


@njit(**JIT)
def _grow(array, n, need):
    """``array`` if it has ``need`` rows, else a copy with twice the room (first ``n`` rows)."""
    if array.shape[0] >= need:
        return array
    shape = (max(need, 2 * array.shape[0]),) + array.shape[1:]
    grown = np.empty(shape, array.dtype)
    grown[:n] = array[:n]
    return grown
