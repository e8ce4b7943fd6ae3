"""The tree build: every face one leaf, breadth-first layout, conservative ε, determinism,
threads and progress, sampled fits, validation."""

from __future__ import annotations

import numpy as np
import pytest

from engine import InvalidArgumentError, shapes
from engine.geometry.reference import point_triangle_distance_naive
from engine.trees.build import build_tree


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
