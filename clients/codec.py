"""The client's side of the wire format: request bodies as msgpack (numpy arrays as typed
binary, :mod:`mrdem_common.codec`, the one array codec the service uses too) or JSON, and answers
read back. Imports neither engine nor service."""

from __future__ import annotations

import json
from typing import Any

from mrdem_common.codec import (
    JSON,
    MSGPACK,
    NDARRAY_EXT,
    array_ext,
    array_from_ext,
    packb,
    plain,
    unpackb,
)

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


def encode(payload: Any, media: str) -> bytes:
    """``payload`` as a request body of ``media`` (:data:`MSGPACK`, else JSON: arrays as
    nested lists, non-finite numbers refused)."""
    if media == MSGPACK:
        return packb(payload)
    return json.dumps(payload, default=plain, allow_nan=False).encode()


def decode(content: bytes, media: str) -> Any:
    """An answer's body of the ``media`` type (a ``content-type`` value): msgpack with arrays
    as numpy arrays (other extension types kept as ``msgpack.ExtType``; ``ValueError`` for an
    unreadable array), else JSON."""
    if media.startswith(MSGPACK):
        return unpackb(content)
    return json.loads(content)
