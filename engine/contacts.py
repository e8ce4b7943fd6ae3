"""Contact detection between two posed bodies (paper §2, §5.1): flat and multiresolution.

Every query runs in body A's frame (a pair-local frame): B's tree is moved by the
relative pose ``pose_a⁻¹ ∘ pose_b``, so coordinates stay small wherever the bodies are.

Multiresolution search (``hierarchy=True``) keeps a **front of node pairs**, starting
at the two roots, and streams each level's front through one listed kernel call:

* a pair with a surrogate is evaluated with the iterative kernel (exact if
  ``kernel="exact"``); "no contact" prunes both subtrees, "contact" or "not
  converged" unfolds the node with the larger ε (a leaf is never unfolded);
* a leaf–leaf pair is evaluated with ``kernel`` (hybrid: exact for not-converged).

Surrogate ε carries a small safety margin at query time (a few hundred ulp of the
pair's scale) so that rounding can never prune a pair the flat search reports;
leaf–leaf evaluations are bit-identical to the flat search's. Hence (Lemma 1) the
finest-level contact pairs equal those of the flat search, pair for pair.

Contacts: for a leaf pair with closest points p (on A), q (on B) at distance d, the
point is on the segment p→q weighted by the ε's (midpoint for equal ε), the normal
points from A to B ((q − p)/d, or A's face normal when d ≈ 0), and the overlap is
ε_a + ε_b − d. Points of one body pair closer than the smaller ε are merged into
their average (normals averaged and renormalised, overlaps averaged).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .arguments import KERNELS, check_kernel, check_precision, kernel_constants
from .distance import (
    DEFAULT_ITERATIONS,
    DEFAULT_RTOL,
    TriangleSet,
    _contact_buffers,
    triangle_contacts,
)
from .errors import InvalidArgumentError
from .kernels import triangle_batch as tb
from .kernels.contact_merge import merge_kernel
from .kernels.traversal import traverse_kernel
from .pose import Pose
from .tree import SurrogateTree

__all__ = ["ContactSet", "ContactStats", "find_contacts"]

_MARGIN_ULPS = 256


@dataclass(frozen=True)
class ContactStats:
    """Counters of one query.

    comparisons_per_level : triangle pairs evaluated per front level (one entry, all
        leaf pairs, for the flat search)
    iterative, fallbacks : iterative evaluations and exact fallbacks
    unfoldings : node pairs unfolded
    raw_contacts, merged_contacts : contact points before and after merging
    """

    comparisons_per_level: tuple[int, ...] = ()
    iterative: int = 0
    fallbacks: int = 0
    unfoldings: int = 0
    raw_contacts: int = 0
    merged_contacts: int = 0

    @property
    def comparisons(self) -> int:
        return sum(self.comparisons_per_level)


@dataclass(frozen=True)
class ContactSet:
    """Contacts between two bodies, in the world frame.

    pairs : (m, 2) int64 — (face of A, face of B) in contact, before merging, sorted
    points : (k, 3) float64 — merged contact points
    normals : (k, 3) float64 — unit, from A to B
    overlaps : (k,) float64 — ε_a + ε_b − d, in [0, ε_a + ε_b]
    stats : ContactStats
    """

    pairs: np.ndarray
    points: np.ndarray
    normals: np.ndarray
    overlaps: np.ndarray
    stats: ContactStats = field(default_factory=ContactStats)


def find_contacts(
    tree_a: SurrogateTree,
    pose_a: Pose,
    tree_b: SurrogateTree,
    pose_b: Pose,
    kernel: str = "hybrid",
    hierarchy: bool = True,
    precision: str = "float64",
    traversal: str = "pairs",
) -> ContactSet:
    """Contacts between body A (``tree_a`` at ``pose_a``) and body B.

    Parameters
    ----------
    tree_a, tree_b : SurrogateTree — the bodies' trees (body frames); ε of the leaves
        is each body's halo
    pose_a, pose_b : Pose
    kernel : "exact", "iterative" or "hybrid" — for leaf pairs ("iterative" then
        reports only certified contacts)
    hierarchy : bool — multiresolution search; False runs the flat search over all
        leaf pairs
    precision : "float32" or "float64"
    traversal : "pairs" — a front of node pairs, one Numba kernel per query (default);
        "sets" — the paper's Algorithm 5: every pair of two active node sets per round
        (driven from Python; for comparison, see BENCHMARKS.md)

    Returns
    -------
    ContactSet
    """
    for name, tree in (("tree_a", tree_a), ("tree_b", tree_b)):
        if not isinstance(tree, SurrogateTree):
            raise InvalidArgumentError(f"{name} must be a SurrogateTree")
    for name, pose in (("pose_a", pose_a), ("pose_b", pose_b)):
        if not isinstance(pose, Pose):
            raise InvalidArgumentError(f"{name} must be a Pose")
    check_kernel(kernel), check_precision(precision)  # validate before any work
    relative = pose_a.inverse().compose(pose_b)
    if traversal not in ("pairs", "sets"):
        raise InvalidArgumentError(f"traversal must be 'pairs' or 'sets', got {traversal!r}")
    if hierarchy and traversal == "sets":
        pairs, res, stats = _active_sets(tree_a, tree_b, relative, kernel, precision)
    elif hierarchy:
        pairs, res, stats = _hierarchical(tree_a, tree_b, relative, kernel, precision)
    else:
        pairs, res, stats = _flat(tree_a, tree_b, relative, kernel, precision)
    contact = res.status == 1 if kernel == "iterative" else np.ones(len(pairs), bool)
    pairs, distance = pairs[contact], res.distance[contact].astype(np.float64)
    p, q = res.point_a[contact].astype(np.float64), res.point_b[contact].astype(np.float64)
    order = np.lexsort((pairs[:, 1], pairs[:, 0]))
    pairs, distance, p, q = pairs[order], distance[order], p[order], q[order]
    points, normals, overlaps = _contact_points(tree_a, tree_b, pairs, distance, p, q)
    points, normals, overlaps = _merge(
        points, normals, overlaps, min(tree_a.leaf_epsilon, tree_b.leaf_epsilon)
    )
    stats = ContactStats(stats[0], stats[1], stats[2], stats[3], len(pairs), len(points))
    rot = pose_a.rotation
    return ContactSet(pairs, points @ rot.T + pose_a.position, normals @ rot.T, overlaps, stats)


def _face_nodes(tree: SurrogateTree) -> np.ndarray:
    """(F,) node index of each face's leaf."""
    if "_face_nodes" not in tree.__dict__:
        leaves = np.flatnonzero(tree.face >= 0)
        tree.__dict__["_face_nodes"] = leaves[np.argsort(tree.face[leaves])]
    return tree.__dict__["_face_nodes"]


