"""Contact detection between two posed bodies (paper §2, §5.1): flat and multiresolution.

Every query runs in body A's frame (a pair-local frame): B's tree is moved by the
relative pose ``pose_a⁻¹ ∘ pose_b``, so coordinates stay small wherever the bodies are.

Multiresolution search (``hierarchy=True``, ``traversal="pairs"``) keeps a **front of
node pairs**, starting at the two roots, inside one Numba call with flat arguments
(:func:`~engine.kernels.collision.pair_query.pair_query`: relative pose, margin,
traversal and merged contacts; the per-tree arguments are cached on ``tree.views``), a
level per round — unless the node bounds alone show the bodies apart (:func:`far_apart`,
on the host, one bounds-only search that the kernel then skips):

* a node pair whose bounding spheres (:attr:`~engine.trees.views.TreeViews.spheres`) are
  apart, or else whose oriented bounding boxes
  (:attr:`~engine.trees.views.TreeViews.boxes`) are, is pruned before any triangle
  comparison;
* a pair with a surrogate is evaluated with the iterative kernel (exact if
  ``kernel="exact"``); "no contact" prunes both subtrees, "contact" or "not converged"
  replaces it by its child pairs — every surrogate of the pair unfolds, a leaf stays
  (the unfold rule, :mod:`engine.collision.query`);
* the leaf–leaf pairs reached are evaluated together at the end with ``kernel``
  (hybrid: exact for the not-converged).

``traversal="sets"`` runs the paper's Algorithm 5 instead (every pair of two active node
sets per round, driven from Python); ``hierarchy=False`` the flat search over all leaf
pairs. All three find the same leaf pairs.

Surrogate ε carries a small safety margin at query time (a few hundred ulp of the
pair's scale) so that rounding can never prune a pair the flat search reports;
leaf–leaf evaluations are bit-identical to the flat search's. Hence (Lemma 1) the
finest-level contact pairs equal those of the flat search, pair for pair.

Contacts (:func:`~engine.kernels.collision.contact_merge.contact_kernel`): for a leaf pair
with closest points p (on A), q (on B) at distance d, the point is on the segment p→q
weighted by the ε's (midpoint for equal ε), the normal points from A to B ((q − p)/d, or
A's face normal when p and q coincide) and the overlap is ε_a + ε_b − d, clipped to
[0, ε_a + ε_b]. The points of one body pair are then merged greedily, deepest first: a
point within the smaller ε of a cluster's first point joins it, and each cluster becomes
its average (overlaps averaged) with the normal of its deepest member.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field

import numpy as np

from engine.arguments import PRECISIONS, check_kernel, check_precision
from engine.collision.query import (
    TINY,
    ULP,
    check_posed_pair,
    contact_constants,
    query_parameters,
    unfold_nodes,
)
from engine.errors import InvalidArgumentError
from engine.geometry.distance import (
    DEFAULT_ITERATIONS,
    DEFAULT_PRECISION,
    TriangleSet,
    triangle_contacts,
)
from engine.geometry.pose import Pose
from engine.kernels.collision.batch import MARGIN_ULPS, SQRT3, query_margin, relative_pose
from engine.kernels.collision.contact_merge import contact_kernel
from engine.kernels.collision.pair_query import pair_query, roots_apart
from engine.kernels.collision.rigid import margin_kernel, move_kernel
from engine.kernels.geometry import triangle_batch as tb
from engine.trees.tree import SurrogateTree

__all__ = ["FAR_APART", "ContactSet", "ContactStats", "far_apart", "find_contacts"]


@dataclass(frozen=True)
class ContactStats:
    """Counters of one query.

    comparisons_per_level : triangle pairs evaluated per front level (one entry, all
        leaf pairs, for the flat search)
    iterative, fallbacks : iterative evaluations and exact fallbacks
    unfoldings : node pairs unfolded
    raw_contacts, merged_contacts : contact points before and after merging
    sphere_pruned : node pairs pruned by their bounding spheres or boxes, before any
        triangle comparison (not counted as comparisons): the root pair if the node
        bounds alone show the bodies apart (then 1, and nothing else is counted; also
        when :func:`far_apart` settles the query on the host), else every child pair of
        an unfolded pair that does not
        enter the next level (each side's children are tested against the other side's
        node first, then the survivors against each other)
    """

    comparisons_per_level: tuple[int, ...] = ()
    iterative: int = 0
    fallbacks: int = 0
    unfoldings: int = 0
    raw_contacts: int = 0
    merged_contacts: int = 0
    sphere_pruned: int = 0

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

    A result without contacts holds shared read-only empty arrays.
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
    precision: str = DEFAULT_PRECISION,
    traversal: str = "pairs",
    iterations: int = DEFAULT_ITERATIONS,
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
    precision : "float32" or "float64" (default:
        :data:`~engine.geometry.distance.DEFAULT_PRECISION`)
    traversal : "pairs" — a front of node pairs, one Numba kernel per query (default);
        "sets" — the paper's Algorithm 5: every pair of two active node sets per round
        (driven from Python; for comparison, see BENCHMARKS.md)
    iterations : int ≥ 1 — sweeps of the iterative kernel per pair, for surrogate pairs and
        (kernels "iterative" and "hybrid") leaf pairs; ``benchmarks/search_pareto.py`` sweeps it

    Returns
    -------
    ContactSet
    """
    check_posed_pair(tree_a, pose_a, tree_b, pose_b)
    check_kernel(kernel), check_precision(precision)  # validate before any work
    if traversal not in ("pairs", "sets"):
        raise InvalidArgumentError(f"traversal must be 'pairs' or 'sets', got {traversal!r}")
    if type(iterations) is not int and (
        isinstance(iterations, bool) or not isinstance(iterations, (int, np.integer))
    ):
        raise InvalidArgumentError(f"iterations must be an integer, got {iterations!r}")
    if iterations < 1:
        raise InvalidArgumentError(f"iterations must be at least 1, got {iterations}")
    if hierarchy and traversal == "pairs":
        # far_apart inline, using the last outcome of the same pair of trees (temporal
        # coherence): past the early-out last time (TreeViews.near_partner), one kernel
        # call that makes the early-out's bounds-only search itself (FAR_APART when it
        # shows them apart); else that search in its own small call first. The same result
        # either way, counters included (BENCHMARKS.md, issue 15, ninth step).
        views_a, views_b = tree_a.views, tree_b.views
        distance, slack = _far_slack(tree_a, pose_a, tree_b, pose_b)
        if distance > views_a.root_reach + views_b.root_reach + 2.0 * slack:
            return FAR_APART
        partner = id(views_b)
        if views_a.near_partner == partner:
            found = _pair_query(
                tree_a, pose_a, tree_b, pose_b, kernel, precision, int(iterations), slack
            )
            if found is FAR_APART:
                views_a.near_partner = 0
            return found
        if _roots_apart(views_a, pose_a, views_b, pose_b, slack):
            return FAR_APART
        views_a.near_partner = partner
        # the bounds-only search ran, with the kernel's outcome: skipped there
        return _pair_query(tree_a, pose_a, tree_b, pose_b, kernel, precision, int(iterations), -1.0)
    return _search(
        tree_a, pose_a, tree_b, pose_b, kernel, hierarchy, precision, traversal, iterations
    )


