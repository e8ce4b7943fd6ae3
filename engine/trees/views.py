"""Derived arrays of a surrogate tree, computed on first use and kept with the tree.

A :class:`~engine.trees.tree.SurrogateTree` is immutable, so whatever the searches derive
from it (the leaf of each face, prepared triangle sets, bounding spheres, writable copies
of the traversal arrays) is computed once. :class:`TreeGeometry` holds what depends on the
triangles only and is shared by a tree and its ε-shifted copies
(:meth:`~engine.trees.tree.SurrogateTree.with_leaf_epsilon`); :class:`TreeViews` adds what
depends on the node ε. Every tree has one, as ``tree.views``.
"""

from __future__ import annotations

from functools import cached_property
from typing import NamedTuple

import numpy as np

from engine.geometry.distance import TriangleSet
from engine.geometry.mesh import Mesh
from engine.kernels.collision import distance_bounds as db
from engine.kernels.collision import distance_search as ds

__all__ = ["DistanceBounds", "TreeGeometry", "TreeStructure", "TreeViews"]


class TreeStructure(NamedTuple):
    """Writable copies of a tree's traversal arrays, as every kernel takes them (the tree's
    own arrays are read-only, and Numba compiles a kernel once more for every
    read-only/writable combination of its arguments).

    epsilon : (N,) float64; face : (N,) int32 (−1 for surrogates); first_child,
    child_count : (N,) int32
    """

    epsilon: np.ndarray
    face: np.ndarray
    first_child: np.ndarray
    child_count: np.ndarray


class DistanceBounds(NamedTuple):
    """The pose-independent node data of the distance branch and bound
    (:mod:`engine.collision.proximity`), body frame.

    gap : (N,) float64 — a surrogate's ε beyond the leaf ε (0 for leaves): a lower bound
        on the distance of its covered leaves is its own distance minus this
    leaf : (N,) bool; first_child, child_count : (N,) int64
    representative : (N,) int64 — the covered leaf whose centroid is nearest the node's
    centre : (N, 3) float64; radius : (N,) float64 — bounding sphere of the covered
        triangles (without the leaf ε)
    """

    gap: np.ndarray
    leaf: np.ndarray
    first_child: np.ndarray
    child_count: np.ndarray
    representative: np.ndarray
    centre: np.ndarray
    radius: np.ndarray


