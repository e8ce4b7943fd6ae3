"""Level-synchronous multiresolution contact query of two posed surrogate trees.

One call per body pair does the whole query: B's nodes are moved into A's frame
lazily (a node when the traversal first reaches it), surrogate ε get their
safety margin, the front of node pairs is traversed, and the leaf pairs found
become merged contacts.

The front is a list of node pairs, starting at the two roots. Each level is split
(:func:`_leaf_pair`) into leaf–leaf pairs, streamed through
:func:`~engine.kernels.geometry.triangle_batch.listed_kernel` with the leaf parameters
(their contacts are final), and pairs with a surrogate, streamed with the surrogate
parameters (iterative, or exact): a pair reported in contact or not converged is
unfolded into the next level's front — *both* nodes unfold at once, each surrogate
replaced by its children and a leaf standing for itself (:func:`_children`), so the
pair becomes every pair of the two sides, one level per pair (pairs whose bounding
spheres are apart are dropped: each side's children are first tested against the other
side's node, then the survivors against each other). :func:`front_kernel` evaluates one
such front for the multiscale step, whose host unfolds the hits by the same rule.
"""

from __future__ import annotations

import numpy as np
from numba import carray, njit

from engine.kernels.collision.boxes import box_set_up, place_box, place_row, separated
from engine.kernels.collision.contact_merge import contact_kernel
from engine.kernels.collision.rigid import margin_kernel, move_kernel
from engine.kernels.geometry.triangle_batch import (
    EXACT,
    ITERATIVE,
    STAT_SPHERES,
    ZERO,
    listed_kernel,
    listed_workspace,
    result_buffers,
)
from engine.kernels.jit import BORROW, JIT, select, sqrt, stack_buffer


@njit(**JIT)
def query_kernel(
    body_a, body_b, pose, margin, inflate, coarse_params, leaf_params, contact, stats, levels
):
    """Contacts between two posed trees; returns ``(depth, unfoldings, result, near,
    near_distances)``.

    ``body_a = (coords (Na, 9), frames (Na, 14), epsilon (Na,) float64, face,
    first_child, child_count (Na,) int32, spheres (Na, 4) float64, boxes (Na, 15)
    float64)``: A's nodes prepared in the query's precision, row-major, each node's
    bounding sphere (centre, radius) of its covered leaves' ε-regions and its oriented
    box (as :mod:`~engine.kernels.collision.boxes` reads them; ``(0, 15)`` for none:
    spheres only); ``body_b``: the same for B
    except that coordinates and frames are B's float64 master arrays in its body
    frame. ``pose = (rotation (3, 3), shift (3,))`` maps B's frame to A's.
    Surrogate ε get ``margin`` added. The search is :func:`traverse`'s.

    ``contact = (faces of B, keep_all, normals_a, setup)`` as in
    :func:`~engine.kernels.collision.contact_merge.contact_kernel`. ``stats`` (int64) is
    added to; ``levels`` (int64) receives the pairs evaluated per level (levels
    beyond its length are counted but not stored).

    ``depth`` is the number of levels, ``unfoldings`` the node pairs unfolded and
    ``result = (pairs, points, normals, overlaps)`` the contacts, as
    ``contact_kernel`` writes them (trimmed; world frame). ``near (m, 2)`` int64 are
    the leaf node pairs within their ε plus ``2·inflate``: with ``inflate > 0`` the
    traversal runs with every ε grown by ``inflate`` (bounding spheres too), and the
    contacts are those of ``near`` at the true ε — a superset list that stays valid
    while B moves by less than ``2·inflate`` relative to A (see :func:`listed_query`);
    ``near_distances`` as :func:`traverse` returns them.
    """
    coords_a, frames_a, epsilon_a, face_a, first_a, count_a, spheres_a, boxes_a = body_a
    master_coords, master_frames, epsilon_b, face_b, first_b, count_b, spheres_b, boxes_b = body_b
    depth, unfoldings, n, found, near, near_distances, _ = traverse(
        coords_a,
        frames_a,
        epsilon_a,
        face_a,
        first_a,
        count_a,
        spheres_a,
        master_coords,
        master_frames,
        epsilon_b,
        face_b,
        first_b,
        count_b,
        spheres_b,
        boxes_a,
        boxes_b,
        pose[0],
        pose[1],
        margin,
        inflate,
        coarse_params,
        leaf_params,
        stats,
        levels,
    )
    contacts = _contacts(found, n, face_a, face_b, contact)
    return depth, unfoldings, contacts, near, near_distances


