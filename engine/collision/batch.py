"""Contacts of many body pairs in one call (the narrow phase of a scene).

A :class:`TreeBank` holds several surrogate trees concatenated in one precision;
:meth:`TreeBank.find_contacts` runs the multiresolution search of every listed body
pair inside Numba (worker threads over chunks of pairs; the kernels release the
GIL) and returns ragged results (:class:`ContactBatch`). :func:`find_contacts_batch`
is the convenience form over ``(tree_a, pose_a, tree_b, pose_b)`` tuples.

Each pair's result is exactly what :func:`~engine.collision.contacts.find_contacts` returns for
it: both run the same ``query_kernel`` on the same arrays and poses.
"""

from __future__ import annotations

import functools
import os
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from engine.arguments import check_kernel, check_precision, check_quaternions, check_rows
from engine.collision.contacts import ContactSet, ContactStats, find_contacts
from engine.collision.query import TINY, ULP, query_parameters
from engine.errors import InvalidArgumentError
from engine.geometry.distance import DEFAULT_PRECISION
from engine.geometry.pose import Pose
from engine.kernels.collision import batch as kb
from engine.kernels.collision.pair_lists import join_lists
from engine.trees.tree import SurrogateTree
from engine.workers import worker_pool

__all__ = ["ContactBatch", "TreeBank", "find_contacts_batch"]

MAX_LEVELS = 32
"""Per-level comparison counts kept per pair (deeper levels are counted, not kept)."""
_PAIRS_PER_TASK = 64  # below this many pairs per worker, one thread is faster
_CPUS = os.cpu_count() or 1  # looked up once: os.cpu_count() costs µs per call


@dataclass(frozen=True)
class ContactBatch:
    """Contacts of ``k`` body pairs, ragged (CSR): pair ``q`` owns
    ``pairs[pair_offsets[q]:pair_offsets[q + 1]]`` and
    ``points/normals/overlaps[contact_offsets[q]:contact_offsets[q + 1]]``.

    pair_offsets, contact_offsets : (k + 1,) int64
    pairs : (m, 2) int64 — (face of A, face of B) per pair, sorted within each pair;
        held as ``pair_chunks`` (the worker chunks' rows, in order) and joined on first
        access; none for a call that counted them only (:meth:`TreeBank.run` with
        ``keep_pairs=False``: a scene step reads only their count, ``pair_offsets[-1]``;
        on the paper's "aligned" grid 16 M rows, 256 MB an evaluation)
    points, normals : (c, 3) float64 — world frame; normals unit, from A to B
    overlaps : (c,) float64
    levels : (k, MAX_LEVELS) int64 — comparisons per level of each pair
    counts : (k, 7) int64 — depth, unfoldings, iterative, fallbacks, comparisons,
        node pairs pruned by bounding spheres, 1 if the pair's cached list served
    """

    pair_offsets: np.ndarray
    pair_chunks: tuple[np.ndarray, ...] = field(repr=False)
    contact_offsets: np.ndarray
    points: np.ndarray
    normals: np.ndarray
    overlaps: np.ndarray
    levels: np.ndarray
    counts: np.ndarray

    def __len__(self) -> int:
        return len(self.pair_offsets) - 1

    @functools.cached_property
    def pairs(self) -> np.ndarray:
        """(m, 2) int64: ``pair_chunks`` joined (once)."""
        chunks = self.pair_chunks
        if not chunks:
            raise InvalidArgumentError(
                "this batch counted its face pairs without keeping them"
                " (TreeBank.run(..., keep_pairs=False)); run it with keep_pairs=True"
            )
        return chunks[0] if len(chunks) == 1 else np.concatenate(chunks)

    def __getitem__(self, q: int) -> ContactSet:
        """Pair ``q`` as a :class:`~engine.collision.contacts.ContactSet`."""
        q = range(len(self))[q]
        p0, p1 = self.pair_offsets[q], self.pair_offsets[q + 1]
        c0, c1 = self.contact_offsets[q], self.contact_offsets[q + 1]
        depth = min(int(self.counts[q, kb.COUNT_DEPTH]), MAX_LEVELS)
        stats = ContactStats(
            tuple(self.levels[q, :depth].tolist()),
            int(self.counts[q, kb.COUNT_ITERATIVE]),
            int(self.counts[q, kb.COUNT_FALLBACKS]),
            int(self.counts[q, kb.COUNT_UNFOLDINGS]),
            int(p1 - p0),
            int(c1 - c0),
            int(self.counts[q, kb.COUNT_SPHERES]),
        )
        return ContactSet(
            self.pairs[p0:p1],
            self.points[c0:c1],
            self.normals[c0:c1],
            self.overlaps[c0:c1],
            stats,
        )

    @property
    def comparisons(self) -> int:
        """Triangle comparisons over all pairs."""
        return int(self.counts[:, kb.COUNT_COMPARISONS].sum())


