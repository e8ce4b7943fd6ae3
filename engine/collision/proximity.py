"""Minimum distance between two posed triangle meshes: branch and bound over surrogate trees.

The query runs in body A's frame, like :func:`engine.collision.contacts.find_contacts`: B's
nodes are moved by the relative pose ``pose_a⁻¹ ∘ pose_b``.

**Bound.** A surrogate's ε is the largest distance from a covered vertex to the
surrogate triangle *plus the leaf ε* (the body's halo, :mod:`engine.trees.tree`). Distance
to a triangle is convex, so every point of every covered triangle lies within
``g = ε − leaf ε`` of the surrogate (``g = 0`` for a leaf, an original triangle). For
nodes a, b with surrogates S_a, S_b, every descendant leaf pair (t_a, t_b) then has

    d(t_a, t_b) ≥ d(S_a, S_b) − g_a − g_b,

a lower bound; the exact distance of any leaf pair is an upper bound on the minimum.

**Search** (level-synchronous; each round is one batched call of the exact kernel,
:func:`~engine.kernels.geometry.triangle_batch.paired_kernel` in ``EXACT`` mode as
:func:`~engine.geometry.distance.triangle_distances` runs it, for the front, and one for
probes):

1. the front starts at the pair of roots;
2. every front pair gets its exact distance in ``precision``; a leaf pair's is a
   candidate for the minimum;
3. the :data:`PROBES` surrogate pairs with the smallest lower bounds are probed: the
   exact distance of their *representative* leaves (per node, the covered face whose
   centroid is nearest the node triangle's centroid) is a candidate too, which gives
   a tight upper bound long before the front reaches the leaves;
4. a surrogate pair survives if its lower bound, less a rounding margin (256 ulp of
   the pair's scale, :func:`~engine.kernels.collision.batch.query_margin`), is at most the
   best candidate; each survivor unfolds the node with the larger g (a leaf never), and a
   child pair enters the next front only if the bounding spheres of its covered
   triangles (:attr:`~engine.trees.views.TreeViews.distance_bounds`: the tree's
   :attr:`~engine.trees.views.TreeViews.spheres` less the halo) pass the same test;
5. the search stops when the front is empty, or at once when a candidate has
   distance 0 (the meshes touch or intersect).

This is not the contact traversal's unfold rule (every surrogate of a pair unfolds,
:mod:`engine.collision.query`), on purpose: the contact search must reach every leaf
pair in contact anyway, while a branch and bound wants each evaluated pair to tighten its
lower bound most, and the larger of the two g is the larger slack in that bound.
Unfolding one node per pair (rather than both when their g are close) and 64 probes
gave the fewest evaluated pairs over icospheres of 1,280 and 5,120 faces at four gaps
and interlocked tori (sweep of 16 / 64 / 256 probes, one or both nodes).

A pair containing the minimum is pruned only if its bound exceeds a candidate by more
than the rounding margin, so the result is the minimum over all face pairs up to
rounding of the exact kernel (the tests compare it with every face pair).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from engine.arguments import check_precision, kernel_constants
from engine.collision.query import ULP, check_posed_pair
from engine.geometry.distance import DEFAULT_ITERATIONS, DEFAULT_RTOL
from engine.geometry.pose import Pose
from engine.kernels.collision.batch import query_margin, relative_pose
from engine.kernels.collision.rigid import move_kernel
from engine.kernels.geometry import triangle_batch as tb
from engine.trees.tree import SurrogateTree

__all__ = ["MeshDistance", "mesh_distance"]

PROBES = 64
"""Surrogate pairs per round whose representative leaves are evaluated (upper bounds)."""


@dataclass(frozen=True)
class MeshDistance:
    """Result of :func:`mesh_distance`.

    distance : float — minimum Euclidean distance between the triangles of A and of B
        (0 when they intersect or touch), computed in the query precision
    faces : (2,) int64 — (face of A, face of B) attaining it
    point_a, point_b : (3,) float64 — closest points on those faces, world frame
    node_pairs : int — node pairs whose surrogate (or leaf) distance was evaluated
    probes : int — representative leaf pairs evaluated for upper bounds
    rounds : int — fronts evaluated
    largest_front : int — node pairs in the largest front
    sphere_pruned : int — node pairs pruned by their bounding spheres before evaluation
    """

    distance: float
    faces: np.ndarray
    point_a: np.ndarray
    point_b: np.ndarray
    node_pairs: int
    probes: int
    rounds: int
    largest_front: int
    sphere_pruned: int


def mesh_distance(
    tree_a: SurrogateTree,
    pose_a: Pose,
    tree_b: SurrogateTree,
    pose_b: Pose,
    precision: str = "float64",
) -> MeshDistance:
    """Minimum distance between body A (``tree_a`` at ``pose_a``) and body B.

    Parameters
    ----------
    tree_a, tree_b : SurrogateTree — the bodies' trees (body frames); the halos (leaf ε)
        play no part: the distance is between the triangles themselves
    pose_a, pose_b : Pose
    precision : "float32" or "float64" — arithmetic of the exact kernel

    Returns
    -------
    MeshDistance
    """
    check_posed_pair(tree_a, pose_a, tree_b, pose_b)
    dtype = check_precision(precision)
    _, rotation, shift = relative_pose(
        pose_a.position, pose_a.orientation, pose_b.position, pose_b.orientation
    )
    margin = query_margin(
        tree_a.views.geometry.extent, tree_b.views.geometry.extent, shift, ULP[dtype]
    )
    set_a, master_b = tree_a.views.geometry.node_set(precision, False), tree_b.views.geometry.master
    body_a = _Body(set_a.coords_rm, set_a.frames_rm, None, *tree_a.views.distance_bounds)
    static_b = tree_b.views.distance_bounds
    body_b = _Body(
        np.empty(master_b.coords_rm.shape, dtype),  # rows filled as they are reached
        np.empty(master_b.frames_rm.shape, dtype),
        (master_b.coords_rm, master_b.frames_rm, rotation, shift),
        *static_b[:-2],
        static_b[-2] @ rotation.T + shift,
        static_b[-1],
    )
    search = _Search(body_a, body_b, dtype, margin)
    search.run()
    if search.best_pair is None:  # unreachable: the roots' representatives are evaluated
        raise AssertionError("mesh_distance evaluated no leaf pair")
    node_a, node_b = search.best_pair
    point_a, point_b = (pose_a.apply(p.astype(np.float64)) for p in search.best_points)
    return MeshDistance(
        distance=float(search.best),
        faces=np.array([tree_a.face[node_a], tree_b.face[node_b]], dtype=np.int64),
        point_a=point_a,
        point_b=point_b,
        node_pairs=search.node_pairs,
        probes=search.probes,
        rounds=search.rounds,
        largest_front=search.largest_front,
        sphere_pruned=search.sphere_pruned,
    )


@dataclass(frozen=True)
class _Body:
    """One body's nodes as the search reads them (N nodes; B's in A's frame).

    coords, frames : (N, 9), (N, 14) — row-major kernel layout
        (:class:`~engine.geometry.distance.TriangleSet`), in the query dtype
    move : None, or for B ``(coords, frames, rotation, shift)``: the float64 body-frame
        rows that :func:`~engine.kernels.collision.rigid.move_kernel` moves into ``coords``,
        ``frames`` when a node is reached (the contact search's mover)
    gap : (N,) float64 — g = ε − leaf ε of a surrogate, 0 for a leaf
    leaf : (N,) bool
    first_child, child_count : (N,) int64
    representative : (N,) int64 — node index of the node's representative leaf
    centre : (N, 3) float64 — centre of the node's bounding sphere
    radius : (N,) float64 — its radius (covered triangles, without the halo)
    """

    coords: np.ndarray
    frames: np.ndarray
    move: tuple | None
    gap: np.ndarray
    leaf: np.ndarray
    first_child: np.ndarray
    child_count: np.ndarray
    representative: np.ndarray
    centre: np.ndarray
    radius: np.ndarray


class _Search:
    """State of one branch-and-bound query (see the module docstring)."""

    def __init__(self, a: _Body, b: _Body, dtype, margin: float) -> None:
        self.a, self.b = a, b
        self.dtype, self.margin = dtype, float(margin)
        # the exact mode of the paired kernel, with the argument types triangle_distances
        # passes (one compiled specialisation); iterations and rtol are unused
        self.params = (tb.EXACT, np.int64(DEFAULT_ITERATIONS), dtype(DEFAULT_RTOL))
        self.params += kernel_constants(dtype)
        self.best, self.best_pair, self.best_points = np.inf, None, None
        self.node_pairs = self.probes = self.rounds = self.largest_front = self.sphere_pruned = 0

    def exact(self, na: np.ndarray, nb: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Exact distances ``(n,)`` and closest points ``(3, n)`` of node pairs (na, nb)."""
        n = len(na)
        for body, index in ((self.a, na), (self.b, nb)):
            if body.move is not None:
                move_kernel(*body.move[:2], index, *body.move[2:], body.coords, body.frames)
        ca, fa = (np.ascontiguousarray(x[na].T) for x in (self.a.coords, self.a.frames))
        cb, fb = (np.ascontiguousarray(x[nb].T) for x in (self.b.coords, self.b.frames))
        distance, lower = np.empty(n, self.dtype), np.empty(n, self.dtype)
        point_a, point_b = np.empty((3, n), self.dtype), np.empty((3, n), self.dtype)
        status, stats = np.empty(n, np.int8), np.zeros(tb.N_STATS, np.int64)
        eps = np.zeros(n, self.dtype)
        tb.paired_kernel(
            ca, fa, cb, fb, eps, 0, n, self.params,
            distance, lower, point_a, point_b, status, stats,
        )  # fmt: skip
        return distance, point_a, point_b

    def offer(self, na, nb, distance, point_a, point_b) -> None:
        """Leaf pairs (na, nb) with their exact distances: keep the smallest."""
        if not len(distance):
            return
        k = int(np.argmin(distance))
        if distance[k] < self.best:
            self.best = float(distance[k])
            self.best_pair = (int(na[k]), int(nb[k]))
            self.best_points = (point_a[:, k].copy(), point_b[:, k].copy())

    def run(self) -> None:
        """Rounds until the front is empty or the distance is 0."""
        a, b = self.a, self.b
        na, nb = np.zeros(1, np.int64), np.zeros(1, np.int64)
        while len(na):
            self.rounds += 1
            self.node_pairs += len(na)
            self.largest_front = max(self.largest_front, len(na))
            distance, point_a, point_b = self.exact(na, nb)
            finest = a.leaf[na] & b.leaf[nb]
            if finest.any():
                found = distance[finest], point_a[:, finest], point_b[:, finest]
                self.offer(na[finest], nb[finest], *found)
            inner = np.flatnonzero(~finest)
            if self.best <= 0.0 or not len(inner):
                return
            na, nb = na[inner], nb[inner]
            lower = distance[inner].astype(np.float64) - a.gap[na] - b.gap[nb]
            probe = np.argpartition(lower, PROBES)[:PROBES] if len(lower) > PROBES else slice(None)
            qa, qb = a.representative[na[probe]], b.representative[nb[probe]]
            self.probes += len(qa)
            self.offer(qa, qb, *self.exact(qa, qb))
            if self.best <= 0.0:
                return
            keep = lower - self.margin <= self.best
            na, nb = _unfold(na[keep], nb[keep], a, b)
            apart = a.centre[na] - b.centre[nb]
            reach = np.sqrt(np.einsum("ij,ij->i", apart, apart)) - a.radius[na] - b.radius[nb]
            keep = reach - self.margin <= self.best
            self.sphere_pruned += len(keep) - int(np.count_nonzero(keep))
            na, nb = na[keep], nb[keep]


def _unfold(na: np.ndarray, nb: np.ndarray, a: _Body, b: _Body) -> tuple[np.ndarray, np.ndarray]:
    """Child pairs ``(na, nb)``, both ``(m,)`` int64, of the node pairs ``na, nb (k,)`` int64,
    none of them two leaves: the node with the larger g is unfolded (a leaf, g = 0, only
    if the other is one too: never), the other stays.

    The branch and bound's own rule, not the traversal's
    (:func:`~engine.collision.query.unfold_pairs`, both surrogates unfold): splitting only
    the node with the larger gap tightens the lower bound d(S_a, S_b) − g_a − g_b where it
    is loosest, and evaluated the fewest pairs in the sweep of the module docstring."""
    split_a = ~a.leaf[na] & (b.leaf[nb] | (a.gap[na] >= b.gap[nb]))
    count = np.where(split_a, a.child_count[na], b.child_count[nb])
    owner = np.repeat(np.arange(len(na)), count)
    child = np.arange(len(owner)) - np.repeat(np.cumsum(count) - count, count)
    na, nb, split_a = na[owner], nb[owner], split_a[owner]
    return (
        np.where(split_a, a.first_child[na] + child, na),
        np.where(split_a, nb, b.first_child[nb] + child),
    )
