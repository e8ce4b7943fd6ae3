"""Surrogate trees (paper §4, Appendix B): a cascade of coarse triangle models of a mesh.

The root is one surrogate triangle for the whole mesh; each surrogate's children are
surrogates of compact groups of its covered triangles or, below ``branching`` triangles,
the original triangles themselves (the leaves). :func:`~engine.trees.build.build_tree`
builds a tree; this module holds its type, :class:`SurrogateTree`.

Each surrogate has a **conservative** ε: the maximum, over the vertices of the
covered original triangles, of their distance to the surrogate, plus the leaf ε.
Distance to a triangle is convex, so its maximum over a covered triangle is attained
at a vertex: every covered triangle's ε-region lies inside the surrogate's.

Storage is flat and in breadth-first order (levels contiguous, each node's children
contiguous): ``triangles (N, 3, 3)`` float64, ``epsilon (N,)`` float64, ``level``,
``parent`` (−1 for the root), ``first_child``, ``child_count`` and ``face`` (the original
face of a leaf, −1 for a surrogate), (N,) int32, all read-only and saved in one
versioned ``.npz``. Derived arrays live in ``tree.views`` (:mod:`engine.trees.views`).
"""

from __future__ import annotations

import io
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from engine.errors import InvalidArgumentError
from engine.trees.surrogates import region_volume
from engine.trees.views import TreeViews

__all__ = ["TREE_FORMAT", "SurrogateTree", "TreeStats"]

TREE_FORMAT = 2
"""Version of the ``.npz`` layout written by :meth:`SurrogateTree.save`."""
_ARRAYS = ("triangles", "epsilon", "level", "parent", "first_child", "child_count", "face")


@dataclass(frozen=True)
class TreeStats:
    """Shape of a tree, and the paper's "surrogate properties" (root diameter and ε).

    depth : number of levels below the root (0 for a single-node tree)
    nodes_per_level : surrogates and leaves per level, root first
    surrogates, leaves : node counts
    root_diameter : longest edge of the root surrogate
    root_epsilon : ε of the root
    volume_ratio : volume of the root's ε-region (a prism with rounded edges, bounded
        by area·2ε + perimeter·πε²/2 + 4/3·πε³) over that of the mesh's bounding sphere
    """

    depth: int
    nodes_per_level: tuple[int, ...]
    surrogates: int
    leaves: int
    root_diameter: float
    root_epsilon: float
    volume_ratio: float