@njit(**JIT)
def traverse(
    coords_a,
    frames_a,
    epsilon_a,
    face_a,
    first_a,
    count_a,
    spheres_a,
    master_coords,
    master_frames,
    epsilon_b,
    face_b,
    first_b,
    count_b,
    spheres_b,
    boxes_a,
    boxes_b,
    rotation,
    shift,
    margin,
    inflate,
    coarse_params,
    leaf_params,
    stats,
    levels,
):
    """The pair-front search (arguments as :func:`query_kernel`'s, flattened, and each
    node's oriented bounding box ``boxes_* (N, 15)`` float64, body frame, as
    :mod:`~engine.kernels.collision.boxes` reads them; ``(0, 15)`` for none); returns
    ``(depth, unfoldings, n, found, near, near_distances, closest)``: the first ``n`` rows
    of ``found`` (:func:`~engine.kernels.geometry.triangle_batch.result_buffers`) are the
    leaf pairs in contact (A's frame), ``near`` as in :func:`query_kernel`,
    ``near_distances (len(near),)`` float64 the distance each near pair was recorded with
    (outside ``ITERATIVE`` mode its exact distance, as a contact records it), and
    ``closest`` (float64) the least ``d − ε`` over the leaf pairs evaluated (d the
    distance of two points of the triangles: at least their distance, within rounding;
    ε their contact distance, grown by ``2·inflate``; +∞ when none was), as the
    workspace records it
    (:func:`~engine.kernels.geometry.triangle_batch.workspace`).

    With ``inflate > 0`` each near leaf pair is evaluated once, at the grown ε; its
    contact at the true ε is decided from the values recorded (:func:`_at_true_epsilon`).

    A node pair whose bounding spheres, or (given) boxes, are apart (by more than
    ``margin``) cannot hold a leaf pair in contact: it is pruned before any triangle
    comparison, the root pair included. A hit pair (i, j) unfolds in one pass: A's
    children are tested against j's sphere and B's children against i's, then the
    surviving children against each other (spheres, then boxes); every child pair not
    put in the next front counts in ``stats[STAT_SPHERES]``.
    The fronts are two buffers reused across levels (grown by doubling). B's nodes are
    moved into A's frame, and the ε of both trees get their margin, only for the nodes
    reached (a level's new B nodes moved together, by
    :func:`~engine.kernels.collision.rigid.move_kernel`: the flat search's bits).
    """
    dtype = coords_a.dtype
    na = coords_a.shape[0]
    nb = master_coords.shape[0]
    reach = margin + 2.0 * inflate  # added to the sum of two bounding radii
    if roots_apart(spheres_a, boxes_a, spheres_b, boxes_b, rotation, shift, reach):
        stats[STAT_SPHERES] += 1  # before any set-up
        none = result_buffers(0, coords_a)
        return ZERO, ZERO, ZERO, none, np.zeros((0, 2), np.int64), np.zeros(0), np.inf
    centres_b = np.empty((nb, 3))  # B's sphere centres in A's frame, once needed
    centred = np.zeros(nb, np.bool_)
    _centre(spheres_b, centres_b, centred, ZERO, rotation, shift)
    boxed, placed_b, placed = box_set_up(boxes_a, boxes_b, rotation, shift)
    moved = np.zeros(nb, np.bool_)  # B's node moved, its ε set
    seen_a = np.zeros(na, np.bool_)  # A's node ε set
    coords_b = np.empty((nb, 9), dtype)
    frames_b = np.empty((nb, 14), dtype)
    eps_a = np.empty(na, dtype)
    eps_b = np.empty(nb, dtype)
    found = result_buffers(256, coords_a)
    # B's nodes to move this level (each node is moved once: nb entries always suffice; an
    # array reassigned inside the loops below would be reference-counted on every pass)
    to_move = np.empty(nb, np.int64)
    to_move[0] = 0  # the root first
    move_kernel(master_coords, master_frames, to_move[:1], rotation, shift, coords_b, frames_b)
    moved[0], seen_a[0] = True, True
    _eps(epsilon_a, face_a, ZERO, margin, inflate, eps_a)
    _eps(epsilon_b, face_b, ZERO, margin, inflate, eps_b)
    rm = (coords_a, frames_a, coords_b, frames_b)
    buffers = listed_workspace(coords_a)
    hits = result_buffers(256, coords_a)
    front = np.zeros((256, 2), np.int64)
    following = np.empty((256, 2), np.int64)
    finest = np.empty((256, 2), np.int64)
    coarse = np.empty((256, 2), np.int64)
    keep_a = np.empty(64, np.int64)  # the children of one side that survive
    keep_b = np.empty(64, np.int64)
    m = np.int64(1)
    pruned = ZERO
    depth = ZERO
    unfoldings = ZERO
    nf = ZERO  # leaf pairs, evaluated together once the front is exhausted
    while m > 0:
        if depth < levels.shape[0]:
            levels[depth] = m
        depth += 1
        if coarse.shape[0] < m:
            coarse = np.empty((2 * m, 2), np.int64)
        if finest.shape[0] < nf + m:
            finest = _grown_pairs(finest, nf, nf + m)
        nc = ZERO
        for t in range(m):
            i, j = front[t, 0], front[t, 1]
            if _leaf_pair(face_a, i, face_b, j):
                finest[nf, 0], finest[nf, 1] = i, j
                nf += 1
            else:
                coarse[nc, 0], coarse[nc, 1] = i, j
                nc += 1
        if nc == 0:
            break
        hits = _room(hits, ZERO, nc)
        h = listed_kernel(
            rm, eps_a, eps_b, coarse, ZERO, nc, coarse_params, buffers, hits, ZERO, stats
        )
        hi, hj = hits[0], hits[1]
        unfoldings += h
        # room for the level's children, made before the loop (see ``to_move``)
        most_a, most_b, most_pairs = ZERO, ZERO, ZERO
        for k in range(h):
            a0, a1 = _children(face_a, first_a, count_a, hi[k])
            b0, b1 = _children(face_b, first_b, count_b, hj[k])
            most_a, most_b = max(most_a, a1 - a0), max(most_b, b1 - b0)
            most_pairs += (a1 - a0) * (b1 - b0)
        if keep_a.shape[0] < most_a:
            keep_a = np.empty(2 * most_a, np.int64)
        if keep_b.shape[0] < most_b:
            keep_b = np.empty(2 * most_b, np.int64)
        if following.shape[0] < most_pairs:  # filled from its first row: nothing to keep
            following = np.empty((max(most_pairs, 2 * following.shape[0]), 2), np.int64)
        r = ZERO
        new = ZERO
        for k in range(h):
            i, j = hi[k], hj[k]
            # both nodes unfold (a leaf stands for itself): every pair of the two sides
            a0, a1 = _children(face_a, first_a, count_a, i)
            b0, b1 = _children(face_b, first_b, count_b, j)
            ka = ZERO  # A's children near j's sphere (a leaf i: itself, tested with j)
            for ca in range(a0, a1):
                if a1 - a0 == 1 or not _far(spheres_a, ca, centres_b, spheres_b, j, reach):
                    keep_a[ka] = ca
                    ka += 1
            kb = ZERO  # B's children near i's sphere
            for cb in range(b0, b1):
                _centre(spheres_b, centres_b, centred, cb, rotation, shift)
                if b1 - b0 == 1 or not _far(spheres_a, i, centres_b, spheres_b, cb, reach):
                    keep_b[kb] = cb
                    kb += 1
                    if boxed:
                        place_row(boxes_b, cb, rotation, shift, placed_b, placed)
            cross = a1 - a0 > 1 and b1 - b0 > 1  # else the tests above were the pairs'
            r0 = r
            for u in range(ka):
                ca = keep_a[u]
                for v in range(kb):
                    cb = keep_b[v]
                    if cross and _far(spheres_a, ca, centres_b, spheres_b, cb, reach):
                        continue
                    if boxed and separated(boxes_a, ca, placed_b, cb, reach):
                        continue
                    following[r, 0], following[r, 1] = ca, cb
                    r += 1
                    if not seen_a[ca]:
                        seen_a[ca] = True
                        _eps(epsilon_a, face_a, ca, margin, inflate, eps_a)
                    if not moved[cb]:
                        moved[cb] = True
                        _eps(epsilon_b, face_b, cb, margin, inflate, eps_b)
                        to_move[new] = cb
                        new += 1
            pruned += (a1 - a0) * (b1 - b0) - (r - r0)
        front, following = following, front
        m = r
        move_kernel(
            master_coords, master_frames, to_move[:new], rotation, shift, coords_b, frames_b
        )
    found = _room(found, ZERO, nf)
    least = buffers[0][11]  # lowered by the leaf pairs' evaluation alone
    least[0] = np.inf
    n = listed_kernel(rm, eps_a, eps_b, finest, ZERO, nf, leaf_params, buffers, found, ZERO, stats)
    closest = least[0]
    stats[STAT_SPHERES] += pruned
    near = np.empty((n, 2), np.int64)
    near_distances = np.empty(n)
    for t in range(n):
        near[t, 0], near[t, 1], near_distances[t] = found[0][t], found[1][t], found[2][t]
    if inflate > 0.0:  # the near pairs at their true ε
        for t in range(na):
            if seen_a[t]:
                _eps(epsilon_a, face_a, t, margin, 0.0, eps_a)
        for t in range(nb):
            if moved[t]:
                _eps(epsilon_b, face_b, t, margin, 0.0, eps_b)
        if leaf_params[0] == ITERATIVE:
            n = listed_kernel(
                rm, eps_a, eps_b, near, ZERO, n, leaf_params, buffers, found, ZERO, stats
            )
        else:
            n = _at_true_epsilon(rm, eps_a, eps_b, near, leaf_params, buffers, found, stats)
    return depth, unfoldings, n, found, near, near_distances, closest