def _search(tree_a, pose_a, tree_b, pose_b, kernel, hierarchy, precision, traversal, iterations):
    """:func:`find_contacts` on valid arguments, without the :func:`far_apart` early-out
    (the multiresolution kernel runs the same bounds-only search itself)."""
    if hierarchy and traversal == "pairs":
        margin = _far_slack(tree_a, pose_a, tree_b, pose_b)[1]
        return _pair_query(
            tree_a, pose_a, tree_b, pose_b, kernel, precision, int(iterations), margin
        )
    rot_a, rotation, shift = relative_pose(
        pose_a.position, pose_a.orientation, pose_b.position, pose_b.orientation
    )
    pose = (rotation, shift)
    contact = _contact_setup(tree_a, tree_b, rot_a, pose_a.position.copy(), kernel)
    search = _active_sets if hierarchy else _flat
    found, count, face_a, face_b, counters = search(
        tree_a, tree_b, pose, kernel, precision, int(iterations)
    )
    result = (
        np.empty((count, 2), np.int64),
        np.empty((count, 3)),
        np.empty((count, 3)),
        np.empty(count),
    )
    m, k = contact_kernel(found, count, face_a, face_b, *contact, result)
    result = (result[0][:m], result[1][:k], result[2][:k], result[3][:k])
    stats = ContactStats(*counters[:4], len(result[0]), len(result[1]), *counters[4:])
    return ContactSet(*result, stats)


