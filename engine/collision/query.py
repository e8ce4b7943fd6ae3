"""What every query of a posed body pair shares: argument checks, the rounding constants,
the kernel parameters, the contact set-up and the traversal's unfold rule on the host.

Used by the contact search (:mod:`engine.collision.contacts`), the narrow phase's batches
(:mod:`engine.collision.batch`), the multiscale fronts (:mod:`engine.collision.multiscale`)
and the distance query (:mod:`engine.collision.proximity`), so that a body pair gets the
same margins, parameters and contact constants whichever of them runs it.

**The unfold rule.** A node pair whose test says "contact" or "not converged" is replaced
by its child pairs: every surrogate of the pair unfolds into its children, a leaf stays
(it stands for itself), so a pair of a surrogate with ``k`` children and a leaf gives ``k``
pairs and two surrogates give the product of their children. The kernels apply it inside
the traversal (:func:`~engine.kernels.collision.traversal.query_kernel`); on the host,
:func:`unfold_pairs` applies it to a front of pairs (the multiscale search) and
:func:`unfold_nodes` to single nodes (the active sets of the paper's Algorithm 5).
"""

from __future__ import annotations

import functools

import numpy as np

from engine.arguments import KERNELS, kernel_constants
from engine.errors import InvalidArgumentError
from engine.geometry.distance import DEFAULT_ITERATIONS, DEFAULT_RTOL
from engine.geometry.pose import Pose
from engine.kernels.geometry import triangle_batch as tb
from engine.trees.tree import SurrogateTree

__all__ = [
    "TINY",
    "ULP",
    "check_posed_pair",
    "contact_constants",
    "query_parameters",
    "unfold_nodes",
    "unfold_pairs",
    "unfolded_ranges",
]

ULP = {np.float32: float(np.finfo(np.float32).eps), np.float64: float(np.finfo(np.float64).eps)}
"""Machine epsilon of each query dtype (the unit of the surrogate ε margin,
:func:`~engine.kernels.collision.batch.query_margin`)."""
TINY = 1e3 * float(np.finfo(np.float32).eps)
"""Gap, relative to the larger bounding radius, below which a contact's two closest
points count as coincident (its normal is then A's face normal)."""


def check_posed_pair(tree_a, pose_a, tree_b, pose_b) -> None:
    """Raise :class:`~engine.errors.InvalidArgumentError` unless the trees are
    :class:`~engine.trees.tree.SurrogateTree` and the poses :class:`~engine.geometry.pose.Pose`.
    The common case, exact types, costs four identity tests (a far pair's whole query is
    about 2 µs)."""
    if (
        type(tree_a) is SurrogateTree
        and type(tree_b) is SurrogateTree
        and type(pose_a) is Pose
        and type(pose_b) is Pose
    ):
        return
    for name, tree in (("tree_a", tree_a), ("tree_b", tree_b)):
        if not isinstance(tree, SurrogateTree):
            raise InvalidArgumentError(f"{name} must be a SurrogateTree")
    for name, pose in (("pose_a", pose_a), ("pose_b", pose_b)):
        if not isinstance(pose, Pose):
            raise InvalidArgumentError(f"{name} must be a Pose")


@functools.lru_cache(maxsize=64)
def query_parameters(
    kernel: str, dtype, iterations: int = DEFAULT_ITERATIONS
) -> tuple[tuple, tuple]:
    """Kernel parameters ``(mode, iterations, rtol, one, band)`` for surrogate pairs
    (iterative; exact when ``kernel="exact"``) and for leaf pairs (``kernel``), as
    :func:`~engine.kernels.geometry.triangle_batch.listed_kernel` takes them: ``mode``
    int, ``iterations`` int64, ``rtol``, ``one``, ``band`` of type ``dtype`` (np.float32
    or np.float64). Cached (immutable scalars)."""
    one, band = kernel_constants(dtype)
    iterations, rtol = np.int64(iterations), dtype(DEFAULT_RTOL)
    coarse_mode = tb.EXACT if kernel == "exact" else tb.ITERATIVE
    return (coarse_mode, iterations, rtol, one, band), (
        KERNELS[kernel],
        iterations,
        rtol,
        one,
        band,
    )


def contact_constants(tree_a: SurrogateTree, tree_b: SurrogateTree) -> tuple:
    """The pose-free head ``(ε_a, ε_b, tiny, merge radius)`` (floats) of the ``setup`` that
    :func:`~engine.kernels.collision.contact_merge.contact_kernel` takes: the leaf ε of each
    body, :data:`TINY` times the larger bounding radius, and the smaller leaf ε."""
    ea, eb = tree_a.leaf_epsilon, tree_b.leaf_epsilon
    return ea, eb, TINY * max(tree_a.bounding_radius, tree_b.bounding_radius), min(ea, eb)


def unfolded_ranges(tree: SurrogateTree, nodes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The unfold rule for single nodes (see the module docstring): ``(first, count)``,
    both ``(k,)`` int64, such that node ``nodes[t]`` (``nodes (k,)`` int) is replaced by
    nodes ``first[t] … first[t] + count[t] − 1`` — a surrogate's children, or the leaf
    itself (``count`` 1)."""
    leaf = tree.face[nodes] >= 0
    first = np.where(leaf, nodes, tree.first_child[nodes]).astype(np.int64)
    count = np.where(leaf, 1, tree.child_count[nodes]).astype(np.int64)
    return first, count


def unfold_nodes(tree: SurrogateTree, nodes: np.ndarray) -> np.ndarray:
    """``(m,)`` int64: what replaces each of ``nodes (k,)`` (int), in order (a surrogate's
    children, a leaf itself; repeated nodes give repeated rows)."""
    first, count = unfolded_ranges(tree, nodes)
    return np.repeat(first, count) + _ranks(count)


def unfold_pairs(
    tree_a: SurrogateTree, tree_b: SurrogateTree, pairs: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """The child pairs of node pairs ``pairs (g, 2)`` (int; A's node, B's node): returns
    ``(children (m, 2) int64, owner (m,) int64)``, ``owner`` the row of ``pairs`` each
    child pair comes from. Each pair gives the product of what its two nodes unfold into
    (:func:`unfolded_ranges`), contiguous and A-major — the order in which
    :func:`~engine.kernels.collision.traversal.query_kernel` lists them."""
    first_a, count_a = unfolded_ranges(tree_a, pairs[:, 0])
    first_b, count_b = unfolded_ranges(tree_b, pairs[:, 1])
    sizes = count_a * count_b
    owner = np.repeat(np.arange(len(pairs)), sizes)
    rank, width = _ranks(sizes), count_b[owner]
    children = np.stack([first_a[owner] + rank // width, first_b[owner] + rank % width], 1)
    return children, owner


def _ranks(sizes: np.ndarray) -> np.ndarray:
    """``(sizes.sum(),)`` int64: 0 … sizes[t] − 1 for each ``t`` in turn."""
    return np.arange(sizes.sum()) - np.repeat(np.cumsum(sizes) - sizes, sizes)