@njit(**JIT)
def roots_apart(spheres_a, boxes_a, spheres_b, boxes_b, rotation, shift, reach):
    """The traversal's first test: the root nodes' bounding spheres, or (both bodies having
    boxes, ``(0, 15)`` else) their boxes, are apart by more than ``reach`` with B moved
    into A's frame by ``x ↦ rotation x + shift`` (arrays as :func:`traverse` takes them).
    One called function, so that :func:`traverse` and a caller that tests the roots
    before it (:func:`~engine.kernels.collision.batch.batch_kernel`: a pruned pair costs
    no set-up) decide alike. Allocates nothing (its buffers are in its stack frame)."""
    centre = carray(stack_buffer(3, np.float64), (1, 3))
    centred = carray(stack_buffer(1, np.bool_), (1,))
    centred[0] = False
    _centre(spheres_b, centre, centred, ZERO, rotation, shift)
    if _far(spheres_a, ZERO, centre, spheres_b, ZERO, reach):
        return True
    if boxes_a.shape[0] == 0 or boxes_b.shape[0] == 0:
        return False
    placed = carray(stack_buffer(15, np.float64), (1, 15))
    done = carray(stack_buffer(1, np.bool_), (1,))
    done[0] = False
    place_box(boxes_b, ZERO, rotation, shift, placed, done)
    return separated(boxes_a, ZERO, placed, ZERO, reach)


