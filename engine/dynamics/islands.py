"""Islands of a Picard step (:mod:`engine.dynamics.picard`): where a search's forces fail
Picard's test on some bodies only, the islands (bodies connected by acting contacts) that
passed keep their applied forces, and so their configuration, bit for bit, while the
islands that failed iterate on. The search that checks the next configuration then searches
only the body pairs with a moved body: a pair whose two bodies are where they were has the
contacts it had, bit for bit (a pair's contacts are a function of its two poses, the pair
cache's lists included), so the answer is the whole configuration's.

An island that passed is not in contact with one that failed (they would be one island),
so the Newton corrections of the failing islands do not involve it; should a moving body
come to touch a held one, that pair is searched again and the held body's forces are
tested again with every other body's.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from engine.collision.configuration import Contacts, batched_contacts
from engine.kernels.dynamics import contact_forces as kf

__all__ = ["Searched", "moving", "search"]


@dataclass(frozen=True)
class Searched:
    """A search of one configuration: ``positions (n, 3)``, ``orientations (n, 4)``
    float64, its ``contacts`` and each body pair's triangle pairs in contact
    ``triangles (k,)`` int64."""

    positions: np.ndarray
    orientations: np.ndarray
    contacts: Contacts
    triangles: np.ndarray


def search(scene, positions, orientations, last: Searched | None = None) -> Searched:
    """The multiresolution contacts of ``scene`` at ``positions``, ``orientations``; with
    ``last``, the body pairs whose two bodies have the same position and orientation (bit
    for bit) as in ``last`` keep its contacts, and only the others are searched (through
    the pair cache's lists, which it then leaves as they were: the next whole search
    renews what moved). A search of every pair renews the cache as any search does."""
    origins, pairs = scene.configuration(positions, orientations)
    n, k = len(positions), len(pairs)
    changed = np.ones(k, np.bool_)
    if last is not None:
        moved = (positions != last.positions).any(axis=1)
        moved |= (orientations != last.orientations).any(axis=1)
        changed = moved[pairs[:, 0]] | moved[pairs[:, 1]]
        keys = pairs[:, 0] * n + pairs[:, 1]
        before = last.contacts.bodies[:, 0] * n + last.contacts.bodies[:, 1]
        at = np.searchsorted(before, keys[~changed])
        found_all = (at < len(before)).all() and np.array_equal(before[at], keys[~changed])
        if not found_all:
            changed[:] = True  # an unmoved pair the last search had not: search it all
    whole = bool(changed.all())
    triangles = np.empty(int(changed.sum()), np.int64)
    found = batched_contacts(
        scene.bank, scene.tree_index, pairs[changed], origins, orientations, scene.kernel,
        scene.threads, scene.pair_cache, read_only=not whole, triangle_pairs=triangles,
    )  # fmt: skip
    if whole:
        return Searched(positions.copy(), orientations.copy(), found, triangles)
    same, old = ~changed, last.contacts
    counts = np.empty(k, np.int64)
    counts[changed] = np.diff(found.offsets)
    counts[same] = np.diff(old.offsets)[at]
    offsets = np.zeros(k + 1, np.int64)
    np.cumsum(counts, out=offsets[1:])
    source, target = _rows(old.offsets[at], counts[same]), _rows(offsets[:-1][same], counts[same])
    fresh = _rows(offsets[:-1][changed], counts[changed])
    merged = []
    for kept, new in ((old.points, found.points), (old.normals, found.normals),
                      (old.overlaps, found.overlaps)):  # fmt: skip
        out = np.empty((int(offsets[-1]), *kept.shape[1:]))
        out[target], out[fresh] = kept[source], new
        merged.append(out)
    per_pair = np.empty(k, np.int64)
    per_pair[changed], per_pair[same] = triangles, last.triangles[at]
    counters = {**found.counters, "triangle_pairs": int(per_pair.sum())}
    contacts = Contacts(pairs, offsets, *merged, counters)
    return Searched(positions.copy(), orientations.copy(), contacts, per_pair)


def _rows(starts: np.ndarray, counts: np.ndarray) -> np.ndarray:
    """(Σ counts,) int64: the rows ``starts[i] … starts[i] + counts[i] − 1``, in order."""
    if not len(counts):
        return np.zeros(0, np.int64)
    ends = np.cumsum(counts)
    return np.repeat(starts - ends + counts, counts) + np.arange(int(ends[-1]))


def moving(scene, evaluation, failing: np.ndarray) -> np.ndarray:
    """(n,) bool: the free bodies in the islands of the ``failing (n,)`` bool bodies — the
    bodies connected to one by acting contacts of ``evaluation``, through free bodies."""
    found, free = evaluation.contacts, ~scene.fixed
    island = np.empty(len(free), np.int64)  # each body's island, labelled by its smallest body
    kf.contact_islands(found.bodies, found.offsets, evaluation.terms, free, island)
    marked = np.zeros(len(free), np.bool_)
    marked[island[failing]] = True
    return free & marked[island]
