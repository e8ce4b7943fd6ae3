"""Checks that turn decoded request values into arrays and numbers, or 422 problems that
name the offending field. Quaternions: a norm within :data:`QUATERNION_TOLERANCE` of 1 is
normalised, anything else is rejected."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from .errors import Unprocessable

__all__ = ["QUATERNION_TOLERANCE", "array", "choice", "field", "flag", "number", "pose"]

QUATERNION_TOLERANCE = 1e-6


def field(body: Any, name: str, where: str = "body") -> Any:
    if not isinstance(body, dict):
        raise Unprocessable(f"{where} must be an object")
    if name not in body:
        raise Unprocessable(f"{where} is missing {name!r}")
    return body[name]


def _shape_text(shape: tuple) -> str:
    dims = ["n" if s is None else str(s) for s in shape]
    return "(" + ", ".join(dims) + ("," if len(dims) == 1 else "") + ")"


def array(value: Any, name: str, shape: tuple, integer: bool = False) -> np.ndarray:
    """``value`` as a float64 (or int64) array of ``shape`` (None: any length); finite."""
    kinds = "iu" if integer else "iuf"
    try:
        raw = value if isinstance(value, np.ndarray) else np.asarray(value)
    except (ValueError, TypeError):
        raw = None
    if raw is None or raw.dtype.kind not in kinds:
        what = "integers" if integer else "numbers"
        raise Unprocessable(f"{name} must be an array of {what} of shape {_shape_text(shape)}")
    if raw.ndim != len(shape) or any(
        s is not None and s != n for s, n in zip(shape, raw.shape, strict=True)
    ):
        raise Unprocessable(f"{name} must have shape {_shape_text(shape)}, got {list(raw.shape)}")
    out = raw.astype(np.int64 if integer else np.float64)
    if not integer and not np.isfinite(out).all():
        where = np.argwhere(~np.isfinite(out))[0].tolist()
        raise Unprocessable(f"{name} has a non-finite value at index {where}")
    return out


def number(value: Any, name: str, lo: float, hi: float = math.inf, integer: bool = False):
    """A finite number in [lo, hi] (an integer when ``integer``)."""
    if isinstance(value, bool) or not isinstance(value, int | float | np.integer | np.floating):
        raise Unprocessable(f"{name} must be a number, got {value!r}")
    if integer and float(value) != int(value):
        raise Unprocessable(f"{name} must be an integer, got {value!r}")
    v = int(value) if integer else float(value)
    if not (math.isfinite(v) and lo <= v <= hi):
        raise Unprocessable(f"{name} must be finite and in [{lo}, {hi}], got {value!r}")
    return v


def flag(value: Any, name: str) -> bool:
    if not isinstance(value, bool):
        raise Unprocessable(f"{name} must be true or false, got {value!r}")
    return value


def choice(value: Any, name: str, options) -> str:
    if not isinstance(value, str) or value not in options:
        raise Unprocessable(f"{name} must be one of {sorted(options)}, got {value!r}")
    return value


def pose(value: Any, name: str) -> tuple[np.ndarray, np.ndarray]:
    """``{"position": [x, y, z], "orientation": [w, x, y, z]}`` (orientation optional:
    identity) as (position (3,), unit quaternion (4,))."""
    if not isinstance(value, dict):
        raise Unprocessable(f"{name} must be an object with position and orientation")
    position = array(field(value, "position", name), f"{name}.position", (3,))
    orientation = quaternion(value.get("orientation", [1.0, 0.0, 0.0, 0.0]), name)
    return position, orientation


def quaternion(value: Any, name: str) -> np.ndarray:
    q = array(value, f"{name}.orientation", (4,))
    norm = float(np.linalg.norm(q))
    if abs(norm - 1.0) > QUATERNION_TOLERANCE:
        raise Unprocessable(
            f"{name}.orientation must be a unit quaternion (w, x, y, z); its norm is {norm:.9g}"
            f" (norms within {QUATERNION_TOLERANCE:g} of 1 are normalised)"
        )
    return q / norm
