"""Scale-out on Ray (``pip install 'mrdem[cluster]'``): the service as a Ray Serve
deployment of N replicas (:mod:`.deployment`), scenes as Ray actors (:mod:`.scenes`), big
contacts requests as Ray tasks across the nodes (:mod:`.batches`), over the shared store
(PostgreSQL + an S3-compatible bucket). ``mrdem cluster serve`` starts it.

The names below are loaded on first use (PEP 562): a scene's actor or a contacts task,
which Ray starts by importing :mod:`.scenes` or :mod:`.batches`, does not import Ray Serve,
FastAPI and the app (about a second of its start on a 2-vCPU VM)."""

from __future__ import annotations

from typing import TYPE_CHECKING

from mrdem_common.lazy import attributes

if TYPE_CHECKING:
    from .deployment import APP_NAME, Ingress, application, run
    from .scenes import NAMESPACE, ActorScenes, SceneActor, actor_name

__all__ = [
    "APP_NAME",
    "NAMESPACE",
    "ActorScenes",
    "Ingress",
    "SceneActor",
    "actor_name",
    "application",
    "run",
]

_HOMES = {
    **dict.fromkeys(("APP_NAME", "Ingress", "application", "run"), ".deployment"),
    **dict.fromkeys(("NAMESPACE", "ActorScenes", "SceneActor", "actor_name"), ".scenes"),
}

__getattr__ = attributes(__name__, _HOMES)
