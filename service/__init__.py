"""mrdem service: a FastAPI app that keeps surrogate trees of uploaded meshes and answers
batched contact queries (and, next, scene steps) over HTTP. Imports engine, never clients."""

from .app import create_app
from .cli import serve
from .settings import Settings

__all__ = ["Settings", "create_app", "serve"]
