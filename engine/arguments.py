"""Validation of the kernels' arguments, shared by the host modules.

Every check raises :class:`~engine.errors.InvalidArgumentError` with a message
naming the argument; none returns a partially checked value.
"""

from __future__ import annotations

import numpy as np

from engine.errors import InvalidArgumentError
from engine.kernels.geometry import triangle_batch as tb

__all__ = [
    "BAND_ULPS",
    "KERNELS",
    "PRECISIONS",
    "check_epsilon",
    "check_iterations",
    "check_kernel",
    "check_pairs",
    "check_precision",
    "check_quaternions",
    "check_rows",
    "check_triangles",
    "check_vector",
    "coordinate_limit",
    "kernel_constants",
]

KERNELS = {"exact": tb.EXACT, "iterative": tb.ITERATIVE, "hybrid": tb.HYBRID}
PRECISIONS = {"float32": np.float32, "float64": np.float64}
BAND_ULPS = 64
"""Relative width, in ulp of the kernel precision, of the rounding band around ε (and of
the sliver threshold on sin² of a triangle's largest angle)."""


def kernel_constants(dtype) -> tuple:
    """``(1, 64 ulp)`` in ``dtype``: the unit, and the relative size of the rounding
    band around ε (and of the sliver threshold on sin² of a triangle's largest angle)."""
    return dtype(1.0), dtype(BAND_ULPS * np.finfo(dtype).eps)


def check_kernel(kernel: str) -> int:
    try:
        return KERNELS[kernel]
    except (KeyError, TypeError):
        raise InvalidArgumentError(
            f"kernel must be one of {sorted(KERNELS)}, got {kernel!r}"
        ) from None


def check_precision(precision: str):
    try:
        return PRECISIONS[precision]
    except (KeyError, TypeError):
        raise InvalidArgumentError(
            f"precision must be one of {sorted(PRECISIONS)}, got {precision!r}"
        ) from None