@functools.lru_cache(maxsize=64)
def _parameters(kernel: str, precision: str, iterations: int) -> tuple:
    """The parameter group of :func:`~engine.kernels.collision.pair_query.pair_query`:
    ``(ulp, coarse mode, leaf mode, iterations, rtol, one, band, keep_all)``. Cached."""
    dtype = PRECISIONS[precision]
    coarse, leaf = query_parameters(kernel, dtype, iterations)
    out = (ULP[dtype], coarse[0], leaf[0], *coarse[1:], kernel != "iterative")
    # Python scalars type as the numpy ones (int64, float64) but pass Numba's dispatcher
    # faster; float32 constants stay numpy scalars (their type is the query's)
    return tuple(x.item() if isinstance(x, (np.int64, np.float64)) else x for x in out)


_LEVELS = 64  # levels whose pair counts a query records


def _pair_query(
    tree_a, pose_a, tree_b, pose_b, kernel, precision, iterations, bounds_margin
) -> ContactSet:
    """The pair-front search in one
    :func:`~engine.kernels.collision.pair_query.pair_query` call (flat arguments; the
    per-tree ones cached on ``tree.views``; ``bounds_margin`` float, its bounds-only
    search's margin, negative to skip that search; :data:`FAR_APART` when that search shows
    the bodies apart). The contacts are written into fresh buffers
    with room for as many leaf pairs as either tree's queries last needed
    (``views.leaf_pairs_hint``; run again, with room, when more are found)."""
    views_a, views_b = tree_a.views, tree_b.views
    side_a = views_a.query_side_a(precision)
    side_b = views_b.query_side_b
    parameters = _parameters(kernel, precision, iterations)
    # conditional expressions: the max and min builtins cost twice as much a call
    radius_a, radius_b = tree_a.bounding_radius, tree_b.bounding_radius
    tiny = TINY * (radius_a if radius_a >= radius_b else radius_b)
    merge_a, merge_b = tree_a.leaf_epsilon, tree_b.leaf_epsilon
    merge = merge_a if merge_a <= merge_b else merge_b
    capacity_a, capacity_b = views_a.leaf_pairs_hint, views_b.leaf_pairs_hint
    capacity = capacity_a if capacity_a >= capacity_b else capacity_b
    while True:
        counters = np.zeros(tb.N_STATS + _LEVELS, np.int64)
        pairs, points = np.empty((capacity, 2), np.int64), np.empty((capacity, 3))
        normals, overlaps = np.empty((capacity, 3)), np.empty(capacity)
        found, m, k, depth, unfoldings = pair_query(
            *side_a,
            *side_b,
            pose_a.position,
            pose_a.orientation,
            pose_b.position,
            pose_b.orientation,
            bounds_margin,
            *parameters,
            tiny,
            merge,
            counters,
            pairs,
            points,
            normals,
            overlaps,
        )
        if m >= 0:
            break
        capacity = 2 * found
        views_a.leaf_pairs_hint = views_b.leaf_pairs_hint = capacity
    if found < 0:  # the bounds-only search showed the bodies apart, as far_apart would
        return FAR_APART
    counts = counters[: tb.N_STATS + min(depth, _LEVELS)].tolist()  # the levels recorded
    stats = _made(
        ContactStats,
        {
            "comparisons_per_level": tuple(counts[tb.N_STATS :]),
            "iterative": counts[tb.STAT_ITERATIVE],
            "fallbacks": counts[tb.STAT_FALLBACKS],
            "unfoldings": unfoldings,
            "raw_contacts": m,
            "merged_contacts": k,
            "sphere_pruned": counts[tb.STAT_SPHERES],
        },
    )
    if m == 0:  # no contact: the shared read-only empty arrays, as FAR_APART's
        pairs, points, normals, overlaps = _NO_CONTACT
    else:
        pairs, points, normals, overlaps = pairs[:m], points[:k], normals[:k], overlaps[:k]
    return _made(
        ContactSet,
        {
            "pairs": pairs,
            "points": points,
            "normals": normals,
            "overlaps": overlaps,
            "stats": stats,
        },
    )


