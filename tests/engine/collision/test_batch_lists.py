"""The pair cache's new lists hold every leaf pair within ε_a + ε_b + s at the reference
pose, each once, with its exact distance there, and nothing beyond (brute force over all
leaf pairs, on shapes with pole fans); the contacts of a call that makes them are the
traversal's, bit for bit."""

from __future__ import annotations

import numpy as np
import pytest
from posed_pairs import batch_trees, query_arrays, random_queries

from engine import PairCache, TreeBank, build_tree, shapes, triangle_distances
from engine.kernels.collision.contact_merge import key_order

SKIN = 0.5


@pytest.fixture(scope="module")
def trees():
    pole_fans = build_tree(shapes.uv_sphere(16, 8, radius=0.8), epsilon=0.02)
    return [*batch_trees(), pole_fans]


def _all_leaf_pairs(tree_a, pose_a, tree_b, pose_b):
    """Every (leaf row of A, leaf row of B) with its exact distance (float64), brute force."""
    sides = []
    for tree, pose in ((tree_a, pose_a), (tree_b, pose_b)):
        mesh = tree.views.geometry.mesh
        corners = mesh.vertices[mesh.faces[tree.face[tree.views.geometry.face_nodes]]]
        sides.append(pose.apply(corners.reshape(-1, 3)).reshape(-1, 3, 3))
    fa, fb = len(sides[0]), len(sides[1])
    a = np.repeat(sides[0], fb, axis=0)
    b = np.tile(sides[1], (fa, 1, 1))
    distance = triangle_distances(a, b, kernel="exact").distance
    rows_a = np.repeat(tree_a.views.geometry.face_nodes, fb)
    rows_b = np.tile(tree_b.views.geometry.face_nodes, fa)
    return rows_a, rows_b, distance


@pytest.mark.parametrize("precision", ["float64", "float32"])
def test_a_new_list_holds_every_leaf_pair_within_reach_and_skin(trees, precision):
    bank = TreeBank(trees, precision)
    queries = random_queries(trees, 40, seed=5)
    cache = PairCache(skin=SKIN)
    keys = np.arange(len(queries), dtype=np.int64)
    got = bank.find_contacts(*query_arrays(trees, queries), cache=cache, keys=keys, threads=1)
    assert (got.counts[:, 6] == 0).all()  # every list is new
    tolerance = 1e-9 if precision == "float64" else 1e-4
    listed_total = 0
    for e, (tree_a, pose_a, tree_b, pose_b) in enumerate(queries):
        near = cache.near[cache.offsets[e] : cache.offsets[e + 1]]
        distances = cache.distances[cache.offsets[e] : cache.offsets[e + 1]]
        reach = (tree_a.leaf_epsilon + tree_b.leaf_epsilon) * (1.0 + SKIN)
        rows_a, rows_b, distance = _all_leaf_pairs(tree_a, pose_a, tree_b, pose_b)
        within = distance <= reach - tolerance
        want = set(zip(rows_a[within].tolist(), rows_b[within].tolist(), strict=True))
        listed = set(zip(near[:, 0].tolist(), near[:, 1].tolist(), strict=True))
        assert len(listed) == len(near)  # no pair twice
        assert want <= listed
        exact = dict(zip(zip(rows_a.tolist(), rows_b.tolist(), strict=True), distance, strict=True))
        brute = np.array(
            [exact[pair] for pair in zip(near[:, 0].tolist(), near[:, 1].tolist(), strict=True)]
        )
        np.testing.assert_allclose(distances, brute, rtol=0, atol=tolerance)
        assert (brute <= reach + tolerance).all()
        listed_total += len(near)
    assert listed_total > 0


@pytest.mark.parametrize("precision", ["float64", "float32"])
def test_contacts_of_a_call_that_makes_the_lists_are_the_traversals(trees, precision):
    bank = TreeBank(trees, precision)
    queries = random_queries(trees, 120, seed=9)
    args = query_arrays(trees, queries)
    keys = np.arange(len(queries), dtype=np.int64) * 7
    got = bank.find_contacts(*args, cache=PairCache(skin=SKIN), keys=keys, threads=2)
    want = bank.find_contacts(*args, threads=2)
    for name in ("pair_offsets", "pairs", "contact_offsets", "points", "normals", "overlaps"):
        np.testing.assert_array_equal(getattr(got, name), getattr(want, name))
    assert (np.diff(want.pair_offsets) > 0).sum() > 10


def test_a_new_list_is_sorted_by_faces(trees):
    """Lists are kept in the order of their face pairs (so that a listed query's contacts
    need no sort in ``contact_kernel``)."""
    bank = TreeBank(trees, "float64")
    queries = random_queries(trees, 40, seed=11)
    cache = PairCache(skin=SKIN)
    keys = np.arange(len(queries), dtype=np.int64)
    bank.find_contacts(*query_arrays(trees, queries), cache=cache, keys=keys, threads=1)
    sorted_lists = 0
    for e, (tree_a, _, tree_b, _) in enumerate(queries):
        near = cache.near[cache.offsets[e] : cache.offsets[e + 1]]
        faces = tree_a.face[near[:, 0]].astype(np.int64) * len(tree_b.views.geometry.face_normals)
        faces += tree_b.face[near[:, 1]]
        assert (np.diff(faces) > 0).all()
        sorted_lists += len(near) > 1
    assert sorted_lists > 5


