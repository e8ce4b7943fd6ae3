"""Surrogate trees (paper §4, Appendix B): a cascade of coarse triangle models of a mesh.

The root is one surrogate triangle for the whole mesh. A node covering more than
``branching`` triangles is split by seeded k-means on triangle centroids into
``branching`` compact groups, each with its own surrogate node; a node covering at
most ``branching`` triangles has the original triangles as its children (leaves).

Each surrogate has a **conservative** ε: the maximum, over the vertices of the
covered original triangles, of their distance to the surrogate, plus the leaf ε.
Distance to a triangle is convex, so its maximum over a covered triangle is attained
at a vertex: every covered triangle's ε-region lies inside the surrogate's. The
distances come from the exact triangle kernel (a vertex is a zero-area triangle).

Surrogate construction (:mod:`engine.surrogates`): the initial triangle is the smallest
enclosing equilateral triangle of the covered vertices in their mid-height PCA plane
(24 orientations), whose ε is the half-thickness of the group. It is then **fitted** by
minimising the Appendix-A functional (``fit="epsilon"``, the default: soft maximum of the
distances from the covered vertices to the surrogate, plus a weighted copy of the
paper's surrogate-to-covered term that keeps the triangle small, plus the area
regulariser; see :data:`engine.surrogates.FITS`). The fitted triangle replaces the
initial one only if its ε-region — 2·area·ε + perimeter·πε²/2 + 4/3·πε³ with its exact
conservative ε — is not larger, so fitting never makes a node worse. ``fit="paper"``
minimises the paper's literal functional instead, ``fit="initial"`` keeps the initial
triangle. k-means is the only random step: equal inputs and seed give identical trees.

Storage is flat and in breadth-first order (levels contiguous, each node's children
contiguous): ``triangles (N, 3, 3)``, ``epsilon (N,)``, ``level``, ``parent``,
``first_child``, ``child_count`` and ``face`` (the original face of a leaf, -1 for a
surrogate), all saved in one versioned ``.npz``.
"""

from __future__ import annotations

import io
import os
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .distance import triangle_distances
from .errors import InvalidArgumentError
from .mesh import Mesh
from .surrogates import (
    DEFAULT_FIT,
    FitParameters,
    enclosing_triangle,
    fit_triangle,
    region_volume,
    resolve_fit,
)

__all__ = ["TREE_FORMAT", "SurrogateTree", "TreeStats", "build_tree"]

TREE_FORMAT = 1
"""Version of the ``.npz`` layout written by :meth:`SurrogateTree.save`."""
_ARRAYS = ("triangles", "epsilon", "level", "parent", "first_child", "child_count", "face")
_KMEANS_ITERATIONS = 20


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

    Build with :func:`build_tree`; persist with :meth:`save` / :meth:`load`.
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

    def __len__(self) -> int:
        return len(self.epsilon)

    @property
    def is_leaf(self) -> np.ndarray:
        """(N,) bool — node is an original triangle."""
        return self.face >= 0

    def children(self, node: int) -> np.ndarray:
        """Indices of the children of ``node`` (empty for a leaf)."""
        start = self.first_child[node]
        return np.arange(start, start + self.child_count[node])

    def covered_faces(self, node: int) -> np.ndarray:
        """Original face indices below ``node`` (sorted)."""
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