class SurrogateTree:
    """A surrogate tree in flat, breadth-first arrays (see the module docstring).

    Build with :func:`~engine.trees.build.build_tree`; persist with :meth:`save` /
    :meth:`load`.

    Parameters
    ----------
    arrays : dict of str to ndarray — ``triangles``, ``epsilon``, ``level``, ``parent``,
        ``first_child``, ``child_count``, ``face`` (the module docstring's layout); kept
        as read-only contiguous arrays
    leaf_epsilon : float — ε of the leaves (the body's halo)
    branching : int — the build's branching factor
    seed : int — the build's seed
    bounding_radius : float — largest distance of a vertex from the vertices' mean
    """

    def __init__(
        self,
        arrays: dict[str, np.ndarray],
        leaf_epsilon: float,
        branching: int,
        seed: int,
        bounding_radius: float,
    ) -> None:
        for name in _ARRAYS:
            setattr(self, name, np.ascontiguousarray(arrays[name]))
            getattr(self, name).flags.writeable = False
        self.leaf_epsilon = float(leaf_epsilon)
        self.branching = int(branching)
        self.seed = int(seed)
        self.bounding_radius = float(bounding_radius)
        self.views = TreeViews(self)  # derived arrays, computed on first use (engine.trees.views)

    def __len__(self) -> int:
        return len(self.epsilon)

    @property
    def is_leaf(self) -> np.ndarray:
        """(N,) bool — node is an original triangle."""
        return self.face >= 0

    def with_leaf_epsilon(self, leaf_epsilon: float) -> SurrogateTree:
        """This tree at leaf ε = ``leaf_epsilon`` (≥ 0): the same read-only arrays except
        ``epsilon (N,) float64``, each node's shifted by the change of the leaf ε. A node's
        ε is (largest distance of a covered vertex from its triangle) + leaf ε and the
        triangles do not depend on the leaf ε, so the shift is as conservative as a build
        at ``leaf_epsilon``: ε_node − ε_leaf loses up to half an ulp of the old ε, which
        one ulp adds back, and the sum is rounded up by 8 ulp. Leaves get
        ``leaf_epsilon`` exactly. Returns ``self`` when the ε is its own."""
        leaf_epsilon = float(leaf_epsilon)
        if leaf_epsilon == self.leaf_epsilon:
            return self
        geometric = np.maximum(self.epsilon - self.leaf_epsilon + np.spacing(self.epsilon), 0.0)
        shifted = (geometric + leaf_epsilon) * (1 + 8 * np.finfo(float).eps)
        arrays = {name: getattr(self, name) for name in _ARRAYS}
        arrays["epsilon"] = np.where(self.face >= 0, leaf_epsilon, shifted)
        out = SurrogateTree(arrays, leaf_epsilon, self.branching, self.seed, self.bounding_radius)
        out.views = TreeViews(out, self.views.geometry)  # the triangles' views are shared
        return out

    def children(self, node: int) -> np.ndarray:
        """``(k,)`` int node indices of the children of ``node`` (empty for a leaf)."""
        start = self.first_child[node]
        return np.arange(start, start + self.child_count[node])

    def covered_faces(self, node: int) -> np.ndarray:
        """``(k,)`` int64 original face indices below ``node``, sorted."""
        stack, faces = [int(node)], []
        while stack:
            k = stack.pop()
            if self.face[k] >= 0:
                faces.append(int(self.face[k]))
            else:
                stack.extend(self.children(k).tolist())
        return np.sort(np.array(faces, dtype=np.int64))

    @property
    def stats(self) -> TreeStats:
        """Shape of the tree and its root's surrogate properties (:class:`TreeStats`)."""
        levels = np.bincount(self.level)
        root = self.triangles[0]
        edges = np.linalg.norm(root - np.roll(root, 1, axis=0), axis=1)
        eps = float(self.epsilon[0])
        region = region_volume(root, eps)
        sphere = 4 / 3 * np.pi * self.bounding_radius**3
        return TreeStats(
            depth=len(levels) - 1,
            nodes_per_level=tuple(int(n) for n in levels),
            surrogates=int((self.face < 0).sum()),
            leaves=int((self.face >= 0).sum()),
            root_diameter=float(edges.max()),
            root_epsilon=eps,
            volume_ratio=float(region / sphere) if sphere > 0 else float("inf"),
        )

    def save(self, path: str | Path | io.BytesIO) -> None:
        """Write one ``.npz`` (format :data:`TREE_FORMAT`); a path is written atomically."""
        payload = {name: getattr(self, name) for name in _ARRAYS}
        meta = np.array(
            [TREE_FORMAT, self.leaf_epsilon, self.branching, self.seed, self.bounding_radius],
            dtype=np.float64,
        )
        if isinstance(path, str | Path):
            path = Path(path)
            tmp = path.with_name(path.name + ".tmp")
            with open(tmp, "wb") as fh:
                np.savez(fh, meta=meta, **payload)
                fh.flush()
                os.fsync(fh.fileno())
            tmp.replace(path)
        else:
            np.savez(path, meta=meta, **payload)

    @classmethod
    def load(cls, path: str | Path | io.BytesIO) -> SurrogateTree:
        """Read a tree written by :meth:`save`; a wrong or damaged file raises
        :class:`~engine.errors.InvalidArgumentError`."""
        try:
            with np.load(path, allow_pickle=False) as data:
                meta = data["meta"]
                arrays = {name: data[name] for name in _ARRAYS}
        except (OSError, ValueError, KeyError, EOFError) as exc:
            raise InvalidArgumentError(f"not a surrogate tree file: {exc}") from None
        if meta.shape != (5,) or int(meta[0]) != TREE_FORMAT:
            raise InvalidArgumentError(
                f"surrogate tree format {meta[0] if meta.size else '?'} is not supported "
                f"(this version reads format {TREE_FORMAT})"
            )
        tree = cls(arrays, meta[1], int(meta[2]), int(meta[3]), meta[4])
        tree._check()
        return tree

    def _check(self) -> None:
        n = len(self.epsilon)
        shapes_ok = self.triangles.shape == (n, 3, 3) and all(
            getattr(self, name).shape == (n,) for name in _ARRAYS[1:]
        )
        if not shapes_ok or n == 0 or not np.isfinite(self.triangles).all():
            raise InvalidArgumentError("surrogate tree file has inconsistent arrays")
        ends = self.first_child + self.child_count
        if (self.child_count < 0).any() or (ends > n).any() or (self.parent[1:] < 0).any():
            raise InvalidArgumentError("surrogate tree file has an invalid node structure")
