"""Halos that match intuition: a tree shifted to another ε finds what a tree built with it
finds; fixed bodies default to a tenth of the free bodies' ε; a ball dropped on a floor
with no ε anywhere rests within 1 % of its radius above it."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from engine import PaperSpring, Scene, build_tree, shapes, triangle_distances
from engine.collision.contacts import find_contacts
from engine.geometry.pose import Pose
from engine.kernels.dynamics import motion as kd
from engine.trees.halos import (
    DEFAULT_RELATIVE_EPSILON,
    FIXED_EPSILON_FRACTION,
    size_epsilon,
)

PROPS = settings(
    max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow], database=None
)
BUILT = 0.03  # the ε the shifted trees were built with
TARGETS = (0.004, 0.05)  # the ε they are shifted to
MESHES = {
    "noisy": shapes.noisy_sphere(subdivisions=1, eta_r=1.3, seed=2),
    "torus": shapes.torus(major_segments=12, minor_segments=6),
    "plane": shapes.plane(size=(3.0, 3.0), divisions=4),
}


def _trees():
    """Per mesh and target ε: (the tree built with BUILT, shifted; a tree built with it)."""
    out = {}
    for name, mesh in MESHES.items():
        base = build_tree(mesh, BUILT, seed=1)
        for eps in TARGETS:
            out[name, eps] = (base.with_leaf_epsilon(eps), build_tree(mesh, eps, seed=1))
    return out


TREES = _trees()
unit = st.tuples(*[st.floats(-1, 1) for _ in range(4)]).map(np.array)


def _unit(values: np.ndarray) -> np.ndarray:
    norm = np.linalg.norm(values)
    assume(norm > 0.1)
    return values / norm


@PROPS
@given(
    a=st.sampled_from(sorted(MESHES)),
    b=st.sampled_from(sorted(MESHES)),
    eps_a=st.sampled_from(TARGETS),
    eps_b=st.sampled_from(TARGETS),
    qa=unit,
    qb=unit,
    direction=unit,
    reach=st.floats(0.3, 1.05),
)
def test_a_shifted_tree_finds_the_contacts_of_a_tree_built_with_its_epsilon(
    a, b, eps_a, eps_b, qa, qb, direction, reach
):
    (shift_a, built_a), (shift_b, built_b) = TREES[a, eps_a], TREES[b, eps_b]
    direction = _unit(direction)[:3]
    assume(np.linalg.norm(direction) > 0.1)
    offset = direction / np.linalg.norm(direction) * reach
    offset *= built_a.bounding_radius + built_b.bounding_radius
    pa, pb = Pose([0.1, 0.2, -0.3], _unit(qa)), Pose(np.array([0.1, 0.2, -0.3]) + offset, _unit(qb))
    shifted = find_contacts(shift_a, pa, shift_b, pb)
    built = find_contacts(built_a, pa, built_b, pb)
    np.testing.assert_array_equal(shifted.pairs, built.pairs)
    np.testing.assert_array_equal(shifted.overlaps, built.overlaps)
    np.testing.assert_array_equal(shifted.points, built.points)
    np.testing.assert_array_equal(shifted.normals, built.normals)


def test_shifted_node_epsilon_is_conservative_and_the_built_one_to_rounding():
    mesh = shapes.icosphere(2, radius=0.5)
    base = build_tree(mesh, 0.02, branching=4, seed=3)
    for eps in (0.001, 0.02, 0.3):
        tree = base.with_leaf_epsilon(eps)
        assert tree.leaf_epsilon == eps and tree.triangles is base.triangles
        assert (tree.epsilon[tree.face >= 0] == eps).all()
        for node in np.flatnonzero(tree.face < 0):
            faces = tree.covered_faces(node)
            points = np.unique(mesh.triangles[faces].reshape(-1, 3), axis=0)
            as_triangles = np.repeat(points[:, None], 3, axis=1)
            surrogate = np.broadcast_to(tree.triangles[node], as_triangles.shape)
            far = triangle_distances(as_triangles, surrogate, "exact").distance.max()
            # every covered halo inside the node's (to the distance kernel's rounding)
            assert far + eps <= tree.epsilon[node] + 1e-15
        built = build_tree(mesh, eps, branching=4, seed=3)
        np.testing.assert_array_equal(built.triangles, tree.triangles)
        assert (tree.epsilon >= built.epsilon).all()
        np.testing.assert_allclose(tree.epsilon, built.epsilon, rtol=1e-14, atol=0)
    assert base.with_leaf_epsilon(0.02) is base


# ---------------------------------------------------------------------- the default rule
def _size(mesh) -> float:
    spread = mesh.vertices - mesh.vertices.mean(axis=0)
    return DEFAULT_RELATIVE_EPSILON * 2 * float(np.linalg.norm(spread, axis=1).max())


def test_a_fixed_body_takes_a_tenth_of_the_smallest_free_body_epsilon():
    floor, ball, pebble = shapes.plane(size=(10, 10), divisions=4), shapes.icosphere(1), None
    pebble = shapes.icosphere(1, radius=0.05)
    scene = Scene()
    f = scene.add_body(floor, fixed=True)  # before any free body: its own size default
    assert scene.epsilon[f] == _size(floor) == size_epsilon(floor)
    built = scene.trees[scene.tree_index[f]]
    b = scene.add_body(ball, position=(0, 0, 2))
    assert scene.epsilon[b] == _size(ball)
    assert scene.epsilon[f] == pytest.approx(FIXED_EPSILON_FRACTION * _size(ball), rel=1e-15)
    wall = scene.add_body(shapes.box((1, 4, 4)), position=(5, 0, 0), fixed=True, epsilon=0.07)
    plane = scene.add_plane(point=(0, 0, -3))  # not given: the rule
    given = scene.add_plane(point=(0, 0, -6), epsilon=0.02)  # given: kept
    p = scene.add_body(pebble, position=(0, 3, 2))  # a smaller free body: the rule follows
    eps = scene.epsilon
    assert eps[f] == eps[plane] == pytest.approx(FIXED_EPSILON_FRACTION * eps[p], rel=1e-15)
    assert eps[wall] == 0.07 and eps[given] == 0.02 and eps[b] == _size(ball)
    # the trees no body uses any more are dropped; the floor's shifts share its arrays
    assert len(scene.trees) == len(np.unique(scene.tree_index))
    assert scene.trees[scene.tree_index[f]].triangles is built.triangles
    # a fixed body's ε never exceeds its own size default
    tiny = Scene()
    grain = tiny.add_body(shapes.box((0.01, 0.01, 0.01)), fixed=True)
    tiny.add_body(ball, position=(0, 0, 2))
    assert tiny.epsilon[grain] == _size(shapes.box((0.01, 0.01, 0.01)))


def test_auto_applies_the_rule_to_trees():
    floor_tree = build_tree(shapes.plane(size=(10, 10), divisions=4), 0.5)
    ball_tree = build_tree(shapes.icosphere(1), 0.3)
    scene = Scene()
    kept = scene.add_body(floor_tree, fixed=True)  # a tree keeps its own ε
    ruled = scene.add_body(floor_tree, position=(0, 0, -1), fixed=True, epsilon="auto")
    ball = scene.add_body(ball_tree, position=(0, 0, 2), epsilon="auto")  # its size default
    eps = scene.epsilon
    assert eps[kept] == 0.5 and eps[ball] == _size(shapes.icosphere(1))
    assert eps[ruled] == pytest.approx(FIXED_EPSILON_FRACTION * eps[ball], rel=1e-15)


# ---------------------------------------------------------------------- resting height
def _floor(scene: Scene, kind: str) -> None:
    """A fixed 10 m × 10 m floor with its top at z = 0, no ε given."""
    if kind == "plane mesh":
        scene.add_body(shapes.plane(size=(10, 10), divisions=8), fixed=True)
    elif kind == "box":
        scene.add_body(shapes.box((10, 10, 1)), position=(0, 0, -0.5), fixed=True)
    else:
        scene.add_plane(size=10.0)


@pytest.mark.parametrize("kind", ["plane mesh", "box", "add_plane"])
def test_a_ball_with_no_epsilon_anywhere_rests_within_one_percent_of_its_radius(kind):
    """An icosphere of radius 0.5 (a vertex at its bottom), default density, dropped 10 cm
    onto the floor added first. The law (K_s·δ/(ε_a + ε_b)·√m against a fixed body)
    holds it where δ/(ε_a + ε_b) = √m·g/K_s: its surface (ε_a + ε_b)(1 − √m·g/K_s) above."""
    radius, law = 0.5, PaperSpring(damping=0.3)
    ball = shapes.icosphere(2, radius=radius)
    assert -ball.vertices[:, 2].min() == pytest.approx(radius, rel=1e-15)
    scene = Scene(contact_model=law)
    _floor(scene, kind)
    body = scene.add_body(ball, position=(0.3, -0.2, radius + 0.1))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        for _ in range(1500):
            assert scene.step(1e-3).converged
    assert np.linalg.norm(scene.velocities[body]) < 1e-6
    rot = np.empty((len(scene), 3, 3))
    kd.rotation_matrices(scene.orientations, rot)
    lowest = ((ball.vertices - scene.centers[body]) @ rot[body].T)[:, 2].min()
    gap = scene.positions[body, 2] + lowest  # from the ball's lowest vertex to the floor
    height = scene.positions[body, 2] - radius  # of the centre, above the radius
    assert gap >= 0.0 and 0.0 <= height <= 0.01 * radius
    reach = scene.epsilon.sum()
    phi = math.sqrt(scene.masses[body]) * np.linalg.norm(scene.gravity) / law.stiffness
    assert gap == pytest.approx(reach * (1 - phi), rel=1e-4)


@pytest.mark.parametrize(("built_with", "shifted_to"), [(1.0, 1e-9), (5.0, 1e-12), (1e-9, 2.0)])
def test_a_large_shift_keeps_every_node_at_least_as_conservative_as_a_direct_build(
    built_with, shifted_to
):
    """ε_node − ε_leaf loses up to half an ulp of the old ε; the shift adds it back, so
    even a shift from a thick halo to a hair's breadth is never below a direct build."""
    mesh = shapes.noisy_sphere(subdivisions=2, seed=7)
    tree = build_tree(mesh, built_with, seed=2).with_leaf_epsilon(shifted_to)
    built = build_tree(mesh, shifted_to, seed=2)
    np.testing.assert_array_equal(built.triangles, tree.triangles)
    assert (tree.epsilon >= built.epsilon).all()
    # and above it by at most the rounding of the old ε (a few ulp of it)
    np.testing.assert_allclose(
        tree.epsilon, built.epsilon, rtol=1e-14, atol=4 * np.spacing(built_with)
    )
