"""The service as a Ray Serve deployment: the same FastAPI app (:func:`service.app.
create_app`) in N replicas behind Serve's HTTP proxy, the scenes in Ray actors
(:mod:`.scenes`), big contacts requests split into Ray tasks (:mod:`.batches`), and the store
shared by all (PostgreSQL and an S3-compatible bucket: ``MRDEM_STORE_URL``,
``MRDEM_OBJECT_STORE_URL``).

A replica sizes its engine threads to the CPUs Ray gave it, and compiles or loads every
kernel in its constructor: a failure there fails the replica loudly (Serve reports it and
retries), and Serve routes to a replica only once its constructor returned, so no request
waits for a compile. Replicas, scene actors and tasks share ``NUMBA_CACHE_DIR`` (Numba writes
each cache file to a temporary name and renames it: concurrent writers are safe; every
process must be able to write the folder).
"""

from __future__ import annotations

import logging
import os

import ray
from ray import serve

import engine

from ..app import create_app
from ..settings import Settings
from .batches import IDLE_WORKERS_MS, IDLE_WORKERS_VARIABLE, RaySplitter
from .metrics import ray_metric
from .scenes import NAMESPACE, ActorScenes

__all__ = ["APP_NAME", "Ingress", "application", "niceness_warning", "run", "scaling"]

APP_NAME = "mrdem"
log = logging.getLogger("mrdem.cluster")

#: variables a replica, a scene actor and a task need from the environment that started
#: the deployment: the kernel cache, boto3's credentials for the object store, and glibc's
#: arena count (below)
PASSED_ON = (
    "NUMBA_CACHE_DIR",
    "MALLOC_ARENA_MAX",
    "AWS_ACCESS_KEY_ID",
    "AWS_SECRET_ACCESS_KEY",
    "AWS_SESSION_TOKEN",
    "AWS_DEFAULT_REGION",
    "AWS_REGION",
)


#: glibc's ``MALLOC_ARENA_MAX`` in the cluster's processes (with ``MRDEM_KEEP_LARGE_BLOCKS``,
#: unless the environment sets it). A replica's threads (Ray's and the engine's) otherwise
#: each get an arena of their own, whose heaps glibc maps and unmaps as a request's arrays
#: come and go, whatever ``mrdem_common.malloc`` asks: measured, a 10,000-pair request took
#: ~15,000 page faults in the replica and its answer 20-28 ms to encode; with one arena
#: ~12 faults and 4-6 ms (the plain service: 5-8 ms; BENCHMARKS.md, issue 18, third session).
ARENAS = "1"


#: Ray starts its worker processes (replicas, tasks, actors) at nice 15 unless the nodes
#: were started with ``RAY_worker_niceness=0``: any process at the default priority on a
#: node then takes its CPU first. Measured (BENCHMARKS.md, issue 18, fourth session): a
#: task's search slowed 27x by one process spinning on its node's CPU, where a plain
#: process is slowed 2.1x (its fair share).
NICENESS = "RAY_worker_niceness=0"


def niceness_warning() -> str | None:
    """What to tell the operator when this process runs below the default priority
    (None when it does not)."""
    nice = os.nice(0)
    if nice <= 0:
        return None
    return (
        f"this process runs at nice {nice}: any other work on its node takes the CPU"
        f" first (searches measured 27x slower beside one busy process); start the Ray"
        f" nodes with {NICENESS} (ray start, or the containers' environment)"
    )


class Ingress:
    """One replica: settings from the deployment (``values``, what ``Settings`` takes),
    threads sized to its CPUs, kernels ready before it serves."""

    def __init__(self, values: dict) -> None:
        cpus = ray.get_runtime_context().get_assigned_resources().get("CPU", 1.0)
        threads = max(1, int(round(cpus)))
        self.settings = Settings(
            **{**values, "engine_threads": threads, "engine_concurrency": threads, "warmup": False}
        )
        if not (self.settings.store_url and self.settings.object_store_url):
            raise RuntimeError(
                "replicas share their store: set MRDEM_STORE_URL (postgresql://…) and"
                " MRDEM_OBJECT_STORE_URL (s3://bucket/prefix)"
            )
        if warning := niceness_warning():
            log.warning("replica: %s", warning)
        seconds = engine.warmup(1)  # raises on failure: the replica fails to start
        log.info("replica ready: %d engine threads, kernels in %.1f s", threads, seconds)

    def __serve_build_asgi_app__(self):
        settings = self.settings

        def scene_host(store, settings):
            return ActorScenes(
                store, settings, settings.scene_cpus, settings.scene_idle, settings.scene_spares
            )

        def splitter(store, settings):
            return RaySplitter(
                settings, settings.split_pairs, settings.split_chunks, settings.task_cpus
            )

        app = create_app(
            settings, scene_host=scene_host, splitter=splitter, metrics_copy=ray_metric
        )
        replica = serve.get_replica_context().replica_id.unique_id

        @app.middleware("http")
        async def served_by(request, call_next):  # which replica answered (for operators)
            response = await call_next(request)
            response.headers["X-Mrdem-Replica"] = replica
            return response

        return app


