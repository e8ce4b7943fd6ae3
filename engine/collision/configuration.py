"""Contacts of a scene configuration: the record the contact searches hand the force kernel,
and the two fresh searches of a configuration's candidate body pairs.

:func:`batched_contacts` (multiresolution, every pair in one batched call through the pair
cache) and :func:`flat_contacts` (the flat search, pair by pair), which
:meth:`engine.scene.Scene.contacts` chooses between, and
:class:`~engine.collision.multiscale.MultiscaleSearch` (fronts kept between calls) both
return a :class:`Contacts`; :mod:`engine.dynamics.picard` evaluates forces from it and sums
its :data:`SEARCH_COUNTERS` into the step's statistics.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from engine.collision.batch import TreeBank
from engine.collision.contacts import find_contacts
from engine.collision.pair_cache import PairCache
from engine.errors import InvalidArgumentError
from engine.geometry.pose import Pose
from engine.kernels.collision import batch as kb
from engine.workers import in_parts

__all__ = [
    "SEARCH_COUNTERS",
    "Contacts",
    "batched_contacts",
    "flat_contacts",
    "gathered_queries",
]

_ROWS_PER_PART = 8192  # pairs a worker thread gathers at least (~0.06 ms)

SEARCH_COUNTERS = (
    "comparisons",
    "iterative",
    "fallbacks",
    "sphere_pruned",
    "unfoldings",
    "folds",
    "listed",
)
"""The search counters summed over a configuration's body pairs (:class:`Contacts`)."""


@dataclass(frozen=True)
class Contacts:
    """Contacts of one configuration, as the force kernel takes them.

    bodies : (k, 2) int64 body pairs (a < b) tested in the narrow phase
    offsets : (k + 1,) int64 — pair q owns rows ``offsets[q]:offsets[q + 1]``
    points, normals : (c, 3) float64; overlaps : (c,) float64
    counters : dict of summed search counters (:data:`SEARCH_COUNTERS` and
        ``triangle_pairs``)
    """

    bodies: np.ndarray
    offsets: np.ndarray
    points: np.ndarray
    normals: np.ndarray
    overlaps: np.ndarray
    counters: dict


_BATCH_COUNTERS = (
    ("comparisons", kb.COUNT_COMPARISONS),
    ("iterative", kb.COUNT_ITERATIVE),
    ("fallbacks", kb.COUNT_FALLBACKS),
    ("sphere_pruned", kb.COUNT_SPHERES),
    ("unfoldings", kb.COUNT_UNFOLDINGS),
    ("listed", kb.COUNT_LISTED),
)


def batched_contacts(
    bank: TreeBank,
    tree_index: np.ndarray,
    pairs: np.ndarray,
    origins: np.ndarray,
    orientations: np.ndarray,
    kernel: str,
    threads: int | None,
    cache: PairCache | None,
    read_only: bool = False,
    triangle_pairs: np.ndarray | None = None,
) -> Contacts:
    """The multiresolution contacts of body ``pairs (k, 2)`` int64 (a < b, distinct) in one
    batched call: body i is tree ``tree_index[i]`` of ``bank`` with its mesh-frame origin at
    ``origins (n, 3)`` float64 and orientation ``orientations (n, 4)`` (unit within 1e-6,
    renormalised here as the bank would); pair (a, b) is cached under ``a·n + b``
    (``read_only``: the cache's lists serve, but it keeps them as they were).
    ``triangle_pairs (k,)`` int64, if given, receives each pair's triangle pairs in contact."""
    queries = gathered_queries(pairs, tree_index, origins, orientations, threads)
    keys = pairs[:, 0] * len(tree_index) + pairs[:, 1]
    batch = bank.run(queries, kernel, threads, cache, keys, keep_pairs=False,
                     read_only=read_only)  # fmt: skip
    if triangle_pairs is not None:
        triangle_pairs[:] = np.diff(batch.pair_offsets)
    totals = batch.totals
    counters = dict.fromkeys(SEARCH_COUNTERS, 0)
    for name, column in _BATCH_COUNTERS:
        counters[name] = int(totals[column])
    counters["triangle_pairs"] = int(batch.pair_offsets[-1])  # counted, not kept
    return Contacts(
        pairs, batch.contact_offsets, batch.points, batch.normals, batch.overlaps, counters
    )


def gathered_queries(
    pairs: np.ndarray,
    tree_index: np.ndarray,
    origins: np.ndarray,
    orientations: np.ndarray,
    threads: int | None,
) -> kb.PairQueries:
    """The :class:`~engine.kernels.collision.batch.PairQueries` of body ``pairs (k, 2)``
    int64 (arguments as :func:`batched_contacts`): orientations renormalised as numpy's
    ``q / np.linalg.norm(q)`` rounds it, rows gathered per pair in parts on the worker
    threads (``threads``; None: all cores). An orientation whose norm is not within
    1e-6 of 1 raises :class:`~engine.errors.InvalidArgumentError` naming the first."""
    k, n = len(pairs), len(orientations)
    queries = kb.PairQueries(
        np.empty(k, np.int64), np.empty(k, np.int64), np.empty((k, 3)), np.empty((k, 4)),
        np.empty((k, 3)), np.empty((k, 4)),
    )  # fmt: skip
    unit = np.empty((n, 4))
    bad = kb.unit_orientations(orientations, unit)  # 0.1 ms for 24,576 bodies
    if bad >= 0:
        norm = float(np.linalg.norm(orientations[bad]))
        raise InvalidArgumentError(
            f"orientations[{bad}] must be a unit quaternion; its norm is {norm:.6g}"
        )

    def rows(first: int, last: int) -> None:
        kb.gather_queries(pairs, tree_index, origins, unit, first, last, queries)

    in_parts(threads, k, rows, least=_ROWS_PER_PART)
    return queries


def flat_contacts(
    trees: list,
    tree_index: np.ndarray,
    pairs: np.ndarray,
    origins: np.ndarray,
    orientations: np.ndarray,
    kernel: str,
    precision: str,
) -> Contacts:
    """The flat search's contacts of body ``pairs (k, 2)``, one :func:`find_contacts` call per
    pair (``trees``: the SurrogateTrees ``tree_index (n,)`` points into; other arguments as
    :func:`batched_contacts`)."""
    counters = dict.fromkeys(SEARCH_COUNTERS, 0)
    offsets, points, normals, overlaps, triangle_pairs = [0], [], [], [], 0
    for a, b in pairs:
        res = find_contacts(
            trees[tree_index[a]],
            Pose(origins[a], orientations[a]),
            trees[tree_index[b]],
            Pose(origins[b], orientations[b]),
            kernel=kernel,
            hierarchy=False,
            precision=precision,
        )
        offsets.append(offsets[-1] + len(res.points))
        points.append(res.points), normals.append(res.normals), overlaps.append(res.overlaps)
        counters["comparisons"] += res.stats.comparisons
        counters["iterative"] += res.stats.iterative
        counters["fallbacks"] += res.stats.fallbacks
        triangle_pairs += len(res.pairs)
    counters["triangle_pairs"] = triangle_pairs
    return Contacts(
        pairs,
        np.array(offsets, np.int64),
        np.concatenate(points) if points else np.zeros((0, 3)),
        np.concatenate(normals) if normals else np.zeros((0, 3)),
        np.concatenate(overlaps) if overlaps else np.zeros(0),
        counters,
    )
