"""The wire format, client side: msgpack with numpy arrays as extension type 1 holding
``[dtype, shape, bytes]`` (the service's format; no pickle), or JSON."""

from __future__ import annotations

import json
import math
from typing import Any

import msgpack
import numpy as np

__all__ = ["JSON", "MSGPACK", "decode", "encode"]

JSON = "application/json"
MSGPACK = "application/msgpack"
NDARRAY_EXT = 1


def _default(value):
    if isinstance(value, np.ndarray):
        array = np.ascontiguousarray(value)
        if array.dtype.byteorder == ">":
            array = array.astype(array.dtype.newbyteorder("<"))
        payload = msgpack.packb([array.dtype.str, list(array.shape), array.tobytes()])
        return msgpack.ExtType(NDARRAY_EXT, payload)
    if isinstance(value, np.generic):
        return value.item()
    raise TypeError(f"cannot encode {type(value).__name__}")


def _ext_hook(code: int, payload: bytes):
    if code != NDARRAY_EXT:
        return msgpack.ExtType(code, payload)
    dtype, shape, data = msgpack.unpackb(payload, raw=False)
    dtype = np.dtype(dtype)
    if dtype.kind not in "biuf" or math.prod(shape) * dtype.itemsize != len(data):
        raise ValueError(f"malformed array from the server: {dtype.str} {shape}")
    return np.frombuffer(data, dtype).reshape(shape).copy()


def _json_default(value):
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    raise TypeError(f"cannot encode {type(value).__name__}")


def encode(payload: Any, media: str) -> bytes:
    if media == MSGPACK:
        return msgpack.packb(payload, default=_default, use_bin_type=True)
    return json.dumps(payload, default=_json_default, allow_nan=False).encode()


def decode(content: bytes, media: str) -> Any:
    if media.startswith(MSGPACK):
        return msgpack.unpackb(content, raw=False, ext_hook=_ext_hook)
    return json.loads(content)