def scaling(settings: Settings, replicas: int, cpus: float) -> dict:
    """The deployment's replica options: ``num_replicas`` (``replicas``), or, where
    ``settings.replicas_max`` is above ``replicas``, Serve's autoscaling between the two
    (``MRDEM_REPLICA_TARGET_REQUESTS`` … ``MRDEM_REPLICA_LOAD_WINDOW``); with
    ``max_ongoing_requests``, the requests a replica takes at once (the others wait in
    Serve's queue or HAProxy's). :class:`ValueError` for a target a replica cannot reach."""
    most = max(8, 4 * int(cpus))
    options: dict = {"max_ongoing_requests": most}
    top = settings.replicas_max
    if top is None or top <= replicas:
        return {**options, "num_replicas": replicas}
    if settings.replica_target_requests > most:
        raise ValueError(
            f"MRDEM_REPLICA_TARGET_REQUESTS ({settings.replica_target_requests:g}) is above the"
            f" {most} requests a replica of {cpus:g} CPUs takes at once: its load would never"
            f" reach it; set it to {most} or less"
        )
    autoscaling = {
        "min_replicas": replicas,
        "initial_replicas": replicas,
        "max_replicas": top,
        "target_ongoing_requests": settings.replica_target_requests,
        "upscale_delay_s": settings.replica_upscale_delay,
        "downscale_delay_s": settings.replica_downscale_delay,
        "look_back_period_s": settings.replica_load_window,
    }
    return {**options, "autoscaling_config": autoscaling}


def application(settings: Settings, replicas: int, cpus: float) -> serve.Application:
    """The Serve application: ``replicas`` replicas of ``cpus`` CPUs each (or between
    ``replicas`` and ``settings.replicas_max``, by load: :func:`scaling`)."""
    env = {k: os.environ[k] for k in PASSED_ON if k in os.environ}
    if settings.keep_large_blocks:  # one malloc arena: see ARENAS
        env.setdefault("MALLOC_ARENA_MAX", ARENAS)
    deployment = serve.deployment(
        serve.ingress()(Ingress),
        name="mrdem",
        ray_actor_options={"num_cpus": cpus, "runtime_env": {"env_vars": env}},
        **scaling(settings, replicas, cpus),
        health_check_period_s=5,
        logging_config={"enable_access_log": settings.replica_access_log},
    )
    return deployment.bind(settings.model_dump(mode="json"))


def run(
    settings: Settings,
    address: str | None,
    replicas: int,
    cpus: float,
    blocking: bool = True,
    proxies: str = "EveryNode",
) -> None:
    """Deploy on the Ray cluster at ``address`` (``auto``: the one this machine joined;
    None: a new local one), Serve's HTTP proxy on ``settings.host:settings.port`` of every
    node (``proxies="HeadOnly"``: of the head only); with ``blocking``, until interrupted
    (then the application is deleted)."""
    starts = not address and not os.environ.get("RAY_ADDRESS")  # a new local cluster
    local = {"_system_config": {"worker_niceness": 0}} if starts else {}  # see NICENESS
    if starts:  # its raylet reads it, and its workers see it (batches.IDLE_WORKERS)
        os.environ.setdefault(IDLE_WORKERS_VARIABLE, str(IDLE_WORKERS_MS))
    ray.init(address=address, namespace=NAMESPACE, **local)
    serve.start(proxy_location=proxies, http_options={"host": settings.host, "port": settings.port})
    serve.run(
        application(settings, replicas, cpus),
        name=APP_NAME,
        route_prefix="/",
        blocking=blocking,
    )
