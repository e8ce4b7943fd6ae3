"""mesh_distance: the branch and bound over surrogate trees against every face pair.

The oracle is the exact kernel on all face pairs of the two posed meshes, in the world
frame (its own rounding differs from the query's, which runs in A's frame: distances
are compared to 1e-12 of the scene's size).
"""

from __future__ import annotations

import functools
import importlib
from unittest import mock

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from engine import (
    InvalidArgumentError,
    MeshDistance,
    Pose,
    build_tree,
    mesh_distance,
    shapes,
    triangle_distances,
)

MESHES = {
    "ico80": lambda: shapes.icosphere(1),
    "ico320": lambda: shapes.icosphere(2, radius=0.8),
    "torus": lambda: shapes.torus(1.0, 0.3, 16, 8),
    "noisy": lambda: shapes.noisy_sphere(subdivisions=1, eta_r=1.4, seed=3),
}
PAIRS = [("ico80", "ico320"), ("torus", "torus"), ("ico320", "noisy"), ("noisy", "torus")]
md = importlib.import_module("engine.collision.proximity")
TOL = 1e-12  # relative to the scene's size
PROPS = settings(
    max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow], database=None
)


@functools.cache
def body(name: str):
    """(mesh, tree) of a test shape, built once; halo 0.02 (it plays no part)."""
    mesh = MESHES[name]()
    return mesh, build_tree(mesh, epsilon=0.02, seed=1)


def posed(mesh, pose: Pose) -> np.ndarray:
    """(F, 3, 3) float64 world-frame triangles."""
    return pose.apply(mesh.vertices)[mesh.faces]


def oracle(name_a: str, pose_a: Pose, name_b: str, pose_b: Pose):
    """Exact distance of every face pair: ``(d (Fa, Fb) float64, point_a, point_b (Fa, Fb, 3))``."""
    ta, tb = posed(body(name_a)[0], pose_a), posed(body(name_b)[0], pose_b)
    a = np.repeat(ta, len(tb), axis=0)
    b = np.tile(tb, (len(ta), 1, 1))
    found = triangle_distances(a, b, kernel="exact", precision="float64")
    shape = (len(ta), len(tb))
    return (
        found.distance.reshape(shape),
        found.point_a.reshape(*shape, 3),
        found.point_b.reshape(*shape, 3),
    )


def scale(name_a: str, pose_a: Pose, name_b: str, pose_b: Pose) -> float:
    points = np.concatenate(
        [posed(body(n)[0], p).reshape(-1, 3) for n, p in ((name_a, pose_a), (name_b, pose_b))]
    )
    return float(np.abs(points).max())


def point_to_triangle(point: np.ndarray, triangle: np.ndarray) -> float:
    """Exact distance from ``point (3,)`` to ``triangle (3, 3)`` (a point is a zero-area
    triangle)."""
    found = triangle_distances(np.repeat(point[None, None], 3, axis=1), triangle[None], "exact")
    return float(found.distance[0])


def check_against_oracle(name_a, pose_a, name_b, pose_b, precision="float64") -> MeshDistance:
    """The query's distance is the oracle's minimum; its faces attain it; its points lie
    on those faces and are that distance apart."""
    result = mesh_distance(body(name_a)[1], pose_a, body(name_b)[1], pose_b, precision=precision)
    every, _, _ = oracle(name_a, pose_a, name_b, pose_b)
    size = scale(name_a, pose_a, name_b, pose_b)
    tol = (TOL if precision == "float64" else 1e-5) * size
    assert isinstance(result, MeshDistance)
    assert result.faces.dtype == np.int64 and result.faces.shape == (2,)
    assert result.point_a.shape == result.point_b.shape == (3,)
    assert abs(result.distance - every.min()) <= tol, (result.distance, every.min())
    fa, fb = result.faces
    assert abs(every[fa, fb] - every.min()) <= tol
    tri_a = posed(body(name_a)[0], pose_a)[fa]
    tri_b = posed(body(name_b)[0], pose_b)[fb]
    assert point_to_triangle(result.point_a, tri_a) <= tol
    assert point_to_triangle(result.point_b, tri_b) <= tol
    assert abs(np.linalg.norm(result.point_b - result.point_a) - result.distance) <= tol
    assert result.node_pairs >= 1 and result.rounds >= 1
    return result


unit = st.tuples(*[st.floats(-1, 1) for _ in range(4)]).map(np.array)


def quaternion(values: np.ndarray) -> np.ndarray:
    norm = np.linalg.norm(values)
    assume(norm > 0.1)
    return values / norm


