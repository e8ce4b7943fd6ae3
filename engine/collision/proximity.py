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
whose module documents it): a greedy descent gives a first upper bound; then a best-first
search pops node pairs from a heap keyed on their lower bound, unfolds the node with the
larger bounding sphere (both nodes when their spheres are of a size and the pair is
apart), bounds each child pair with its spheres, the projection of the two node
triangles on the axis through the sphere centres, and the exact distance of the two node
triangles less their g (vectorised over the children of up to 8 pairs), and evaluates
the surviving leaf pairs with the exact kernel
(:func:`~engine.kernels.geometry.triangle_batch.exact_point`, in ``precision``, on B's
triangles moved as the contact search moves them). It stops when the smallest bound in
the heap exceeds the best distance, or at a distance of 0 (the meshes touch or
intersect). The host validates, looks up the trees' packed node rows (built once per
tree), calls the kernel once and wraps its output.

A pair containing the minimum is pruned only if its bound exceeds a candidate by more
than the rounding margin (256 ulp of the pair's scale,
:func:`~engine.kernels.collision.batch.query_margin`), so the result is the minimum of
the exact kernel over every face pair (the tests compare it with every face pair).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from engine.arguments import check_precision
from engine.collision.query import ULP, check_posed_pair
from engine.geometry.pose import Pose
from engine.kernels.collision import distance_search as ds
from engine.trees.tree import SurrogateTree

__all__ = ["MeshDistance", "mesh_distance"]


@dataclass(frozen=True)
class MeshDistance:
    """Result of :func:`mesh_distance`.

    distance : float — minimum Euclidean distance between the triangles of A and of B
        (0 when they intersect or touch), computed in the query precision
    faces : (2,) int64 — (face of A, face of B) attaining it
    point_a, point_b : (3,) float64 — closest points on those faces, world frame
    node_pairs : int — node pairs bounded (the roots', and every child pair of an
        unfolded pair)
    probes : int — leaf pairs whose exact distance and closest points were evaluated
    rounds : int — node pairs unfolded
    largest_front : int — largest number of node pairs waiting in the search's heap
    sphere_pruned : int — child pairs dropped by their sphere or projection bound, before
        any triangle distance
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
    rows_a, rows_b = tree_a.views.distance_rows, tree_b.views.distance_rows
    prepared_a = rows_a if dtype is np.float64 else tree_a.views.prepared_rows(precision)
    out_i, out_f = np.empty(ds.N_OUT_I, np.int64), np.empty(ds.N_OUT_F)
    ds.distance_kernel(
        prepared_a, rows_a, rows_b,
        pose_a.position, pose_a.orientation, pose_b.position, pose_b.orientation,
        ULP[dtype], dtype(1.0), out_i, out_f,
    )  # fmt: skip
    pairs, probes, rounds, largest, pruned = out_i[ds.OUT_PAIRS :].tolist()
    return MeshDistance(
        distance=float(out_f[ds.OUT_DISTANCE]),
        faces=out_i[: ds.OUT_FACE_B + 1],
        point_a=out_f[ds.OUT_POINT_A : ds.OUT_POINT_A + 3],
        point_b=out_f[ds.OUT_POINT_B : ds.OUT_POINT_B + 3],
        node_pairs=pairs,
        probes=probes,
        rounds=rounds,
        largest_front=largest,
        sphere_pruned=pruned,
    )
