"""Optional bearer API keys. With ``MRDEM_API_KEYS`` set, every ``/v1`` call needs one, and
the key's owner (a digest of the key, never the key itself) scopes what it sees."""

from __future__ import annotations

import hashlib
import hmac

from fastapi import Request

from .errors import Unauthorized

__all__ = ["owner_of"]

_CHALLENGE = {"WWW-Authenticate": "Bearer"}


def owner_of(request: Request) -> str:
    """FastAPI dependency: the caller's owner id ("" when the service has no keys)."""
    keys = request.app.state.settings.api_keys
    if not keys:
        return ""
    scheme, _, token = request.headers.get("authorization", "").partition(" ")
    if scheme.lower() != "bearer" or not token.strip():
        raise Unauthorized("missing API key: send 'Authorization: Bearer <key>'", _CHALLENGE)
    token = token.strip().encode()
    for key in keys:
        if hmac.compare_digest(token, key.encode()):
            return hashlib.sha256(key.encode()).hexdigest()[:24]
    raise Unauthorized("unknown API key", _CHALLENGE)