DEFAULT_SKIN = 0.25
"""Default :class:`PairCache` skin, relative to ε_a + ε_b. A larger skin keeps lists
valid for more motion but makes each list longer and its traversal dearer (ε grown more):
on the paper's grid 0.25 against 0.5 took a traversal that makes the list of a pole pair
from 301 to 251 µs and the "aligned" grid's first step from 7.3–7.6 to 6.4–6.6 s (2
threads), steady steps unchanged; a rolling sphere and a falling pile of 64 spheres
(implicit-surrogate) stepped in the same time (0.23/0.24 and 3.73/3.71 ms)."""


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
    skin : float — s relative to the pair's ε_a + ε_b (0: no caching)
    keys : (m,) int64 sorted; rotations (m, 3, 3), shifts (m, 3) float64 — reference poses
    offsets : (m + 1,) int64; near : (L, 2) int64 — the lists (node pairs), CSR
    distances : (L,) float64 — each listed pair's exact distance at the reference pose
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
        self.rotations = np.zeros((0, 3, 3))
        self.shifts = np.zeros((0, 3))
        self.offsets = np.zeros(1, np.int64)
        self.near = np.zeros((0, 2), np.int64)
        self.distances = np.zeros(0)

    def __len__(self) -> int:
        return len(self.keys)

    @property
    def nbytes(self) -> int:
        return sum(
            a.nbytes
            for a in (
                self.keys,
                self.rotations,
                self.shifts,
                self.offsets,
                self.near,
                self.distances,
            )
        )

    def _slots(self, keys: np.ndarray) -> np.ndarray:
        """(k,) int64 entry of each key, −1 where none."""
        at = np.searchsorted(self.keys, keys)
        hit = at < len(self.keys)
        hit[hit] = self.keys[at[hit]] == keys[hit]
        return np.where(hit, at, -1).astype(np.int64)

    def _lists(self, slots: np.ndarray) -> kb.PairLists:
        """The lists as the kernel reads them, ``slots (k,)`` int64 naming each query's."""
        return kb.PairLists(
            self.skin, slots, self.rotations, self.shifts, self.offsets, self.near, self.distances
        )

    def _replace(
        self,
        keys: np.ndarray,
        slots: np.ndarray,
        kept: np.ndarray,
        batch: kb.BatchResult,
        parts: list[kb.BatchResult],
        threads: int = 1,
    ) -> None:
        """Hold exactly the pairs ``keys (k,)``: entry ``slots[q]`` where ``kept[q]`` (the
        query used its list, which stays valid), else the query's new list: ``batch``'s
        ``near_offsets``, and the ``rotations``, ``shifts``, ``near`` and
        ``near_distances`` of the worker chunks ``parts`` (in order; joined here, once;
        large rows are copied on ``threads`` worker threads)."""
        if kept.all() and np.array_equal(keys, self.keys):
            return  # the same pairs, every list kept: nothing to copy
        pool = worker_pool(threads) if threads > 1 else None
        near_offsets = batch.near_offsets
        rotations = _joined([part.rotations for part in parts])
        shifts = _joined([part.shifts for part in parts])
        near = _joined([part.near for part in parts], pool)
        near_distances = _joined([part.near_distances for part in parts], pool)
        order = np.argsort(keys, kind="stable")
        identity = bool((order == np.arange(len(order))).all())
        if identity and not kept.any():  # every list new, in key order: the rows as made
            self.keys = np.ascontiguousarray(keys, np.int64)
            self.rotations, self.shifts = rotations, shifts
            self.offsets, self.near, self.distances = near_offsets, near, near_distances
            return
        slots, kept = slots[order], kept[order]
        fresh = np.diff(near_offsets)[order]
        sizes = np.where(kept, self.offsets[slots + 1] - self.offsets[slots], fresh)
        offsets = np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64)
        lists = np.empty((int(offsets[-1]), 2), np.int64)
        distances = np.empty(int(offsets[-1]))
        sizes, old_start, new_start = (
            sizes.astype(np.int64),
            self.offsets[slots],
            near_offsets[:-1][order],
        )

        def fill(q0: int, q1: int) -> None:  # entries q0 … q1 − 1, into their own rows
            r0, r1 = offsets[q0], offsets[q1]
            join_lists(
                sizes[q0:q1],
                old_start[q0:q1],
                new_start[q0:q1],
                kept[q0:q1],
                (self.near, self.distances),
                (near, near_distances),
                (lists[r0:r1], distances[r0:r1]),
            )

        if pool is None or distances.nbytes < _PARALLEL_JOIN:
            fill(0, len(sizes))
        else:  # first-touch page faults of the new rows, on the workers (see _joined)
            bounds = np.searchsorted(offsets, np.linspace(0, offsets[-1], 2 * threads + 1))
            bounds[0], bounds[-1] = 0, len(sizes)
            bounds = np.unique(bounds).tolist()
            list(pool.map(fill, bounds[:-1], bounds[1:]))
        self.keys = np.ascontiguousarray(keys[order], np.int64)
        self.rotations = rotations[order]
        self.shifts = shifts[order]
        self.offsets, self.near, self.distances = offsets, lists, distances