def _master(tree: SurrogateTree) -> TriangleSet:
    """All nodes of ``tree`` prepared in float64 (cached on the tree)."""
    if "_master" not in tree.__dict__:
        tree.__dict__["_master"] = TriangleSet(tree.triangles, "float64", "tree")
    return tree.__dict__["_master"]


def _flat(tree_a, tree_b, relative, kernel, precision):
    # B's leaves moved exactly as the hierarchical search moves them: leaf pairs are
    # then evaluated on bit-identical inputs by both searches
    sa = _master(tree_a).subset(_face_nodes(tree_a), precision)
    coords_b, frames_b = _moved_row_major(_master(tree_b), relative, np.dtype(precision).type)
    leaves = _face_nodes(tree_b)
    sb = TriangleSet.prepared(coords_b[leaves].T, frames_b[leaves].T)
    res = triangle_contacts(
        sa,
        sb,
        tree_a.leaf_epsilon,
        tree_b.leaf_epsilon,
        kernel=kernel,
        precision=precision,
        threads=1,
    )
    s = res.stats
    return res.pairs, res, ((s.pairs,), s.iterative, s.fallbacks, 0)


def _hierarchical(tree_a, tree_b, relative, kernel, precision):
    dtype = np.dtype(precision).type
    cache = tree_a.__dict__.setdefault("_node_sets", {})
    if precision not in cache:
        cache[precision] = _master(tree_a).subset(np.arange(len(tree_a)), precision)
    sa = cache[precision]
    coords_b, frames_b = _moved_row_major(_master(tree_b), relative, dtype)
    eps_a, eps_b = _node_epsilons(tree_a, tree_b, relative, precision)
    one, band = kernel_constants(dtype)
    iterations, rtol = np.int64(DEFAULT_ITERATIONS), dtype(DEFAULT_RTOL)
    coarse_mode = tb.EXACT if kernel == "exact" else tb.ITERATIVE
    coarse = (coarse_mode, iterations, rtol, one, band)
    leaf = (KERNELS[kernel], iterations, rtol, one, band)
    rm = (sa.coords_rm, sa.frames_rm, coords_b, frames_b)
    trees = [(t.face, t.first_child, t.child_count) for t in (tree_a, tree_b)]
    capacity = 1024 + 16 * max(len(tree_a), len(tree_b))
    while True:  # count, allocate, fill: a re-run only when the first guess was short
        out = _contact_buffers(capacity, dtype)
        stats = np.zeros(tb.N_STATS, np.int64)
        levels = np.zeros(64, np.int64)
        count, depth, unfoldings = traverse_kernel(
            rm, eps_a, eps_b, trees[0], trees[1], coarse, leaf, out, stats, levels
        )
        if count <= capacity:
            break
        capacity = count
    nodes = np.stack([out[0][:count], out[1][:count]], axis=1)
    faces = np.stack([tree_a.face[nodes[:, 0]], tree_b.face[nodes[:, 1]]], axis=1)
    per_level = tuple(int(x) for x in levels[: min(depth, len(levels))])
    counters = (
        per_level,
        int(stats[tb.STAT_ITERATIVE]),
        int(stats[tb.STAT_FALLBACKS]),
        int(unfoldings),
    )
    return faces.astype(np.int64), _Results(out, count), counters