def _made(cls, fields: dict):
    """An instance of the frozen dataclass ``cls`` with ``fields`` (a new dict of every
    field, by name), made without its ``__init__`` (which sets each field through
    ``object.__setattr__``: a few microseconds, a tenth of a small query) and without
    keyword arguments (a dict display is built faster than ``**fields``)."""
    out = object.__new__(cls)
    object.__setattr__(out, "__dict__", fields)
    return out


def _empty(shape: tuple, dtype=np.float64) -> np.ndarray:
    """A read-only empty array."""
    out = np.empty(shape, dtype)
    out.flags.writeable = False
    return out


FAR_APART = ContactSet(
    _empty((0, 2), np.int64),
    _empty((0, 3)),
    _empty((0, 3)),
    _empty(0),
    ContactStats(sphere_pruned=1),
)
"""The result of every query that :func:`far_apart` settles: no contact, the root pair
pruned by its bounding spheres or boxes (the multiresolution search's own counters for
that case).
One shared object, its arrays read-only."""

_NO_CONTACT = (FAR_APART.pairs, FAR_APART.points, FAR_APART.normals, FAR_APART.overlaps)
"""The arrays of every result without contacts (read-only, shared)."""

_FAR_SLACK = 2.0 * MARGIN_ULPS * ULP[np.float32] * 2.0  # twice the float32 query margin
_SQRT3 = float(SQRT3)  # a Python float: numpy scalars' arithmetic costs ~40 ns an operation


def far_apart(tree_a: SurrogateTree, pose_a: Pose, tree_b: SurrogateTree, pose_b: Pose) -> bool:
    """True when the node bounds show the two bodies apart by more than ``slack``, twice the
    largest query margin at this distance (:func:`_far_slack`): first whatever the
    rotations, ``|p_b − p_a| > R_a + R_b + 2·slack``, ``R`` each tree's
    :attr:`~engine.trees.views.TreeViews.root_reach` (no covered point of a body lies
    farther than ``R`` from its position; host floats, about a microsecond); else by the
    node bounds alone: a short depth-first search from the root pair that drops node
    pairs whose spheres or boxes are apart by more than ``slack``
    (:attr:`~engine.trees.views.TreeViews.bounds_table`,
    :func:`~engine.kernels.collision.pair_query.roots_apart`: one small kernel call, B
    placed by the search's own arithmetic, at most
    :data:`~engine.kernels.collision.boxes.SEARCH_BUDGET` node pairs). The multiresolution
    kernel makes that search with the same margin and bits when run without the early-out
    (``_search``), so it then prunes the root pair exactly when this returns True (the
    first test leaves ``slack`` for rounding before its root-sphere test): :func:`find_contacts`
    returns :data:`FAR_APART` without running it, and otherwise runs it without that
    search."""
    distance, slack = _far_slack(tree_a, pose_a, tree_b, pose_b)
    va, vb = tree_a.views, tree_b.views
    if distance > va.root_reach + vb.root_reach + 2.0 * slack:
        return True
    return _roots_apart(va, pose_a, vb, pose_b, slack)


