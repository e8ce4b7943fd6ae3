"""Scale-out on Ray (``pip install 'mrdem[cluster]'``): the service as a Ray Serve
deployment of N replicas (:mod:`.deployment`), scenes as Ray actors (:mod:`.scenes`), big
contacts requests as Ray tasks across the nodes (:mod:`.batches`), over the shared store
(PostgreSQL + an S3-compatible bucket). ``mrdem cluster serve`` starts it."""

from __future__ import annotations

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
