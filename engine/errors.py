"""Errors raised by the engine.

One hierarchy for the whole engine layer; the service maps each class to an
RFC 9457 problem (all of them are client errors: bad input, never a crash)::

    EngineError
     ├── InvalidMeshError        a mesh that cannot be used (non-finite coordinates,
     │                           indices out of range, no faces, not closed where a
     │                           volume is needed, unreadable file)
     └── InvalidArgumentError    an argument of the wrong shape, dtype or range
                                 (also a ValueError, so numpy-style callers catch it)
"""

from __future__ import annotations

__all__ = ["EngineError", "InvalidArgumentError", "InvalidMeshError"]


class EngineError(Exception):
    """Base class of every error the engine raises on purpose."""


class InvalidMeshError(EngineError, ValueError):
    """The mesh is unusable; the message says which check failed and where."""


class InvalidArgumentError(EngineError, ValueError):
    """An argument has the wrong shape, dtype or value; the message names it."""
