"""One body pair's whole multiresolution contact query in one call with flat arguments.

:func:`pair_query` is what :func:`engine.collision.contacts.find_contacts` calls: the
relative pose, the surrogate ε margin, the traversal
(:func:`~engine.kernels.collision.traversal.traverse`) and the merged contacts, from
arrays and scalars only. Numba unboxes a flat argument list several times faster than
nested tuples of arrays, and the contacts are written into the caller's buffers instead of
being returned as new arrays (boxing a tuple of arrays costs microseconds), so the fixed
cost of a query is a few microseconds. The pose helpers are the batch's
(:mod:`engine.kernels.collision.batch`, compiled without fast-math): the same rotations and
shifts bit for bit, hence the same contacts as :func:`~engine.kernels.collision.batch.batch_kernel`.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from engine.kernels.collision.batch import query_margin, relative_pose
from engine.kernels.collision.boxes import SEARCH_BUDGET, bounds_apart
from engine.kernels.collision.contact_merge import contact_kernel
from engine.kernels.collision.traversal import traverse
from engine.kernels.geometry.triangle_batch import N_STATS, STAT_SPHERES
from engine.kernels.jit import JIT

# Entries of the integer tuple pair_query returns.
QUERY_FOUND, QUERY_PAIRS, QUERY_CONTACTS, QUERY_DEPTH, QUERY_UNFOLDINGS = range(5)


@njit(**JIT)
def pair_query(
    coords_a,
    frames_a,
    epsilon_a,
    face_a,
    first_a,
    count_a,
    spheres_a,
    normals_a,
    extent_a,
    leaf_epsilon_a,
    boxes_a,
    table_a,
    master_coords,
    master_frames,
    epsilon_b,
    face_b,
    first_b,
    count_b,
    spheres_b,
    extent_b,
    leaf_epsilon_b,
    n_faces_b,
    boxes_b,
    table_b,
    position_a,
    orientation_a,
    position_b,
    orientation_b,
    bounds_margin,
    ulp,
    coarse_mode,
    leaf_mode,
    iterations,
    rtol,
    one,
    band,
    keep_all,
    tiny,
    merge_radius,
    counters,
    out_pairs,
    out_points,
    out_normals,
    out_overlaps,
):
    """Contacts of body A (its nodes ``coords_a … spheres_a`` as
    :func:`~engine.kernels.collision.traversal.query_kernel`'s ``body_a``, face normals
    ``normals_a (F, 3)`` float64, largest body-frame coordinate ``extent_a``, leaf ε, node
    boxes ``boxes_a (N, 15)`` float64 as :mod:`~engine.kernels.collision.boxes` reads them,
    or ``(0, 15)`` for none, and its node bounds ``table_a (N, 21)`` as
    :func:`~engine.kernels.collision.boxes.bounds_apart` reads them, or ``(0, 21)``) at
    ``position_a (3,)``, ``orientation_a (4,)`` (unit quaternion) and body B
    (``master_coords … spheres_b``, its ``body_b``; ``n_faces_b`` faces; ``boxes_b``,
    ``table_b``) at ``position_b``, ``orientation_b``. Node pairs are pruned by their
    bounding spheres, then by their boxes
    (:func:`~engine.kernels.collision.traversal.traverse`), with the query margin. When
    the node bounds alone show the bodies apart by more than ``bounds_margin`` (float64;
    ``bounds_apart``, at most ``SEARCH_BUDGET`` node pairs tested: the same outcome as
    :func:`roots_apart` with that margin) the result is the root pair pruned: ``f = −1``,
    nothing written, ``counters`` zero but for that pruned pair. That search runs only
    when the traversal found no leaf pair in contact and none whose distance, as the
    traversal evaluated it, is within ``bounds_margin / 2`` of contact (every bound that
    covers a leaf pair holds both leaves' ε-regions, so the search cannot show those
    bodies apart), and not at all for a negative ``bounds_margin`` (the host has run
    :func:`roots_apart`, which found them not apart).
    The arguments come in four groups: A's, B's (each fixed per tree, so the host keeps
    them as one tuple per tree), the poses and bounds margin, and the parameters.

    ``extent_*``, ``ulp``: the query margin's inputs
    (:func:`~engine.kernels.collision.batch.query_margin`); ``coarse_mode``, ``leaf_mode``
    (int64), ``iterations`` (int64), ``rtol``, ``one``, ``band`` (the query dtype): the
    surrogate and leaf kernel parameters; ``n_faces_b``, ``keep_all``, the leaf ε of
    both, ``tiny`` and ``merge_radius``: the contact set-up
    (:func:`~engine.kernels.collision.contact_merge.contact_kernel`).

    ``counters (N_STATS + L,)`` int64, zero: the traversal's stats, then the pairs
    evaluated per level. The contacts go to ``out_pairs (c, 2)`` int64, ``out_points,
    out_normals (c, 3)``, ``out_overlaps (c,)`` float64 when the ``f`` leaf pairs found fit
    (``f ≤ c``); else nothing is written and the caller runs the query again with room
    for ``f``. Returns ``(f, m, k, depth, unfoldings)`` (int64; ``m``, ``k`` the pair and
    merged-contact counts, −1 when nothing was written).
    """
    rot_a, rotation, shift = relative_pose(position_a, orientation_a, position_b, orientation_b)
    margin = query_margin(extent_a, extent_b, shift, ulp)
    stats = counters[:N_STATS]
    levels = counters[N_STATS:]
    depth, unfoldings, n, found, _, _, closest = traverse(
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
        0.0,
        (coarse_mode, iterations, rtol, one, band),
        (leaf_mode, iterations, rtol, one, band),
        stats,
        levels,
    )
    # the bounds-only search, after the traversal, only where it may find the bodies apart:
    # every bound that covers a leaf pair holds both leaves' ε-regions, which are within
    # d − ε of each other, so a pair in contact (n > 0), or one whose evaluated distance
    # is within half the search's margin of contact (the rounding of d is far smaller),
    # keeps that search from ending apart
    if (
        n == 0
        and not closest <= 0.5 * bounds_margin
        and bounds_margin >= 0.0
        and table_a.shape[0] > 0
        and table_b.shape[0] > 0
        and bounds_apart(table_a, table_b, rotation, shift, bounds_margin, SEARCH_BUDGET)
    ):  # the root pair pruned, as the traversal counts it; f = −1 tells the host
        counters[:] = 0
        stats[STAT_SPHERES] = 1
        none = np.int64(0)
        return np.int64(-1), none, none, none, none
    if n > out_pairs.shape[0]:
        return n, np.int64(-1), np.int64(-1), depth, unfoldings
    position = np.empty(3)  # contact_kernel's set-up takes writable arrays
    position[:] = position_a
    setup = (leaf_epsilon_a, leaf_epsilon_b, tiny, merge_radius, rot_a, position)
    m, k = contact_kernel(
        found,
        n,
        face_a,
        face_b,
        n_faces_b,
        keep_all,
        normals_a,
        setup,
        (out_pairs, out_points, out_normals, out_overlaps),
    )
    return n, np.int64(m), np.int64(k), depth, unfoldings


@njit(**JIT)
def roots_apart(table_a, table_b, position_a, orientation_a, position_b, orientation_b, margin):
    """:func:`~engine.kernels.collision.boxes.bounds_apart` (budget ``SEARCH_BUDGET``) of
    two bodies' node bounds ``table_* (N, 21)`` float64 (body frames) at ``position_*
    (3,)``, ``orientation_* (4,)`` (unit quaternions), B placed in A's frame as
    :func:`pair_query` places it (the same
    :func:`~engine.kernels.collision.batch.relative_pose`); ``margin`` float64 (at least
    the query margin). Returns bool: the host's early-out, the outcome of
    :func:`pair_query`'s own search with ``bounds_margin = margin`` (one no-fast-math
    body: the same bits), so the host can skip that search."""
    _, rotation, shift = relative_pose(position_a, orientation_a, position_b, orientation_b)
    return bounds_apart(table_a, table_b, rotation, shift, margin, SEARCH_BUDGET)
