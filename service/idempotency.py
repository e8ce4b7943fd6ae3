"""``Idempotency-Key`` on the POSTs that change state: creating a scene and stepping one.

A client that loses the connection after sending such a request cannot tell whether it
happened; sent again, the scene would be created twice or stepped twice. With an
``Idempotency-Key`` header (1–255 visible ASCII characters, for example a UUID) the
service stores the answer with the key, in the same transaction as the scene or its new
state, so that an acknowledged request and its key are kept or lost together. A request
repeated with the same key and the same body (method, path, media type and bytes) gets
the first answer again, with ``Idempotent-Replayed: true``; the same key with another
body is refused with 422; while the first request with a key is still running, a second
one gets 409 with ``Retry-After``. Keys belong to an owner and are kept for
``MRDEM_IDEMPOTENCY_RETENTION`` seconds (default a day).
"""

from __future__ import annotations

import hashlib
import threading
from collections.abc import AsyncIterator, Iterator
from contextlib import asynccontextmanager, contextmanager

from fastapi import Request
from fastapi.responses import Response

from mrdem_common.codec import unpackb

from .codecs import respond
from .errors import BadRequest, Conflict, Unprocessable
from .store import Key  # where a step's actor unpickles it without FastAPI

__all__ = ["HEADER", "InFlight", "Key", "key_of", "keyed", "replayed"]

HEADER = "Idempotency-Key"
REPLAYED = "Idempotent-Replayed"
_LONGEST = 255


def key_of(request: Request, body: bytes) -> Key | None:
    """The request's :class:`Key`, None without the header; 400 for a malformed one. The
    fingerprint covers the method, the path, the media type and the body's bytes."""
    value = request.headers.get(HEADER)
    if value is None:
        return None
    if not 1 <= len(value) <= _LONGEST or not all("!" <= c <= "~" for c in value):
        raise BadRequest(
            f"{HEADER} must be 1 to {_LONGEST} visible ASCII characters (no spaces), for"
            " example a UUID"
        )
    media = (request.headers.get("content-type") or "").split(";")[0].strip().lower()
    digest = hashlib.sha256()
    for part in (request.method, request.url.path, media):
        digest.update(part.encode() + b"\n")
    digest.update(body)
    return Key(value, digest.hexdigest())


def replayed(request: Request, store, owner: str, key: Key | None) -> Response | None:
    """The stored answer of ``key``'s first request (None if there is none yet); 422 if
    the key came with another request."""
    if key is None:
        return None
    row = store.remembered(owner, key.value)
    if row is None:
        return None
    fingerprint, status, payload = row
    if fingerprint != key.fingerprint:
        raise Unprocessable(
            f"{HEADER} {key.value!r} was used with a different request (method, path or"
            " body); send a new key with each new request"
        )
    response = respond(request, unpackb(payload), status)
    response.headers[REPLAYED] = "true"
    return response


class InFlight:
    """The keys whose first request is running, per owner (one process)."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._keys: set[tuple[str, str]] = set()

    @contextmanager
    def claim(self, owner: str, key: Key | None) -> Iterator[None]:
        """Hold ``key`` while its request runs; 409 if another request holds it."""
        if key is None:
            yield
            return
        slot = (owner, key.value)
        with self._lock:
            if slot in self._keys:
                raise Conflict(
                    f"a request with {HEADER} {key.value!r} is still running; send it again"
                    " when that one has answered",
                    headers={"Retry-After": "1"},
                )
            self._keys.add(slot)
        try:
            yield
        finally:
            with self._lock:
                self._keys.discard(slot)


@asynccontextmanager
async def keyed(
    request: Request, owner: str, body: bytes, store, engine, in_flight: InFlight
) -> AsyncIterator[tuple[Key | None, Response | None]]:
    """Around a request that changes state: its :class:`Key` (None without the header),
    held in ``in_flight`` (the app's :class:`InFlight`) while the block runs, and the
    stored answer of the key's first request (None if there is none: the block does the
    work). The store is read off the event loop (``engine.io``)."""
    key = await engine.io(key_of, request, body)  # hashes the body
    with in_flight.claim(owner, key):
        yield key, await engine.io(replayed, request, store, owner, key)
