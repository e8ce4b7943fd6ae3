"""Request and response bodies: JSON, or msgpack with numpy arrays as typed binary.

msgpack arrays travel as extension type :data:`NDARRAY_EXT` holding ``[dtype, shape,
data]``, read and written by :mod:`mrdem_common.codec` (the one implementation, shared with the
clients): little-endian or byte-order-free bool, integer, unsigned or float dtypes of at most
8 bytes, nothing else, so decoding never executes code (no pickle). This module adds the HTTP
parts: content negotiation, 400/406/413/415 problems, the body-size limit. In JSON, arrays
are nested lists and non-finite numbers (``NaN``, ``Infinity``) are rejected.
"""

from __future__ import annotations

import json
from typing import Any

import msgpack
from fastapi import Request
from fastapi.responses import Response
from pydantic import BaseModel

from mrdem_common.codec import JSON, MSGPACK, NDARRAY_EXT, CodecError, packb, plain, unpackb

from .errors import BadRequest, NotAcceptable, PayloadTooLarge, UnsupportedMediaType

__all__ = [
    "JSON",
    "MSGPACK",
    "NDARRAY_EXT",
    "BodyLimit",
    "decode",
    "encode_msgpack",
    "respond",
    "server_timing",
]


def _no_constant(name: str):
    raise BadRequest(f"non-finite number {name} in JSON (only finite numbers are accepted)")


def decode(body: bytes, content_type: str | None) -> Any:
    """The decoded body; 400 for a malformed one, 415 for another media type."""
    media = (content_type or "").split(";")[0].strip().lower()
    if not body:
        raise BadRequest("empty request body")
    if media in (JSON, ""):
        try:
            return json.loads(body, parse_constant=_no_constant)
        except (ValueError, RecursionError) as exc:
            raise BadRequest(f"malformed JSON: {exc}") from None
    if media in (MSGPACK, "application/x-msgpack"):
        try:
            return unpackb(body, strict=True)
        except CodecError as exc:
            raise BadRequest(str(exc)) from None
        except (ValueError, TypeError, msgpack.UnpackException, RecursionError) as exc:
            raise BadRequest(f"malformed msgpack: {exc}") from None
    raise UnsupportedMediaType(
        f"content type {media!r} not accepted; use {JSON}, {MSGPACK} or multipart/form-data"
    )


def encode_msgpack(payload: Any) -> bytes:
    """``payload`` as msgpack, arrays as typed binary (:func:`mrdem_common.codec.packb`)."""
    return packb(payload)


def _wants(request: Request) -> str:
    accept = request.headers.get("accept", "").lower()
    if not accept:
        return JSON
    kinds = [part.split(";")[0].strip() for part in accept.split(",")]
    for kind in kinds:
        if kind in (MSGPACK, "application/x-msgpack"):
            return MSGPACK
        if kind in (JSON, "application/*", "*/*", "application/problem+json"):
            return JSON
    raise NotAcceptable(f"cannot answer {accept!r}; this service speaks {JSON} and {MSGPACK}")


def respond(request: Request, payload: Any, status: int = 200, headers=None) -> Response:
    """``payload`` (a model, or plain values and arrays) in the media type the request
    accepts (JSON unless it asks msgpack)."""
    if isinstance(payload, BaseModel):
        payload = payload.model_dump()
    if _wants(request) == MSGPACK:
        return Response(encode_msgpack(payload), status, headers, media_type=MSGPACK)
    body = json.dumps(payload, default=plain, allow_nan=False, separators=(",", ":"))
    return Response(body, status, headers, media_type=JSON)


def server_timing(seconds: dict[str, float]) -> str:
    """A ``Server-Timing`` header's value (W3C Server Timing) of ``seconds`` (name →
    seconds): ``name;dur=milliseconds`` entries, comma-separated, in order."""
    return ", ".join(f"{name};dur={value * 1e3:.3f}" for name, value in seconds.items())


class BodyLimit:
    """ASGI middleware: request bodies larger than ``limit`` bytes get a 413 — at once from
    ``Content-Length``, else as soon as the streamed bytes pass the limit."""

    def __init__(self, app, limit: int) -> None:
        self.app, self.limit = app, limit

    async def __call__(self, scope, receive, send):
        if scope["type"] != "http":
            return await self.app(scope, receive, send)
        for name, value in scope.get("headers", ()):
            if name == b"content-length":
                try:
                    length = int(value)
                except ValueError:
                    length = -1
                if length > self.limit:
                    return await _too_large(send, self.limit)
        seen = 0

        async def counted():
            nonlocal seen
            message = await receive()
            seen += len(message.get("body", b""))
            if seen > self.limit:
                raise PayloadTooLarge(f"request body over the limit of {self.limit} bytes")
            return message

        return await self.app(scope, counted, send)


async def _too_large(send, limit: int) -> None:
    body = json.dumps(
        {
            "type": "about:blank",
            "title": PayloadTooLarge.title,
            "status": 413,
            "detail": f"request body over the limit of {limit} bytes",
        }
    ).encode()
    await send(
        {
            "type": "http.response.start",
            "status": 413,
            "headers": [
                (b"content-type", b"application/problem+json"),
                (b"content-length", str(len(body)).encode()),
                (b"connection", b"close"),
            ],
        }
    )
    await send({"type": "http.response.body", "body": body})
