"""Array fields of the HTTP models: one type for JSON (nested lists) and msgpack (typed
binary, decoded to numpy arrays by :mod:`mrdem_common.codec`), checked for shape, kind and
finiteness, with the JSON schema of the nested lists.

``Annotated[np.ndarray, Shape(None, 3)]`` is an ``(n, 3)`` float64 array; ``integer=True``
an int64 one; ``unit=True`` makes rows of 4 unit quaternions (norms within
:data:`QUATERNION_TOLERANCE` of 1 are normalised, anything else is rejected). An invalid
value fails with the field's path and what was expected.
"""

from __future__ import annotations

from typing import Annotated, Any

import numpy as np
from pydantic_core import PydanticCustomError, core_schema

__all__ = [
    "QUATERNION_TOLERANCE",
    "Indices",
    "Matrix3",
    "Points",
    "Quaternion",
    "Quaternions",
    "Shape",
    "Vector3",
    "shape_text",
]

QUATERNION_TOLERANCE = 1e-6


def shape_text(shape: tuple) -> str:
    """``(n, 3)`` for ``(None, 3)``; ``(n,)`` for ``(None,)``."""
    dims = ["n" if s is None else str(s) for s in shape]
    return "(" + ", ".join(dims) + ("," if len(dims) == 1 else "") + ")"


class Shape:
    """Pydantic metadata of an array field: its shape (None: any length), its kind."""

    def __init__(self, *shape: int | None, integer: bool = False, unit: bool = False) -> None:
        self.shape, self.integer, self.unit = shape, integer, unit

    def __get_pydantic_core_schema__(self, source, handler) -> core_schema.CoreSchema:
        return core_schema.no_info_plain_validator_function(
            self.validate,
            serialization=core_schema.plain_serializer_function_ser_schema(
                _listed, when_used="json"
            ),
        )

    def __get_pydantic_json_schema__(self, schema, handler) -> dict:
        item: dict = {"type": "integer" if self.integer else "number"}
        for size in reversed(self.shape):
            item = {"type": "array", "items": item}
            if size is not None:
                item["minItems"] = item["maxItems"] = size
        what = "integers" if self.integer else "finite numbers"
        extra = ", rows unit quaternions (w, x, y, z)" if self.unit else ""
        item["description"] = f"{shape_text(self.shape)} {what}{extra}"
        return item

    def validate(self, value: Any) -> np.ndarray:
        """``value`` as a float64 (int64) array of the shape; finite; unit rows if asked."""
        kinds = "iu" if self.integer else "iuf"
        what = "integers" if self.integer else "numbers"
        expected = f"an array of {what} of shape {shape_text(self.shape)}"
        if isinstance(value, str | bytes | dict | bool):
            raise PydanticCustomError("array_type", f"must be {expected}")
        try:
            raw = value if isinstance(value, np.ndarray) else np.asarray(value)
        except (ValueError, TypeError, OverflowError):
            raise PydanticCustomError("array_type", f"must be {expected}") from None
        if raw.size == 0 and raw.ndim == 1 and len(self.shape) > 1 and None not in self.shape[1:]:
            raw = raw.reshape((0, *self.shape[1:]))  # JSON's [] of (0, 3): no row to say so
        if raw.dtype.kind not in kinds and raw.size:
            raise PydanticCustomError("array_type", f"must be {expected}")
        if raw.ndim != len(self.shape) or any(
            s is not None and s != n for s, n in zip(self.shape, raw.shape, strict=True)
        ):
            raise PydanticCustomError(
                "array_shape",
                f"must have shape {shape_text(self.shape)}, got {list(raw.shape)}",
            )
        try:  # no copy when the array has the dtype already (msgpack's typed binary)
            out = np.asarray(raw, np.int64 if self.integer else np.float64)
        except OverflowError:
            raise PydanticCustomError("array_type", f"must be {expected}") from None
        if not self.integer and not np.isfinite(out).all():
            where = np.argwhere(~np.isfinite(out))[0].tolist()
            raise PydanticCustomError(
                "array_finite", "must hold finite numbers only", {"index": where}
            )
        if self.unit:
            out = _unit_rows(out)
        return out


def _unit_rows(q: np.ndarray) -> np.ndarray:
    norms = np.linalg.norm(q, axis=-1)
    bad = np.argwhere(np.abs(norms - 1.0) > QUATERNION_TOLERANCE)
    if len(bad):
        row = tuple(bad[0].tolist())
        raise PydanticCustomError(
            "unit_quaternion",
            f"must be a unit quaternion (w, x, y, z); its norm is {norms[row]:.9g}"
            f" (norms within {QUATERNION_TOLERANCE:g} of 1 are normalised)",
            {"index": list(row)},
        )
    return q / norms[..., None]


def _listed(value: np.ndarray) -> list:
    return np.asarray(value).tolist()


Vector3 = Annotated[np.ndarray, Shape(3)]
Matrix3 = Annotated[np.ndarray, Shape(3, 3)]
Points = Annotated[np.ndarray, Shape(None, 3)]
Indices = Annotated[np.ndarray, Shape(None, integer=True)]
Quaternion = Annotated[np.ndarray, Shape(4, unit=True)]
Quaternions = Annotated[np.ndarray, Shape(None, 4, unit=True)]