@pytest.mark.parametrize("case", ["random", "sorted", "two runs", "three runs", "empty", "one"])
def test_key_order_is_argsorts_permutation(case):
    rng = np.random.default_rng(3)
    keys = rng.choice(10_000, size=300, replace=False).astype(np.int64)
    if case == "sorted":
        keys = np.sort(keys)
    elif case == "two runs":
        keys = np.concatenate([np.sort(keys[:120]), np.sort(keys[120:])])
    elif case == "three runs":
        keys = np.concatenate([np.sort(keys[:100]), np.sort(keys[100:200]), np.sort(keys[200:])])
    elif case == "empty":
        keys = keys[:0]
    elif case == "one":
        keys = keys[:1]
    np.testing.assert_array_equal(key_order(keys), np.argsort(keys))


@pytest.mark.parametrize("precision", ["float64", "float32"])
@pytest.mark.parametrize("kernel", ["exact", "hybrid", "iterative"])
def test_pairs_at_their_reach_get_the_traversals_decision(precision, kernel):
    """Two parallel plates whose facing leaf pairs lie at ε_a + ε_b, or within a few
    rounding steps of it: a call that makes the lists decides each pair's contact at the
    true ε from the distance it recorded at the grown ε, and sends the pairs within its
    rounding bands through the kernel again. Its contacts are the traversal's, bit for
    bit, on both sides of the reach."""
    plate = build_tree(shapes.plane(size=(1.0, 1.0), divisions=3), epsilon=0.01)
    bank = TreeBank([plate], precision)
    reach = 2 * plate.leaf_epsilon
    ulp = float(np.finfo(precision).eps)
    gaps = reach + reach * ulp * np.array([-64.0, -4.0, -1.0, 0.0, 1.0, 4.0, 64.0])
    gaps = np.concatenate([gaps, reach * np.array([0.5, 0.999, 1.001, 1.4])])
    k = len(gaps)
    shift = np.array([0.01, -0.02])  # B slid a little, so that vertices face faces
    position_b = np.column_stack([np.tile(shift, (k, 1)), gaps])
    unit = np.tile([1.0, 0.0, 0.0, 0.0], (k, 1))
    args = (np.zeros(k, int), np.zeros((k, 3)), unit, np.zeros(k, int), position_b, unit)
    keys = np.arange(k, dtype=np.int64)
    cache = PairCache(skin=SKIN)
    want = bank.find_contacts(*args, kernel=kernel)
    found = np.diff(want.pair_offsets)
    assert found[gaps < reach * 0.9].min() > 0 and found[-1] == 0  # contact, then none
    for served in (0, 1):  # a call that makes the lists, then one they serve
        got = bank.find_contacts(*args, kernel=kernel, cache=cache, keys=keys)
        assert (got.counts[:, 6] == served).all()
        for name in ("pair_offsets", "pairs", "contact_offsets", "points", "normals"):
            np.testing.assert_array_equal(getattr(got, name), getattr(want, name), name)
        np.testing.assert_array_equal(got.overlaps, want.overlaps)


def test_the_motion_bound_holds_and_is_tight():
    """``motion_bound`` bounds how far any point within the radius moves between two poses,
    and is the exact largest motion (2·sin(θ/2)·radius + |Δs|, θ the turn between them)
    to rounding: a list lasts as long as the bodies' motion allows."""
    from engine.kernels.collision.batch import motion_bound
    from engine.kernels.dynamics.motion import rotation_matrices

    rng = np.random.default_rng(5)
    for case in range(300):
        q0 = rng.normal(size=4)
        turn = 10.0 ** rng.uniform(-9, 0) if case % 3 else 0.0
        axis = rng.normal(size=3)
        axis /= np.linalg.norm(axis)
        dq = np.concatenate([[np.cos(turn / 2)], np.sin(turn / 2) * axis])
        w0, v0, w1, v1 = q0[0], q0[1:], dq[0], dq[1:]  # q1 = dq ⊗ q0
        q1 = np.concatenate([[w1 * w0 - v1 @ v0], w1 * v0 + w0 * v1 + np.cross(v1, v0)])
        rotations = np.empty((2, 3, 3))
        rotation_matrices(np.array([q0, q1]) / np.linalg.norm(q0), rotations)
        s0, s1 = rng.normal(size=3), rng.normal(size=3) * (case % 2)
        radius = rng.uniform(0.01, 10.0)
        points = rng.normal(size=(2000, 3))
        points *= (
            radius
            * rng.uniform(0, 1, size=(2000, 1)) ** 0.2
            / np.linalg.norm(points, axis=1, keepdims=True)
        )
        edge = np.cross(axis, rng.normal(size=3))  # the farthest a turn moves: ⊥ the axis
        points[0] = radius * edge / np.linalg.norm(edge)
        moved = (points @ rotations[1].T + s1) - (points @ rotations[0].T + s0)
        largest = np.linalg.norm(moved, axis=1).max()
        bound = motion_bound(rotations[0], s0, rotations[1], s1, radius)
        assert largest <= bound
        exact = 2 * np.sin(turn / 2) * radius + np.linalg.norm(s1 - s0)
        assert bound <= exact + 1e-13 * radius
