"""The service's errors, each an RFC 9457 problem (``application/problem+json``).

One hierarchy for the service layer::

    ServiceError                  status, title, detail (+ extra members)
     ├── BadRequest (400)         a body that cannot be decoded
     ├── Unauthorized (401)       missing or unknown API key
     ├── NotFound (404)           unknown id (or another key's)
     ├── NotAcceptable (406)      no response media type the client accepts
     ├── Conflict (409)           the mesh was deleted while its upload (or scene) waited
     ├── PayloadTooLarge (413)    body over ``max_body_bytes``
     ├── UnsupportedMediaType (415)
     ├── Unprocessable (422)      well-formed but invalid: shapes, ranges, limits
     └── Unavailable (503)        not now (Retry-After): no room in a cluster for a scene's actor
          └── NotReady            /readyz: kernels still compiling, the store not answering

Engine errors (:class:`engine.EngineError`) are client errors by construction and become
422 problems; request-validation errors too (the responses: :mod:`service.handlers`, apart
so that a process using only the errors — a scene's actor — does not import FastAPI).
Anything else is a bug: logged, answered with a 500 problem, the server stays up. A tree
build that failed while its upload waited is answered with the job's own cause
(:func:`service.routers.meshes._failure`): 422 for a mesh the engine cannot build, 409 when
cancelled, 503 when out of memory, 500 (a plain :class:`ServiceError`) when the server
failed — the detail says why either way.
"""

from __future__ import annotations

from .models.problems import field_errors, joined

__all__ = [
    "BadRequest",
    "Conflict",
    "NotAcceptable",
    "NotFound",
    "NotReady",
    "PayloadTooLarge",
    "ServiceError",
    "Unauthorized",
    "Unprocessable",
    "Unavailable",
    "UnsupportedMediaType",
    "invalid",
]

PROBLEM = "application/problem+json"


class ServiceError(Exception):
    """An error the client can act on; ``detail`` says exactly what was wrong."""

    status = 500
    title = "Internal Server Error"

    def __init__(self, detail: str, headers: dict | None = None, **extra) -> None:
        super().__init__(detail)
        self.detail, self.headers, self.extra = detail, headers or {}, extra


class BadRequest(ServiceError):
    status, title = 400, "Bad Request"


class Unauthorized(ServiceError):
    status, title = 401, "Unauthorized"


class NotFound(ServiceError):
    status, title = 404, "Not Found"


class NotAcceptable(ServiceError):
    status, title = 406, "Not Acceptable"


class Conflict(ServiceError):
    status, title = 409, "Conflict"


class PayloadTooLarge(ServiceError):
    status, title = 413, "Content Too Large"


class UnsupportedMediaType(ServiceError):
    status, title = 415, "Unsupported Media Type"


class Unprocessable(ServiceError):
    status, title = 422, "Unprocessable Content"


class Unavailable(ServiceError):
    """503: the service cannot do it now (say when to come back: ``Retry-After``)."""

    status, title = 503, "Service Unavailable"


class NotReady(Unavailable):
    """503 of ``/readyz``: kernels compiling, the store not answering."""


def invalid(error) -> Unprocessable:
    """The 422 problem of a validation error (pydantic's, or FastAPI's for parameters):
    ``errors`` names each invalid field's path and what was wrong, ``detail`` joins them."""
    errors = field_errors(error.errors())
    return Unprocessable(joined(errors), errors=errors)
