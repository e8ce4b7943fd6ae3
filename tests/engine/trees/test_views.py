"""A tree's derived arrays (engine/trees/views.py, ``tree.views``) against direct computation
from the tree's own arrays and mesh; what ε-shifted copies share and what they do not."""

from __future__ import annotations

import numpy as np
import pytest

from engine import TriangleSet, build_tree, shapes

MESHES = {
    "sphere": shapes.icosphere(2, radius=0.7),  # 320 faces, convex
    "torus": shapes.torus(1.0, 0.3, 12, 8),  # 192 faces, non-convex
}


@pytest.fixture(scope="module", params=sorted(MESHES))
def built(request):
    mesh = MESHES[request.param]
    return mesh, build_tree(mesh, epsilon=0.01, branching=4)


def leaves_under(tree, node: int) -> np.ndarray:
    """(k,) int64 the leaf nodes under ``node``, from the tree's own arrays."""
    faces = tree.covered_faces(node)
    return np.array([np.flatnonzero(tree.face == f)[0] for f in faces], np.int64)


# ------------------------------------------------------------------ the triangles' views
def test_face_nodes_and_faces(built):
    mesh, tree = built
    geometry = tree.views.geometry
    expected = np.array([np.flatnonzero(tree.face == f)[0] for f in range(mesh.n_faces)])
    np.testing.assert_array_equal(geometry.face_nodes, expected)
    assert geometry.face_nodes.dtype == np.int64
    np.testing.assert_array_equal(tree.face[geometry.face_nodes], geometry.faces)
    assert geometry.faces.dtype == np.int32
    np.testing.assert_array_equal(geometry.faces, np.arange(mesh.n_faces))
    # a leaf is its face's triangle, so the leaves in face order are the mesh
    np.testing.assert_array_equal(tree.triangles[geometry.face_nodes], mesh.triangles)


def test_face_normals_are_the_meshs(built):
    mesh, tree = built
    normals = tree.views.geometry.face_normals
    assert normals.shape == (mesh.n_faces, 3) and normals.dtype == np.float64
    np.testing.assert_allclose(normals, mesh.face_normals, rtol=0, atol=1e-15)


def test_extent_is_the_largest_absolute_node_coordinate(built):
    _, tree = built
    largest = max(abs(float(x)) for x in tree.triangles.ravel())
    assert tree.views.geometry.extent == largest
    assert largest >= np.abs(tree.triangles[tree.face >= 0]).max()  # surrogates may stick out


def test_master_and_node_sets_are_the_prepared_node_triangles(built):
    _, tree = built
    geometry = tree.views.geometry
    leaves = tree.triangles[geometry.face_nodes]
    np.testing.assert_array_equal(geometry.master.coords, TriangleSet(tree.triangles).coords)
    np.testing.assert_array_equal(geometry.master.frames, TriangleSet(tree.triangles).frames)
    for precision in ("float32", "float64"):
        every = geometry.node_set(precision, False)
        only = geometry.node_set(precision, True)
        assert len(every) == len(tree) and len(only) == len(leaves)
        assert every.dtype == only.dtype == np.dtype(precision)
        direct = TriangleSet(leaves, precision)
        np.testing.assert_array_equal(only.coords, direct.coords)
        np.testing.assert_array_equal(only.frames, direct.frames)
        assert geometry.node_set(precision, True) is only  # prepared once
    assert geometry.node_set("float32", True) is not geometry.node_set("float64", True)


def test_the_mesh_of_the_leaves(built):
    mesh, tree = built
    leaves = tree.views.geometry.mesh
    assert leaves.n_faces == mesh.n_faces and leaves.n_vertices == mesh.n_vertices
    np.testing.assert_array_equal(leaves.triangles, mesh.triangles)
    assert leaves.is_closed


def test_representatives_are_the_nearest_covered_leaf(built):
    _, tree = built
    representatives = tree.views.geometry.representatives
    centroid = tree.triangles.mean(axis=1)
    for node in range(len(tree)):
        leaves = leaves_under(tree, node)
        distance = np.linalg.norm(centroid[leaves] - centroid[node], axis=1)
        nearest = leaves[distance == distance.min()].min()  # ties: the lower index
        assert representatives[node] == nearest
    leaves = np.flatnonzero(tree.face >= 0)
    np.testing.assert_array_equal(representatives[leaves], leaves)


