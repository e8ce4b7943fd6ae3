"""Surrogate trees: structure, conservative ε, determinism, persistence, validation."""

from __future__ import annotations

import io

import numpy as np
import pytest

from engine import InvalidArgumentError, shapes
from engine.geometry.reference import point_triangle_distance_naive
from engine.trees.build import build_tree
from engine.trees.tree import TREE_FORMAT, SurrogateTree

MESHES = {
    "icosphere": lambda: shapes.icosphere(2),
    "noisy_sphere": lambda: shapes.noisy_sphere(subdivisions=2, eta_r=1.4, seed=5),
    "stretched_sphere": lambda: shapes.stretched_sphere(subdivisions=2, eta=2.6),
    "torus": lambda: shapes.torus(major_segments=24, minor_segments=10),
    "box": lambda: shapes.box(extents=(2.0, 1.0, 0.5)),
    "plane": lambda: shapes.plane(size=(4.0, 4.0), divisions=6),
}


@pytest.fixture(scope="module", params=sorted(MESHES))
def built(request):
    mesh = MESHES[request.param]()
    return mesh, build_tree(mesh, epsilon=0.01, branching=8, seed=1)


def test_every_face_is_exactly_one_leaf(built):
    mesh, tree = built
    faces = tree.face[tree.face >= 0]
    np.testing.assert_array_equal(np.sort(faces), np.arange(mesh.n_faces))
    np.testing.assert_array_equal(tree.covered_faces(0), np.arange(mesh.n_faces))
    leaves = tree.face >= 0
    np.testing.assert_array_equal(tree.triangles[leaves], mesh.triangles[tree.face[leaves]])
    np.testing.assert_array_equal(tree.epsilon[leaves], 0.01)


def test_breadth_first_layout(built):
    _, tree = built
    assert tree.parent[0] == -1 and tree.level[0] == 0
    assert (np.diff(tree.level) >= 0).all()  # levels contiguous
    surrogates = np.flatnonzero(tree.face < 0)
    assert (tree.child_count[surrogates] >= 1).all()
    assert (tree.child_count[tree.face >= 0] == 0).all()
    for node in surrogates:
        kids = tree.children(node)
        assert len(kids) <= tree.branching
        assert (tree.parent[kids] == node).all()
        assert (tree.level[kids] == tree.level[node] + 1).all()
        # a node's faces are the union of its children's, each face once
        below = np.concatenate([tree.covered_faces(k) for k in kids])
        np.testing.assert_array_equal(np.sort(below), tree.covered_faces(node))


def test_every_surrogate_is_conservative(built):
    """Points on the covered triangles lie within ε_node − ε_leaf of the surrogate."""
    mesh, tree = built
    rng = np.random.default_rng(0)
    size = mesh.diameter
    for node in np.flatnonzero(tree.face < 0):
        tris = mesh.triangles[tree.covered_faces(node)]
        w = rng.dirichlet(np.ones(3), size=(len(tris), 4))  # 4 random points per triangle
        points = np.concatenate(
            [np.einsum("tkv,tvd->tkd", w, tris).reshape(-1, 3), tris.reshape(-1, 3)]
        )
        surrogate = tree.triangles[node]
        worst = max(point_triangle_distance_naive(p, surrogate) for p in points)
        assert worst <= tree.epsilon[node] - tree.leaf_epsilon + 1e-9 * size, node
        # and ε is not loose: some covered vertex attains it
        vertex_worst = max(point_triangle_distance_naive(p, surrogate) for p in tris.reshape(-1, 3))
        assert vertex_worst == pytest.approx(
            tree.epsilon[node] - tree.leaf_epsilon, abs=1e-9 * size
        )


def test_statistics(built):
    mesh, tree = built
    stats = tree.stats
    assert sum(stats.nodes_per_level) == len(tree) == stats.surrogates + stats.leaves
    assert stats.leaves == mesh.n_faces and stats.depth == int(tree.level.max())
    assert stats.root_epsilon == tree.epsilon[0] > 0.01
    assert stats.root_diameter > 0 and stats.volume_ratio > 0


