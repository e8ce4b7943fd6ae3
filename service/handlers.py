"""The HTTP side of :mod:`service.errors`: each error as an RFC 9457 problem response
(``application/problem+json``), and the app's exception handlers: a :class:`ServiceError`
with its status, an engine error or a request-validation error as 422, an unknown route as
404, anything else (a bug) logged and answered 500 while the server stays up."""

from __future__ import annotations

import logging

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from starlette.exceptions import HTTPException as StarletteHTTPException

from engine import EngineError

from .errors import PROBLEM, ServiceError, Unprocessable, invalid

__all__ = ["install_handlers", "problem"]

log = logging.getLogger("mrdem.service")


def problem(
    status: int, title: str, detail: str, instance: str | None = None, headers=None, **extra
) -> JSONResponse:
    """An RFC 9457 problem response."""
    body = {"type": "about:blank", "title": title, "status": status, "detail": detail}
    if instance:
        body["instance"] = instance
    body.update(extra)
    return JSONResponse(body, status_code=status, media_type=PROBLEM, headers=headers)


def install_handlers(app: FastAPI) -> None:
    """Map every error to a problem response."""

    @app.exception_handler(ServiceError)
    async def _service(request: Request, exc: ServiceError):
        return problem(
            exc.status, exc.title, exc.detail, request.url.path, exc.headers, **exc.extra
        )

    @app.exception_handler(EngineError)
    async def _engine(request: Request, exc: EngineError):
        return problem(422, Unprocessable.title, str(exc), request.url.path)

    @app.exception_handler(RequestValidationError)
    async def _validation(request: Request, exc: RequestValidationError):
        error = invalid(exc)
        return problem(422, error.title, error.detail, request.url.path, **error.extra)

    @app.exception_handler(StarletteHTTPException)
    async def _http(request: Request, exc: StarletteHTTPException):
        titles = {404: "Not Found", 405: "Method Not Allowed"}
        detail = exc.detail if isinstance(exc.detail, str) else str(exc.detail)
        if exc.status_code == 404 and detail == "Not Found":
            detail = f"no route {request.method} {request.url.path}"
        return problem(
            exc.status_code,
            titles.get(exc.status_code, "Error"),
            detail,
            request.url.path,
            getattr(exc, "headers", None),
        )

    @app.exception_handler(Exception)
    async def _bug(request: Request, exc: Exception):
        log.exception("unhandled error on %s %s", request.method, request.url.path)
        return problem(500, ServiceError.title, "internal error (logged)", request.url.path)
