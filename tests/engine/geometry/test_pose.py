"""Rigid poses (engine/geometry/pose.py): validation, the rotation, apply, compose, inverse."""

from __future__ import annotations

import copy
import math
import pickle

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from engine import InvalidArgumentError, Pose

PROPS = settings(max_examples=80, deadline=None)

finite = st.floats(-1e3, 1e3, allow_nan=False, allow_infinity=False)
positions = st.tuples(finite, finite, finite).map(np.array)
quaternions = (
    st.tuples(*[st.floats(-1, 1, allow_nan=False)] * 4)
    .map(np.array)
    .filter(lambda q: np.linalg.norm(q) > 0.1)
    .map(lambda q: q / np.linalg.norm(q))
)
poses = st.builds(Pose, positions, quaternions)
points = st.lists(st.tuples(finite, finite, finite), min_size=1, max_size=5).map(np.array)


def axis_angle(axis, angle: float) -> np.ndarray:
    """The unit quaternion (w, x, y, z) of a rotation by ``angle`` about ``axis``."""
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    return np.array([math.cos(angle / 2), *(math.sin(angle / 2) * axis)])


# ------------------------------------------------------------------ validation
@pytest.mark.parametrize(
    ("position", "orientation", "message"),
    [
        ((0, 0), (1, 0, 0, 0), "position must be 3 finite numbers"),
        ((0, 0, 0, 0), (1, 0, 0, 0), "position must be 3 finite numbers"),
        ((0, float("nan"), 0), (1, 0, 0, 0), "position must be 3 finite numbers"),
        ((0, 0, float("inf")), (1, 0, 0, 0), "position must be 3 finite numbers"),
        ("abc", (1, 0, 0, 0), "position must be 3 numbers"),
        ((0, 0, 0), (1, 0, 0), "orientation must be 4 finite numbers"),
        ((0, 0, 0), (1, 0, 0, float("nan")), "orientation must be 4 finite numbers"),
        ((0, 0, 0), (0, 0, 0, 0), "orientation must be a unit quaternion"),
        ((0, 0, 0), (1, 1, 0, 0), "orientation must be a unit quaternion"),
        ((0, 0, 0), (1 + 2e-6, 0, 0, 0), "orientation must be a unit quaternion"),
        ((0, 0, 0), [object()] * 4, "orientation must be 4 numbers"),
    ],
)
def test_bad_position_or_orientation_is_rejected(position, orientation, message):
    with pytest.raises(InvalidArgumentError, match=message):
        Pose(position, orientation)


def test_invalid_argument_is_a_value_error():
    with pytest.raises(ValueError):
        Pose((0, 0, 0), (2, 0, 0, 0))


def test_a_nearly_unit_quaternion_is_renormalised():
    q = np.array([1.0, 1.0, 1.0, 1.0]) / 2 * (1 + 5e-7)  # norm within 1e-6 of 1
    pose = Pose((0, 0, 0), q)
    assert np.linalg.norm(pose.orientation) == pytest.approx(1.0, abs=1e-15)
    np.testing.assert_allclose(pose.orientation, [0.5, 0.5, 0.5, 0.5], rtol=1e-15)


def test_the_pose_owns_read_only_float64_copies():
    position, orientation = [1, 2, 3], np.array([1.0, 0.0, 0.0, 0.0])
    pose = Pose(position, orientation)
    orientation[0] = 5.0  # the caller's array is not the pose's
    assert pose.orientation[0] == 1.0
    assert pose.position.dtype == pose.orientation.dtype == np.float64
    for array in (pose.position, pose.orientation, pose.rotation):
        with pytest.raises(ValueError):
            array[0] = 7.0


def test_the_kernels_copy_is_the_position_then_the_orientation():
    """``_packed`` (what kernels take, writeable) holds the pose's values, and the public
    arrays are read-only views of it: what a kernel reads is what the user sees."""
    pose = Pose([1.0, -2.0, 3.5], np.array([1.0, 1.0, 1.0, 1.0]) / 2)
    np.testing.assert_array_equal(pose._packed, [1.0, -2.0, 3.5, 0.5, 0.5, 0.5, 0.5])
    assert pose._packed.flags.writeable and pose._packed.dtype == np.float64
    assert np.shares_memory(pose.position, pose._packed)
    assert np.shares_memory(pose.orientation, pose._packed)
    assert "_packed" not in repr(pose)


def test_a_pickled_pose_is_the_same_bits_and_still_read_only():
    """Pickling (as multiprocessing and Ray do) and copying keep every bit, the arrays
    read-only and the kernel's copy theirs (numpy's own pickles drop both)."""
    q = np.array([0.1, 0.7, -0.3, 0.2])
    pose = Pose([1.0 / 3.0, -2.0, 1e-300], q / np.linalg.norm(q))
    for copied in (pickle.loads(pickle.dumps(pose)), copy.deepcopy(pose), copy.copy(pose)):
        assert type(copied) is Pose
        np.testing.assert_array_equal(copied._packed, pose._packed)
        assert copied.position.tobytes() == pose.position.tobytes()
        assert copied.orientation.tobytes() == pose.orientation.tobytes()
        assert np.shares_memory(copied.position, copied._packed)
        assert np.shares_memory(copied.orientation, copied._packed)
        for array in (copied.position, copied.orientation):
            with pytest.raises(ValueError):
                array[0] = 7.0
        np.testing.assert_array_equal(copied.rotation, pose.rotation)


def test_identity():
    pose = Pose.identity()
    np.testing.assert_array_equal(pose.position, np.zeros(3))
    np.testing.assert_array_equal(pose.rotation, np.eye(3))
    xyz = np.array([[1.0, -2.0, 3.0]])
    np.testing.assert_array_equal(pose.apply(xyz), xyz)


