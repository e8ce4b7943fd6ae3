"""The wire format: msgpack with numpy arrays as extension type 1 holding ``[dtype, shape,
bytes]`` (no pickle), or JSON. A pure-data helper shared with the service (which may use
helpers that live in ``clients/``; this module imports neither engine nor service)."""

from __future__ import annotations

import json
import math
from typing import Any

import msgpack
import numpy as np

__all__ = [
    "JSON",
    "MSGPACK",
    "NDARRAY_EXT",
    "array_ext",
    "array_from_ext",
    "decode",
    "encode",
    "plain",
]

JSON = "application/json"
MSGPACK = "application/msgpack"
NDARRAY_EXT = 1


def array_ext(array: np.ndarray) -> msgpack.ExtType:
    """``array`` as the wire's extension type (little-endian, row-major bytes)."""
    array = np.ascontiguousarray(array)
    if array.dtype.byteorder == ">":
        array = array.astype(array.dtype.newbyteorder("<"))
    payload = msgpack.packb([array.dtype.str, list(array.shape), array.tobytes()])
    return msgpack.ExtType(NDARRAY_EXT, payload)


def array_from_ext(payload: bytes) -> np.ndarray:
    """The array of an extension payload; ``ValueError`` saying what is wrong with it
    (only little-endian or byte-order-free bool, integer and float dtypes of at most 8
    bytes are accepted: nothing that could execute code)."""
    try:
        dtype_name, shape, data = msgpack.unpackb(payload, raw=False)
        dtype = np.dtype(dtype_name)
        shape = tuple(int(n) for n in shape)
    except (ValueError, TypeError, msgpack.UnpackException) as exc:
        raise ValueError(f"malformed msgpack array: {exc}") from None
    if dtype.kind not in "biuf" or dtype.itemsize > 8 or dtype.byteorder == ">":
        raise ValueError(f"array dtype {dtype.str!r} not accepted (little-endian numbers only)")
    if any(n < 0 for n in shape) or not isinstance(data, bytes):
        raise ValueError("malformed msgpack array: negative dimension or non-binary data")
    if math.prod(shape) * dtype.itemsize != len(data):
        raise ValueError(
            f"msgpack array of shape {list(shape)} and dtype {dtype.str} needs"
            f" {math.prod(shape) * dtype.itemsize} bytes, got {len(data)}"
        )
    return np.frombuffer(data, dtype).reshape(shape).copy()


def plain(value):
    """``default`` for encoders: numpy scalars as Python numbers (arrays as lists for JSON)."""
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    raise TypeError(f"cannot encode {type(value).__name__}")


def _default(value):
    if isinstance(value, np.ndarray):
        return array_ext(value)
    return plain(value)


def _ext_hook(code: int, payload: bytes):
    if code != NDARRAY_EXT:
        return msgpack.ExtType(code, payload)
    return array_from_ext(payload)


def encode(payload: Any, media: str) -> bytes:
    if media == MSGPACK:
        return msgpack.packb(payload, default=_default, use_bin_type=True)
    return json.dumps(payload, default=plain, allow_nan=False).encode()


def decode(content: bytes, media: str) -> Any:
    if media.startswith(MSGPACK):
        return msgpack.unpackb(content, raw=False, ext_hook=_ext_hook)
    return json.loads(content)