def _moved_row_major(master: TriangleSet, pose: Pose, dtype) -> tuple[np.ndarray, np.ndarray]:
    """Row-major ``(N, 9)`` coordinates and ``(N, 14)`` frames of ``master`` moved by
    ``pose`` (frame vectors rotate, scalars stay), rounded to ``dtype`` in one pass."""
    rot = pose.rotation
    coords = master.coords_rm.reshape(-1, 3, 3) @ rot.T + pose.position
    frames = master.frames_rm.copy()
    frames[:, :9] = (master.frames_rm[:, :9].reshape(-1, 3, 3) @ rot.T).reshape(-1, 9)
    return (
        np.ascontiguousarray(coords.reshape(-1, 9), dtype=dtype),
        np.ascontiguousarray(frames, dtype=dtype),
    )


def _active_sets(tree_a, tree_b, relative, kernel, precision):
    """Algorithm 5: compare all pairs of the active sets; unfold both nodes of a hit."""
    dtype = np.dtype(precision).type
    sa = _master(tree_a).subset(np.arange(len(tree_a)), precision)
    coords_b, frames_b = _moved_row_major(_master(tree_b), relative, dtype)
    sb = TriangleSet.prepared(coords_b.T, frames_b.T)
    eps_a, eps_b = _node_epsilons(tree_a, tree_b, relative, precision)
    surrogate_kernel = "exact" if kernel == "exact" else "iterative"
    active_a, active_b = np.zeros(1, np.int64), np.zeros(1, np.int64)
    found, per_level, iterative, fallbacks, unfoldings = [], [], 0, 0, 0
    while len(active_a) and len(active_b):
        grid = np.stack(np.meshgrid(active_a, active_b, indexing="ij"), -1).reshape(-1, 2)
        per_level.append(len(grid))
        finest = (tree_a.face[grid[:, 0]] >= 0) & (tree_b.face[grid[:, 1]] >= 0)
        if finest.any():
            res = triangle_contacts(
                sa,
                sb,
                eps_a,
                eps_b,
                pairs=grid[finest],
                kernel=kernel,
                precision=precision,
                threads=1,
            )
            found.append(res)
            iterative, fallbacks = iterative + res.stats.iterative, fallbacks + res.stats.fallbacks
        res = triangle_contacts(
            sa,
            sb,
            eps_a,
            eps_b,
            pairs=grid[~finest],
            kernel=surrogate_kernel,
            precision=precision,
            threads=1,
        )
        iterative += res.stats.iterative
        hits = res.pairs
        unfoldings += len(hits)
        active_a = _unfold_set(tree_a, hits[:, 0])
        active_b = _unfold_set(tree_b, hits[:, 1])
    pairs = np.concatenate([r.pairs for r in found]) if found else np.zeros((0, 2), np.int64)
    first = np.unique(pairs, axis=0, return_index=True)[1]  # a leaf pair may recur
    out = _Stacked(found, first)
    faces = np.stack([tree_a.face[pairs[first, 0]], tree_b.face[pairs[first, 1]]], axis=1)
    return faces.astype(np.int64), out, (tuple(per_level), iterative, fallbacks, unfoldings)