class TreeGeometry:
    """What depends on a tree's triangles only (shared by its ε-shifted copies).

    Parameters
    ----------
    triangles : (N, 3, 3) float64 — the nodes' triangles, body frame
    face : (N,) int32 — original face of a leaf, −1 for a surrogate
    parent : (N,) int32 — parent node, −1 for the root
        (the read-only arrays of the tree it is made for)
    """

    def __init__(self, triangles: np.ndarray, face: np.ndarray, parent: np.ndarray) -> None:
        self._triangles, self._face, self._parent = triangles, face, parent
        self._node_sets: dict[tuple[str, bool], TriangleSet] = {}
        self._mesh: Mesh | None = None

    @cached_property
    def face_nodes(self) -> np.ndarray:
        """(F,) int64 node index of each face's leaf."""
        leaves = np.flatnonzero(self._face >= 0)
        return leaves[np.argsort(self._face[leaves])]

    @cached_property
    def faces(self) -> np.ndarray:
        """(F,) int32 0 … F−1: the face of each leaf when leaves are indexed in face order."""
        return np.arange(len(self.face_nodes), dtype=np.int32)

    @cached_property
    def face_normals(self) -> np.ndarray:
        """(F, 3) float64 unit normals of the faces, body frame."""
        face = self._triangles[self.face_nodes]
        normal = np.cross(face[:, 1] - face[:, 0], face[:, 2] - face[:, 0])
        return normal / np.linalg.norm(normal, axis=1, keepdims=True)

    @cached_property
    def master(self) -> TriangleSet:
        """Every node prepared in float64, body frame (``coords_rm (N, 9)``, ``frames_rm
        (N, 14)``): the source the searches move and round."""
        return TriangleSet(self._triangles, "float64", "tree")

    def node_set(self, precision: str, leaves_only: bool) -> TriangleSet:
        """Every node (``N`` rows, node order) or, with ``leaves_only``, the leaves (``F``
        rows, face order) prepared in ``precision`` ("float32" or "float64"), body frame:
        :attr:`master`'s rows rounded. Computed once per key."""
        key = (precision, leaves_only)
        if key not in self._node_sets:
            index = self.face_nodes if leaves_only else np.arange(len(self._face))
            self._node_sets[key] = self.master.subset(index, precision)
        return self._node_sets[key]

    @cached_property
    def extent(self) -> float:
        """Largest absolute coordinate of the nodes (float), body frame."""
        return float(np.abs(self._triangles).max())

    @cached_property
    def radius(self) -> float:
        """Largest distance of a node's corner from the body-frame origin (float): a turn
        R₀ → R moves no point of the body by more than ‖R − R₀‖₂ times this."""
        return float(np.sqrt((self._triangles * self._triangles).sum(axis=-1)).max())

    @cached_property
    def representatives(self) -> np.ndarray:
        """(N,) int64: for each node, the covered leaf whose centroid is nearest the node
        triangle's centroid (a leaf represents itself; ties go to the lower index)."""
        centroid = self._triangles.mean(axis=1)
        leaves = np.flatnonzero(self._face >= 0)
        owners, members, dist = [leaves], [leaves], [np.zeros(len(leaves))]
        node, leaf = self._parent[leaves].astype(np.int64), leaves
        while len(node):
            keep = node >= 0
            node, leaf = node[keep], leaf[keep]
            owners.append(node)
            members.append(leaf)
            dist.append(np.linalg.norm(centroid[leaf] - centroid[node], axis=1))
            node = self._parent[node].astype(np.int64)
        owner, member, d = (np.concatenate(x) for x in (owners, members, dist))
        order = np.lexsort((member, d, owner))  # by owner, then distance, then index
        first = np.ones(len(order), bool)
        first[1:] = owner[order][1:] != owner[order][:-1]
        out = np.empty(len(self._face), np.int64)
        out[owner[order][first]] = member[order][first]
        return out

    @property
    def mesh(self) -> Mesh:
        """The mesh of the leaves (faces in face order, vertices deduplicated), unless the
        mesh the tree was built from was attached with :meth:`attach_mesh`."""
        if self._mesh is None:
            tris = self._triangles[self.face_nodes].reshape(-1, 3)
            vertices, faces = np.unique(tris, axis=0, return_inverse=True)
            self._mesh = Mesh(vertices, faces.reshape(-1, 3))
        return self._mesh

    def attach_mesh(self, mesh: Mesh) -> None:
        """Use ``mesh`` (the one the tree was built from) as :attr:`mesh`."""
        self._mesh = mesh


