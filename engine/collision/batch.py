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
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from engine.arguments import check_kernel, check_precision, check_quaternions, check_rows
from engine.collision.contacts import ContactSet, ContactStats, find_contacts
from engine.collision.pair_cache import NO_LISTS, PairCache, joined_offsets
from engine.collision.query import TINY, ULP, query_parameters
from engine.errors import InvalidArgumentError
from engine.geometry.distance import DEFAULT_PRECISION
from engine.geometry.pose import Pose
from engine.kernels.collision import batch as kb
from engine.trees.tree import SurrogateTree
from engine.workers import CPUS, worker_pool

__all__ = ["ContactBatch", "TreeBank", "find_contacts_batch"]

MAX_LEVELS = 32
"""Per-level comparison counts kept per pair (deeper levels are counted, not kept)."""
_PAIRS_PER_TASK = 256
"""Below this many pairs per worker, the pairs are not dealt out in chunks to the worker
threads. Most pairs of a scene can be cheap (a body and a far wall: an empty list, issue
16): the 48-object pile's 330 pairs took 1.00–1.08 ms a search on 2 threads in 5 chunks of
64 pairs, 0.65 ms in one chunk, and its 1.5 s run went from 8.78 to 7.07 s. Fewer pairs are
searched in one chunk, or in two halves of equal listed work (:data:`SPLIT_ENTRIES`)."""
SPLIT_ENTRIES = 3000
"""A search of fewer than 2 × :data:`_PAIRS_PER_TASK` pairs, on two threads or more, whose
pair cache lists at least this many leaf pairs for them is split in two halves of about
equal work, the first run on the calling thread and the second on a worker (one hand-off:
the worker started 5 µs after the caller on the 2-vCPU VM of BENCHMARKS.md in issue 16's
seventh session, 60–75 µs in its eighth, when a sleeping vCPU woke slowly; worker chunks
that all went to the pool started 0.1–1.0 ms after the search began). Work is estimated
from the lists: a pair's listed leaf pairs, plus :data:`_QUERY_ENTRIES`, or
:data:`_NEW_PAIR_ENTRIES` for a pair without a list. On the 48-object pile (issue 16,
seventh session) the first search of a falling step went from 1.62 to 1.15 ms, and seed 1's
whole 3 s run from 10.8 to 9.9 s (seed 4's from 13.0 to 11.7 s with the threshold at 2,000;
at 1,000 the smaller searches split as well and seed 1 took 10.2 s)."""
SPLIT_COMPARISONS = 4000
"""… and only after a search that renewed the cache with at least this many triangle
comparisons (``PairCache.comparisons``): the falling pile's first search of a step makes
about 5,800, a settled pile's 2,300, whose lists are long (4,200 leaf pairs) but mostly
skipped before any arithmetic. With this gate the settled search stayed whole, 0.51 against
0.55 ms split, and the falling one split, 1.31 against 1.39 ms (second searches 0.32 against
0.36 ms), on one window each."""
_QUERY_ENTRIES = 4  # a query's own work (pose, root test), in listed leaf pairs
_NEW_PAIR_ENTRIES = 64  # a pair without a list: traversed, its work unknown
# chunks of pairs a worker thread takes in turn, on average (on the grid with 16 threads, 4
# kept 12.9-13.8 threads busy and 8 kept 14.2-14.9; BENCHMARKS.md, issue 15, thirteenth step)
_CHUNKS_PER_THREAD = 8


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
    totals : (7,) int64 — ``counts`` summed over the pairs (by the worker chunks)
    """

    pair_offsets: np.ndarray
    pair_chunks: tuple[np.ndarray, ...] = field(repr=False)
    contact_offsets: np.ndarray
    points: np.ndarray
    normals: np.ndarray
    overlaps: np.ndarray
    levels: np.ndarray
    counts: np.ndarray
    totals: np.ndarray

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
        return int(self.totals[kb.COUNT_COMPARISONS])

    @property
    def iterative(self) -> int:
        """Iterative triangle evaluations over all pairs."""
        return int(self.totals[kb.COUNT_ITERATIVE])

    @property
    def fallbacks(self) -> int:
        """Exact fallbacks of the iterative kernel over all pairs."""
        return int(self.totals[kb.COUNT_FALLBACKS])

    @property
    def sphere_pruned(self) -> int:
        """Node pairs pruned by bounding spheres or boxes over all pairs."""
        return int(self.totals[kb.COUNT_SPHERES])


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
            boxes=np.concatenate([t.views.boxes for t in trees]),
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
            radius=np.array([t.views.geometry.radius for t in trees]),
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
        read_only: bool = False,
    ):
        """Run queries that are already valid (:meth:`find_contacts` checks them; the
        scene's own arrays are valid by construction), optionally through a
        :class:`PairCache` under ``keys (k,) int64``. ``queries``: a
        :class:`~engine.kernels.collision.batch.PairQueries`, or its six arrays in order.
        ``keep_pairs=False`` counts the face pairs (``pair_offsets``) without writing them
        (``pairs`` then raises): a scene step reads only their count. ``read_only``: the
        cache's lists serve where they are valid, and it is left as it was (a search of
        some pairs only: the lists of the others stay)."""
        # read-only arrays (a Pose's) copied: Numba would compile the kernel once more
        queries = kb.PairQueries(*(a if a.flags.writeable else a.copy() for a in queries))
        k = len(queries.tree_a)
        threads = int(threads or CPUS)
        halves = threads > 1 and k < 2 * _PAIRS_PER_TASK
        if halves:
            bounds = _halves(cache, keys, k)
        elif threads == 1:
            bounds = np.array([0, k], np.int64)
        else:
            chunks = min(k // _PAIRS_PER_TASK, _CHUNKS_PER_THREAD * threads)
            bounds = np.linspace(0, k, chunks + 1).astype(np.int64)
        # the pairs and chunks of the cache's last search: chunk c reads and renews part c
        by_part = cache is not None and not read_only and cache._aligned(keys, bounds)
        if by_part:
            slots = np.arange(k, dtype=np.int64) - np.repeat(bounds[:-1], np.diff(bounds))
        else:
            slots = None if cache is None else cache._slots(keys)
            lists = NO_LISTS if cache is None else cache._lists(slots, threads)
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
        totals = np.empty((len(bounds) - 1, kb.N_COUNTS), np.int64)  # a row per chunk

        def chunk(c: int):
            start, stop = int(bounds[c]), int(bounds[c + 1])
            result = kb.batch_kernel(
                self.nodes,
                self.table,
                queries,
                params,
                cache._part(c, slots) if by_part else lists,
                start,
                stop,
                counts[start:stop],
                levels[start:stop],
            )
            kb.count_totals(counts[start:stop], totals[c])
            if by_part:
                cache._renew(c, counts[start:stop, kb.COUNT_LISTED] == 1, result)
            return result

        if len(bounds) == 2:
            parts = [chunk(0)]
        elif halves:  # the second half on a worker, the first here
            second = worker_pool(threads).submit(chunk, 1)
            parts = [chunk(0), second.result()]
        else:
            pool = worker_pool(threads)
            parts = [f.result() for f in [pool.submit(chunk, c) for c in range(len(bounds) - 1)]]
        joined = _join(parts)
        if cache is not None and not read_only:
            cache.comparisons = int(totals[:, kb.COUNT_COMPARISONS].sum())
        if cache is not None and not by_part and not read_only:
            kept = counts[:, kb.COUNT_LISTED] == 1
            cache._replace(keys, slots, kept, joined.near_offsets, parts, bounds, threads)
        return ContactBatch(
            joined.pair_offsets,
            tuple(part.pairs for part in parts) if keep_pairs else (),
            joined.contact_offsets,
            joined.points,
            joined.normals,
            joined.overlaps,
            levels,
            counts,
            totals.sum(axis=0),
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


def _halves(cache: PairCache | None, keys, k: int) -> np.ndarray:
    """Query bounds ``(2,)`` or ``(3,)`` int64: one chunk, or two halves of about equal
    work when ``cache`` lists at least :data:`SPLIT_ENTRIES` leaf pairs for the ``k`` pairs
    ``keys`` and its last renewal made :data:`SPLIT_COMPARISONS` comparisons."""
    if cache is None or keys is None or k < 2 or cache.comparisons < SPLIT_COMPARISONS:
        return np.array([0, k], np.int64)
    sizes = cache.sizes(keys)
    if int(np.maximum(sizes, 0).sum()) < SPLIT_ENTRIES:
        return np.array([0, k], np.int64)
    work = np.cumsum(np.where(sizes < 0, _NEW_PAIR_ENTRIES, sizes) + _QUERY_ENTRIES)
    cut = min(max(int(np.searchsorted(work, 0.5 * work[-1])) + 1, 1), k - 1)
    return np.array([0, cut, k], np.int64)


def _join(parts: list[kb.BatchResult]) -> kb.BatchResult:
    """The results of consecutive chunks of queries as one (one chunk: as it is), except
    ``pairs``, ``near``, ``near_distances``, ``rotations`` and ``shifts``, left empty:
    :class:`ContactBatch` keeps the chunks' own pairs, and the :class:`PairCache` keeps the
    chunks' lists and poses as parts (the paper's "aligned" grid makes 32 M rows of
    lists; in a steady step every list is kept)."""
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
            joined_offsets([getattr(p, name) for p in parts])
            if name.endswith("_offsets")
            else left[name]
            if name in left
            else np.concatenate([getattr(p, name) for p in parts])
            for name in kb.BatchResult._fields
        )
    )


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
