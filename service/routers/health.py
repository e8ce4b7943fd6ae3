"""Probes and metrics: ``/healthz`` (the process answers), ``/readyz`` (kernels compiled and
the store reachable), ``/metrics`` (Prometheus)."""

from __future__ import annotations

from fastapi import APIRouter
from fastapi.responses import JSONResponse, PlainTextResponse, Response
from prometheus_client import CONTENT_TYPE_LATEST
from pydantic import BaseModel

from ..deps import Engine, Meter, Storage, Warming
from ..errors import PROBLEM, NotReady

router = APIRouter(tags=["health"])


class Health(BaseModel):
    status: str


class Ready(BaseModel):
    status: str
    warmup_seconds: float | None


def _json(model: type[BaseModel], text: str) -> dict:
    return {
        "description": text,
        "content": {"application/json": {"schema": model.model_json_schema()}},
    }


@router.get("/healthz", summary="The process answers", responses={200: _json(Health, "Alive")})
async def healthz():
    return JSONResponse({"status": "ok"})


@router.get(
    "/readyz",
    summary="Kernels compiled and the store reachable",
    responses={
        200: _json(Ready, "Ready for requests"),
        503: {
            "description": "Not ready (Retry-After while compiling)",
            "content": {PROBLEM: {"schema": {"$ref": "#/components/schemas/Problem"}}},
        },
    },
)
async def readyz(warmup: Warming, store: Storage, engine: Engine):
    if warmup.error is not None:
        raise NotReady(f"kernel warm-up failed: {warmup.error}")
    if not warmup.ready.is_set():
        raise NotReady("compiling kernels", {"Retry-After": "5"})
    if not await engine.io(store.ping):
        raise NotReady("the store does not answer", {"Retry-After": "5"})
    return JSONResponse({"status": "ready", "warmup_seconds": warmup.seconds})


@router.get(
    "/metrics",
    summary="Prometheus metrics",
    response_class=PlainTextResponse,
    responses={
        200: {
            "description": "Prometheus text",
            "content": {"text/plain": {"schema": {"type": "string"}}},
        }
    },
)
async def metrics(meter: Meter):
    return Response(meter.exposition(), media_type=CONTENT_TYPE_LATEST)