class TreeViews:
    """Derived arrays of one tree: its shared :attr:`geometry` and what depends on ε.

    Parameters
    ----------
    tree : SurrogateTree — the tree the views are of
    geometry : TreeGeometry, optional — the triangle views to share (an ε-shifted copy
        passes its source tree's); made for ``tree`` when None
    """

    def __init__(self, tree, geometry: TreeGeometry | None = None) -> None:
        self._tree = tree
        self._query_sides: dict = {}
        self._prepared_rows: dict = {}
        self.leaf_pairs_hint = 64
        """Room for leaf pairs that ``find_contacts`` gives its buffers on this tree: the
        most a query of it has needed so far (twice the count found), a hint only."""
        self.near_partner = 0
        """``id`` of the other tree's views in the last query of this tree (as body A)
        that got past the early-out, 0 once a later query of that pair is settled by the
        early-out's bounds-only search: ``find_contacts`` runs that pair's next query
        without the early-out's own kernel call (a hint only: the answer is the same
        either way)."""
        self.geometry = (
            TreeGeometry(tree.triangles, tree.face, tree.parent) if geometry is None else geometry
        )

    @cached_property
    def structure(self) -> TreeStructure:
        """Writable copies of ``(epsilon, face, first_child, child_count)``."""
        t = self._tree
        return TreeStructure(
            *(np.array(a) for a in (t.epsilon, t.face, t.first_child, t.child_count))
        )

    @cached_property
    def spheres(self) -> np.ndarray:
        """(N, 4) float64 bounding sphere (centre, radius) of each node's covered leaves'
        ε-regions, body frame: centred on the bounding box of the covered vertices, radius
        the farthest covered vertex plus the leaf ε (a ball is convex, so it then holds
        every covered triangle and its ε-region)."""
        tree = self._tree
        out = np.empty((len(tree), 4))
        low, high = np.empty((len(tree), 3)), np.empty((len(tree), 3))
        leaves = tree.face >= 0
        low[leaves], high[leaves] = tree.triangles[leaves].min(1), tree.triangles[leaves].max(1)
        for node in np.flatnonzero(~leaves)[::-1]:  # children before parents (BFS order)
            kids = slice(tree.first_child[node], tree.first_child[node] + tree.child_count[node])
            low[node], high[node] = low[kids].min(0), high[kids].max(0)
        out[:, :3] = (low + high) / 2
        radius = np.zeros(len(tree))
        node = np.flatnonzero(leaves)
        verts = tree.triangles[node]
        while len(node):  # every leaf's vertices against the centres of all its ancestors
            far = np.linalg.norm(verts - out[node, None, :3], axis=2).max(1)
            np.maximum.at(radius, node, far)
            keep = tree.parent[node] >= 0
            node, verts = tree.parent[node][keep], verts[keep]
        out[:, 3] = radius + tree.leaf_epsilon
        return out

    @cached_property
    def _box_ranges(self) -> tuple[np.ndarray, ...]:
        """Each node's covered leaf vertices measured two ways: ``axes (N, 3, 3)`` the
        principal axes (rows, unit: eigenvectors of the vertices' second moments about the
        node's sphere centre), ``lo, hi (N, 3)`` the vertices' range along them, and
        ``low, high (N, 3)`` their range along the body axes; float64
        (:func:`~engine.kernels.collision.distance_bounds.box_moments`, ``box_extents``)."""
        tree = self._tree
        n = len(tree)
        triangles = np.ascontiguousarray(tree.triangles, dtype=np.float64)
        face, parent = tree.face.astype(np.int64), tree.parent.astype(np.int64)
        second = np.zeros((n, 3, 3))
        db.box_moments(triangles, face, parent, np.ascontiguousarray(self.spheres[:, :3]), second)
        axes = np.ascontiguousarray(np.swapaxes(np.linalg.eigh(second)[1], 1, 2))  # rows
        ranges = []
        for frame in (axes, np.ascontiguousarray(np.broadcast_to(np.eye(3), (n, 3, 3)))):
            low, high = np.full((n, 3), np.inf), np.full((n, 3), -np.inf)
            db.box_extents(triangles, face, parent, frame, low, high)
            ranges += [low, high]
        return (axes, *ranges)

    def _grown_boxes(self, grow: float) -> np.ndarray:
        """(N, 15) float64 box of each node's covered vertices grown by ``grow`` plus a
        few ulp of the tree's extent (the layout of :attr:`boxes`): along the principal
        axes, or the body axes where that box is smaller."""
        axes, lo, hi, low, high = self._box_ranges
        grow = grow + 16.0 * np.finfo(float).eps * max(self.geometry.extent, 1e-300)
        principal = np.prod(hi - lo + 2 * grow, axis=1) < np.prod(high - low + 2 * grow, axis=1)
        out = np.empty((len(self._tree), 15))
        out[:, :3] = np.where(
            principal[:, None], np.einsum("nk,nki->ni", (lo + hi) / 2, axes), (low + high) / 2
        )
        out[:, 3:12] = np.where(principal[:, None], axes.reshape(-1, 9), np.eye(3).ravel())
        out[:, 12:] = np.where(principal[:, None], (hi - lo) / 2, (high - low) / 2) + grow
        return out  # writable, as the kernels take it (see TreeStructure); never written

    @cached_property
    def boxes(self) -> np.ndarray:
        """(N, 15) float64 oriented bounding box of each node's covered leaves' ε-regions,
        body frame, as :mod:`~engine.kernels.collision.boxes` reads it: centre (columns
        0–2), three orthonormal axes (3–5, 6–8, 9–11) and the half-extents along them
        (12–14). The axes are the principal axes of the covered leaves' vertices, or the
        body axes where that box is smaller (the leaf ε included); the half-extents reach
        the farthest covered vertex along each axis, plus the leaf ε and a few ulp of the
        tree's extent (a box grown by ε holds the ε-ball of each point it holds). So every
        point a node's :attr:`spheres` row must hold lies in its box."""
        return self._grown_boxes(self._tree.leaf_epsilon)

    @cached_property
    def bounds_table(self) -> np.ndarray:
        """(N, 21) float64 bounds of every node, body frame, as
        :func:`~engine.kernels.collision.boxes.bounds_apart` reads them (the search's and
        the early-out's bounds-only test): its :attr:`boxes` row, its :attr:`spheres` row,
        first child and child count (0 for a leaf)."""
        tree = self._tree
        count = np.where(tree.face >= 0, 0, tree.child_count)
        return np.hstack([self.boxes, self.spheres, tree.first_child[:, None], count[:, None]])

    def query_side_a(self, precision: str) -> tuple:
        """The A-side arguments of :func:`~engine.kernels.collision.pair_query.pair_query`
        (computed once per precision): ``(coords (N, 9), frames (N, 14)`` in
        ``precision``, ``epsilon, face, first_child, child_count (N,), spheres (N, 4),
        face normals (F, 3) float64, extent, leaf ε, boxes (N, 15), bounds table (N, 21))``."""
        side = self._query_sides.get(precision)
        if side is None:
            nodes = self.geometry.node_set(precision, False)
            side = (
                nodes.coords_rm,
                nodes.frames_rm,
                *self.structure,
                self.spheres,
                self.geometry.face_normals,
                self.geometry.extent,
                self._tree.leaf_epsilon,
                self.boxes,
                self.bounds_table,
            )
            self._query_sides[precision] = side
        return side

    @cached_property
    def query_side_b(self) -> tuple:
        """The B-side arguments of :func:`~engine.kernels.collision.pair_query.pair_query`:
        ``(coords (N, 9), frames (N, 14)`` float64 (the master set, body frame),
        ``epsilon, face, first_child, child_count (N,), spheres (N, 4), extent, leaf ε,
        number of faces, boxes (N, 15), bounds table (N, 21))``."""
        master = self.geometry.master
        return (
            master.coords_rm,
            master.frames_rm,
            *self.structure,
            self.spheres,
            self.geometry.extent,
            self._tree.leaf_epsilon,
            len(self.geometry.face_nodes),
            self.boxes,
            self.bounds_table,
        )

    @cached_property
    def root_sphere(self) -> tuple[tuple[float, float, float], float]:
        """The root's bounding sphere (:attr:`spheres` row 0) as Python floats:
        ``((x, y, z), radius)``, body frame."""
        x, y, z, radius = self.spheres[0].tolist()
        return (x, y, z), radius

    @cached_property
    def root_reach(self) -> float:
        """``|c| + r`` (float) of the root's bounding sphere (:attr:`spheres`, centre ``c``,
        radius ``r``, body frame): every covered ε-region lies within this distance of the
        body-frame origin, whatever the pose's rotation."""
        centre, radius = self.spheres[0, :3], self.spheres[0, 3]
        return float(np.sqrt(centre @ centre) + radius)

    @cached_property
    def distance_bounds(self) -> DistanceBounds:
        """The node data of the distance branch and bound (:class:`DistanceBounds`)."""
        tree, ball = self._tree, self.spheres
        leaf = tree.face >= 0
        return DistanceBounds(
            np.where(leaf, 0.0, np.maximum(tree.epsilon - tree.leaf_epsilon, 0.0)),
            leaf,
            tree.first_child.astype(np.int64),
            tree.child_count.astype(np.int64),
            self.geometry.representatives,
            ball[:, :3],
            np.maximum(ball[:, 3] - tree.leaf_epsilon, 0.0),
        )

    @cached_property
    def distance_boxes(self) -> np.ndarray:
        """``(N, 15)`` float64 oriented box of each node's covered faces, body frame
        (the layout of :attr:`boxes`, which :mod:`~engine.kernels.collision.distance_bounds`
        reads too): the box of the covered vertices without the leaf ε (a few ulp of the
        extent only), so it holds every covered face."""
        return self._grown_boxes(0.0)

    @cached_property
    def distance_rows(self) -> np.ndarray:
        """``(N, N_COLUMNS)`` float64 read-only node rows as
        :func:`~engine.kernels.collision.distance_search.distance_kernel` reads them (the
        column layout is that module's): each node's triangle and frame (the master set),
        bounding sphere, ``g``, children, face, the tree's extent and the node's box
        (:attr:`distance_boxes`)."""
        return _read_only(self.kernel_distance_rows)

    @cached_property
    def kernel_distance_rows(self) -> np.ndarray:
        """:attr:`distance_rows`, writeable, for the kernel only (which reads them): Numba
        types a read-only array argument on a slower path."""
        master, bounds = self.geometry.master, self.distance_bounds
        rows = np.empty((len(self._tree), ds.N_COLUMNS))
        rows[:, ds.COORDS : ds.COORDS + 9] = master.coords_rm
        rows[:, ds.FRAMES : ds.FRAMES + 14] = master.frames_rm
        rows[:, ds.CENTRE : ds.CENTRE + 3] = bounds.centre
        rows[:, ds.RADIUS] = bounds.radius
        rows[:, ds.GAP] = bounds.gap
        rows[:, ds.FIRST] = bounds.first_child
        rows[:, ds.COUNT] = np.where(bounds.leaf, 0, bounds.child_count)
        rows[:, ds.FACE] = self._tree.face
        rows[:, ds.EXTENT] = self.geometry.extent
        rows[:, db.BOX : db.BOX + db.N_BOX] = self.distance_boxes
        return rows

    def prepared_rows(self, precision: str) -> np.ndarray:
        """``(N, 23)`` read-only node triangles and frames in ``precision``, row-major (the
        float64 master rows rounded as :meth:`TreeGeometry.node_set` rounds them): the A
        side of :func:`~engine.kernels.collision.distance_search.distance_kernel` in
        float32; computed once per precision."""
        return _read_only(self.kernel_prepared_rows(precision))

    def kernel_prepared_rows(self, precision: str) -> np.ndarray:
        """:meth:`prepared_rows`, writeable, for the kernel only (as
        :attr:`kernel_distance_rows`)."""
        rows = self._prepared_rows.get(precision)
        if rows is None:
            nodes = self.geometry.node_set(precision, False)
            rows = np.ascontiguousarray(np.hstack([nodes.coords_rm, nodes.frames_rm]))
            self._prepared_rows[precision] = rows
        return rows


def _read_only(array: np.ndarray) -> np.ndarray:
    """A read-only view of ``array``."""
    view = array.view()
    view.flags.writeable = False
    return view
