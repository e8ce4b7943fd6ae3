"""Optional bearer API keys (the OpenAPI document's ``HTTPBearer`` scheme). With
``MRDEM_API_KEYS`` set, every ``/v1`` call needs one, and the key's owner (a digest of the
key, never the key itself) scopes what it sees."""

from __future__ import annotations

import hashlib
import hmac

from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer

from .errors import Unauthorized

__all__ = ["bearer", "owner_of"]

_CHALLENGE = {"WWW-Authenticate": "Bearer"}

bearer = HTTPBearer(
    auto_error=False,
    description="An API key, when the service has any (MRDEM_API_KEYS); none otherwise.",
)


def owner_of(keys: tuple[str, ...], credentials: HTTPAuthorizationCredentials | None) -> str:
    """The caller's owner id ("" when the service has no keys); 401 without a known key."""
    if not keys:
        return ""
    if credentials is None or not credentials.credentials.strip():
        raise Unauthorized("missing API key: send 'Authorization: Bearer <key>'", _CHALLENGE)
    token = credentials.credentials.strip().encode()
    for key in keys:
        if hmac.compare_digest(token, key.encode()):
            return hashlib.sha256(key.encode()).hexdigest()[:24]
    raise Unauthorized("unknown API key", _CHALLENGE)
