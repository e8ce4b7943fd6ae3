"""mrdem service: a FastAPI app that keeps surrogate trees of uploaded meshes and answers
batched contact queries and scene steps over HTTP. Imports engine, never clients.

The names below are loaded on first use (PEP 562): a process that needs only part of the
service — a scene's actor on a Ray node, a contacts task — does not import FastAPI and
every router (:mod:`mrdem_common.lazy`)."""

from __future__ import annotations

from typing import TYPE_CHECKING

from mrdem_common.lazy import attributes

if TYPE_CHECKING:
    from .app import create_app
    from .cli import serve
    from .settings import Settings

__all__ = ["Settings", "create_app", "serve"]

_HOMES = {"Settings": ".settings", "create_app": ".app", "serve": ".cli"}

__getattr__ = attributes(__name__, _HOMES)