@njit(**JIT)
def _at_true_epsilon(rm, eps_a, eps_b, near, leaf_params, buffers, found, stats):
    """The contacts among ``near (n, 2)`` at the ε of ``eps_a``, ``eps_b``, where row t of
    ``found`` (:func:`~engine.kernels.geometry.triangle_batch.result_buffers`) is pair
    ``near[t]`` as ``listed_kernel`` recorded it at larger ε (``EXACT`` or ``HYBRID``:
    :func:`~engine.kernels.geometry.triangle_points.certified_points`' distance and points,
    which do not depend on ε); returns their count, the rows kept in ``found`` in order
    and any re-evaluated after them.

    ``listed_kernel`` at these ε would record a pair, with these same values, exactly when
    its distance d is within its ε (``EXACT``), or when the iterative kernel certifies
    contact or does not converge and d is within ε (``HYBRID``). The iterative bounds
    enclose d up to their rounding band, so away from ε by more than four bands
    (``band_factor · (d + both longest edges) · κ``) the decision is d's; the pairs within
    go through ``listed_kernel`` itself, appended after the kept rows (the order of
    ``found`` changes no contact: :func:`~engine.kernels.collision.contact_merge.contact_kernel`
    orders the pairs by their faces)."""
    _, fa_rm, _, fb_rm = rm
    one, band_factor = leaf_params[3], leaf_params[4]
    exact = leaf_params[0] == EXACT
    out_i, out_j, out_d, out_p, out_q, out_s = found
    n = near.shape[0]
    doubtful = np.empty((n, 2), np.int64)
    kept, nd = ZERO, ZERO
    four = one + one + one + one
    for t in range(n):
        i, j = near[t, 0], near[t, 1]
        d, reach = out_d[t], eps_a[i] + eps_b[j]
        if exact:
            keep = d <= reach
        else:
            longest = one / sqrt(min(fa_rm[i, 9], min(fa_rm[i, 10], fa_rm[i, 11]))) + one / sqrt(
                min(fb_rm[j, 9], min(fb_rm[j, 10], fb_rm[j, 11]))
            )
            kappa = max(fa_rm[i, 13], fb_rm[j, 13])
            band = four * band_factor * (abs(d) + longest) * kappa
            if not (d < reach - band or d > reach + band):  # NaN is doubtful too
                doubtful[nd, 0], doubtful[nd, 1] = i, j
                nd += 1
                continue
            keep = d <= reach
        if keep:
            if kept < t:
                out_i[kept], out_j[kept], out_d[kept], out_s[kept] = i, j, d, out_s[t]
                for c in range(3):
                    out_p[c, kept], out_q[c, kept] = out_p[c, t], out_q[c, t]
            kept += 1
    if nd == 0:
        return kept
    return listed_kernel(
        rm, eps_a, eps_b, doubtful, ZERO, nd, leaf_params, buffers, found, kept, stats
    )


