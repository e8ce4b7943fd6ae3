"""Probes and metrics: ``/healthz`` (the process answers), ``/readyz`` (kernels compiled and
the store reachable), ``/metrics`` (Prometheus)."""

from __future__ import annotations

from fastapi import APIRouter, Request
from fastapi.responses import JSONResponse, Response
from prometheus_client import CONTENT_TYPE_LATEST

from ..errors import NotReady

router = APIRouter(tags=["health"])


@router.get("/healthz")
async def healthz():
    return JSONResponse({"status": "ok"})


@router.get("/readyz")
async def readyz(request: Request):
    state = request.app.state
    if state.warmup_error is not None:
        raise NotReady(f"kernel warm-up failed: {state.warmup_error}")
    if not state.ready.is_set():
        raise NotReady("compiling kernels", {"Retry-After": "5"})
    if not state.store.ping():
        raise NotReady("the store does not answer", {"Retry-After": "5"})
    return JSONResponse({"status": "ready", "warmup_seconds": state.warmup_seconds})


@router.get("/metrics")
async def metrics(request: Request):
    return Response(request.app.state.metrics.exposition(), media_type=CONTENT_TYPE_LATEST)
