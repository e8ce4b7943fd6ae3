"""An idempotency key as the store keeps it (:class:`Key`), apart from the HTTP handling of
:mod:`service.idempotency`: a key travels with a step to the process that runs it — a scene's
Ray actor, which unpickles it — and importing this module brings in no web framework (the
HTTP module's FastAPI and codecs took a scene's first step on a spare actor 0.10–0.14 s
longer, measured on the 2-vCPU VM)."""

from __future__ import annotations

from dataclasses import dataclass

from mrdem_common.codec import packb

__all__ = ["Key"]


@dataclass(frozen=True)
class Key:
    """An idempotency key and the fingerprint of the request that came with it."""

    value: str
    fingerprint: str

    def remember(self, status: int, payload) -> tuple[str, str, int, bytes]:
        """The row the store keeps with the request's effect: ``(key, fingerprint,
        status, payload as msgpack)``."""
        return self.value, self.fingerprint, int(status), packb(payload)