def build_tree(
    mesh: Mesh,
    epsilon: float,
    branching: int = 8,
    seed: int = 0,
    fit: str | FitParameters = DEFAULT_FIT,
    *,
    progress: Callable[[int, int], None] | None = None,
) -> SurrogateTree:
    """Build the surrogate tree of ``mesh``.

    Parameters
    ----------
    mesh : Mesh
    epsilon : float — ε of the original triangles (the body's halo), ≥ 0
    branching : int — surrogates per split and most leaves per node (N_surrogate), ≥ 2
    seed : int — k-means seed; equal inputs give identical trees
    fit : str or FitParameters — surrogate construction: a key of
        :data:`engine.surrogates.FITS` ("epsilon", fitted, the default; "paper", the
        paper's literal functional; "initial", the enclosing triangle unfitted) or
        parameters of the functional
    progress : callable, optional — ``progress(levels_done, nodes_done)`` after each
        finished level, on the building thread (levels_done counts the root's as 1)

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
    params = resolve_fit(fit)
    tris = mesh.triangles
    centroids = tris.mean(axis=1)
    rng = np.random.default_rng(seed)
    nodes: dict[str, list] = {name: [] for name in _ARRAYS}

    def add(triangle, eps, level, parent, face) -> int:
        nodes["triangles"].append(triangle)
        nodes["epsilon"].append(eps)
        nodes["level"].append(level)
        nodes["parent"].append(parent)
        nodes["first_child"].append(0)
        nodes["child_count"].append(0)
        nodes["face"].append(face)
        return len(nodes["face"]) - 1

    all_faces = np.arange(len(tris))
    root_tri, root_eps = _surrogate(tris[all_faces], epsilon, params)
    queue = deque([(add(root_tri, root_eps, 0, -1, -1), all_faces)])
    reported = 0
    while queue:
        node, faces = queue.popleft()
        level = nodes["level"][node] + 1
        if progress is not None and level > reported:
            reported = level
            progress(level, len(nodes["face"]))  # levels 0 … level − 1 are all built
        nodes["first_child"][node] = len(nodes["face"])
        if len(faces) <= branching:
            for f in faces:
                add(tris[f], epsilon, level, node, int(f))
            nodes["child_count"][node] = len(faces)
            continue
        groups = _kmeans(centroids[faces], branching, rng)
        for group in groups:
            sub = faces[group]
            tri, eps = _surrogate(tris[sub], epsilon, params)
            queue.append((add(tri, eps, level, node, -1), sub))
        nodes["child_count"][node] = len(groups)
    arrays = {
        "triangles": np.array(nodes["triangles"], dtype=np.float64).reshape(-1, 3, 3),
        "epsilon": np.array(nodes["epsilon"], dtype=np.float64),
        **{k: np.array(nodes[k], dtype=np.int32) for k in _ARRAYS[2:]},
    }
    if progress is not None:
        progress(reported + 1, len(nodes["face"]))
    verts = tris.reshape(-1, 3)
    radius = float(np.linalg.norm(verts - verts.mean(axis=0), axis=1).max())
    return SurrogateTree(arrays, epsilon, branching, seed, radius)


def _kmeans(points: np.ndarray, k: int, rng: np.random.Generator) -> list[np.ndarray]:
    """Split ``points (m, 3)`` into ``k`` non-empty groups (index arrays), m > k.

    k-means++ seeding from the points themselves, then Lloyd iterations; an emptied
    cluster is re-seeded with the point farthest from its centre. Coincident points
    that k-means cannot separate are split evenly by index.
    """
    m = len(points)
    centres = [points[rng.integers(m)]]
    for _ in range(1, k):
        d2 = np.min([((points - c) ** 2).sum(axis=1) for c in centres], axis=0)
        total = d2.sum()
        pick = rng.choice(m, p=d2 / total) if total > 0 else rng.integers(m)
        centres.append(points[pick])
    centres = np.array(centres)
    for _ in range(_KMEANS_ITERATIONS):
        d2 = ((points[:, None, :] - centres[None]) ** 2).sum(axis=2)
        label = d2.argmin(axis=1)
        for c in range(k):
            members = label == c
            if members.any():
                centres[c] = points[members].mean(axis=0)
            else:
                far = int(d2[np.arange(m), label].argmax())
                centres[c] = points[far]
                label[far] = c
    d2 = ((points[:, None, :] - centres[None]) ** 2).sum(axis=2)
    label = d2.argmin(axis=1)
    groups = [np.flatnonzero(label == c) for c in range(k)]
    groups = [g for g in groups if len(g)]
    if len(groups) < 2:  # k-means cannot separate the points: split by index
        return [g for g in np.array_split(np.arange(m), k) if len(g)]
    return groups


def _surrogate(
    tris: np.ndarray, leaf_epsilon: float, params: FitParameters | None
) -> tuple[np.ndarray, float]:
    """Surrogate triangle ``(3, 3)`` and conservative ε for the triangles ``(m, 3, 3)``.

    The fitted triangle (``params`` None: no fit) replaces the initial one only if its
    ε-region with its exact ε is not larger.
    """
    if len(tris) == 1:
        return tris[0].copy(), float(leaf_epsilon)
    points = np.unique(tris.reshape(-1, 3), axis=0)
    tri = enclosing_triangle(points, tris)
    if params is None:
        return tri, float(_point_distances(points, tri[None]).max() + leaf_epsilon)
    fitted = fit_triangle(points, tris, tri, params)
    eps, fitted_eps = _point_distances(points, np.stack([tri, fitted])).max(axis=1)
    if region_volume(fitted, fitted_eps) <= region_volume(tri, eps):
        tri, eps = fitted, fitted_eps
    return tri, float(eps + leaf_epsilon)


def _point_distances(points: np.ndarray, tris: np.ndarray) -> np.ndarray:
    """Distances ``(k, m)`` from ``points (m, 3)`` to each of ``tris (k, 3, 3)``.

    Exact kernel, float64; a point is passed as a zero-area triangle.
    """
    pts = np.broadcast_to(points[None, :, None, :], (len(tris), len(points), 3, 3))
    other = np.broadcast_to(tris[:, None], pts.shape)
    found = triangle_distances(pts.reshape(-1, 3, 3), other.reshape(-1, 3, 3), "exact", "float64")
    return found.distance.reshape(len(tris), len(points))