@njit(**JIT)
def listed_query(body_a, body_b, pose, margin, near, leaf_params, contact, stats):
    """Contacts of the listed leaf node pairs ``near (m, 2)`` only (arguments as in
    :func:`query_kernel`); returns ``result``. B's listed nodes are moved by the same
    :func:`~engine.kernels.collision.rigid.move_kernel` as in the traversal, so each pair gives
    the traversal's bits, and ``result`` equals the traversal's whenever ``near`` holds
    every leaf pair in contact."""
    coords_a, frames_a, epsilon_a, face_a, first_a, count_a, spheres_a = body_a
    master_coords, master_frames, epsilon_b, face_b, first_b, count_b, spheres_b = body_b
    nb = master_coords.shape[0]
    m = near.shape[0]
    moved = np.zeros(nb, np.bool_)
    to_move = np.empty(m, np.int64)
    new = ZERO
    for t in range(m):
        j = near[t, 1]
        if not moved[j]:
            moved[j] = True
            to_move[new] = j
            new += 1
    rm, eps_a, eps_b = _posed(body_a, body_b, pose, margin, to_move[:new])
    found = result_buffers(max(m, 1), coords_a)
    n = listed_kernel(
        rm, eps_a, eps_b, near, ZERO, m, leaf_params, listed_workspace(coords_a), found, ZERO, stats
    )
    return _contacts(found, n, face_a, face_b, contact)