# ------------------------------------------------------------------ the ε-dependent views
def test_structure_is_a_writable_copy_of_the_traversal_arrays(built):
    _, tree = built
    structure = tree.views.structure
    for name in ("epsilon", "face", "first_child", "child_count"):
        mine, theirs = getattr(structure, name), getattr(tree, name)
        np.testing.assert_array_equal(mine, theirs)
        assert mine.dtype == theirs.dtype and mine.flags.writeable
        assert not np.shares_memory(mine, theirs)
    assert tree.views.structure is structure  # computed once


def test_spheres_hold_every_covered_triangle_and_its_halo(built):
    _, tree = built
    spheres = tree.views.spheres
    assert spheres.shape == (len(tree), 4) and spheres.dtype == np.float64
    for node in range(len(tree)):
        vertices = tree.triangles[leaves_under(tree, node)].reshape(-1, 3)
        low, high = vertices.min(0), vertices.max(0)
        np.testing.assert_allclose(spheres[node, :3], (low + high) / 2, rtol=0, atol=1e-15)
        farthest = np.linalg.norm(vertices - spheres[node, :3], axis=1).max()
        assert spheres[node, 3] == pytest.approx(farthest + tree.leaf_epsilon, rel=1e-14)


def test_distance_bounds(built):
    _, tree = built
    bounds, spheres = tree.views.distance_bounds, tree.views.spheres
    leaf = tree.face >= 0
    np.testing.assert_array_equal(bounds.leaf, leaf)
    np.testing.assert_array_equal(bounds.first_child, tree.first_child)
    np.testing.assert_array_equal(bounds.child_count, tree.child_count)
    assert bounds.first_child.dtype == bounds.child_count.dtype == np.int64
    for node in range(len(tree)):
        gap = 0.0 if leaf[node] else max(tree.epsilon[node] - tree.leaf_epsilon, 0.0)
        assert bounds.gap[node] == gap
        vertices = tree.triangles[leaves_under(tree, node)].reshape(-1, 3)
        radius = np.linalg.norm(vertices - bounds.centre[node], axis=1).max()
        assert bounds.radius[node] == pytest.approx(radius, rel=1e-12)
    np.testing.assert_array_equal(bounds.centre, spheres[:, :3])
    np.testing.assert_array_equal(bounds.representative, tree.views.geometry.representatives)


# ------------------------------------------------------------------ ε-shifted copies
def test_epsilon_copies_share_the_triangle_views_and_not_the_epsilon_ones(built):
    _, tree = built
    assert tree.with_leaf_epsilon(tree.leaf_epsilon) is tree
    copy = tree.with_leaf_epsilon(0.03)
    assert copy.views is not tree.views
    assert copy.views.geometry is tree.views.geometry  # face_nodes, normals, node sets, …
    assert copy.views.geometry.master is tree.views.geometry.master
    # what depends on ε is the copy's own
    shift = copy.leaf_epsilon - tree.leaf_epsilon
    assert copy.views.spheres is not tree.views.spheres
    np.testing.assert_array_equal(copy.views.spheres[:, :3], tree.views.spheres[:, :3])
    np.testing.assert_allclose(copy.views.spheres[:, 3], tree.views.spheres[:, 3] + shift)
    np.testing.assert_array_equal(copy.views.structure.epsilon, copy.epsilon)
    assert not np.array_equal(copy.views.structure.epsilon, tree.views.structure.epsilon)
    gap, old_gap = copy.views.distance_bounds.gap, tree.views.distance_bounds.gap
    np.testing.assert_allclose(gap, old_gap, rtol=0, atol=1e-14)  # the shift's rounding only
    assert (gap >= 0).all()


def test_distance_rows_are_read_only_views_of_the_kernels_rows(built):
    """The public rows cannot be written; the kernel's (writeable: Numba types read-only
    arguments on a slower path) are the same memory, for float64 and float32."""
    _, tree = built
    views = tree.views
    for public, kernel in (
        (views.distance_rows, views.kernel_distance_rows),
        (views.prepared_rows("float32"), views.kernel_prepared_rows("float32")),
    ):
        assert not public.flags.writeable and kernel.flags.writeable
        assert np.shares_memory(public, kernel)
        np.testing.assert_array_equal(public, kernel)
        with pytest.raises(ValueError):
            public[0, 0] = 1.0
