"""The wire format's msgpack arrays, for the service and the clients alike (pure data:
numpy and msgpack only; the HTTP parts live in ``service/codecs.py`` and ``clients/codec.py``).

A numpy array travels as msgpack extension type :data:`NDARRAY_EXT` whose payload is the
msgpack array ``[dtype, shape, data]``: the numpy dtype string (little-endian or
byte-order-free bool, integer, unsigned or float of at most 8 bytes), the shape as a list of
ints and the raw row-major bytes. Big-endian arrays are sent little-endian, non-contiguous
ones as a contiguous copy (a 0-d array as shape ``(1,)``). Nothing else is accepted when
reading, so decoding never executes code (no pickle). numpy scalars travel as plain numbers.
"""

from __future__ import annotations

import math
from typing import Any

import msgpack
import numpy as np

__all__ = [
    "ACCEPTED_KINDS",
    "JSON",
    "MAX_ITEMSIZE",
    "MSGPACK",
    "NDARRAY_EXT",
    "CodecError",
    "array_ext",
    "array_from_ext",
    "packb",
    "plain",
    "unpackb",
]

JSON = "application/json"
MSGPACK = "application/msgpack"
NDARRAY_EXT = 1
ACCEPTED_KINDS = "biuf"  # numpy dtype kinds: bool, signed, unsigned, float
MAX_ITEMSIZE = 8


class CodecError(ValueError):
    """A msgpack array (or extension type) that cannot be read; the message says why."""


def array_ext(array: np.ndarray) -> msgpack.ExtType:
    """``array`` (any shape, an accepted dtype) as the wire's extension type: little-endian,
    row-major bytes."""
    array = np.ascontiguousarray(array)
    if array.dtype.byteorder == ">":
        array = array.astype(array.dtype.newbyteorder("<"))
    payload = msgpack.packb([array.dtype.str, list(array.shape), array.tobytes()])
    return msgpack.ExtType(NDARRAY_EXT, payload)


def array_from_ext(payload: bytes) -> np.ndarray:
    """The array of an extension payload: a writeable, C-contiguous array that owns its
    data. :class:`CodecError` saying what is wrong with a malformed payload or a dtype not
    accepted (only little-endian or byte-order-free bool, integer and float dtypes of at
    most 8 bytes: nothing that could execute code)."""
    try:
        dtype_name, shape, data = msgpack.unpackb(payload, raw=False)
        dtype = np.dtype(dtype_name)
        shape = tuple(int(n) for n in shape)
    except (ValueError, TypeError, msgpack.UnpackException) as exc:
        raise CodecError(f"malformed msgpack array: {exc}") from None
    if dtype.kind not in ACCEPTED_KINDS or dtype.itemsize > MAX_ITEMSIZE or dtype.byteorder == ">":
        raise CodecError(f"array dtype {dtype.str!r} not accepted (little-endian numbers only)")
    if any(n < 0 for n in shape) or not isinstance(data, bytes):
        raise CodecError("malformed msgpack array: negative dimension or non-binary data")
    if math.prod(shape) * dtype.itemsize != len(data):
        raise CodecError(
            f"msgpack array of shape {list(shape)} and dtype {dtype.str} needs"
            f" {math.prod(shape) * dtype.itemsize} bytes, got {len(data)}"
        )
    return np.frombuffer(data, dtype).reshape(shape).copy()


def plain(value):
    """``default`` for JSON encoders: numpy arrays as nested lists, numpy scalars as Python
    numbers; ``TypeError`` for anything else."""
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    raise TypeError(f"cannot encode {type(value).__name__}")


def _default(value):
    if isinstance(value, np.ndarray):
        return array_ext(value)
    return plain(value)


def packb(payload: Any) -> bytes:
    """``payload`` (dicts, lists, strings, numbers, numpy arrays and scalars) as msgpack
    bytes, arrays as :data:`NDARRAY_EXT`; ``TypeError`` for anything else."""
    return msgpack.packb(payload, default=_default, use_bin_type=True)


def _strict_hook(code: int, payload: bytes):
    if code != NDARRAY_EXT:
        raise CodecError(f"unknown msgpack extension type {code} (arrays use {NDARRAY_EXT})")
    return array_from_ext(payload)


def _lenient_hook(code: int, payload: bytes):
    if code != NDARRAY_EXT:
        return msgpack.ExtType(code, payload)
    return array_from_ext(payload)


def unpackb(content: bytes, *, strict: bool = False) -> Any:
    """The value of msgpack ``content``, :data:`NDARRAY_EXT` as numpy arrays (map keys must be
    strings or bytes). Another extension type is kept as ``msgpack.ExtType``, or with
    ``strict`` a :class:`CodecError`. Raises :class:`CodecError` for an unreadable array and
    msgpack's own errors (``ValueError`` and ``msgpack.UnpackException`` subclasses,
    ``TypeError``) for malformed msgpack."""
    hook = _strict_hook if strict else _lenient_hook
    return msgpack.unpackb(content, raw=False, ext_hook=hook, strict_map_key=True)