@PROPS
@given(
    pair=st.sampled_from(PAIRS),
    qa=unit,
    qb=unit,
    direction=unit,
    reach=st.floats(0.0, 1.4),
    kind=st.sampled_from(["as drawn", "touching"]),
    probes=st.sampled_from([md.PROBES, 1, 0]),
)
def test_equals_the_minimum_over_every_face_pair(pair, qa, qb, direction, reach, kind, probes):
    """Random poses from deep overlap (reach 0) to well apart (reach 1.4 bounding
    radii), and the same poses moved until the closest points touch; with the default
    probes, and with (almost) none, where every bound must prune on its own."""
    name_a, name_b = pair
    direction = quaternion(direction)[:3]
    assume(np.linalg.norm(direction) > 0.1)
    direction = direction / np.linalg.norm(direction)
    radii = body(name_a)[1].bounding_radius + body(name_b)[1].bounding_radius
    pose_a = Pose([0.3, -0.2, 0.1], quaternion(qa))
    pose_b = Pose(pose_a.position + reach * radii * direction, quaternion(qb))
    if kind == "touching":  # move B by the oracle's closest-point offset: distance ≈ 0
        every, pa, pb = oracle(name_a, pose_a, name_b, pose_b)
        k = np.unravel_index(np.argmin(every), every.shape)
        pose_b = Pose(pose_b.position - (pb[k] - pa[k]), pose_b.orientation)
    with mock.patch.object(md, "PROBES", probes):
        check_against_oracle(name_a, pose_a, name_b, pose_b)


@pytest.mark.parametrize("gap", [0.3, 0.02, 1e-6, 0.0, -0.01, -0.1])
def test_interlocked_tori(gap):
    """A chain link: B's ring through A's hole, tube surfaces ``gap`` apart (for the
    smooth tori; the meshes' faces lie inside them, so the mesh distance is larger)."""
    quarter = [np.cos(np.pi / 4), np.sin(np.pi / 4), 0.0, 0.0]  # B's ring in the xz plane
    pose_a, pose_b = Pose.identity(), Pose([0.6 + gap, 0.0, 0.0], quarter)
    result = check_against_oracle("torus", pose_a, "torus", pose_b)
    assert (result.distance > 0) == (oracle("torus", pose_a, "torus", pose_b)[0].min() > 0)


@pytest.mark.parametrize("pair", PAIRS)
def test_float32_within_its_rounding(pair):
    rng = np.random.default_rng(7)
    for _ in range(5):
        q = rng.normal(size=(2, 4))
        pose_a = Pose(rng.normal(size=3), q[0] / np.linalg.norm(q[0]))
        offset = rng.normal(size=3)
        offset *= rng.uniform(0.5, 2.5) / np.linalg.norm(offset)
        pose_b = Pose(pose_a.position + offset, q[1] / np.linalg.norm(q[1]))
        check_against_oracle(*pair[:1], pose_a, pair[1], pose_b, precision="float32")


def test_identical_bodies_are_at_distance_zero():
    _, tree = body("noisy")
    pose = Pose([1.0, 2.0, 3.0], [0.5, 0.5, 0.5, 0.5])
    result = mesh_distance(tree, pose, tree, pose)
    assert result.distance == 0.0
    np.testing.assert_allclose(result.point_a, result.point_b, atol=1e-12)


def test_separated_bodies_prune_most_pairs():
    """Far apart, the search evaluates a small part of the face pairs."""
    _, tree = body("ico320")
    result = mesh_distance(tree, Pose.identity(), tree, Pose([3.0, 0.5, 0.0], [1, 0, 0, 0]))
    faces = int(tree.is_leaf.sum())
    assert result.node_pairs + result.probes < faces * faces / 20
    assert result.sphere_pruned > 0 and result.largest_front <= result.node_pairs


def test_bad_arguments():
    _, tree = body("ico80")
    pose = Pose.identity()
    with pytest.raises(InvalidArgumentError, match="tree_a"):
        mesh_distance(None, pose, tree, pose)
    with pytest.raises(InvalidArgumentError, match="tree_b"):
        mesh_distance(tree, pose, body("ico80")[0], pose)
    with pytest.raises(InvalidArgumentError, match="pose_a"):
        mesh_distance(tree, np.zeros(3), tree, pose)
    with pytest.raises(InvalidArgumentError, match="pose_b"):
        mesh_distance(tree, pose, tree, (np.zeros(3), [1, 0, 0, 0]))
    with pytest.raises(InvalidArgumentError, match="precision"):
        mesh_distance(tree, pose, tree, pose, precision="float16")
