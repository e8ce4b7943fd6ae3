"""The halo ε of bodies in a scene: defaults, and overrides by shifting a tree's node ε.

**Shifting.** Every node of a surrogate tree has ε = (largest distance from a covered
vertex to its surrogate triangle) + leaf ε, and the triangles do not depend on the leaf ε.
So a tree for another leaf ε′ is the same arrays with ``ε_node′ = ε_node − ε + ε′``
(leaves: exactly ε′): exactly as conservative as a tree built with ε′, and a contact query
on it finds the same leaf pairs with the same overlaps
(:meth:`~engine.trees.tree.SurrogateTree.with_leaf_epsilon`, which shares the tree's
triangle views: one array copy instead of a build). A scene builds each mesh's tree once
and shifts it for every other ε it is given.

**Defaults** (a body added without ε, or with ``epsilon="auto"``):

* a free body: :data:`DEFAULT_RELATIVE_EPSILON` (0.4 %) of its diameter, taken as twice
  the largest distance of a vertex from the vertices' mean (:func:`size_epsilon`);
* a fixed body (a floor, a wall, a plane): :data:`FIXED_EPSILON_FRACTION` (0.1) of the
  smallest free body's ε in the scene, never more than its own size default — resolved
  again whenever bodies are added, so a floor added before the balls follows them
  (:func:`fixed_epsilon`).

**Why these numbers.** With the paper's law (``PaperSpring``: F = K_s·δ/(ε_a + ε_b)·√m
against a fixed body) a body of mass m rests where its overlap fraction is
φ = δ/(ε_a + ε_b) = √m·g/K_s, i.e. with its surface (ε_a + ε_b)·(1 − φ) above the surface
it rests on: never below it (φ < 1), and for a radius-0.5 ball of density 1 (m = 0.52,
φ = 0.0071 at K_s = 1,000) a gap of 0.993·(ε_ball + ε_floor). The gap stays within 1 % of
the radius (0.005) only if ε_ball + ε_floor ≤ 0.00504: the ball's own default must be below
0.5 % of its diameter, whatever the floor's. 0.4 % and a tenth of it for the floor give
0.0044 and a gap of 0.00437 = 0.87 % of the radius (measured the same to 6 digits). The old
defaults (1 % of each body's diameter) left that ball 0.149 above a 14 m floor, 0.0199 above
a plane of ε = 0.01.

The price of thin halos: the paper's spring stores at most ½·K_s·√m·(ε_a + ε_b), so a body
dropped from rest higher than about (ε_a + ε_b)/(2φ) above the surface (0.31 m for that
ball; measured: from 0.28 m the overlap peaks at 0.90 of the halos, from 0.34 m at all of
them) is not stopped within the halos and its triangles reach the floor's. Give larger ε,
or a stiffer law, to drop things from higher.
"""

from __future__ import annotations

import math

import numpy as np

from engine.errors import InvalidArgumentError
from engine.geometry.mesh import Mesh
from engine.trees.build import build_tree
from engine.trees.tree import SurrogateTree

__all__ = [
    "AUTO",
    "DEFAULT_RELATIVE_EPSILON",
    "FIXED_EPSILON_FRACTION",
    "SceneTrees",
    "check_epsilon",
    "fixed_epsilon",
    "size_epsilon",
]

DEFAULT_RELATIVE_EPSILON = 0.004
"""A body's ε when not given: this fraction of its diameter (twice the largest distance of a
vertex from the vertices' mean; rotation invariant, 1 for a unit-diameter sphere). A fixed
body takes the smaller of this and :data:`FIXED_EPSILON_FRACTION` of the free bodies' ε."""
FIXED_EPSILON_FRACTION = 0.1
"""A fixed body's default ε: this fraction of the smallest free body's ε in its scene."""
AUTO = "auto"
"""``epsilon=AUTO``: the default rule, also for a tree (which otherwise keeps its own ε)."""
"""Caches on a tree that depend on its triangles only, shared by its shifted copies."""


def size_epsilon(mesh: Mesh, relative: float = DEFAULT_RELATIVE_EPSILON) -> float:
    """``relative`` × the diameter of ``mesh`` (float), the diameter taken as twice the
    largest distance of a vertex from the vertices' mean."""
    spread = mesh.vertices - mesh.vertices.mean(axis=0)
    return relative * 2 * float(np.sqrt((spread**2).sum(1).max()))


def fixed_epsilon(size: float, free_epsilon: np.ndarray) -> float:
    """A fixed body's default ε: the smaller of its own ``size`` default and
    :data:`FIXED_EPSILON_FRACTION` × the smallest of ``free_epsilon (k,) float64`` (the
    free bodies' ε in its scene; none: ``size``)."""
    if len(free_epsilon) == 0:
        return float(size)
    return min(float(size), FIXED_EPSILON_FRACTION * float(np.min(free_epsilon)))


