"""A body pair's leaf-pair list made from bounding spheres alone (the pair cache's listing).

When the pair cache (see :class:`~engine.kernels.collision.batch.PairLists`) renews a
body pair's list, it needs every leaf pair within ε_a + ε_b + s at the new reference
pose, with its exact distance there. :func:`sphere_leaf_pairs` descends both trees
testing node bounding spheres only (each bounds its covered leaves' ε-regions, so two
spheres apart by more than s plus a rounding margin hold no such pair), and
:func:`first_listing` keeps the leaf pairs whose exact distance (the one later
evaluations compare against, :func:`~engine.kernels.collision.pair_lists.reference_distances`)
is within reach, then finds the contacts at the reference pose as any later evaluation
of the list does (:func:`~engine.kernels.collision.pair_lists.listed_contacts`, B not
moved). No triangle kernel runs above the leaves: on the paper's grid the traversal with
grown ε compared ~1,500 surrogate and leaf pairs per body pair to make a list of ~100.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from engine.kernels.collision.pair_lists import listed_contacts, reference_distances
from engine.kernels.geometry.triangle_batch import STAT_PAIRS, STAT_SPHERES, ZERO
from engine.kernels.jit import INLINE, JIT


@njit(**JIT)
def sphere_workspace(nodes):
    """Buffers of :func:`sphere_leaf_pairs` for trees of at most ``nodes`` nodes: B's
    sphere centres in A's frame (nodes, 3) float64, the query that last placed each (nodes,)
    int64, a stack of node pairs and the output pairs ((256, 2) int64 each, grown)."""
    return (
        np.empty((nodes, 3)),
        np.full(nodes, -1, np.int64),
        np.empty((256, 2), np.int64),
        np.empty((256, 2), np.int64),
    )


@njit(**INLINE)
def _place(spheres_b, centres, placed, j, stamp, rotation, shift):
    """B's sphere centre ``j`` in A's frame, into ``centres[j]``, once per ``stamp``."""
    if placed[j] != stamp:
        x, y, z = spheres_b[j, 0], spheres_b[j, 1], spheres_b[j, 2]
        for c in range(3):
            centres[j, c] = rotation[c, 0] * x + rotation[c, 1] * y + rotation[c, 2] * z + shift[c]
        placed[j] = stamp


@njit(**INLINE)
def _near(spheres_a, i, spheres_b, centres, j, reach):
    """The spheres of A's node ``i`` and B's node ``j`` (centre placed) are within ``reach``."""
    dx = spheres_a[i, 0] - centres[j, 0]
    dy = spheres_a[i, 1] - centres[j, 1]
    dz = spheres_a[i, 2] - centres[j, 2]
    r = spheres_a[i, 3] + spheres_b[j, 3] + reach
    return dx * dx + dy * dy + dz * dz <= r * r


@njit(**JIT)
def _push(stack, top, i, j):
    """``stack`` (maybe grown by doubling) with ``(i, j)`` at row ``top``."""
    if top == stack.shape[0]:
        grown = np.empty((2 * top, 2), np.int64)
        grown[:top] = stack[:top]
        stack = grown
    stack[top, 0], stack[top, 1] = i, j
    return stack


@njit(**JIT)
def sphere_leaf_pairs(bank, rows, pose, reach, stamp, work, stats):
    """Leaf pairs of two trees whose bounding spheres lie within ``reach`` of each other;
    returns ``(pairs, p, work)``: the first ``p`` rows of ``pairs`` (int64, local leaf rows
    of A, of B) and the workspace (its buffers maybe grown).

    ``bank``: a :class:`~engine.kernels.collision.batch.NodeBank`; ``rows = (a0, a1, b0,
    b1)`` the two trees' rows in it; ``pose = (rotation (3, 3), shift (3,))`` float64 moves
    B into A's frame; ``stamp`` (int64) a number not used by an earlier call on ``work``
    (:func:`sphere_workspace`). Depth first from the roots: a node pair within reach
    unfolds its node with the larger sphere (a leaf stands for itself), and each child
    pair is tested in turn; ``stats[STAT_SPHERES]`` counts the pairs dropped."""
    a0, a1, b0, b1 = rows
    rotation, shift = pose
    spheres_a, spheres_b = bank.spheres[a0:a1], bank.spheres[b0:b1]
    face_a, face_b = bank.face[a0:a1], bank.face[b0:b1]
    first_a, first_b = bank.first_child[a0:a1], bank.first_child[b0:b1]
    count_a, count_b = bank.child_count[a0:a1], bank.child_count[b0:b1]
    centres, placed, stack, pairs = work
    p = ZERO
    pruned = ZERO
    _place(spheres_b, centres, placed, ZERO, stamp, rotation, shift)
    if not _near(spheres_a, ZERO, spheres_b, centres, ZERO, reach):
        stats[STAT_SPHERES] += 1
        return pairs, p, work
    stack[0, 0], stack[0, 1] = 0, 0
    top = np.int64(1)
    while top > 0:
        top -= 1
        i, j = stack[top, 0], stack[top, 1]
        leaf_a, leaf_b = face_a[i] >= 0, face_b[j] >= 0
        if leaf_a and leaf_b:
            if p == pairs.shape[0]:
                grown = np.empty((2 * p, 2), np.int64)
                grown[:p] = pairs[:p]
                pairs = grown
            pairs[p, 0], pairs[p, 1] = i, j
            p += 1
        elif leaf_b or (not leaf_a and spheres_a[i, 3] >= spheres_b[j, 3]):
            c0 = np.int64(first_a[i])
            for c in range(c0, c0 + count_a[i]):
                if _near(spheres_a, c, spheres_b, centres, j, reach):
                    stack = _push(stack, top, c, j)
                    top += 1
                else:
                    pruned += 1
        else:
            c0 = np.int64(first_b[j])
            for c in range(c0, c0 + count_b[j]):
                _place(spheres_b, centres, placed, c, stamp, rotation, shift)
                if _near(spheres_a, i, spheres_b, centres, c, reach):
                    stack = _push(stack, top, i, c)
                    top += 1
                else:
                    pruned += 1
    stats[STAT_SPHERES] += pruned
    return pairs, p, (centres, placed, stack, pairs)


@njit(**JIT)
def first_listing(bank, rows, pose, margin, skin, leaf_params, stamp, scratch, stats):
    """A body pair's new list at the reference pose ``pose`` and its contacts there;
    returns ``(near, distances, found, n, face_b, work)``.

    ``rows = (a0, a1, b0, b1)``, ``pose`` as in :func:`sphere_leaf_pairs`; ``margin`` the
    query's rounding margin, ``skin`` s (the list holds the leaf pairs within ε_a + ε_b + s).
    The candidates are the leaf pairs whose spheres lie within s + ``margin``; each gets
    its exact distance (:func:`reference_distances`, in the query precision, ``leaf_params[3]``
    its 1); kept are those with distance − (ε_a + ε_b) ≤ s + κ·``margin`` (κ = max(1, κ_a,
    κ_b), the rounding allowance :func:`listed_contacts` gives a pair): a pair in contact
    while B has moved by less than s − ``margin`` is on the list, and no kept pair lies
    beyond ε_a + ε_b + s but for rounding. ``near (m, 2)`` int64 and ``distances (m,)``
    float64 are the list; ``(found, n, face_b)`` its contacts at ``pose`` as
    :func:`listed_contacts` returns them (slack: two margins, B has not moved).
    ``scratch = (local, buffers, found, work)``: as :func:`listed_contacts`'s, then the
    :func:`sphere_workspace` (returned, maybe grown). ``stats[STAT_PAIRS]`` counts the
    exact distances and the pairs evaluated."""
    a0, a1, b0, b1 = rows
    local, buffers, found, work = scratch
    candidates, c, work = sphere_leaf_pairs(bank, rows, pose, skin + margin, stamp, work, stats)
    distances = np.empty(c)
    reference_distances(
        bank, (a0, b0), pose, candidates[:c], leaf_params[3], (local, buffers), distances
    )
    stats[STAT_PAIRS] += c
    keep = ZERO
    for t in range(c):
        i, j = candidates[t, 0], candidates[t, 1]
        reach = bank.epsilon[a0 + i] + bank.epsilon[b0 + j]
        kappa = max(1.0, max(bank.master_frames[a0 + i, 13], bank.master_frames[b0 + j, 13]))
        if distances[t] - reach <= skin + kappa * margin:
            candidates[keep, 0], candidates[keep, 1] = i, j
            distances[keep] = distances[t]
            keep += 1
    near = candidates[:keep].copy()
    distances = distances[:keep]
    found, n, face_b = listed_contacts(
        bank,
        (a0, a1, b0),
        pose,
        near,
        distances,
        2.0 * margin,
        leaf_params,
        (local, buffers, found),
        stats,
    )
    return near, distances, found, n, face_b, work
