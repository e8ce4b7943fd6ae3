"""Rigid poses: a position and a unit quaternion (w, x, y, z)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from engine.errors import InvalidArgumentError
from mrdem_common.rotation import rotation_matrix

__all__ = ["Pose"]

_UNIT_TOLERANCE = 1e-6


@dataclass(frozen=True)
class Pose:
    """Placement of a body: ``world = rotation @ body + position``.

    Parameters
    ----------
    position : (3,) float
    orientation : (4,) float — unit quaternion (w, x, y, z); a norm within 1e-6 of 1
        is renormalised, anything else is an error
    """

    position: np.ndarray
    orientation: np.ndarray
    # (7,) float64: the position, then the orientation; ``position`` and ``orientation``
    # are read-only views of it. Kernels take this one, writeable: Numba types a read-only
    # array argument on a slower path, and one argument costs less than two (with the
    # node rows writeable too, ``mesh_distance``'s dispatch went from 0.70 to 0.30 µs:
    # BENCHMARKS.md, issue 15, twelfth step). Nothing writes it.
    _packed: np.ndarray = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        p = _vector(self.position, 3, "position")
        q = _vector(self.orientation, 4, "orientation")
        norm = math.sqrt(q.dot(q))  # np.linalg.norm's arithmetic, without its checks
        if abs(norm - 1.0) > _UNIT_TOLERANCE:
            raise InvalidArgumentError(
                f"orientation must be a unit quaternion (w, x, y, z); its norm is {norm:.6g}"
            )
        packed = np.empty(7)
        packed[:3] = p
        np.divide(q, norm, out=packed[3:])
        _hold(self, packed)

    def __reduce__(self):
        # a copy of the packed array, held again on loading: numpy's pickles drop the
        # read-only flag and the views, and validating again would renormalise the
        # quaternion (a last bit may change)
        return (_unpickled, (self._packed.copy(),))

    @classmethod
    def identity(cls) -> Pose:
        return cls(np.zeros(3), np.array([1.0, 0.0, 0.0, 0.0]))

    @cached_property
    def rotation(self) -> np.ndarray:
        """(3, 3) float64 rotation matrix (read-only;
        :func:`mrdem_common.rotation.rotation_matrix`)."""
        rot = rotation_matrix(self.orientation)
        rot.flags.writeable = False
        return rot

    def apply(self, points: np.ndarray) -> np.ndarray:
        """Body-frame ``points (..., 3)`` to the world frame."""
        return np.asarray(points, dtype=np.float64) @ self.rotation.T + self.position

    def inverse(self) -> Pose:
        w, x, y, z = self.orientation
        conj = np.array([w, -x, -y, -z])
        return Pose(-(self.rotation.T @ self.position), conj)

    def compose(self, other: Pose) -> Pose:
        """``self ∘ other``: apply ``other`` first, then ``self``."""
        w1, x1, y1, z1 = self.orientation
        w2, x2, y2, z2 = other.orientation
        q = np.array(
            [
                w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
                w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
                w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
                w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
            ]
        )
        return Pose(self.apply(other.position), q / np.linalg.norm(q))


def _hold(pose: Pose, packed: np.ndarray) -> None:
    """Make ``packed (7,)`` float64 the pose's: its read-only views are the position and
    the orientation (the rotation is cached)."""
    p, q = packed[:3], packed[3:]
    p.flags.writeable = q.flags.writeable = False
    object.__setattr__(pose, "position", p)
    object.__setattr__(pose, "orientation", q)
    object.__setattr__(pose, "_packed", packed)


def _unpickled(packed: np.ndarray) -> Pose:
    """The pose of a pickled ``packed`` array (:meth:`Pose.__reduce__`), bit for bit."""
    pose = object.__new__(Pose)
    _hold(pose, packed)
    return pose


def _vector(value, n: int, name: str) -> np.ndarray:
    try:
        arr = np.array(value, dtype=np.float64)  # a copy: the pose owns it
    except (TypeError, ValueError):
        raise InvalidArgumentError(f"{name} must be {n} numbers, got {value!r}") from None
    if arr.shape != (n,) or not np.isfinite(arr).all():
        raise InvalidArgumentError(f"{name} must be {n} finite numbers, got {value!r}")
    return arr
