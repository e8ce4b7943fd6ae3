"""The leaf-pair lists of the pair cache: their reference distances, and the contacts of a
query served by its list (see :class:`~engine.kernels.collision.batch.PairLists`).

A list holds a body pair's leaf pairs within ε_a + ε_b + s at a reference pose of B
relative to A, each with its exact distance there (:func:`reference_distances`, when the
list is made). While B has moved by less than s since, :func:`listed_contacts` evaluates
only the listed pairs that may touch now, with B's rows moved by the traversal's
:func:`~engine.kernels.collision.rigid.move_kernel` (packed: only the rows needed).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from engine.kernels.collision.contact_merge import key_order
from engine.kernels.collision.rigid import move_kernel
from engine.kernels.geometry.triangle_batch import (
    BLOCK,
    CONTACT,
    ITERATIVE,
    STAT_PAIRS,
    ZERO,
    gather_rows,
    listed_kernel,
    result_buffers,
)
from engine.kernels.geometry.triangle_points import (
    exact_paired,
    exact_points,
    vertex_points,
)
from engine.kernels.jit import BORROW, HOST_AVX512, JIT

SURE_BLOCK = 256 if HOST_AVX512 else 32
"""Pairs per call of the vertex–vertex certificate (and of ``exact_points`` for the pairs it
refuses) among the sure contacts, per vector width, float64, µs a body pair. AVX2, the
paper's "aligned" grid (414 listed pairs a body pair on average): 32 pairs 65, 64 pairs 74,
256 pairs 81 (the gathered rows of 256 pairs overflow L1). AVX-512 (Zen 5), its
pole-to-pole pair (1,296 listed pairs; ``benchmarks/grid_pairs.py``): 32 pairs 41.6–42.5,
64 pairs 40.0, 128 pairs 39.1, 256 pairs 38.7."""


@njit(**JIT)
def listed_scratch(most, like):
    """Buffers of :func:`listed_contacts` for lists of up to ``most`` pairs, made once per
    batch of queries, in this order: ``kept (most, 2)``, ``sure_a``, ``sure_b``, ``moving
    (most,)`` int64; B's moved rows ``master_coords (most, 9)``, ``master_frames (most,
    14)`` float64 and ``coords (most, 9)``, ``frames (most, 14)``, ``eps (most,)`` in the
    precision of ``like``; ``face (most,)`` int32; ``index (most,)`` int64 = 0, 1, …; the
    result buffers (:func:`~engine.kernels.geometry.triangle_batch.result_buffers`) with
    room for ``most`` contacts. With them a listed query allocates nothing and takes no
    reference counts (:func:`listed_contacts` is a borrowing helper)."""
    most = max(most, 1)
    return (
        np.empty((most, 2), np.int64),
        np.empty(most, np.int64),
        np.empty(most, np.int64),
        np.empty(most, np.int64),
        np.empty((most, 9)),
        np.empty((most, 14)),
        np.empty((most, 9), like.dtype),
        np.empty((most, 14), like.dtype),
        np.empty(most, like.dtype),
        np.empty(most, np.int32),
        np.arange(most),
        result_buffers(most, like),
    )


@njit(**BORROW)
def listed_contacts(bank, rows, pose, near, distances, slack, leaf_params, scratch, stats):
    """The leaf pairs in contact among a query's listed ``near (m, 2)`` int64 pairs (local
    leaf rows of A, of B); returns ``n``: the first ``n`` rows of ``scratch``'s result
    buffers as :func:`~engine.kernels.geometry.triangle_batch.listed_kernel` reports
    them, B's rows renumbered, and the face of each renumbered row in ``scratch``'s
    ``face``.

    ``rows = (a0, a1, b0)``: A's rows in ``bank``, B's first row; ``pose`` moves B into
    A's frame; the exact distance of each pair at the list's reference pose is
    ``distances (m,)`` and ``slack`` how far B moved since plus a rounding allowance
    (two query margins). With δ its distance less its ε_a + ε_b and a = ``slack`` times
    the conditioning max(1, κ_a, κ_b) of its triangles, a pair with δ > a cannot be in
    contact now: it is dropped before any arithmetic. The others, in list order, go
    through the same ``listed_kernel`` with B's rows moved by the same
    :func:`~engine.kernels.collision.rigid.move_kernel` as in the traversal (only those
    rows, packed), so each gives the traversal's bits — except that, outside
    ``ITERATIVE`` mode, a pair with δ < −a is certainly in contact, which every path of
    ``listed_kernel`` then records with ``certified_points``' distance and points and status
    ``CONTACT``: it gets exactly that, without the iterative kernel's decision, appended
    after the others (:func:`contact_kernel` orders pairs by their faces, so the
    contacts do not depend on the order of the results). ``scratch = (local, buffers,
    listed)``: ``local`` (≥ B's node count) int64 all −1 (left so), the listed workspace
    and :func:`listed_scratch` for at least ``m`` pairs."""
    a0, a1, b0 = rows
    rotation, shift = pose
    local, buffers, listed = scratch
    kept, sure_a, sure_b, moving = listed[0], listed[1], listed[2], listed[3]
    found = listed[11]
    coords_a, frames_a = bank.coords[a0:a1], bank.frames[a0:a1]
    m = near.shape[0]
    shortcut = leaf_params[0] != ITERATIVE
    mk, ms, u = ZERO, ZERO, ZERO
    for t in range(m):
        i, j = near[t, 0], near[t, 1]
        reach = bank.epsilon[a0 + i] + bank.epsilon[b0 + j]
        kappa = max(1.0, max(bank.master_frames[a0 + i, 13], bank.master_frames[b0 + j, 13]))
        excess, allowance = distances[t] - reach, slack * kappa
        if excess > allowance:
            continue
        if local[j] < 0:
            local[j] = u
            moving[u] = j
            u += 1
        if shortcut and excess < -allowance:
            sure_a[ms], sure_b[ms] = i, local[j]
            ms += 1
        else:
            kept[mk, 0], kept[mk, 1] = i, local[j]
            mk += 1
    for r in range(u):
        local[moving[r]] = -1
    if mk + ms == 0:  # no listed pair close enough now
        return ZERO
    coords_b, frames_b, eps_b = listed[6], listed[7], listed[8]
    _packed(bank, b0, moving, u, rotation, shift, listed)
    rm = (coords_a, frames_a, coords_b, frames_b)
    eps_a = bank.epsilon_query[a0:a1]
    n = listed_kernel(rm, eps_a, eps_b, kept, ZERO, mk, leaf_params, buffers, found, ZERO, stats)
    if ms > 0:
        stats[STAT_PAIRS] += ms
        n = _sure_contacts(rm, sure_a, sure_b, ms, leaf_params[3], buffers[0], found, n)
    return n


@njit(**BORROW)
def _sure_contacts(rm, index_a, index_b, m, one, work, out, n):
    """Append pairs ``(index_a[t], index_b[t])``, ``t < m``, of rows of ``rm = (A's
    coords, frames, B's coords, frames)`` to ``out`` after its first ``n`` rows (room
    assumed) as :func:`~engine.kernels.geometry.triangle_batch.listed_kernel` records a
    contact: :func:`~engine.kernels.geometry.triangle_points.certified_points`' values,
    status ``CONTACT``; returns the count. ``SURE_BLOCK`` pairs at a time: their
    coordinates gathered for the vertex–vertex certificate
    (:func:`~engine.kernels.geometry.triangle_points.vertex_points`), then only the pairs
    it refuses gathered with their frames for ``exact_points``."""
    coords_a, frames_a, coords_b, frames_b = rm
    ga, gfa, gb, gfb, refused_a, refused_b = (
        work[0],
        work[1],
        work[2],
        work[3],
        work[4],
        work[5],
    )
    r0, r1, r2, r3, r4, r5, r6 = work[9]
    v0, v1, v2, v3, v4, v5, v6 = work[10]
    out_i, out_j, out_d, out_p, out_q, out_s = out
    for t0 in range(0, m, SURE_BLOCK):
        c = min(SURE_BLOCK, m - t0)
        _gather_coords(coords_a, index_a, t0, c, ga)
        _gather_coords(coords_b, index_b, t0, c, gb)
        vertex_points(ga, gb, c, one, v0, v1, v2, v3, v4, v5, v6)
        e = ZERO
        for k in range(c):
            if not v0[k] >= 0:
                refused_a[e], refused_b[e] = index_a[t0 + k], index_b[t0 + k]
                e += 1
        if e > 0:
            gather_rows(coords_a, frames_a, refused_a, e, ga, gfa)
            gather_rows(coords_b, frames_b, refused_b, e, gb, gfb)
            exact_points(ga, gfa, gb, gfb, e, one, r0, r1, r2, r3, r4, r5, r6)
            e = ZERO
            for k in range(c):
                if not v0[k] >= 0:
                    v0[k], v1[k], v2[k], v3[k] = r0[e], r1[e], r2[e], r3[e]
                    v4[k], v5[k], v6[k] = r4[e], r5[e], r6[e]
                    e += 1
        for k in range(c):
            out_i[n], out_j[n], out_d[n] = index_a[t0 + k], index_b[t0 + k], v0[k]
            out_p[0, n], out_p[1, n], out_p[2, n] = v1[k], v2[k], v3[k]
            out_q[0, n], out_q[1, n], out_q[2, n] = v4[k], v5[k], v6[k]
            out_s[n] = CONTACT
            n += 1
    return n


@njit(**BORROW)
def _gather_coords(coords, index, t0, m, out):
    """``out[:, k] = coords[index[t0 + k]]``, ``k < m``: row-major ``(n, 9)`` coordinates
    into the columns of ``out (9, ≥ m)``, unrolled."""
    for k in range(m):
        i = index[t0 + k]
        out[0, k], out[1, k], out[2, k] = coords[i, 0], coords[i, 1], coords[i, 2]
        out[3, k], out[4, k], out[5, k] = coords[i, 3], coords[i, 4], coords[i, 5]
        out[6, k], out[7, k], out[8, k] = coords[i, 6], coords[i, 7], coords[i, 8]


@njit(**JIT)
def reference_distances(bank, rows, pose, near, one, scratch, out):
    """``out[t]`` (float64): the exact distance of the listed leaf pair ``near[t]`` (local
    rows of A, of B; ``rows = (a0, b0)`` their first rows in ``bank``) with B at
    ``pose``, in the query precision (``one``: 1 in it), B's rows moved as the traversal
    moves them. ``scratch = (local, buffers)`` as in :func:`listed_contacts`."""
    a0, b0 = rows
    local, buffers = scratch
    coords_a = bank.coords[a0:]
    frames_a = bank.frames[a0:]
    m = near.shape[0]
    moving = np.empty(m, np.int64)
    index_b = np.empty(m, np.int64)
    u = ZERO
    for t in range(m):
        j = near[t, 1]
        if local[j] < 0:
            local[j] = u
            moving[u] = j
            u += 1
        index_b[t] = local[j]
    listed = listed_scratch(u, bank.coords)
    _packed(bank, b0, moving, u, pose[0], pose[1], listed)
    coords_b, frames_b = listed[6], listed[7]
    for r in range(u):
        local[moving[r]] = -1
    ga, gfa, gb, gfb = buffers[0][0], buffers[0][1], buffers[0][2], buffers[0][3]
    dist = buffers[0][8]
    index_a = np.empty(m, np.int64)
    for t in range(m):
        index_a[t] = near[t, 0]
    for t0 in range(0, m, BLOCK):
        c = min(BLOCK, m - t0)
        gather_rows(coords_a, frames_a, index_a[t0:], c, ga, gfa)
        gather_rows(coords_b, frames_b, index_b[t0:], c, gb, gfb)
        exact_paired(ga, gfa, gb, gfb, c, one, dist)
        for r in range(c):
            out[t0 + r] = dist[r]


@njit(**JIT)
def by_faces(near, distances, face_a, face_b, n_faces_b):
    """``(near, distances)``: the leaf pairs ``near (m, 2)`` int64 (local rows of A, of B)
    and their ``distances (m,)`` float64 sorted by the pairs' faces ``(face_a[i],
    face_b[j])`` (new arrays): a list kept in this order makes the contacts of a listed
    query come in :func:`contact_kernel`'s order already
    (:func:`~engine.kernels.collision.contact_merge.key_order`). The order of a list
    changes no result: every listed pair is evaluated on its own, and
    :func:`contact_kernel` orders the pairs by their faces."""
    m = near.shape[0]
    keys = np.empty(m, np.int64)
    for t in range(m):
        keys[t] = face_a[near[t, 0]] * n_faces_b + face_b[near[t, 1]]
    order = key_order(keys)
    out = np.empty((m, 2), np.int64)
    sorted_distances = np.empty(m)
    for s in range(m):
        out[s, 0], out[s, 1] = near[order[s], 0], near[order[s], 1]
        sorted_distances[s] = distances[order[s]]
    return out, sorted_distances


@njit(**BORROW)
def _packed(bank, b0, moving, u, rotation, shift, listed):
    """B's rows ``b0 + moving[r]``, ``r < u``, packed into row ``r`` of :func:`listed_scratch`
    ``listed`` and moved into A's frame: coordinates and frames (in the precision of its
    buffers), ε and faces (:func:`~engine.kernels.collision.rigid.move_kernel` moves each
    row by the same arithmetic wherever it sits)."""
    master_coords, master_frames = listed[4], listed[5]
    eps, face = listed[8], listed[9]
    for r in range(u):
        j = b0 + moving[r]
        for c in range(9):
            master_coords[r, c] = bank.master_coords[j, c]
        for c in range(14):
            master_frames[r, c] = bank.master_frames[j, c]
        eps[r] = bank.epsilon_query[j]
        face[r] = bank.face[j]
    move_kernel(master_coords, master_frames, listed[10][:u], rotation, shift, listed[6], listed[7])


@njit(**BORROW)
def join_lists(sizes, old_start, new_start, kept, old, new, out):
    """Copy each entry's list into ``out = (near (L, 2) int64, distances (L,) float64)``,
    entry after entry (``sizes (k,)`` int64 rows each): entry q's rows come from ``old =
    (near, distances)`` at row ``old_start[q]`` where ``kept[q]``, else from ``new`` (the
    same layout) at ``new_start[q]``. One pass over the rows (the pair cache's renewal: on
    the paper's "aligned" grid 32 M rows, where index arrays and fancy indexing took four
    passes and 3.8 s)."""
    near_out, distances_out = out
    row = 0
    for q in range(sizes.shape[0]):
        src_near, src_distances = new
        start = new_start[q]
        if kept[q]:
            src_near, src_distances = old
            start = old_start[q]
        for t in range(sizes[q]):
            near_out[row, 0] = src_near[start + t, 0]
            near_out[row, 1] = src_near[start + t, 1]
            distances_out[row] = src_distances[start + t]
            row += 1