def _unfold_set(tree, nodes: np.ndarray) -> np.ndarray:
    """Next active set: each leaf stays, each surrogate is replaced by its children."""
    nodes = np.unique(nodes)
    leaves = nodes[tree.face[nodes] >= 0]
    inner = nodes[tree.face[nodes] < 0]
    counts = tree.child_count[inner].astype(np.int64)
    starts = np.repeat(tree.first_child[inner].astype(np.int64), counts)
    children = starts + np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)
    return np.unique(np.concatenate([leaves, children]))


class _Stacked:
    """Per-pair arrays of several TriangleContacts results, concatenated, rows ``keep``."""

    def __init__(self, parts, keep) -> None:
        def cat(name, shape):
            arrays = [getattr(p, name) for p in parts]
            return (np.concatenate(arrays) if arrays else np.zeros(shape))[keep]

        self.distance = cat("distance", (0,))
        self.point_a = cat("point_a", (0, 3))
        self.point_b = cat("point_b", (0, 3))
        self.status = cat("status", (0,)).astype(np.int8)


def _node_epsilons(tree_a, tree_b, relative, precision):
    """Per-node ε with the safety margin on surrogates (see the module docstring)."""
    dtype = np.dtype(precision).type
    scale = 2 * (tree_a.bounding_radius + tree_b.bounding_radius) + np.linalg.norm(
        relative.position
    )
    margin = _MARGIN_ULPS * np.finfo(precision).eps * scale
    eps_a = (tree_a.epsilon + np.where(tree_a.face < 0, margin, 0.0)).astype(dtype)
    eps_b = (tree_b.epsilon + np.where(tree_b.face < 0, margin, 0.0)).astype(dtype)
    return eps_a, eps_b


class _Results:
    """Per-pair arrays of a kernel's output buffers, trimmed to ``count``."""

    def __init__(self, out, count: int) -> None:
        self.distance = out[2][:count]
        self.point_a = out[3][:, :count].T
        self.point_b = out[4][:, :count].T
        self.status = out[5][:count]


def _contact_points(tree_a, tree_b, pairs, distance, p, q):
    """Contact points, unit normals A→B and overlaps in A's frame, one per pair."""
    ea, eb = tree_a.leaf_epsilon, tree_b.leaf_epsilon
    weight = 0.5 if ea + eb == 0 else ea / (ea + eb)
    points = p + weight * (q - p)
    gap = q - p
    length = np.linalg.norm(gap, axis=1)
    tiny = 1e3 * np.finfo(np.float32).eps * max(tree_a.bounding_radius, tree_b.bounding_radius)
    face = tree_a.triangles[_face_nodes(tree_a)[pairs[:, 0]]]
    face_normal = np.cross(face[:, 1] - face[:, 0], face[:, 2] - face[:, 0])
    # decide on the points' own gap: a (float32) distance can be positive while the
    # two points round to the same coordinates
    normals = np.where((length > tiny)[:, None], gap, face_normal)
    normals = normals / np.linalg.norm(normals, axis=1, keepdims=True)
    overlaps = np.clip(ea + eb - distance, 0.0, ea + eb)
    return points, normals, overlaps


def _merge(points, normals, overlaps, radius):
    """Merge points closer than ``radius`` into their averages (greedy, deepest first):
    normals averaged and renormalised (a cancelling sum keeps the cluster's first normal),
    overlaps averaged."""
    if len(points) <= 1 or radius <= 0:
        return points, normals, overlaps
    order = np.argsort(-overlaps, kind="stable").astype(np.int64)
    label = np.empty(len(points), np.int64)
    centres = np.empty_like(points)
    n = merge_kernel(points, order, float(radius), label, centres)
    count = np.bincount(label, minlength=n)[:, None]
    merged_points = np.stack([np.bincount(label, points[:, c], n) for c in range(3)], 1) / count
    summed = np.stack([np.bincount(label, normals[:, c], n) for c in range(3)], 1)
    norms = np.linalg.norm(summed, axis=1, keepdims=True)
    first = np.empty((n, 3))
    first[label[order[::-1]]] = normals[order[::-1]]  # the first visited point wins
    merged_normals = np.where(norms > 1e-12, summed / np.where(norms > 0, norms, 1), first)
    merged_overlaps = np.bincount(label, overlaps, n) / count[:, 0]
    return merged_points, merged_normals, merged_overlaps