def _roots_apart(views_a, pose_a, views_b, pose_b, slack: float) -> bool:
    """:func:`~engine.kernels.collision.pair_query.roots_apart` of two trees' views at
    their poses, with margin ``slack``."""
    return roots_apart(
        views_a.bounds_table,
        views_b.bounds_table,
        pose_a.position,
        pose_a.orientation,
        pose_b.position,
        pose_b.orientation,
        slack,
    )


def _far_slack(tree_a, pose_a, tree_b, pose_b) -> tuple[float, float]:
    """``(|p_b − p_a|, slack)`` (floats): the positions' distance and twice the float32
    :func:`~engine.kernels.collision.batch.query_margin` at it (at least twice any query's
    margin), the bounds-only search's margin."""
    distance = math.dist(pose_a.position.tolist(), pose_b.position.tolist())
    extent = tree_a.views.geometry.extent + tree_b.views.geometry.extent
    return distance, _FAR_SLACK * (_SQRT3 * extent + distance)


def _contact_setup(tree_a, tree_b, rotation_a, position_a, kernel: str) -> tuple:
    """The ``contact_kernel`` arguments after the found pairs and their face maps
    (``rotation_a``, ``position_a``: A's pose, writable arrays as the batch passes them)."""
    setup = (*contact_constants(tree_a, tree_b), rotation_a, position_a)
    return (
        len(tree_b.views.geometry.face_nodes),
        kernel != "iterative",
        tree_a.views.geometry.face_normals,
        setup,
    )


def _moved(tree: SurrogateTree, pose, index: np.ndarray, dtype) -> tuple[np.ndarray, np.ndarray]:
    """Row-major ``(N, 9)`` coordinates and ``(N, 14)`` frames of ``tree``'s nodes, of which
    rows ``index`` are moved rigidly by ``pose`` (frame vectors rotate, scalars stay) and
    rounded to ``dtype`` (the other rows are undefined). ``move_kernel`` does the moving,
    as in the multiresolution search: leaf inputs are identical (Invariant 1)."""
    master = tree.views.geometry.master
    coords = np.empty(master.coords_rm.shape, dtype)
    frames = np.empty(master.frames_rm.shape, dtype)
    move_kernel(master.coords_rm, master.frames_rm, index, *pose, coords, frames)
    return coords, frames


def _flat(tree_a, tree_b, pose, kernel, precision, iterations):
    """The flat search: every leaf of A against every leaf of B (``pose = (rotation (3, 3),
    shift (3,))`` float64, B's frame to A's). Returns ``(found, count, faces of A, faces of
    B, counters)``: the leaf pairs found in the kernels' layout (:func:`_found`), indexed by
    face; ``faces (F,) int32`` the identity maps; ``counters = ((pairs,), iterative,
    fallbacks, 0)``."""
    leaves = tree_b.views.geometry.face_nodes
    coords, frames = _moved(tree_b, pose, leaves, np.dtype(precision).type)
    res = triangle_contacts(
        tree_a.views.geometry.node_set(precision, True),
        TriangleSet.prepared(coords[leaves].T, frames[leaves].T),
        tree_a.leaf_epsilon,
        tree_b.leaf_epsilon,
        kernel=kernel,
        precision=precision,
        threads=1,
        iterations=iterations,
    )
    s = res.stats
    found = _found(res.pairs, res)
    return (
        found,
        len(res),
        tree_a.views.geometry.faces,
        tree_b.views.geometry.faces,
        ((s.pairs,), s.iterative, s.fallbacks, 0),
    )


def _found(pairs: np.ndarray, res) -> tuple:
    """The kernels' result layout ``(i (n,) int64, j (n,) int64, distance (n,), point_a
    (3, n), point_b (3, n), status (n,) int8)`` of ``pairs (n, 2)`` int64 from a
    :class:`~engine.geometry.distance.TriangleContacts`-like result ``res`` (points
    ``(n, 3)``, in the query dtype)."""
    return (
        np.ascontiguousarray(pairs[:, 0]),
        np.ascontiguousarray(pairs[:, 1]),
        res.distance,
        np.ascontiguousarray(res.point_a.T),
        np.ascontiguousarray(res.point_b.T),
        res.status,
    )