@njit(**JIT)
def front_kernel(body_a, body_b, pose, margin, nodes, coarse_params, leaf_params, contact, stats):
    """One evaluation of a multiscale front: the node pairs ``nodes (m, 2)`` (int64),
    each as the traversal evaluates it (bounding spheres first; leaf pairs with the
    leaf parameters, pairs with a surrogate with the surrogate ones); arguments as in
    :func:`query_kernel`. Returns ``(status, result, hits)``: ``status (m,)`` int8 of
    each entry (``NO_CONTACT`` when its spheres are apart), ``result`` the merged
    contacts of the leaf entries and ``hits`` the surrogate entries in contact or not
    converged, as :func:`~engine.kernels.geometry.triangle_batch.result_buffers` trimmed to them
    (node pairs, distance, points in A's frame, status)."""
    coords_a, frames_a, epsilon_a, face_a, first_a, count_a, spheres_a = body_a
    master_coords, master_frames, epsilon_b, face_b, first_b, count_b, spheres_b = body_b
    rotation, shift = pose
    nb = master_coords.shape[0]
    m = nodes.shape[0]
    centres_b = np.empty((nb, 3))
    centred = np.zeros(nb, np.bool_)
    moved = np.zeros(nb, np.bool_)
    to_move = np.empty(m, np.int64)
    leaves = np.empty((m, 2), np.int64)
    coarse = np.empty((m, 2), np.int64)
    entry_of_leaf = np.empty(m, np.int64)  # the entry each listed row came from
    entry_of_coarse = np.empty(m, np.int64)
    new, nl, nc, pruned = ZERO, ZERO, ZERO, ZERO
    for t in range(m):
        i, j = nodes[t, 0], nodes[t, 1]
        if _apart(spheres_a, i, spheres_b, centres_b, centred, j, rotation, shift, margin):
            pruned += 1
            continue
        if not moved[j]:
            moved[j] = True
            to_move[new] = j
            new += 1
        if _leaf_pair(face_a, i, face_b, j):
            leaves[nl, 0], leaves[nl, 1] = i, j
            entry_of_leaf[nl] = t
            nl += 1
        else:
            coarse[nc, 0], coarse[nc, 1] = i, j
            entry_of_coarse[nc] = t
            nc += 1
    stats[STAT_SPHERES] += pruned
    rm, eps_a, eps_b = _posed(body_a, body_b, pose, margin, to_move[:new])
    buffers = listed_workspace(coords_a)
    hits = result_buffers(max(nc, 1), coords_a)
    h = listed_kernel(rm, eps_a, eps_b, coarse, ZERO, nc, coarse_params, buffers, hits, ZERO, stats)
    found = result_buffers(max(nl, 1), coords_a)
    n = listed_kernel(rm, eps_a, eps_b, leaves, ZERO, nl, leaf_params, buffers, found, ZERO, stats)
    # each reported pair's status onto its entry: listed_kernel reports a subsequence of
    # its list, in order, so one forward walk over the list finds every row
    status = np.zeros(m, np.int8)
    for out, k, listed, entry, rows in (
        (hits, h, coarse, entry_of_coarse, nc),
        (found, n, leaves, entry_of_leaf, nl),
    ):
        p = ZERO
        for r in range(k):
            while p < rows and (listed[p, 0] != out[0][r] or listed[p, 1] != out[1][r]):
                p += 1
            status[entry[min(p, rows - 1)]] = out[5][r]
    trimmed = (
        hits[0][:h].copy(),
        hits[1][:h].copy(),
        hits[2][:h].copy(),
        hits[3][:, :h].copy(),
        hits[4][:, :h].copy(),
        hits[5][:h].copy(),
    )
    return status, _contacts(found, n, face_a, face_b, contact), trimmed


@njit(**JIT)
def _posed(body_a, body_b, pose, margin, moving):
    """``(rm, eps_a, eps_b)`` for :func:`~engine.kernels.geometry.triangle_batch.listed_kernel`: B's
    nodes ``moving`` (int64) moved into A's frame (other rows unset) and both trees' ε with
    the ``margin`` on surrogates, in A's precision."""
    coords_a, frames_a, epsilon_a, face_a = body_a[0], body_a[1], body_a[2], body_a[3]
    master_coords, master_frames, epsilon_b, face_b = body_b[0], body_b[1], body_b[2], body_b[3]
    dtype = coords_a.dtype
    nb = master_coords.shape[0]
    coords_b = np.empty((nb, 9), dtype)
    frames_b = np.empty((nb, 14), dtype)
    move_kernel(master_coords, master_frames, moving, pose[0], pose[1], coords_b, frames_b)
    eps_a = np.empty(epsilon_a.shape[0], dtype)
    eps_b = np.empty(nb, dtype)
    margin_kernel(epsilon_a, face_a, margin, eps_a)
    margin_kernel(epsilon_b, face_b, margin, eps_b)
    return (coords_a, frames_a, coords_b, frames_b), eps_a, eps_b