_NO_LISTS = kb.PairLists(
    skin=0.0,
    slot=np.zeros(0, np.int64),
    rotations=np.zeros((0, 3, 3)),
    shifts=np.zeros((0, 3)),
    offsets=np.zeros(1, np.int64),
    near=np.zeros((0, 2), np.int64),
    distances=np.zeros(0),
)


class TreeBank:
    """Surrogate trees concatenated for batched queries, in one precision.

    Parameters
    ----------
    trees : sequence of SurrogateTree — referred to by position in queries
    precision : "float32" or "float64"

    Attributes
    ----------
    nodes : :class:`~engine.kernels.collision.batch.NodeBank` — every tree's node arrays
        concatenated (prepared triangles in ``precision``, float64 masters, ε, tree
        structure, face normals, bounding spheres)
    table : :class:`~engine.kernels.collision.batch.TreeTable` — per tree: its rows in
        ``nodes`` (node and face offsets and counts), leaf ε, bounding radius, extent
    """

    def __init__(self, trees: Sequence[SurrogateTree], precision: str = DEFAULT_PRECISION) -> None:
        check_precision(precision)
        trees = list(trees)
        if not trees:
            raise InvalidArgumentError("a TreeBank needs at least one tree")
        for t, tree in enumerate(trees):
            if not isinstance(tree, SurrogateTree):
                raise InvalidArgumentError(f"trees[{t}] must be a SurrogateTree")
        self.trees, self.precision = trees, precision
        self.dtype = np.dtype(precision).type
        sets = [t.views.geometry.node_set(precision, False) for t in trees]
        masters = [t.views.geometry.master for t in trees]
        epsilon = np.concatenate([t.epsilon for t in trees])
        self.nodes = kb.NodeBank(
            coords=np.concatenate([s.coords_rm for s in sets]),
            frames=np.concatenate([s.frames_rm for s in sets]),
            master_coords=np.concatenate([m.coords_rm for m in masters]),
            master_frames=np.concatenate([m.frames_rm for m in masters]),
            epsilon=epsilon,
            epsilon_query=epsilon.astype(self.dtype),
            face=np.concatenate([t.face for t in trees]),
            first_child=np.concatenate([t.first_child for t in trees]),
            child_count=np.concatenate([t.child_count for t in trees]),
            face_normals=np.concatenate([t.views.geometry.face_normals for t in trees]),
            spheres=np.concatenate([t.views.spheres for t in trees]),
        )
        nodes = np.array([len(t) for t in trees], np.int64)
        faces = np.array([len(t.views.geometry.face_normals) for t in trees], np.int64)
        self.table = kb.TreeTable(
            node_offset=np.concatenate([[0], np.cumsum(nodes)[:-1]]).astype(np.int64),
            node_count=nodes,
            face_offset=np.concatenate([[0], np.cumsum(faces)[:-1]]).astype(np.int64),
            face_count=faces,
            leaf_epsilon=np.array([t.leaf_epsilon for t in trees]),
            bounding_radius=np.array([t.bounding_radius for t in trees]),
            extent=np.array([t.views.geometry.extent for t in trees]),
        )

    def __len__(self) -> int:
        return len(self.trees)

    def find_contacts(
        self,
        tree_a: np.ndarray,
        position_a: np.ndarray,
        orientation_a: np.ndarray,
        tree_b: np.ndarray,
        position_b: np.ndarray,
        orientation_b: np.ndarray,
        kernel: str = "hybrid",
        threads: int | None = None,
        cache: PairCache | None = None,
        keys: np.ndarray | None = None,
    ) -> ContactBatch:
        """Multiresolution contacts of ``k`` body pairs.

        Parameters
        ----------
        tree_a, tree_b : (k,) int — bank positions of each pair's trees
        position_a, position_b : (k, 3) float64
        orientation_a, orientation_b : (k, 4) float64 — unit quaternions (w, x, y, z);
            norms within 1e-6 of 1 are renormalised
        kernel : "exact", "iterative" or "hybrid" — for leaf pairs
        threads : int, optional — worker threads (default: all cores)
        cache : PairCache, optional — lists kept between calls, with ``keys (k,)`` int64
            naming each pair (distinct); the cache then holds exactly these pairs

        Returns
        -------
        ContactBatch
        """
        check_kernel(kernel)
        k = _count(tree_a, "tree_a")
        if cache is not None:
            keys = np.asarray(keys)
            if keys.shape != (k,) or (k and not np.issubdtype(keys.dtype, np.integer)):
                raise InvalidArgumentError(f"keys must be {k} integers naming the pairs")
            keys = keys.astype(np.int64)
            if len(np.unique(keys)) != k:
                raise InvalidArgumentError("keys must be distinct")
        queries = kb.PairQueries(
            tree_a=_indices(tree_a, k, len(self), "tree_a"),
            tree_b=_indices(tree_b, k, len(self), "tree_b"),
            position_a=check_rows(position_a, k, 3, "position_a"),
            orientation_a=check_quaternions(orientation_a, k, "orientation_a"),
            position_b=check_rows(position_b, k, 3, "position_b"),
            orientation_b=check_quaternions(orientation_b, k, "orientation_b"),
        )
        return self.run(queries, kernel, threads, cache, keys)

    def run(
        self,
        queries: tuple,
        kernel: str,
        threads: int | None,
        cache=None,
        keys=None,
        keep_pairs: bool = True,
    ):
        """Run queries that are already valid (:meth:`find_contacts` checks them; the
        scene's own arrays are valid by construction), optionally through a
        :class:`PairCache` under ``keys (k,) int64``. ``queries``: a
        :class:`~engine.kernels.collision.batch.PairQueries`, or its six arrays in order.
        ``keep_pairs=False`` counts the face pairs (``pair_offsets``) without writing them
        (``pairs`` then raises): a scene step reads only their count."""
        queries = kb.PairQueries(*queries)
        k = len(queries.tree_a)
        slots = None if cache is None else cache._slots(keys)
        lists = _NO_LISTS if cache is None else cache._lists(slots)
        surrogate, leaf = query_parameters(kernel, self.dtype)
        params = kb.QueryParams(
            surrogate=surrogate,
            leaf=leaf,
            keep_all=kernel != "iterative",
            ulp=ULP[self.dtype],
            tiny=TINY,
            keep_pairs=bool(keep_pairs),
        )
        # written in full by the chunks, in their threads (the grid's 71,168 pairs: 22 MB,
        # zeroed here serially, was 3 ms an evaluation)
        counts = np.empty((k, kb.N_COUNTS), np.int64)
        levels = np.empty((k, MAX_LEVELS), np.int64)

        def chunk(start: int, stop: int):
            return kb.batch_kernel(
                self.nodes,
                self.table,
                queries,
                params,
                lists,
                start,
                stop,
                counts[start:stop],
                levels[start:stop],
            )

        threads = int(threads or _CPUS)
        if threads == 1 or k < 2 * _PAIRS_PER_TASK:
            parts = [chunk(0, k)]
        else:
            bounds = np.linspace(0, k, min(k // _PAIRS_PER_TASK, 4 * threads) + 1).astype(int)
            pool = worker_pool(threads)
            futures = [
                pool.submit(chunk, int(s), int(e))
                for s, e in zip(bounds[:-1], bounds[1:], strict=True)
            ]
            parts = [f.result() for f in futures]
        joined = _join(parts)
        if cache is not None:
            cache._replace(keys, slots, counts[:, kb.COUNT_LISTED] == 1, joined, parts, threads)
        return ContactBatch(
            joined.pair_offsets,
            tuple(part.pairs for part in parts) if keep_pairs else (),
            joined.contact_offsets,
            joined.points,
            joined.normals,
            joined.overlaps,
            levels,
            counts,
        )


def find_contacts_batch(
    queries: Sequence[tuple[SurrogateTree, Pose, SurrogateTree, Pose]],
    kernel: str = "hybrid",
    hierarchy: bool = True,
    precision: str = DEFAULT_PRECISION,
    threads: int | None = None,
) -> list[ContactSet]:
    """:func:`~engine.collision.find_contacts` for many ``(tree_a, pose_a, tree_b, pose_b)``.

    With ``hierarchy=True`` the pairs run in Numba over a :class:`TreeBank` of the
    distinct trees (worker threads); ``hierarchy=False`` runs the flat search pair by
    pair. Returns one :class:`~engine.collision.contacts.ContactSet` per query, in order.
    """
    check_kernel(kernel), check_precision(precision)
    queries = list(queries)
    for q, item in enumerate(queries):
        ok = isinstance(item, tuple | list) and len(item) == 4
        if not (ok and all(isinstance(x, Pose) for x in item[1::2])) or not all(
            isinstance(x, SurrogateTree) for x in item[::2]
        ):
            raise InvalidArgumentError(f"queries[{q}] must be (tree_a, pose_a, tree_b, pose_b)")
    if not hierarchy:
        return [
            find_contacts(*item, kernel=kernel, hierarchy=False, precision=precision)
            for item in queries
        ]
    if not queries:
        return []
    index: dict[int, int] = {}
    trees = []
    for item in queries:
        for tree in item[::2]:
            if id(tree) not in index:
                index[id(tree)] = len(trees)
                trees.append(tree)
    bank = TreeBank(trees, precision)
    # poses are validated and normalised already: passed on bit for bit, as the single
    # query passes them
    arrays = kb.PairQueries(
        tree_a=np.array([index[id(item[0])] for item in queries], np.int64),
        tree_b=np.array([index[id(item[2])] for item in queries], np.int64),
        position_a=np.array([item[1].position for item in queries]),
        orientation_a=np.array([item[1].orientation for item in queries]),
        position_b=np.array([item[3].position for item in queries]),
        orientation_b=np.array([item[3].orientation for item in queries]),
    )
    batch = bank.run(arrays, kernel, threads)
    return [batch[q] for q in range(len(batch))]


def _join(parts: list[kb.BatchResult]) -> kb.BatchResult:
    """The results of consecutive chunks of queries as one (one chunk: as it is), except
    ``pairs``, ``near``, ``near_distances``, ``rotations`` and ``shifts``, left empty:
    :class:`ContactBatch` keeps the chunks' own pairs, and :meth:`PairCache._replace`
    joins the lists and their poses only where it needs them (the paper's "aligned" grid
    makes 32 M rows of lists; in a steady step every list is kept)."""
    if len(parts) == 1:
        return parts[0]
    left = {
        "pairs": np.zeros((0, 2), np.int64),
        "near": np.zeros((0, 2), np.int64),
        "near_distances": np.zeros(0),
        "rotations": np.zeros((0, 3, 3)),
        "shifts": np.zeros((0, 3)),
    }
    return kb.BatchResult(
        *(
            _offsets([getattr(p, name) for p in parts])
            if name.endswith("_offsets")
            else left[name]
            if name in left
            else np.concatenate([getattr(p, name) for p in parts])
            for name in kb.BatchResult._fields
        )
    )


_PARALLEL_JOIN = 1 << 24
"""Bytes from which :func:`_joined` copies the chunks on the worker threads. Most of a
large join's time is first-touch page faults of the new array (the "aligned" grid's first
lists, 770 MB: 1.7 s of a 8.1 s step on the 2-vCPU VM of BENCHMARKS.md, where a copy into
memory already touched takes 0.04 s); they proceed in parallel."""


def _joined(chunks: list[np.ndarray], pool=None) -> np.ndarray:
    """The chunks' rows as one array (one chunk: itself), copied on the threads of
    ``pool`` (a ThreadPoolExecutor; numpy copies without the GIL) when it is given and
    the rows are at least :data:`_PARALLEL_JOIN` bytes."""
    if len(chunks) == 1:
        return chunks[0]
    if pool is None or sum(c.nbytes for c in chunks) < _PARALLEL_JOIN:
        return np.concatenate(chunks)
    rows = np.cumsum([0] + [len(c) for c in chunks])
    out = np.empty((int(rows[-1]), *chunks[0].shape[1:]), chunks[0].dtype)

    def copy(i: int) -> None:
        out[rows[i] : rows[i + 1]] = chunks[i]

    list(pool.map(copy, range(len(chunks))))
    return out


def _offsets(chunks: list[np.ndarray]) -> np.ndarray:
    """(k + 1,) int64 CSR offsets of consecutive chunks' offsets (each from 0)."""
    out = [np.zeros(1, np.int64)]
    for offsets in chunks:
        out.append(offsets[1:] + out[-1][-1])
    return np.concatenate(out)


def _count(values, name: str) -> int:
    arr = np.asarray(values)
    if arr.ndim != 1:
        raise InvalidArgumentError(f"{name} must be a 1-D array of tree positions")
    return len(arr)


def _indices(values, k: int, n: int, name: str) -> np.ndarray:
    arr = np.asarray(values)
    if arr.shape != (k,) or (k and not np.issubdtype(arr.dtype, np.integer)):
        raise InvalidArgumentError(f"{name} must be {k} integer tree positions")
    if k and (arr.min() < 0 or arr.max() >= n):
        raise InvalidArgumentError(f"{name} refers to a tree outside the bank (0 … {n - 1})")
    return np.ascontiguousarray(arr, dtype=np.int64)
