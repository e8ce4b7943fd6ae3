"""The FastAPI application: settings, store, engine runner, metrics, routers, errors."""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from contextlib import asynccontextmanager
from typing import Any

from fastapi import FastAPI, Request

import engine
from mrdem_common.malloc import keep_large_blocks

from .banks import BankCache
from .builds import BuildJobs
from .codecs import BodyLimit
from .compute import EngineRunner, Warmup
from .handlers import install_handlers
from .idempotency import InFlight
from .metrics import CopyTo, Metrics
from .openapi import install as install_openapi
from .routers import contacts, health, jobs, meshes, scenes
from .scenes import LiveScenes
from .search import BatchSplitter
from .settings import Settings
from .store import Store, open_store

__all__ = ["create_app"]

log = logging.getLogger("mrdem.service")


def create_app(
    settings: Settings | None = None,
    *,
    scene_host: Callable[[Store, Settings], Any] | None = None,
    splitter: Callable[[Store, Settings], BatchSplitter | None] | None = None,
    metrics_copy: CopyTo | None = None,
) -> FastAPI:
    """The service app. When the app starts, the store opens, unfinished tree builds of an
    earlier run are queued again (:class:`BuildJobs`, background threads) and the kernel
    warm-up starts (in a background thread: ``/readyz`` answers 503 until it is done).

    A cluster (:mod:`service.cluster`) passes what it runs elsewhere: ``scene_host(store,
    settings)`` gives what holds the scenes (default: :class:`LiveScenes`, in this
    process) and ``splitter(store, settings)`` what runs big contacts requests as chunks
    (default: none). ``metrics_copy`` records every metric in a copy too (default: none; a
    cluster's replicas: Ray's metrics, see :class:`~service.metrics.Metrics`)."""
    settings = settings or Settings()

    @asynccontextmanager
    async def lifespan(app: FastAPI):
        if settings.keep_large_blocks and not keep_large_blocks():
            log.info("MRDEM_KEEP_LARGE_BLOCKS: not glibc, the allocator keeps its defaults")
        app.state.store = open_store(settings)
        if scene_host is None:
            app.state.scenes = LiveScenes(app.state.store, settings.engine_threads)
        else:
            app.state.scenes = scene_host(app.state.store, settings)
        app.state.splitter = None if splitter is None else splitter(app.state.store, settings)
        app.state.banks = BankCache(app.state.store)
        app.state.builds = BuildJobs(
            app.state.store,
            settings.build_concurrency,
            metrics,
            settings.job_retention,
            settings.engine_threads,
        )
        app.state.builds.start()
        if settings.warmup:
            threading.Thread(target=_warm, args=(app.state,), name="warmup", daemon=True).start()
        else:
            app.state.warmup.ready.set()
        try:
            yield
        finally:
            app.state.builds.close()
            app.state.scenes.close()
            app.state.store.close()

    app = FastAPI(
        title="mrdem",
        version="0.1.0",
        summary="Multiresolution DEM: contacts and rigid-body steps for triangulated meshes",
        lifespan=lifespan,
        generate_unique_id_function=lambda route: route.name,  # operationId: the function
    )
    app.state.settings = settings
    app.state.metrics = metrics = Metrics(metrics_copy)
    app.state.engine = EngineRunner(settings.engine_concurrency, metrics)
    app.state.warmup = Warmup()
    app.state.in_flight = InFlight()  # Idempotency-Keys whose first request is running
    install_handlers(app)
    install_openapi(
        app,
        {
            k: getattr(settings, k)
            for k in ("max_steps", "max_pairs", "max_bodies", "max_triangles")
        },
    )
    for module in (health, jobs, meshes, contacts, scenes):  # jobs before /v1/meshes/{id}
        app.include_router(module.router)
    app.add_middleware(BodyLimit, limit=settings.max_body_bytes)

    @app.middleware("http")
    async def observe(request: Request, call_next):
        start = time.perf_counter()
        response = await call_next(request)
        route = request.scope.get("route")
        path = getattr(route, "path", "unmatched")
        metrics.requests.labels(request.method, path, str(response.status_code)).inc()
        metrics.latency.labels(request.method, path).observe(time.perf_counter() - start)
        return response

    return app


def _warm(state) -> None:
    try:
        state.warmup.seconds = engine.warmup(state.settings.warmup_workers)
        log.info("kernels ready in %.1f s", state.warmup.seconds)
        state.warmup.ready.set()
    except Exception as exc:  # reported by /readyz; the process stays up for diagnosis
        log.exception("kernel warm-up failed")
        state.warmup.error = f"{type(exc).__name__}: {exc}"