@njit(**JIT)
def _contacts(found, n, face_a, face_b, contact):
    """The merged contacts of the first ``n`` rows of ``found`` (trimmed; world frame)."""
    n_faces_b, keep_all, normals_a, setup = contact
    result = (
        np.empty((n, 2), np.int64),
        np.empty((n, 3)),
        np.empty((n, 3)),
        np.empty(n),
    )
    pairs, points, normals, overlaps = result
    count, k = contact_kernel(
        found, n, face_a, face_b, n_faces_b, keep_all, normals_a, setup, result
    )
    return pairs[:count], points[:k], normals[:k], overlaps[:k]


@njit(**BORROW)
def _leaf_pair(face_a, i, face_b, j):
    """A's node ``i`` and B's node ``j`` are both leaves (``face (N,)`` int32, −1 for a
    surrogate): their contacts are final, they never unfold."""
    return (face_a[i] >= 0) & (face_b[j] >= 0)


@njit(**BORROW)
def _children(face, first_child, child_count, i):
    """``(c0, c1)`` int64: node ``i`` unfolds into the nodes ``c0 … c1 − 1`` — its
    children if it is a surrogate (``face[i] < 0``), itself if it is a leaf.
    ``face``, ``first_child``, ``child_count`` are a tree's (N,) int32 arrays."""
    leaf = face[i] >= 0
    first = np.int64(first_child[i])
    return select(leaf, np.int64(i), first), select(
        leaf, np.int64(i) + 1, first + np.int64(child_count[i])
    )


@njit(**BORROW)
def _apart(spheres_a, i, spheres_b, centres_b, centred, j, rotation, shift, margin):
    """Bounding spheres of A's node ``i`` and B's node ``j`` are apart by more than
    ``margin`` (B's centre is moved into A's frame on first use)."""
    _centre(spheres_b, centres_b, centred, j, rotation, shift)
    return _far(spheres_a, i, centres_b, spheres_b, j, margin)


@njit(**BORROW)
def _centre(spheres_b, centres_b, centred, j, rotation, shift):
    """B's sphere centre ``j`` moved into A's frame, into ``centres_b[j]``, once."""
    if not centred[j]:
        x, y, z = spheres_b[j, 0], spheres_b[j, 1], spheres_b[j, 2]
        for c in range(3):
            centres_b[j, c] = (
                rotation[c, 0] * x + rotation[c, 1] * y + rotation[c, 2] * z + shift[c]
            )
        centred[j] = True


@njit(**BORROW)
def _far(spheres_a, i, centres_b, spheres_b, j, margin):
    """As :func:`_apart` for a B node already centred (:func:`_centre`)."""
    dx = spheres_a[i, 0] - centres_b[j, 0]
    dy = spheres_a[i, 1] - centres_b[j, 1]
    dz = spheres_a[i, 2] - centres_b[j, 2]
    reach = spheres_a[i, 3] + spheres_b[j, 3] + margin
    return dx * dx + dy * dy + dz * dz > reach * reach


@njit(**BORROW)
def _eps(epsilon, face, i, margin, inflate, out):
    """``out[i]``: node ``i``'s ε plus ``margin`` if a surrogate, rounded to ``out``'s
    dtype, then plus ``inflate`` (as :func:`~engine.kernels.collision.rigid.margin_kernel`
    and an in-place ``+= inflate`` would write it)."""
    out[i] = epsilon[i] + (margin if face[i] < 0 else 0.0)
    if inflate > 0.0:
        out[i] += inflate


@njit(**JIT)
def _grown_pairs(pairs, n, need):
    """``(max(need, 2·len), 2)`` int64 rows holding the first ``n`` rows of ``pairs``."""
    grown = np.empty((max(need, 2 * pairs.shape[0]), 2), np.int64)
    grown[:n] = pairs[:n]
    return grown


@njit(**JIT)
def _room(out, n, need):
    """``out`` if it holds ``need`` rows, else larger buffers with its first ``n`` rows."""
    if out[0].shape[0] >= need:
        return out
    grown = result_buffers(max(need, 2 * out[0].shape[0]), out[2])
    grown[0][:n] = out[0][:n]
    grown[1][:n] = out[1][:n]
    grown[2][:n] = out[2][:n]
    grown[3][:, :n] = out[3][:, :n]
    grown[4][:, :n] = out[4][:, :n]
    grown[5][:n] = out[5][:n]
    return grown
