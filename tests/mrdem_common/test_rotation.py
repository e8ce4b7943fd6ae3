"""mrdem_common.rotation: unit quaternions (w, x, y, z) to rotation matrices."""

from __future__ import annotations

import math

import numpy as np
import pytest

from engine.geometry.pose import Pose
from mrdem_common.rotation import rotation_matrix


def _unit(rng: np.random.Generator, n: int) -> np.ndarray:
    q = rng.normal(size=(n, 4))
    return q / np.linalg.norm(q, axis=1)[:, None]


def _rodrigues(axis: np.ndarray, angle: float) -> np.ndarray:
    """The rotation by ``angle`` about unit ``axis``: I + sin θ K + (1 − cos θ) K²."""
    kx, ky, kz = axis
    k = np.array([[0.0, -kz, ky], [kz, 0.0, -kx], [-ky, kx, 0.0]])
    return np.eye(3) + math.sin(angle) * k + (1 - math.cos(angle)) * (k @ k)


def test_a_quarter_turn_about_z_takes_x_to_y():
    q = [math.cos(math.pi / 4), 0.0, 0.0, math.sin(math.pi / 4)]
    r = rotation_matrix(q)
    assert r.shape == (3, 3) and r.dtype == np.float64
    np.testing.assert_allclose(r @ [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], atol=1e-15)
    np.testing.assert_allclose(r @ [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], atol=1e-15)
    np.testing.assert_allclose(r @ [0.0, 0.0, 1.0], [0.0, 0.0, 1.0], atol=1e-15)
    np.testing.assert_array_equal(rotation_matrix([1.0, 0.0, 0.0, 0.0]), np.eye(3))


def test_axis_angle_quaternions_give_the_rodrigues_rotation():
    rng = np.random.default_rng(11)
    for _ in range(50):
        axis = rng.normal(size=3)
        axis /= np.linalg.norm(axis)
        angle = rng.uniform(-math.pi, math.pi)
        q = np.concatenate([[math.cos(angle / 2)], math.sin(angle / 2) * axis])
        np.testing.assert_allclose(rotation_matrix(q), _rodrigues(axis, angle), atol=1e-14)


def test_batches_are_orthonormal_proper_and_equal_to_single_calls():
    qs = _unit(np.random.default_rng(5), 500)
    rs = rotation_matrix(qs)
    assert rs.shape == (500, 3, 3) and rs.dtype == np.float64
    identity = np.broadcast_to(np.eye(3), rs.shape)
    np.testing.assert_allclose(rs @ rs.transpose(0, 2, 1), identity, atol=1e-14)
    np.testing.assert_allclose(np.linalg.det(rs), 1.0, atol=1e-14)
    singles = np.array([rotation_matrix(q) for q in qs])
    assert rs.tobytes() == singles.tobytes()  # bit for bit
    assert rotation_matrix(-qs).tobytes() == rs.tobytes()  # q and -q: the same rotation
    assert rotation_matrix(qs[:0]).shape == (0, 3, 3)


def test_the_product_of_quaternions_is_the_product_of_rotations():
    rng = np.random.default_rng(8)
    for a, b in zip(_unit(rng, 20), _unit(rng, 20), strict=True):
        w1, x1, y1, z1 = a
        w2, x2, y2, z2 = b
        ab = [
            w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
            w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
            w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
            w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
        ]
        np.testing.assert_allclose(
            rotation_matrix(ab), rotation_matrix(a) @ rotation_matrix(b), atol=1e-14
        )


def test_the_engine_pose_uses_it():
    for q in _unit(np.random.default_rng(2), 20):
        pose = Pose(np.zeros(3), q)
        assert pose.rotation.tobytes() == rotation_matrix(pose.orientation).tobytes()


@pytest.mark.parametrize("shape", [(3,), (5,), (2, 3), (2, 2, 4), ()])
def test_other_shapes_are_refused(shape):
    with pytest.raises(ValueError, match="quaternion is"):
        rotation_matrix(np.ones(shape))
