"""Minimum distance between two posed triangle meshes: branch and bound over surrogate trees.

The query runs in body A's frame, like :func:`engine.collision.contacts.find_contacts`: B's
nodes are moved by the relative pose ``pose_a⁻¹ ∘ pose_b``.

**Bound.** A surrogate's ε is the largest distance from a covered vertex to the
surrogate triangle *plus the leaf ε* (the body's halo, :mod:`engine.trees.tree`). Distance
to a triangle is convex, so every point of every covered triangle lies within
``g = ε − leaf ε`` of the surrogate (``g = 0`` for a leaf, an original triangle). For
nodes a, b with surrogates S_a, S_b, every descendant leaf pair (t_a, t_b) then has

    d(t_a, t_b) ≥ d(S_a, S_b) − g_a − g_b ≥ (gap of S_a, S_b projected on any axis) − g_a − g_b,

and ``d(t_a, t_b) ≥ |c_a − c_b| − r_a − r_b`` for the bounding spheres (c, r) of the
covered triangles (:attr:`~engine.trees.views.TreeViews.distance_bounds`); the exact
distance of any leaf pair is an upper bound on the minimum.

**Search** (one call of :func:`~engine.kernels.collision.distance_search.distance_kernel`,
which documents it): a greedy descent gives a first upper bound, then a best-first search
pops node pairs from a heap keyed on their lower bound, computes the cheap bounds first
(spheres, then the projection on the axis through the two centres, then, with
:data:`REFINE`, the surrogates' exact distance), unfolds the node with the larger g of a
pair that survives, and evaluates leaf pairs with the exact kernel
(:func:`~engine.kernels.geometry.triangle_batch.exact_point`, in ``precision``, on B's
triangles moved as the contact search moves them). It stops when the smallest bound in
the heap exceeds the best distance, or at a distance of 0 (the meshes touch or
intersect).

A pair containing the minimum is pruned only if its bound exceeds a candidate by more
than the rounding margin (256 ulp of the pair's scale,
:func:`~engine.kernels.collision.batch.query_margin`), so the result is the minimum of
the exact kernel over every face pair (the tests compare it with every face pair).
"""

from __future__ import annotations

import weakref
from dataclasses import dataclass

import numpy as np

from engine.arguments import check_precision
from engine.collision.query import ULP, check_posed_pair
from engine.geometry.pose import Pose
from engine.kernels.collision import distance_search as ds
from engine.trees.tree import SurrogateTree

__all__ = ["MeshDistance", "mesh_distance"]

REFINE = False
"""Evaluate a surrogate pair's exact distance (a third lower bound) before unfolding it."""


@dataclass(frozen=True)
class MeshDistance:
    """Result of :func:`mesh_distance`.

    distance : float — minimum Euclidean distance between the triangles of A and of B
        (0 when they intersect or touch), computed in the query precision
    faces : (2,) int64 — (face of A, face of B) attaining it
    point_a, point_b : (3,) float64 — closest points on those faces, world frame
    node_pairs : int — node pairs that entered the search's heap (each with a sphere bound)
    probes : int — exact triangle distances evaluated (leaf pairs, the greedy descent's
        leaf pair, and surrogate pairs with :data:`REFINE`)
    rounds : int — node pairs unfolded
    largest_front : int — largest number of node pairs waiting in the heap
    sphere_pruned : int — child pairs pruned by their bounding spheres before entering it
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
    a, b = _search_arrays(tree_a), _search_arrays(tree_b)
    coords_a, frames_a = a.rounded(precision)
    out_i, out_f = np.empty(ds.N_OUT_I, np.int64), np.empty(ds.N_OUT_F)
    ds.distance_kernel(
        coords_a, frames_a, a.master_coords, a.node, a.tree,
        b.master_coords, b.master_frames, b.node, b.tree,
        pose_a.position, pose_a.orientation, pose_b.position, pose_b.orientation,
        a.extent, b.extent, ULP[dtype], dtype(1.0), out_i, out_f,
    )  # fmt: skip
    counts = out_i.tolist()
    return MeshDistance(
        distance=float(out_f[ds.OUT_DISTANCE]),
        faces=out_i[: ds.OUT_FACE_B + 1],
        point_a=out_f[ds.OUT_POINT_A : ds.OUT_POINT_A + 3],
        point_b=out_f[ds.OUT_POINT_B : ds.OUT_POINT_B + 3],
        node_pairs=counts[ds.OUT_PAIRS],
        probes=counts[ds.OUT_EXACT],
        rounds=counts[ds.OUT_UNFOLDED],
        largest_front=counts[ds.OUT_LARGEST],
        sphere_pruned=counts[ds.OUT_SPHERES],
    )


class _SearchArrays:
    """One tree's arrays as :func:`~engine.kernels.collision.distance_search.distance_kernel`
    reads them (``N`` nodes, body frame; built once per tree, see :func:`_search_arrays`).

    master_coords, master_frames : (N, 9), (N, 14) float64 — prepared triangles, row-major
    node : (N, 5) float64 — bounding sphere centre and radius of the covered triangles, g
    tree : (N, 3) int64 — first child, child count (0 for a leaf), face (−1 for a surrogate)
    extent : float — largest absolute body-frame coordinate
    """

    def __init__(self, tree: SurrogateTree) -> None:
        views = tree.views
        master = views.geometry.master
        self._geometry = views.geometry
        self.master_coords, self.master_frames = master.coords_rm, master.frames_rm
        bounds = views.distance_bounds
        self.node = np.ascontiguousarray(
            np.column_stack([bounds.centre, bounds.radius, bounds.gap]), dtype=np.float64
        )
        count = np.where(bounds.leaf, 0, bounds.child_count)
        self.tree = np.ascontiguousarray(
            np.column_stack([bounds.first_child, count, tree.face]), dtype=np.int64
        )
        self.extent = float(views.geometry.extent)

    def rounded(self, precision: str) -> tuple[np.ndarray, np.ndarray]:
        """``(coords (N, 9), frames (N, 14))`` in ``precision``, row-major."""
        rows = self._geometry.node_set(precision, False)
        return rows.coords_rm, rows.frames_rm


_ARRAYS: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def _search_arrays(tree: SurrogateTree) -> _SearchArrays:
    """The :class:`_SearchArrays` of ``tree``, built on first use and kept with it."""
    found = _ARRAYS.get(tree)
    if found is None:
        found = _ARRAYS[tree] = _SearchArrays(tree)
    return found