def _active_sets(tree_a, tree_b, pose, kernel, precision, iterations):
    """Algorithm 5: compare all pairs of the active sets; both nodes of a hit unfold
    (:func:`_unfold_set`). Returns what :func:`_flat` returns, the faces as node → face
    maps ``(N,) int32`` (−1 for surrogates) and one comparison count per round."""
    dtype = np.dtype(precision).type
    sa = tree_a.views.geometry.node_set(precision, False)
    sb = TriangleSet.prepared(*(x.T for x in _moved(tree_b, pose, np.arange(len(tree_b)), dtype)))
    margin = query_margin(
        tree_a.views.geometry.extent, tree_b.views.geometry.extent, pose[1], ULP[dtype]
    )
    eps_a, eps_b = np.empty(len(tree_a), dtype), np.empty(len(tree_b), dtype)
    margin_kernel(*tree_a.views.structure[:2], margin, eps_a)
    margin_kernel(*tree_b.views.structure[:2], margin, eps_b)
    surrogate_kernel = "exact" if kernel == "exact" else "iterative"
    active_a, active_b = np.zeros(1, np.int64), np.zeros(1, np.int64)
    found, per_level, iterative, fallbacks, unfoldings = [], [], 0, 0, 0

    def contacts(grid, kernel):
        return triangle_contacts(
            sa,
            sb,
            eps_a,
            eps_b,
            pairs=grid,
            kernel=kernel,
            precision=precision,
            threads=1,
            iterations=iterations,
        )

    while len(active_a) and len(active_b):
        grid = np.stack(np.meshgrid(active_a, active_b, indexing="ij"), -1).reshape(-1, 2)
        per_level.append(len(grid))
        finest = (tree_a.face[grid[:, 0]] >= 0) & (tree_b.face[grid[:, 1]] >= 0)
        if finest.any():
            res = contacts(grid[finest], kernel)
            found.append(res)
            iterative, fallbacks = iterative + res.stats.iterative, fallbacks + res.stats.fallbacks
        res = contacts(grid[~finest], surrogate_kernel)
        iterative += res.stats.iterative
        hits = res.pairs
        unfoldings += len(hits)
        active_a = _unfold_set(tree_a, hits[:, 0])
        active_b = _unfold_set(tree_b, hits[:, 1])
    if not found:
        found = [contacts(np.zeros((0, 2), np.int64), kernel)]
    pairs = np.concatenate([r.pairs for r in found])
    keep = np.unique(pairs, axis=0, return_index=True)[1]  # a leaf pair may recur

    class Stacked:  # the found rows ``keep``, concatenated
        distance, point_a, point_b, status = (
            np.concatenate([getattr(r, name) for r in found])[keep]
            for name in ("distance", "point_a", "point_b", "status")
        )

    counters = (tuple(per_level), iterative, fallbacks, unfoldings)
    faces = tree_a.views.structure[1], tree_b.views.structure[1]
    return _found(pairs[keep], Stacked), len(keep), *faces, counters


def _unfold_set(tree: SurrogateTree, nodes: np.ndarray) -> np.ndarray:
    """Algorithm 5's next active set ``(m,)`` int64, sorted and unique, from the nodes of
    the hit pairs ``nodes (k,)`` int64: each leaf stays, each surrogate is replaced by its
    children — the traversal's unfold rule per node
    (:func:`~engine.collision.query.unfold_nodes`). Algorithm 5 applies it to *sets*, not
    pairs: the next round compares every pair of the two sets, so a child of one hit may
    meet a child of another (more comparisons than the pair front, the same leaf pairs)."""
    return np.unique(unfold_nodes(tree, np.unique(nodes)))
