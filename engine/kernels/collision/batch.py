"""Many body pairs in one call: poses, margins and one :func:`query_kernel` per pair.

Trees live in a *bank*: every node array of several trees concatenated, with each
tree's node and face offsets. A tree's rows are a contiguous slice of the bank, and
its child indices are local to that slice, so a query sees exactly the arrays a
single query sees (the same compiled ``query_kernel`` runs both).

The pose helpers are compiled without fast-math, so the single-pair host path,
which calls them too, moves B by bit-identical rotations and shifts.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from engine.kernels.collision.rigid import EXACT_JIT
from engine.kernels.collision.traversal import listed_query, query_kernel
from engine.kernels.geometry.triangle_batch import (
    N_STATS,
    STAT_FALLBACKS,
    STAT_ITERATIVE,
    STAT_PAIRS,
    STAT_SPHERES,
)
from engine.kernels.jit import JIT

MARGIN_ULPS = 256.0
SQRT3 = np.sqrt(3.0)
# Columns of the per-query counters written by :func:`batch_kernel`.
COUNT_DEPTH, COUNT_UNFOLDINGS, COUNT_ITERATIVE, COUNT_FALLBACKS, COUNT_COMPARISONS = range(5)
COUNT_SPHERES, COUNT_LISTED = 5, 6
N_COUNTS = 7


@njit(**EXACT_JIT)
def rotation_matrix(q):
    """(3, 3) rotation of the unit quaternion ``q = (w, x, y, z)`` (4,) float64."""
    w, x, y, z = q[0], q[1], q[2], q[3]
    r = np.empty((3, 3))
    r[0, 0], r[0, 1], r[0, 2] = 1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)
    r[1, 0], r[1, 1], r[1, 2] = 2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)
    r[2, 0], r[2, 1], r[2, 2] = 2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)
    return r


@njit(**EXACT_JIT)
def relative_pose(position_a, orientation_a, position_b, orientation_b):
    """``(R_a, R, s)``: A's rotation and the map ``x ↦ R x + s`` from B's frame to A's
    (``R = R_aᵀ R_b``, ``s = R_aᵀ (p_b − p_a)``)."""
    ra = rotation_matrix(orientation_a)
    rb = rotation_matrix(orientation_b)
    rotation = np.empty((3, 3))
    shift = np.empty(3)
    d0 = position_b[0] - position_a[0]
    d1 = position_b[1] - position_a[1]
    d2 = position_b[2] - position_a[2]
    for i in range(3):
        for j in range(3):
            rotation[i, j] = ra[0, i] * rb[0, j] + ra[1, i] * rb[1, j] + ra[2, i] * rb[2, j]
        shift[i] = ra[0, i] * d0 + ra[1, i] * d1 + ra[2, i] * d2
    return ra, rotation, shift


@njit(**EXACT_JIT)
def query_margin(extent_a, extent_b, shift, ulp):
    """Safety margin on surrogate ε: ``MARGIN_ULPS`` ulp of the pair's scale, which
    bounds every coordinate in A's frame (B's shift plus both bodies' largest body-frame
    coordinates; a rotation stretches a max-norm by at most √3)."""
    length = np.sqrt(shift[0] * shift[0] + shift[1] * shift[1] + shift[2] * shift[2])
    return MARGIN_ULPS * ulp * 2.0 * (SQRT3 * (extent_a + extent_b) + length)


@njit(**JIT)
def batch_kernel(bank, meta, queries, params, cache, start, stop, counts, levels):
    """Contacts of body pairs ``start ≤ q < stop``; returns ragged results.

    ``bank = (coords (N, 9), frames (N, 14)`` in the query precision, ``master
    coords, master frames`` float64, ``epsilon (N,)`` float64, ``face, first_child,
    child_count (N,)`` int32, ``normals (F, 3)`` float64 unit face normals, ``spheres
    (N, 4)`` float64 bounding spheres);
    ``meta = (node offset, node count, face offset, face count (T,) int64, leaf ε,
    bounding radius, extent (T,) float64)`` per tree; ``queries = (tree_a, tree_b
    (k,) int64, position_a (k, 3), orientation_a (k, 4), position_b, orientation_b)``;
    ``params = (surrogate params, leaf params, keep_all, ulp, tiny)`` (see
    :func:`query_kernel`; ``tiny`` relative to the larger bounding radius).

    ``cache = (skin, slot (k,) int64, rotation (m, 3, 3), shift (m, 3), offsets
    (m + 1,) int64, near (L, 2) int64)``: with ``skin > 0`` each query keeps a list of
    its leaf pairs within ε_a + ε_b + s, s = skin·(ε_a + ε_b) (leaf ε), found at a
    reference pose of B relative to A. Query q uses the list of entry ``slot[q]``
    (−1: none) instead of a traversal while B's points have moved by less than s
    relative to A since its reference pose (:func:`motion_bound`, plus the query's
    margin); else it traverses with every ε grown by s/2 and starts a new list.

    Writes ``counts (stop − start, N_COUNTS)`` int64 and ``levels (stop − start, L)``
    (pairs evaluated per level). Returns ``(pair_offsets, pairs, contact_offsets,
    points, normals, overlaps, near_offsets, near, rotations, shifts)``: query
    ``start + t`` owns rows ``pair_offsets[t]:pair_offsets[t + 1]`` of ``pairs`` and
    likewise for contacts and its new list (empty without a skin, and for a query that
    used its cached list: that list stays valid as it is), whose reference pose is
    ``rotations[t], shifts[t]``.
    """
    coords, frames, master_coords, master_frames, epsilon, face, first, count, normals, spheres = (
        bank
    )
    node_offset, node_count, face_offset, face_count, leaf_eps, radius, extent = meta
    tree_a, tree_b, position_a, orientation_a, position_b, orientation_b = queries
    coarse, leaf, keep_all, ulp, tiny = params
    skin, slot, cached_rotation, cached_shift, cached_offsets, cached_near = cache
    k = stop - start
    pair_offsets = np.zeros(k + 1, np.int64)
    contact_offsets = np.zeros(k + 1, np.int64)
    near_offsets = np.zeros(k + 1, np.int64)
    rotations = np.empty((k, 3, 3))
    shifts = np.empty((k, 3))
    pairs = np.empty((64, 2), np.int64)
    near_out = np.empty((64, 2), np.int64)
    points = np.empty((64, 3))
    normals_out = np.empty((64, 3))
    overlaps = np.empty(64)
    stats = np.zeros(N_STATS, np.int64)
    for t in range(k):
        q = start + t
        ta, tb = tree_a[q], tree_b[q]
        a0, a1 = node_offset[ta], node_offset[ta] + node_count[ta]
        b0, b1 = node_offset[tb], node_offset[tb] + node_count[tb]
        body_a = (
            coords[a0:a1],
            frames[a0:a1],
            epsilon[a0:a1],
            face[a0:a1],
            first[a0:a1],
            count[a0:a1],
            spheres[a0:a1],
        )
        body_b = (
            master_coords[b0:b1],
            master_frames[b0:b1],
            epsilon[b0:b1],
            face[b0:b1],
            first[b0:b1],
            count[b0:b1],
            spheres[b0:b1],
        )
        rot_a, rotation, shift = relative_pose(
            position_a[q], orientation_a[q], position_b[q], orientation_b[q]
        )
        margin = query_margin(extent[ta], extent[tb], shift, ulp)
        ea, eb = leaf_eps[ta], leaf_eps[tb]
        setup = (ea, eb, tiny * max(radius[ta], radius[tb]), min(ea, eb), rot_a, position_a[q])
        f0 = face_offset[ta]
        contact = (face_count[tb], keep_all, normals[f0 : f0 + face_count[ta]], setup)
        stats[:] = 0
        reach = skin * (ea + eb)
        e = slot[q]
        listed = (
            skin > 0.0
            and e >= 0
            and motion_bound(cached_rotation[e], cached_shift[e], rotation, shift, extent[tb])
            + margin
            < reach
        )
        if listed:
            near = cached_near[cached_offsets[e] : cached_offsets[e + 1]]
            result = listed_query(
                body_a, body_b, (rotation, shift), margin, near, leaf, contact, stats
            )
            depth, unfoldings = 0, 0
            rotations[t], shifts[t] = cached_rotation[e], cached_shift[e]
        else:
            inflate = 0.5 * reach if skin > 0.0 else 0.0
            depth, unfoldings, result, near = query_kernel(
                body_a,
                body_b,
                (rotation, shift),
                margin,
                inflate,
                coarse,
                leaf,
                contact,
                stats,
                levels[t],
            )
            rotations[t], shifts[t] = rotation, shift
        found, pts, nrm, ovl = result
        p0, c0, n0 = pair_offsets[t], contact_offsets[t], near_offsets[t]
        p1, c1 = p0 + found.shape[0], c0 + pts.shape[0]
        n1 = n0 + (near.shape[0] if skin > 0.0 and not listed else 0)  # a kept list stays put
        pairs = _grow(pairs, p0, p1)
        near_out = _grow(near_out, n0, n1)
        points, normals_out, overlaps = (
            _grow(points, c0, c1),
            _grow(normals_out, c0, c1),
            _grow(overlaps, c0, c1),
        )
        pairs[p0:p1] = found
        near_out[n0:n1] = near[: n1 - n0]
        points[c0:c1] = pts
        normals_out[c0:c1] = nrm
        overlaps[c0:c1] = ovl
        pair_offsets[t + 1], contact_offsets[t + 1], near_offsets[t + 1] = p1, c1, n1
        counts[t, COUNT_DEPTH] = depth
        counts[t, COUNT_UNFOLDINGS] = unfoldings
        counts[t, COUNT_ITERATIVE] = stats[STAT_ITERATIVE]
        counts[t, COUNT_FALLBACKS] = stats[STAT_FALLBACKS]
        counts[t, COUNT_COMPARISONS] = stats[STAT_PAIRS]
        counts[t, COUNT_SPHERES] = stats[STAT_SPHERES]
        counts[t, COUNT_LISTED] = 1 if listed else 0
    n_pairs, n_contacts, n_near = pair_offsets[k], contact_offsets[k], near_offsets[k]
    return (
        pair_offsets,
        pairs[:n_pairs],
        contact_offsets,
        points[:n_contacts],
        normals_out[:n_contacts],
        overlaps[:n_contacts],
        near_offsets,
        near_out[:n_near],
        rotations,
        shifts,
    )


@njit(**EXACT_JIT)
def motion_bound(rotation_0, shift_0, rotation, shift, extent_b):
    """Upper bound on how far any point of B (coordinates within ``extent_b`` in B's
    frame) moved relative to A between the poses ``x ↦ R₀x + s₀`` and ``x ↦ Rx + s``:
    ‖R − R₀‖_F·√3·extent + |s − s₀| (the Frobenius norm bounds the spectral one; the
    differences are taken entry by entry, so small rotations lose no accuracy)."""
    frobenius = 0.0
    for i in range(3):
        for j in range(3):
            d = rotation[i, j] - rotation_0[i, j]
            frobenius += d * d
    d0, d1, d2 = shift[0] - shift_0[0], shift[1] - shift_0[1], shift[2] - shift_0[2]
    return np.sqrt(frobenius) * SQRT3 * extent_b + np.sqrt(d0 * d0 + d1 * d1 + d2 * d2)


@njit(**JIT)
def _grow(array, n, need):
    """``array`` if it has ``need`` rows, else a copy with twice the room (first ``n`` rows)."""
    if array.shape[0] >= need:
        return array
    shape = (max(need, 2 * array.shape[0]),) + array.shape[1:]
    grown = np.empty(shape, array.dtype)
    grown[:n] = array[:n]
    return grown