def test_deterministic_for_a_seed():
    mesh = shapes.noisy_sphere(subdivisions=2, seed=2)
    a, b = build_tree(mesh, 0.02, seed=7), build_tree(mesh, 0.02, seed=7)
    for name in ("triangles", "epsilon", "level", "parent", "first_child", "child_count", "face"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    c = build_tree(mesh, 0.02, seed=8)
    assert not np.array_equal(a.face, c.face) or not np.array_equal(a.triangles, c.triangles)


def test_small_meshes_and_branching():
    tree = build_tree(shapes.box(), 0.0, branching=12)  # 12 faces: root with 12 leaves
    assert tree.stats.nodes_per_level == (1, 12)
    tree = build_tree(shapes.icosphere(1), 0.05, branching=2)
    assert tree.stats.leaves == 80 and (tree.child_count[tree.face < 0] <= 2).all()


def test_save_and_load_round_trip(tmp_path):
    tree = build_tree(shapes.torus(major_segments=16, minor_segments=8), 0.01, seed=3)
    path = tmp_path / "tree.npz"
    tree.save(path)
    assert not (tmp_path / "tree.npz.tmp").exists()
    buffer = io.BytesIO()
    tree.save(buffer)
    buffer.seek(0)
    for loaded in (SurrogateTree.load(path), SurrogateTree.load(buffer)):
        for name in ("triangles", "epsilon", "level", "parent", "first_child", "child_count"):
            np.testing.assert_array_equal(getattr(loaded, name), getattr(tree, name))
        assert (loaded.leaf_epsilon, loaded.branching, loaded.seed) == (0.01, 8, 3)


def test_load_rejects_garbage_and_other_versions(tmp_path):
    bad = tmp_path / "bad.npz"
    bad.write_bytes(b"not a tree")
    with pytest.raises(InvalidArgumentError, match="not a surrogate tree"):
        SurrogateTree.load(bad)
    tree = build_tree(shapes.box(), 0.01)
    buffer = io.BytesIO()
    arrays = {
        name: getattr(tree, name)
        for name in (
            "triangles",
            "epsilon",
            "level",
            "parent",
            "first_child",
            "child_count",
            "face",
        )
    }
    np.savez(buffer, meta=np.array([TREE_FORMAT + 1, 0.01, 8, 0, 1.0]), **arrays)
    buffer.seek(0)
    with pytest.raises(InvalidArgumentError, match="format"):
        SurrogateTree.load(buffer)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"epsilon": -1.0}, "epsilon"),
        ({"epsilon": float("nan")}, "epsilon"),
        ({"branching": 1}, "branching"),
        ({"branching": True}, "branching"),
        ({"fit": "nope"}, "fit"),
        ({"seed": -1}, "seed"),
        ({"seed": 2**63}, "seed"),  # beyond float64's exact integers (the saved meta)
        ({"seed": 1.5}, "seed"),
    ],
)
def test_bad_arguments(kwargs, match):
    args = {"epsilon": 0.01, **kwargs}
    with pytest.raises(InvalidArgumentError, match=match):
        build_tree(shapes.box(), **args)
    with pytest.raises(InvalidArgumentError, match="engine.Mesh"):
        build_tree("box", 0.01)


def test_threads_and_progress_do_not_change_the_tree():
    """The level-synchronous build gives the same tree on one thread and on several, and
    reports every level, its nodes counted once, in order."""
    mesh = shapes.noisy_sphere(subdivisions=3, seed=4)
    calls = []
    one = build_tree(mesh, 0.01, seed=3, threads=1)
    many = build_tree(mesh, 0.01, seed=3, threads=3, progress=lambda *a: calls.append(a))
    for name in ("triangles", "epsilon", "level", "parent", "first_child", "child_count", "face"):
        np.testing.assert_array_equal(getattr(one, name), getattr(many, name))
    levels = np.bincount(one.level)
    assert [c[0] for c in calls] == list(range(2, len(levels) + 1))
    assert [c[1] for c in calls] == np.cumsum(levels)[1:].tolist()


def test_large_groups_are_fitted_on_a_sample_and_stay_conservative():
    """Groups above the sample size (the root of a 5,120-triangle sphere covers 2,562
    vertices) are fitted on a weighted sample, but their ε is exact over every vertex."""
    mesh = shapes.icosphere(4)
    tree = build_tree(mesh, 0.0, seed=0)
    points = mesh.vertices
    exact = max(point_triangle_distance_naive(p, tree.triangles[0]) for p in points)
    assert tree.epsilon[0] == pytest.approx(exact, abs=1e-12)
    assert tree.stats.volume_ratio < 1.6  # a sphere's root: 1.35x its ball fitted on all


@pytest.mark.parametrize("threads", [0, -1, 1.5, True])
def test_bad_thread_counts(threads):
    with pytest.raises(InvalidArgumentError, match="threads"):
        build_tree(shapes.box(), 0.01, threads=threads)
