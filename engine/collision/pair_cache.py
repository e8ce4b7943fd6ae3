"""The pair cache: leaf pairs near contact kept per body pair between batched searches (a
Verlet list per body pair), held in the parts the worker chunks made them in.

:class:`PairCache` is read and renewed by :meth:`engine.collision.batch.TreeBank.run`.
Its entries live in *parts*, consecutive runs of entries, each with its own arrays. A
search whose pairs (keys, in order) and chunks are those of the last search gives chunk c
the lists of part c and renews that part on the chunk's own worker thread: nothing is
joined or copied across parts. Any other search works on one flat part (the parts joined
once, on the worker threads), as a search did before parts.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from engine.errors import InvalidArgumentError
from engine.kernels.collision import batch as kb
from engine.kernels.collision.pair_lists import join_lists
from engine.workers import worker_pool

__all__ = ["DEFAULT_SKIN", "NO_LISTS", "PairCache", "joined", "joined_offsets"]

DEFAULT_SKIN = 0.25
"""Default :class:`PairCache` skin, relative to ε_a + ε_b. A larger skin keeps lists
valid for more motion but makes each list longer and its traversal dearer (ε grown more):
on the paper's grid 0.25 against 0.5 took a traversal that makes the list of a pole pair
from 314 to 258 µs (``benchmarks/grid_pairs.py --skin``, 1 thread) and the "aligned"
grid's first step from 7.3–7.6 to 6.4–6.6 s (2 threads), steady steps unchanged; a
rolling sphere and a falling pile of 64 spheres (implicit-surrogate) stepped in the same
time (0.23/0.24 and 3.73/3.71 ms)."""

PARALLEL_JOIN = 1 << 24
"""Bytes from which joins copy on the worker threads. Most of a large join's time is
first-touch page faults of the new array (the "aligned" grid's first lists, 770 MB: 1.7 s
of a 8.1 s step on the 2-vCPU VM of BENCHMARKS.md, where a copy into memory already
touched takes 0.04 s); they proceed in parallel."""


class Lists(NamedTuple):
    """The lists of a run of ``e`` entries (one part, or all of them)."""

    rotations: np.ndarray  # (e, 3, 3) float64: reference pose of B relative to A
    shifts: np.ndarray  # (e, 3) float64
    offsets: np.ndarray  # (e + 1,) int64: entry i owns near[offsets[i]:offsets[i + 1]]
    near: np.ndarray  # (L, 2) int64: leaf node pairs (local rows of A, of B)
    distances: np.ndarray  # (L,) float64: exact distances at the reference pose


_EMPTY = Lists(
    rotations=np.zeros((0, 3, 3)),
    shifts=np.zeros((0, 3)),
    offsets=np.zeros(1, np.int64),
    near=np.zeros((0, 2), np.int64),
    distances=np.zeros(0),
)

NO_LISTS = kb.PairLists(0.0, np.zeros(0, np.int64), *_EMPTY)
"""The kernel's lists argument for a search without a cache."""


