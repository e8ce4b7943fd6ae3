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

Every point of a node's covered faces also lies in the node's oriented box (principal
axes of the covered vertices, :attr:`~engine.trees.views.TreeViews.distance_boxes`), so
the gap of two boxes projected on any axis is a lower bound too.

**Search** (one call of :func:`~engine.kernels.collision.distance_search.distance_kernel`,
whose module documents it): a greedy descent gives a first upper bound; then a best-first
search over node pairs keyed on their lower bound (a heap; a stack, depth first, for
those whose bound is ≤ 0): child pairs get the cheap
sphere and box bounds when their parent unfolds, and the exact distance of the two node
triangles less their g only when they reach the top of the heap (vectorised over up to 8
pairs); leaf pairs at the top are evaluated with the exact kernel the same way (in
``precision``, on B's triangles moved as the contact search moves them), each with its
closest points (:func:`~engine.kernels.geometry.triangle_points.exact_points`; the first
descent's pair with the scalar
:func:`~engine.kernels.geometry.triangle_points.exact_point`). It stops when the smallest
bound in the heap exceeds the best distance, or at a distance of 0 (the meshes touch or
intersect). The host validates, looks up the trees' packed node rows (built once per
tree), calls the kernel once and wraps its output.

A pair containing the minimum is pruned only if its bound exceeds a candidate by more
than the rounding margin (256 ulp of the pair's scale,
:func:`~engine.kernels.collision.batch.query_margin`), so the result is the minimum of
the exact kernel over every face pair (the tests compare it with every face pair).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from functools import cached_property

import numba
import numpy as np

from engine.arguments import PRECISIONS, check_precision
from engine.collision.query import check_posed_pair
from engine.geometry.pose import Pose
from engine.kernels.collision import distance_search as ds
from engine.trees.tree import SurrogateTree

__all__ = ["MeshDistance", "mesh_distance"]


@dataclass(frozen=True)
class MeshDistance:
    """Result of :func:`mesh_distance`.

    distance : float — minimum Euclidean distance between the triangles of A and of B
        (0 when they intersect or touch), computed in the query precision
    face_a, face_b : int — the face of A and the face of B attaining it
    closest_points : (2, 3) float64 — the closest points on those faces (A's, then B's),
        world frame
    faces : (2,) int64 — ``(face_a, face_b)`` (made at first use)
    point_a, point_b : (3,) float64 — the rows of ``closest_points`` (made at first use)
    node_pairs : int — node pairs bounded (the roots', and every child pair of an
        unfolded pair)
    probes : int — leaf pairs whose exact distance was evaluated
    rounds : int — node pairs unfolded
    largest_front : int — largest number of node pairs waiting in the search's heap and stack
    sphere_pruned : int — child pairs dropped by their sphere or box bound, before any
        triangle distance
    """

    distance: float
    face_a: int
    face_b: int
    closest_points: np.ndarray
    node_pairs: int
    probes: int
    rounds: int
    largest_front: int
    sphere_pruned: int

    # views made at first use, not by every query (an array and two views: 0.2 µs)
    @cached_property
    def faces(self) -> np.ndarray:
        return np.array((self.face_a, self.face_b), np.int64)

    @cached_property
    def point_a(self) -> np.ndarray:
        return self.closest_points[0]

    @cached_property
    def point_b(self) -> np.ndarray:
        return self.closest_points[1]


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
    # the common case, exact types and a known precision, is checked inline (no calls)
    # and calls the kernel's compiled entry point (_compiled_kernel); anything else is
    # checked in full and dispatched by Numba
    dtype = PRECISIONS.get(precision) if type(precision) is str else None
    exact = (
        dtype is not None
        and type(tree_a) is SurrogateTree
        and type(tree_b) is SurrogateTree
        and type(pose_a) is Pose
        and type(pose_b) is Pose
    )
    if not exact:
        check_posed_pair(tree_a, pose_a, tree_b, pose_b)
        dtype = check_precision(precision)
    rows_a, rows_b = tree_a.views.kernel_distance_rows, tree_b.views.kernel_distance_rows
    prepared_a = rows_a if dtype is np.float64 else tree_a.views.kernel_prepared_rows(precision)
    # the kernel writes the points into an array allocated here, and returns scalars
    # only: three arrays built from returned tuples cost 1.2 µs, this 0.3 µs
    points = np.empty((2, 3))
    # (writeable arrays, the poses packed: Numba's dispatch of the 8 arguments, 7 of
    # them read-only, took 0.70 µs, of these 6 0.30 µs; the compiled entry point, called
    # without the dispatch's type resolution, 0.14 µs less again)
    if exact:
        kernel = _KERNELS.get(dtype) or _compiled_kernel(dtype)
    else:
        kernel = ds.distance_kernel
    found = kernel(prepared_a, rows_a, rows_b, pose_a._packed, pose_b._packed, points)
    distance, face_a, face_b, pairs, probes, rounds, largest, pruned = found
    # the frozen dataclass's __init__ sets each field through object.__setattr__ (1.4 µs
    # of a ~6 µs call); the same fields stored into the new instance's __dict__: 0.5 µs
    result = _new(MeshDistance)
    fields = result.__dict__
    fields["distance"] = distance
    fields["face_a"] = face_a
    fields["face_b"] = face_b
    fields["closest_points"] = points
    fields["node_pairs"] = pairs
    fields["probes"] = probes
    fields["rounds"] = rounds
    fields["largest_front"] = largest
    fields["sphere_pruned"] = pruned
    return result


_new = object.__new__
_KERNELS: dict = {}  # query dtype → the distance kernel's compiled entry point (_compiled_kernel)


def _compiled_kernel(dtype) -> Callable:
    """:func:`~engine.kernels.collision.distance_search.distance_kernel` compiled (or loaded
    from the cache) for its arguments in query ``dtype``, as its entry point: the function
    Numba's dispatch calls once it has resolved the argument types, called directly.

    :func:`mesh_distance` calls it for a :class:`~engine.trees.tree.SurrogateTree` and a
    :class:`~engine.geometry.pose.Pose` of exactly these types, whose arrays have the same
    types in every query of a precision: the trees' kernel rows
    (:attr:`~engine.trees.views.TreeViews.kernel_distance_rows`, ``kernel_prepared_rows``)
    and a pose's packed array are C-contiguous writeable arrays, 2-D float64 (the prepared
    rows in ``dtype``) and ``(7,)`` float64, however the tree or the pose was made (built,
    loaded, unpickled, copied: tested), and the points are allocated there. Called with
    other types, an entry point would read memory wrongly: anything else goes through
    Numba's dispatch."""
    kernel = _KERNELS.get(dtype)
    if kernel is None:
        # arrays of the arguments' types (their shapes play no part in the types)
        rows = np.empty((1, 1))
        prepared = rows if dtype is np.float64 else np.empty((1, 1), dtype)
        example = (prepared, rows, rows, np.empty(1), np.empty(1), np.empty((1, 1)))
        kernel = ds.distance_kernel.compile(tuple(numba.typeof(a) for a in example))
        _KERNELS[dtype] = kernel
    return kernel
