"""Building a surrogate tree (paper §4, Appendix B) from a mesh.

A node covering more than ``branching`` triangles is split by seeded k-means on triangle
centroids into ``branching`` compact groups, each with its own surrogate node; a node
covering at most ``branching`` triangles has the original triangles as its children
(leaves). Each surrogate's ε is conservative (:mod:`engine.trees.tree`); the distances
come from the exact closest point on the surrogate (Ericson's regions).

Surrogate construction (:mod:`engine.trees.surrogates`): the initial triangle is the smallest
enclosing equilateral triangle of the covered vertices in their mid-height PCA plane
(24 orientations), whose ε is the half-thickness of the group. It is then **fitted** by
minimising the Appendix-A functional (``fit="epsilon"``, the default: soft maximum of the
distances from the covered vertices to the surrogate, plus a weighted copy of the
paper's surrogate-to-covered term that keeps the triangle small, plus the area
regulariser; see :data:`engine.trees.surrogates.FITS`). The fitted triangle replaces the
initial one only if its ε-region — 2·area·ε + perimeter·πε²/2 + 4/3·πε³ with its exact
conservative ε — is not larger, so fitting never makes a node worse. ``fit="paper"``
minimises the paper's literal functional instead, ``fit="initial"`` keeps the initial
triangle. Randomness is keyed on the seed and the node: equal inputs and seed give
identical trees, on any number of threads.

The build is level-synchronous (:mod:`engine.kernels.trees.tree_build`): per level, one
k-means kernel call and one surrogate kernel call per worker thread, each over a range
of the level's nodes; no Python work per node (docs/trees.md, "How a tree is built").
The result is a :class:`~engine.trees.tree.SurrogateTree` in breadth-first order.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from engine.errors import InvalidArgumentError
from engine.geometry.mesh import Mesh
from engine.kernels.trees import tree_build as tb
from engine.trees.surrogates import DEFAULT_FIT, FitParameters, resolve_fit
from engine.trees.tree import SurrogateTree

__all__ = ["build_tree"]

_KMEANS_ITERATIONS = 20
_FIT_SAMPLE = 128  # a large group's fit: its 128 farthest covered vertices + 128 drawn
_MAX_THREADS = 8
_PAIR_SAMPLE = 128  # and likewise of its vertex-triangle pairs (the size term)


def build_tree(
    mesh: Mesh,
    epsilon: float,
    branching: int = 8,
    seed: int = 0,
    fit: str | FitParameters = DEFAULT_FIT,
    *,
    progress: Callable[[int, int], None] | None = None,
    threads: int | None = None,
) -> SurrogateTree:
    """Build the surrogate tree of ``mesh``.

    Parameters
    ----------
    mesh : Mesh
    epsilon : float — ε of the original triangles (the body's halo), ≥ 0
    branching : int — surrogates per split and most leaves per node (N_surrogate), ≥ 2
    seed : int in [0, 2**53) — of k-means and the fit's samples; equal inputs give
        identical trees
    fit : str or FitParameters — surrogate construction: a key of
        :data:`engine.trees.surrogates.FITS` ("epsilon", fitted, the default; "paper", the
        paper's literal functional; "initial", the enclosing triangle unfitted) or
        parameters of the functional
    progress : callable, optional — ``progress(levels_done, nodes_done)`` after each
        finished level, on the calling thread (levels_done counts the root's as 1)
    threads : int, optional — worker threads (default: the cores, at most 8); the tree
        does not depend on it

    Returns
    -------
    SurrogateTree
    """
    if not isinstance(mesh, Mesh):
        raise InvalidArgumentError(f"mesh must be an engine.Mesh, got {type(mesh).__name__}")
    if not (np.isfinite(epsilon) and epsilon >= 0):
        raise InvalidArgumentError(f"epsilon must be finite and non-negative, got {epsilon!r}")
    if isinstance(branching, bool) or not isinstance(branching, int | np.integer) or branching < 2:
        raise InvalidArgumentError(f"branching must be an integer >= 2, got {branching!r}")
    if isinstance(seed, bool) or not isinstance(seed, int | np.integer) or not 0 <= seed < 2**53:
        raise InvalidArgumentError(f"seed must be an integer in [0, 2**53), got {seed!r}")
    params = resolve_fit(fit)
    threads = _threads(threads)
    tris = mesh.triangles
    builder = _LevelBuilder(mesh, float(epsilon), int(branching), int(seed), params, threads)
    arrays = builder.run(progress)
    verts = tris.reshape(-1, 3)
    radius = float(np.linalg.norm(verts - verts.mean(axis=0), axis=1).max())
    return SurrogateTree(arrays, epsilon, branching, seed, radius)


def _threads(threads: int | None) -> int:
    if threads is None:
        return max(1, min(len(os.sched_getaffinity(0)), _MAX_THREADS))
    if isinstance(threads, bool) or not isinstance(threads, int | np.integer) or threads < 1:
        raise InvalidArgumentError(f"threads must be an integer >= 1, got {threads!r}")
    return int(threads)


def _chunks(work: np.ndarray, parts: int) -> list[tuple[int, int]]:
    """Split ``range(len(work))`` into at most ``parts`` contiguous ranges of about equal
    summed ``work``."""
    n = len(work)
    if n == 0:
        return []
    if parts <= 1 or n == 1:
        return [(0, n)]
    total = np.cumsum(work, dtype=np.float64)
    cuts = np.searchsorted(total, total[-1] * np.arange(1, parts) / parts, side="right")
    bounds = np.unique(np.concatenate([[0], np.clip(cuts, 1, n - 1), [n]]))
    return list(zip(bounds[:-1].tolist(), bounds[1:].tolist(), strict=True))


class _LevelBuilder:
    """One tree build, a level per step: the nodes of a level are split (k-means) and
    their groups get surrogates, each in Numba kernels over ranges of nodes spread on
    ``threads`` worker threads (the kernels release the GIL)."""

    def __init__(self, mesh, epsilon, branching, seed, params, threads) -> None:
        self.vertices = mesh.vertices
        self.faces = mesh.faces
        self.tris = np.ascontiguousarray(mesh.triangles)
        self.centroids = self.tris.mean(axis=1)
        self.epsilon, self.branching, self.seed = epsilon, branching, seed
        self.params = params
        self.threads = threads
        self.marks = [np.zeros(len(self.vertices), np.int64) for _ in range(threads)]
        self.pool = ThreadPoolExecutor(threads) if threads > 1 else None

    def _spread(self, work: np.ndarray, call) -> None:
        """``call(lo, hi, thread)`` over ranges of about equal ``work``, one per thread."""
        ranges = _chunks(work, self.threads)
        if self.pool is None or len(ranges) <= 1:
            for lo, hi in ranges:
                call(lo, hi, 0)
            return
        futures = [self.pool.submit(call, lo, hi, t) for t, (lo, hi) in enumerate(ranges)]
        for future in futures:
            future.result()

    def _surrogates(self, order, starts, counts, node_ids) -> tuple[np.ndarray, np.ndarray]:
        n = len(starts)
        out_tris = np.empty((n, 3, 3))
        out_eps = np.empty(n)
        p = self.params
        fit = p is not None
        values = p.array if fit else np.zeros(6)
        iterations = int(p.iterations) if fit else 0
        history = int(p.history) if fit else 1
        tolerance = float(p.tolerance) if fit else 0.0

        def call(lo, hi, thread):
            tb.surrogate_nodes(
                self.vertices, self.faces, self.tris, order, starts, counts, node_ids,
                self.epsilon, values, fit, iterations, history, tolerance, _FIT_SAMPLE,
                _PAIR_SAMPLE, self.seed, lo, hi, self.marks[thread], out_tris, out_eps,
            )  # fmt: skip

        self._spread(np.minimum(counts, 4 * _FIT_SAMPLE) + 8, call)
        return out_tris, out_eps

    def run(self, progress) -> dict[str, np.ndarray]:
        try:
            return self._run(progress)
        finally:
            if self.pool is not None:
                self.pool.shutdown()

    def _run(self, progress) -> dict[str, np.ndarray]:
        n_faces, k = len(self.tris), self.branching
        order = np.arange(n_faces, dtype=np.int64)
        zero = np.zeros(1, np.int64)
        root_tri, root_eps = self._surrogates(order, zero, np.array([n_faces]), zero)
        levels = [
            {
                "triangles": root_tri,
                "epsilon": root_eps,
                "parent": np.array([-1], np.int64),
                "face": np.array([-1], np.int64),
            }
        ]
        # the surrogates of the newest level: tree index, segment of `order`
        ids, starts, counts = zero.copy(), zero.copy(), np.array([n_faces], np.int64)
        parents = []  # per level: (node ids, first child, child count)
        next_id = 1
        while len(ids):
            split = counts > k
            order_next = order.copy()
            groups = np.zeros((len(ids), k), np.int64)
            s_idx = np.flatnonzero(split)
            if len(s_idx):
                s_starts, s_counts = starts[s_idx], counts[s_idx]
                s_ids = ids[s_idx]
                s_groups = np.zeros((len(s_idx), k), np.int64)

                def call(lo, hi, thread, s_starts=s_starts, s_counts=s_counts, s_ids=s_ids,
                         s_groups=s_groups, order=order, order_next=order_next):  # fmt: skip
                    tb.split_nodes(
                        self.centroids, order, s_starts, s_counts, s_ids, k,
                        _KMEANS_ITERATIONS, self.seed, lo, hi, order_next, s_groups,
                    )  # fmt: skip

                self._spread(s_counts * k, call)
                groups[s_idx] = s_groups
            order = order_next
            # children per node: its faces as leaves (not split) or its non-empty groups
            n_children = np.where(split, (groups > 0).sum(axis=1), counts)
            child_parent = np.repeat(ids, n_children)
            first = next_id + np.concatenate([[0], np.cumsum(n_children)[:-1]])
            parents.append((ids, first, n_children))
            # segment of each child within its parent's segment
            sizes = _child_sizes(split, groups, counts, n_children)
            child_start = np.repeat(starts, n_children) + _within(sizes, n_children)
            is_leaf = np.repeat(~split, n_children)
            n_new = len(child_parent)
            tri = np.empty((n_new, 3, 3))
            eps = np.empty(n_new)
            face = np.full(n_new, -1, np.int64)
            leaf_faces = order[child_start[is_leaf]]
            tri[is_leaf] = self.tris[leaf_faces]
            eps[is_leaf] = self.epsilon
            face[is_leaf] = leaf_faces
            child_ids = next_id + np.arange(n_new, dtype=np.int64)
            sur = ~is_leaf
            if sur.any():
                tri[sur], eps[sur] = self._surrogates(
                    order, child_start[sur], sizes[sur], child_ids[sur]
                )
            levels.append({"triangles": tri, "epsilon": eps, "parent": child_parent, "face": face})
            next_id += n_new
            ids, starts, counts = child_ids[sur], child_start[sur], sizes[sur]
            if progress is not None:
                progress(len(levels), next_id)  # levels 0 … now all have their nodes
        n = next_id
        arrays = {
            "triangles": np.concatenate([lv["triangles"] for lv in levels]),
            "epsilon": np.concatenate([lv["epsilon"] for lv in levels]),
            "level": np.repeat(
                np.arange(len(levels), dtype=np.int32), [len(lv["face"]) for lv in levels]
            ),
            "parent": np.concatenate([lv["parent"] for lv in levels]).astype(np.int32),
            "face": np.concatenate([lv["face"] for lv in levels]).astype(np.int32),
        }
        fc = np.zeros(n, np.int32)
        cc = np.zeros(n, np.int32)
        for ids, first, n_children in parents:
            fc[ids], cc[ids] = first, n_children
        arrays["first_child"], arrays["child_count"] = fc, cc
        return arrays


def _child_sizes(split, groups, counts, n_children) -> np.ndarray:
    """Faces covered by each child, children in node order: 1 for a leaf, the group size
    for a surrogate (the non-empty groups come first in ``groups``)."""
    sizes = np.ones(int(n_children.sum()), np.int64)
    node_of = np.repeat(np.arange(len(counts)), n_children)
    rank = _within(np.ones(len(sizes), np.int64), n_children)
    take = split[node_of]
    sizes[take] = groups[node_of[take], rank[take]]
    return sizes


def _within(sizes: np.ndarray, n_children: np.ndarray) -> np.ndarray:
    """Exclusive prefix sum of ``sizes`` restarted at each node's first child."""
    total = np.cumsum(sizes) - sizes
    first = np.concatenate([[0], np.cumsum(n_children)[:-1]])
    return total - np.repeat(total[first[n_children > 0]], n_children[n_children > 0])