def check_epsilon(value) -> float | str | None:
    """A body's ``epsilon`` argument: None, :data:`AUTO`, or a finite number > 0."""
    if value is None or (isinstance(value, str) and value == AUTO):
        return value
    if isinstance(value, bool) or not isinstance(value, int | float | np.integer | np.floating):
        raise InvalidArgumentError(f"epsilon must be a number or {AUTO!r}, got {value!r}")
    eps = float(value)
    if not (math.isfinite(eps) and eps > 0):
        raise InvalidArgumentError(f"epsilon must be finite and > 0, got {value!r}")
    return eps


class SceneTrees:
    """The trees of a scene's bodies (host bookkeeping for :class:`~engine.scene.Scene`).

    Each mesh (or tree) given to the scene has one **base** tree — a mesh's built on its
    first use, at the ε it was given or its size default — and every ε its bodies use is
    that base shifted (:meth:`~engine.trees.tree.SurrogateTree.with_leaf_epsilon`, one per
    base and ε). ``trees`` lists the trees some body uses (``Scene.tree_index`` points
    into it). Fixed bodies whose ε follows the default rule are remembered and re-resolved
    by :meth:`resolve`; ``version`` counts the changes of ``trees``.
    """

    def __init__(self) -> None:
        self.trees: list[SurrogateTree] = []
        self.version = 0
        self._slots: dict[int, int] = {}  # id(tree) -> its index in trees
        self._bases: dict[tuple, SurrogateTree] = {}  # ("mesh" | "tree", id) -> base
        self._shifts: dict[tuple, SurrogateTree] = {}  # (id(base), ε) -> shifted tree
        self._ruled: list[tuple[np.ndarray, SurrogateTree, float]] = []  # bodies, base, size

    def base(self, body, epsilon: float | str | None) -> tuple[SurrogateTree, Mesh]:
        """The base tree of ``body`` (a Mesh or SurrogateTree) and its mesh; a mesh's is
        built on its first use (at ``epsilon`` when a number, else its size default)."""
        if isinstance(body, SurrogateTree):
            return self._bases.setdefault(("tree", id(body)), body), body.views.geometry.mesh
        if not isinstance(body, Mesh):
            raise InvalidArgumentError("body must be an engine.Mesh or an engine.SurrogateTree")
        key = ("mesh", id(body))
        if key not in self._bases:
            tree = build_tree(body, epsilon if isinstance(epsilon, float) else size_epsilon(body))
            tree.views.geometry.attach_mesh(body)
            self._bases[key] = tree
        return self._bases[key], body

    def place(self, body, epsilon, base: SurrogateTree, mesh: Mesh, fixed: bool, bodies) -> int:
        """The index in :attr:`trees` for ``bodies (k,) int64`` of ``body`` with the checked
        ``epsilon`` (:func:`check_epsilon`): a number is used; None keeps a tree's own ε;
        otherwise the default — a free body's size default, a fixed body's rule (remembered
        for :meth:`resolve`, placed at its size default until then)."""
        if epsilon is None and isinstance(body, SurrogateTree):
            eps = base.leaf_epsilon
        elif epsilon is None or epsilon == AUTO:
            eps = size_epsilon(mesh)
            if fixed:
                self._ruled.append((np.asarray(bodies), base, eps))
        else:
            eps = float(epsilon)
        return self._slot(self._shifted(base, eps))

    def resolve(self, tree_index: np.ndarray, fixed: np.ndarray) -> np.ndarray | None:
        """Every ruled fixed body's tree for the bodies now in the scene (``tree_index
        (n,) int64``, ``fixed (n,) bool``): :func:`fixed_epsilon` of its size default and
        the free bodies' ε. Drops the trees no body uses any more. Returns the new
        ``tree_index (n,) int64``, or None when nothing changed."""
        if not self._ruled:
            return None
        leaf = np.array([t.leaf_epsilon for t in self.trees])
        free = leaf[tree_index[~fixed]]
        index = tree_index.copy()
        for bodies, base, size in self._ruled:
            index[bodies] = self._slot(self._shifted(base, fixed_epsilon(size, free)))
        if np.array_equal(index, tree_index):
            return None
        used = np.unique(index)
        if len(used) < len(self.trees):
            remap = np.full(len(self.trees), -1, np.int64)
            remap[used] = np.arange(len(used))
            self.trees = [self.trees[t] for t in used]
            self.version += 1
            index = remap[index]
            self._slots = {id(t): i for i, t in enumerate(self.trees)}
            keep = set(self._slots) | {id(t) for t in self._bases.values()}
            self._shifts = {k: t for k, t in self._shifts.items() if id(t) in keep}
        return index

    def _shifted(self, base: SurrogateTree, epsilon: float) -> SurrogateTree:
        key = (id(base), float(epsilon))
        if key not in self._shifts:
            self._shifts[key] = base.with_leaf_epsilon(epsilon)
        return self._shifts[key]

    def _slot(self, tree: SurrogateTree) -> int:
        if id(tree) not in self._slots:
            self._slots[id(tree)] = len(self.trees)
            self.trees.append(tree)
            self.version += 1
        return self._slots[id(tree)]