class PairCache:
    """Leaf pairs near contact kept per body pair between searches (a Verlet list).

    For each cached pair: the leaf pairs within ε_a + ε_b + s at a reference pose of B
    relative to A, s = ``skin``·(ε_a + ε_b), with their exact distances there. While no
    point of B has moved by s or more relative to A since then, every leaf pair in
    contact is on the list (a pair at distance ≤ ε_a + ε_b now was within ε_a + ε_b + s
    then), so evaluating the list alone gives exactly the traversal's contacts — bit for
    bit, with the same kernels on the same moved triangles; of the list only the pairs
    whose reference distance, less how far B has moved since, is still within reach
    (with a rounding allowance) are evaluated, the others cannot touch
    (:func:`~engine.kernels.collision.batch.listed_contacts`). Past that, the pair is
    traversed again (with ε grown by s/2 per body) and its list renewed. Entries are
    keyed by an integer per body pair chosen by the caller; a search keeps exactly the
    entries of the pairs it was asked.

    Attributes
    ----------
    comparisons : int — triangle comparisons the last search that renewed the lists made
        (the two-halves split of :mod:`engine.collision.batch` waits for a dear one)
    skin : float — s relative to the pair's ε_a + ε_b (0: no caching)
    keys : (m,) int64 sorted; rotations (m, 3, 3), shifts (m, 3) float64 — reference poses
    offsets : (m + 1,) int64; near : (L, 2) int64 — the lists (node pairs), CSR
    distances : (L,) float64 — each listed pair's exact distance at the reference pose

    (``rotations`` … ``distances`` join the parts into one when read.)
    """

    def __init__(self, skin: float = DEFAULT_SKIN) -> None:
        skin = float(skin)
        if not (np.isfinite(skin) and skin >= 0):
            raise InvalidArgumentError(f"skin must be finite and >= 0, got {skin}")
        self.skin = skin
        self.clear()

    def clear(self) -> None:
        """Forget every list."""
        self.keys = np.zeros(0, np.int64)
        self._parts: list[Lists] = [_EMPTY]
        self._bounds = np.zeros(2, np.int64)  # entry bounds of the parts
        self.comparisons = 0  # made by the last search that renewed the lists

    def __len__(self) -> int:
        return len(self.keys)

    @property
    def nbytes(self) -> int:
        return self.keys.nbytes + sum(a.nbytes for part in self._parts for a in part)

    rotations = property(lambda self: self._flat().rotations, doc="(m, 3, 3) float64")
    shifts = property(lambda self: self._flat().shifts, doc="(m, 3) float64")
    offsets = property(lambda self: self._flat().offsets, doc="(m + 1,) int64")
    near = property(lambda self: self._flat().near, doc="(L, 2) int64")
    distances = property(lambda self: self._flat().distances, doc="(L,) float64")

    def _flat(self, threads: int = 1) -> Lists:
        """Every entry's lists as one part (the parts joined, once)."""
        if len(self._parts) > 1:
            pool = worker_pool(threads) if threads > 1 else None
            parts = self._parts
            self._parts = [
                Lists(
                    joined([p.rotations for p in parts]),
                    joined([p.shifts for p in parts]),
                    joined_offsets([p.offsets for p in parts]),
                    joined([p.near for p in parts], pool),
                    joined([p.distances for p in parts], pool),
                )
            ]
            self._bounds = np.array([0, len(self.keys)], np.int64)
        return self._parts[0]

    # ---------------------------------------------------------------- searches by part
    def _aligned(self, keys: np.ndarray, bounds: np.ndarray) -> bool:
        """Whether a search of ``keys`` in chunks ``bounds`` (query bounds) finds chunk c's
        lists in part c: the same keys in the same order, the same bounds."""
        return (
            len(keys) == len(self.keys)
            and np.array_equal(bounds, self._bounds)
            and np.array_equal(keys, self.keys)
        )

    def _part(self, c: int, slot: np.ndarray) -> kb.PairLists:
        """Part ``c`` as the kernel reads it; ``slot (k,)`` int64: each query's entry
        within its chunk's part."""
        return kb.PairLists(self.skin, slot, *self._parts[c])

    def _renew(self, c: int, kept: np.ndarray, result: kb.BatchResult) -> None:
        """Part ``c`` after its chunk's search (``result``; ``kept (e,)`` bool: the entry's
        list served and stays valid, else ``result`` holds its new one). Called on the
        chunk's worker thread."""
        if kept.all():
            return
        if not kept.any():
            self._parts[c] = Lists(
                result.rotations,
                result.shifts,
                result.near_offsets,
                result.near,
                result.near_distances,
            )
            return
        old = self._parts[c]
        sizes = np.where(kept, np.diff(old.offsets), np.diff(result.near_offsets))
        offsets = np.zeros(len(sizes) + 1, np.int64)
        np.cumsum(sizes, out=offsets[1:])
        near, distances = np.empty((offsets[-1], 2), np.int64), np.empty(offsets[-1])
        join_lists(
            sizes,
            old.offsets[:-1],
            result.near_offsets[:-1],
            kept,
            (old.near, old.distances),
            (result.near, result.near_distances),
            (near, distances),
        )
        # a listed query's result carries its kept reference pose: the poses are the result's
        self._parts[c] = Lists(result.rotations, result.shifts, offsets, near, distances)

    def sizes(self, keys: np.ndarray) -> np.ndarray:
        """(k,) int64: the length of the list of each of ``keys (k,)`` int64, −1 where there
        is none (the parts are read where they are, not joined)."""
        slots = self._slots(keys)
        if not len(self.keys):
            return slots
        lengths = np.concatenate([np.diff(part.offsets) for part in self._parts])
        return np.where(slots >= 0, lengths[np.maximum(slots, 0)], -1).astype(np.int64)

    # ---------------------------------------------------------------- any other search
    def _slots(self, keys: np.ndarray) -> np.ndarray:
        """(k,) int64 entry of each key, −1 where none."""
        at = np.searchsorted(self.keys, keys)
        hit = at < len(self.keys)
        hit[hit] = self.keys[at[hit]] == keys[hit]
        return np.where(hit, at, -1).astype(np.int64)

    def _lists(self, slots: np.ndarray, threads: int = 1) -> kb.PairLists:
        """Every list as the kernel reads them, ``slots (k,)`` int64 naming each query's."""
        return kb.PairLists(self.skin, slots, *self._flat(threads))

    def _replace(
        self,
        keys: np.ndarray,
        slots: np.ndarray,
        kept: np.ndarray,
        near_offsets: np.ndarray,
        parts: list[kb.BatchResult],
        bounds: np.ndarray,
        threads: int = 1,
    ) -> None:
        """Hold exactly the pairs ``keys (k,)``: entry ``slots[q]`` where ``kept[q]`` (the
        query used its list, which stays valid), else the query's new list: the chunks'
        joined ``near_offsets`` (k + 1,), and the ``rotations``, ``shifts``, ``near`` and
        ``near_distances`` of the worker chunks ``parts`` (queries ``bounds (p + 1,)``).
        Every list new and the keys in order (a first search): the chunks' lists become
        the parts as they are. Else one flat part; large rows are copied on ``threads``
        worker threads."""
        if kept.all() and np.array_equal(keys, self.keys):
            return  # the same pairs, every list kept: nothing to copy
        order = np.argsort(keys, kind="stable")
        identity = bool((order == np.arange(len(order))).all())
        if identity and not kept.any():  # every list new, in key order: the rows as made
            self.keys = np.ascontiguousarray(keys, np.int64)
            self._parts = [
                Lists(p.rotations, p.shifts, p.near_offsets, p.near, p.near_distances)
                for p in parts
            ]
            self._bounds = np.asarray(bounds, np.int64)
            return
        pool = worker_pool(threads) if threads > 1 else None
        old = self._flat(threads)
        rotations = joined([part.rotations for part in parts])
        shifts = joined([part.shifts for part in parts])
        near = joined([part.near for part in parts], pool)
        near_distances = joined([part.near_distances for part in parts], pool)
        slots, kept = slots[order], kept[order]
        fresh = np.diff(near_offsets)[order]
        sizes = np.where(kept, old.offsets[slots + 1] - old.offsets[slots], fresh)
        offsets = np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64)
        lists = np.empty((int(offsets[-1]), 2), np.int64)
        distances = np.empty(int(offsets[-1]))
        sizes, old_start, new_start = (
            sizes.astype(np.int64),
            old.offsets[slots],
            near_offsets[:-1][order],
        )

        def fill(q0: int, q1: int) -> None:  # entries q0 … q1 − 1, into their own rows
            r0, r1 = offsets[q0], offsets[q1]
            join_lists(
                sizes[q0:q1],
                old_start[q0:q1],
                new_start[q0:q1],
                kept[q0:q1],
                (old.near, old.distances),
                (near, near_distances),
                (lists[r0:r1], distances[r0:r1]),
            )

        if pool is None or distances.nbytes < PARALLEL_JOIN:
            fill(0, len(sizes))
        else:  # first-touch page faults of the new rows, on the workers (see joined)
            cut = np.searchsorted(offsets, np.linspace(0, offsets[-1], 2 * threads + 1))
            cut[0], cut[-1] = 0, len(sizes)
            cut = np.unique(cut).tolist()
            list(pool.map(fill, cut[:-1], cut[1:]))
        self.keys = np.ascontiguousarray(keys[order], np.int64)
        self._parts = [Lists(rotations[order], shifts[order], offsets, lists, distances)]
        self._bounds = np.array([0, len(self.keys)], np.int64)


def joined(chunks: list[np.ndarray], pool=None) -> np.ndarray:
    """The chunks' rows as one array (one chunk: itself), copied on the threads of
    ``pool`` (a ThreadPoolExecutor; numpy copies without the GIL) when it is given and
    the rows are at least :data:`PARALLEL_JOIN` bytes."""
    if len(chunks) == 1:
        return chunks[0]
    if pool is None or sum(c.nbytes for c in chunks) < PARALLEL_JOIN:
        return np.concatenate(chunks)
    rows = np.cumsum([0] + [len(c) for c in chunks])
    out = np.empty((int(rows[-1]), *chunks[0].shape[1:]), chunks[0].dtype)

    def copy(i: int) -> None:
        out[rows[i] : rows[i + 1]] = chunks[i]

    list(pool.map(copy, range(len(chunks))))
    return out


def joined_offsets(chunks: list[np.ndarray]) -> np.ndarray:
    """(k + 1,) int64 CSR offsets of consecutive chunks' offsets (each from 0)."""
    out = [np.zeros(1, np.int64)]
    for offsets in chunks:
        out.append(offsets[1:] + out[-1][-1])
    return np.concatenate(out)