# ------------------------------------------------------------------ the rotation
@pytest.mark.parametrize("angle", [0.3, math.pi / 2, 2.0, -1.1])
def test_rotation_about_each_axis_matches_the_hand_derived_matrix(angle):
    c, s = math.cos(angle), math.sin(angle)
    expected = {  # right-handed rotations by `angle`, world = R @ body
        (1, 0, 0): [[1, 0, 0], [0, c, -s], [0, s, c]],
        (0, 1, 0): [[c, 0, s], [0, 1, 0], [-s, 0, c]],
        (0, 0, 1): [[c, -s, 0], [s, c, 0], [0, 0, 1]],
    }
    for axis, matrix in expected.items():
        pose = Pose((0, 0, 0), axis_angle(axis, angle))
        np.testing.assert_allclose(pose.rotation, matrix, rtol=0, atol=1e-15)


def test_a_third_of_a_turn_about_the_diagonal_permutes_the_axes():
    # 120° about (1, 1, 1) takes x to y, y to z and z to x
    pose = Pose((0, 0, 0), axis_angle((1, 1, 1), 2 * math.pi / 3))
    np.testing.assert_allclose(pose.apply(np.eye(3)), np.roll(np.eye(3), 1, axis=1), atol=1e-15)


@PROPS
@given(quaternions)
def test_rotation_is_orthonormal_and_proper(q):
    rot = Pose((0, 0, 0), q).rotation
    np.testing.assert_allclose(rot @ rot.T, np.eye(3), atol=1e-13)
    assert np.linalg.det(rot) == pytest.approx(1.0, abs=1e-13)


@PROPS
@given(quaternions)
def test_q_and_minus_q_are_the_same_rotation(q):
    np.testing.assert_allclose(
        Pose((0, 0, 0), q).rotation, Pose((0, 0, 0), -q).rotation, atol=1e-15
    )


@PROPS
@given(quaternions, st.tuples(finite, finite, finite))
def test_rotation_agrees_with_the_quaternion_sandwich(q, v):
    """R·v equals the vector part of q ⊗ (0, v) ⊗ q̄ (the product written out here)."""

    def product(a, b):
        w1, v1, w2, v2 = a[0], a[1:], b[0], b[1:]
        return np.array([w1 * w2 - v1 @ v2, *(w1 * v2 + w2 * v1 + np.cross(v1, v2))])

    conjugate = q * [1, -1, -1, -1]
    rotated = product(product(q, np.array([0.0, *v])), conjugate)[1:]
    pose = Pose((0, 0, 0), q)
    np.testing.assert_allclose(
        pose.rotation @ np.array(v), rotated, atol=1e-12 * (1 + np.abs(v).max())
    )


# ------------------------------------------------------------------ apply, compose, inverse
def test_apply_rotates_then_translates():
    pose = Pose((1.0, 2.0, 3.0), axis_angle((0, 0, 1), math.pi / 2))  # x → y, y → −x
    body = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [2.0, 3.0, 4.0]])
    world = np.array([[1.0, 3.0, 3.0], [0.0, 2.0, 3.0], [1.0, 2.0, 4.0], [-2.0, 4.0, 7.0]])
    np.testing.assert_allclose(pose.apply(body), world, atol=1e-15)
    assert pose.apply(body[0]).shape == (3,)  # (..., 3) in, (..., 3) out
    assert pose.apply(body.reshape(2, 2, 3)).shape == (2, 2, 3)


@PROPS
@given(poses, poses, points)
def test_compose_applies_the_right_pose_first(a, b, xyz):
    ab = a.compose(b)
    scale = 1 + np.abs(xyz).max() + np.abs(a.position).max() + np.abs(b.position).max()
    np.testing.assert_allclose(ab.apply(xyz), a.apply(b.apply(xyz)), atol=1e-12 * scale)
    assert np.linalg.norm(ab.orientation) == pytest.approx(1.0, abs=1e-15)


@PROPS
@given(poses, poses, poses)
def test_compose_is_associative(a, b, c):
    left, right = a.compose(b).compose(c), a.compose(b.compose(c))
    scale = 1 + max(np.abs(p.position).max() for p in (a, b, c))
    np.testing.assert_allclose(left.rotation, right.rotation, atol=1e-13)
    np.testing.assert_allclose(left.position, right.position, atol=1e-12 * scale)


@PROPS
@given(poses, points)
def test_inverse_undoes_the_pose(pose, xyz):
    inverse = pose.inverse()
    scale = 1 + np.abs(xyz).max() + np.abs(pose.position).max()
    np.testing.assert_allclose(inverse.apply(pose.apply(xyz)), xyz, atol=1e-12 * scale)
    np.testing.assert_allclose(pose.apply(inverse.apply(xyz)), xyz, atol=1e-12 * scale)
    for both in (pose.compose(inverse), inverse.compose(pose)):
        np.testing.assert_allclose(both.rotation, np.eye(3), atol=1e-13)
        np.testing.assert_allclose(both.position, np.zeros(3), atol=1e-12 * scale)


def test_inverse_of_a_hand_made_pose():
    # x → y about z, then moved by (1, 2, 3): the inverse moves by −(1, 2, 3) first, then
    # turns back, y → x: its position is R⁻¹·(−p) = (−2, 1, −3)
    inverse = Pose((1.0, 2.0, 3.0), axis_angle((0, 0, 1), math.pi / 2)).inverse()
    np.testing.assert_allclose(inverse.position, [-2.0, 1.0, -3.0], atol=1e-15)
    np.testing.assert_allclose(inverse.orientation, axis_angle((0, 0, 1), -math.pi / 2))
