"""FastAPI dependencies (``async def``: FastAPI would run a plain ``def`` in a worker thread,
a thread hop for each): the app's parts (settings, store, engine runner, live scenes,
tree banks, build jobs, metrics), the caller's owner, and request bodies decoded by media
type and validated by their model, off the event loop."""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import Depends, Request
from fastapi.security import HTTPAuthorizationCredentials
from pydantic import BaseModel, TypeAdapter, ValidationError

from .auth import bearer, owner_of
from .banks import BankCache
from .builds import BuildJobs
from .codecs import decode
from .compute import EngineRunner, Warmup
from .errors import invalid
from .idempotency import InFlight
from .metrics import Metrics
from .scenes import LiveScenes
from .search import BatchSplitter
from .settings import Settings
from .store import Store

__all__ = [
    "Banks",
    "Builds",
    "Config",
    "Engine",
    "Held",
    "Live",
    "Meter",
    "Owner",
    "Splitter",
    "Storage",
    "Warming",
    "body",
    "validated",
]


async def _settings(request: Request) -> Settings:
    return request.app.state.settings


async def _store(request: Request) -> Store:
    return request.app.state.store


async def _engine(request: Request) -> EngineRunner:
    return request.app.state.engine


async def _scenes(request: Request) -> LiveScenes:
    return request.app.state.scenes


async def _banks(request: Request) -> BankCache:
    return request.app.state.banks


async def _builds(request: Request) -> BuildJobs:
    return request.app.state.builds


async def _metrics(request: Request) -> Metrics:
    return request.app.state.metrics


async def _warmup(request: Request) -> Warmup:
    return request.app.state.warmup


async def _in_flight(request: Request) -> InFlight:
    return request.app.state.in_flight


async def _splitter(request: Request) -> BatchSplitter | None:
    return request.app.state.splitter


Config = Annotated[Settings, Depends(_settings)]
Storage = Annotated[Store, Depends(_store)]
Engine = Annotated[EngineRunner, Depends(_engine)]
Live = Annotated[LiveScenes, Depends(_scenes)]
Banks = Annotated[BankCache, Depends(_banks)]
Builds = Annotated[BuildJobs, Depends(_builds)]
Meter = Annotated[Metrics, Depends(_metrics)]
Warming = Annotated[Warmup, Depends(_warmup)]
Held = Annotated[InFlight, Depends(_in_flight)]
Splitter = Annotated[BatchSplitter | None, Depends(_splitter)]


async def _owner(
    settings: Config,
    credentials: Annotated[HTTPAuthorizationCredentials | None, Depends(bearer)],
) -> str:
    return owner_of(settings.api_keys, credentials)


Owner = Annotated[str, Depends(_owner)]


def validated(kind: type[BaseModel] | TypeAdapter, raw: bytes, content_type: str | None) -> Any:
    """``raw`` decoded by its media type (:func:`service.codecs.decode`), validated as
    ``kind`` (a model, or a ``TypeAdapter`` of a union); 400/415 for a body that cannot be
    decoded, 422 naming the invalid fields."""
    value = decode(raw, content_type)
    try:
        if isinstance(kind, TypeAdapter):
            return kind.validate_python(value)
        return kind.model_validate(value)
    except ValidationError as error:
        raise invalid(error) from None


def body(kind: type[BaseModel] | TypeAdapter):
    """A dependency: the request body as ``kind``, decoded and validated in a worker
    thread (a large JSON body takes a while to parse)."""

    async def parsed(request: Request, engine: Engine) -> Any:
        raw = await request.body()
        return await engine.io(validated, kind, raw, request.headers.get("content-type"))

    return Depends(parsed)