def check_triangles(x, name: str, dtype=np.float64) -> np.ndarray:
    """``x`` as a finite (n, 3, 3) float64 array whose coordinates ``dtype`` can square."""
    if np.iscomplexobj(x):
        raise InvalidArgumentError(f"{name} must be real, got complex values")
    try:
        arr = np.asarray(x, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InvalidArgumentError(f"{name} must be a numeric (n, 3, 3) array: {exc}") from None
    if arr.ndim != 3 or arr.shape[1:] != (3, 3):
        raise InvalidArgumentError(f"{name} must have shape (n, 3, 3), got {arr.shape}")
    finite = np.isfinite(arr).reshape(len(arr), 9).all(axis=1)
    if not finite.all():
        bad = int(np.flatnonzero(~finite)[0])
        raise InvalidArgumentError(f"{name} has a non-finite coordinate in triangle {bad}")
    limit = coordinate_limit(dtype)
    if arr.size and np.abs(arr).max() > limit:
        bad = int(np.flatnonzero(np.abs(arr).reshape(len(arr), 9).max(axis=1) > limit)[0])
        raise InvalidArgumentError(
            f"{name} has a coordinate beyond ±{limit:.3g} in triangle {bad}: squared "
            f"distances would overflow {np.dtype(dtype).name}"
        )
    return arr


def coordinate_limit(dtype) -> float:
    """Largest coordinate magnitude whose squared differences stay finite in ``dtype``.

    The value is representable in ``dtype`` (rounded to it whatever NumPy's promotion rules),
    so a kernel comparing in ``dtype`` uses exactly the host's limit.
    """
    kind = np.dtype(dtype).type
    return float(kind(float(np.sqrt(np.finfo(dtype).max)) * 1e-4))


def check_epsilon(eps, n: int, dtype, name: str) -> np.ndarray:
    if np.iscomplexobj(eps):
        raise InvalidArgumentError(f"{name} must be real, got complex values")
    try:
        arr = np.asarray(eps, dtype=np.float64)
    except (TypeError, ValueError):
        raise InvalidArgumentError(
            f"{name} must be a non-negative number or a ({n},) array, got {eps!r}"
        ) from None
    if arr.ndim == 0:
        arr = np.full(n, float(arr))
    if arr.shape != (n,):
        raise InvalidArgumentError(f"{name} must be a scalar or shape ({n},), got {arr.shape}")
    if not (np.isfinite(arr).all() and (arr >= 0).all()):
        raise InvalidArgumentError(f"{name} must be finite and non-negative")
    if arr.size and arr.max() > coordinate_limit(dtype):
        raise InvalidArgumentError(f"{name} is too large for {np.dtype(dtype).name}")
    return arr.astype(dtype)


def check_iterations(iterations, rtol) -> tuple[int, float]:
    if (
        isinstance(iterations, bool | np.bool_)
        or not isinstance(iterations, int | np.integer)
        or not 1 <= iterations <= 64
    ):
        raise InvalidArgumentError(f"iterations must be an integer in [1, 64], got {iterations!r}")
    try:
        value = float(rtol)
    except (TypeError, ValueError):
        value = float("nan")
    if isinstance(rtol, bool | np.bool_) or not (np.isfinite(value) and value >= 0):
        raise InvalidArgumentError(f"rtol must be finite and non-negative, got {rtol!r}")
    return int(iterations), value


def check_pairs(pairs, na: int, nb: int) -> np.ndarray:
    """Validate index pairs; returns a C-contiguous ``(k, 2)`` int64 array."""
    arr = np.asarray(pairs)
    if arr.size == 0:
        return np.zeros((0, 2), np.int64)
    if arr.ndim != 2 or arr.shape[1] != 2 or not np.issubdtype(arr.dtype, np.integer):
        raise InvalidArgumentError(
            f"pairs must be an integer (k, 2) array, got {arr.dtype} {arr.shape}"
        )
    if np.issubdtype(arr.dtype, np.unsignedinteger) and arr.max() > np.iinfo(np.int64).max:
        raise InvalidArgumentError(
            f"pairs index out of range: a has {na} and b has {nb} triangles, got {arr.max()}"
        )
    arr = np.ascontiguousarray(arr, dtype=np.int64)
    lo, hi_a, hi_b = tb.pair_bounds(arr)
    if lo < 0 or hi_a >= na or hi_b >= nb:
        raise InvalidArgumentError(
            f"pairs index out of range: a has {na} and b has {nb} triangles; the pairs hold "
            f"indices from {lo} up to {hi_a} (into a) and {hi_b} (into b)"
        )
    return arr


def check_vector(value, n: int, name: str) -> np.ndarray:
    """A new ``(n,)`` float64 array of finite numbers."""
    try:
        arr = np.array(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise InvalidArgumentError(f"{name} must be {n} numbers, got {value!r}") from None
    if arr.shape != (n,) or not np.isfinite(arr).all():
        raise InvalidArgumentError(f"{name} must be {n} finite numbers, got {value!r}")
    return arr


def check_rows(values, k: int, width: int, name: str) -> np.ndarray:
    """A new ``(k, width)`` float64 array of finite numbers."""
    try:
        arr = np.array(values, dtype=np.float64)
    except (TypeError, ValueError):
        raise InvalidArgumentError(f"{name} must be a ({k}, {width}) array of numbers") from None
    if arr.shape != (k, width) or not np.isfinite(arr).all():
        raise InvalidArgumentError(f"{name} must be a ({k}, {width}) array of finite numbers")
    return arr


def check_quaternions(values, k: int, name: str) -> np.ndarray:
    """``(k, 4)`` unit quaternions (w, x, y, z): norms within 1e-6 of 1 are renormalised,
    anything else is an error."""
    arr = check_rows(values, k, 4, name)
    norms = np.linalg.norm(arr, axis=1)
    bad = np.flatnonzero(np.abs(norms - 1.0) > 1e-6)
    if len(bad):
        raise InvalidArgumentError(
            f"{name}[{bad[0]}] must be a unit quaternion (w, x, y, z); its norm is "
            f"{norms[bad[0]]:.6g}"
        )
    return arr / norms[:, None]
