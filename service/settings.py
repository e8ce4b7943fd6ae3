"""Service settings, read once from the environment (``MRDEM_*``) by pydantic-settings."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Annotated

from pydantic import Field, field_validator, model_validator
from pydantic_settings import BaseSettings, NoDecode, SettingsConfigDict

__all__ = ["Settings"]


class Settings(BaseSettings):
    """Every knob of the service; each field ``name`` is read from ``MRDEM_NAME``.

    ``api_keys`` is a comma-separated list in the environment (``MRDEM_API_KEYS=k1,k2``);
    empty means no authentication (one anonymous owner).
    """

    model_config = SettingsConfigDict(env_prefix="MRDEM_", extra="ignore")

    host: str = "127.0.0.1"
    port: int = Field(8000, ge=0, le=65535)
    data_dir: Path = Path("data")
    api_keys: Annotated[tuple[str, ...], NoDecode] = ()
    max_body_bytes: int = Field(64 * 2**20, ge=1024, description="largest request body (413)")
    max_triangles: int = Field(1_000_000, ge=1, description="triangles per mesh (422)")
    max_pairs: int = Field(10_000, ge=1, description="body pairs per contacts request (422)")
    max_bodies: int = Field(100_000, ge=1, description="bodies per scene (422)")
    max_steps: int = Field(10_000, ge=1, description="steps per step request (422)")
    engine_concurrency: int = Field(
        default_factory=lambda: max(1, os.cpu_count() or 1),
        ge=1,
        description="engine calls running at once (the rest wait)",
    )
    engine_threads: int = Field(
        default_factory=lambda: max(1, os.cpu_count() or 1),
        ge=1,
        description="worker threads of one batched engine call",
    )
    warmup: bool = Field(True, description="compile or load every kernel before /readyz")
    warmup_workers: int | None = Field(
        None,
        ge=1,
        le=2,
        description=(
            "processes compiling kernels at start-up (default: 1 once a warm-up completed on"
            " this kernel cache, else 2, or 1 on one CPU)"
        ),
    )
    tree_cache: int = Field(256, ge=1, description="surrogate trees kept in memory")
    store_url: str | None = Field(
        None,
        description="PostgreSQL database shared by replicas (postgresql://user:password@host"
        ":port/db; needs mrdem[cluster]); unset: SQLite in data_dir",
    )
    store_pool: int = Field(16, ge=2, description="connections to the PostgreSQL store")
    object_store_url: str | None = Field(
        None,
        description="S3-compatible bucket for tree files (s3://bucket/prefix; needs"
        " mrdem[cluster]; credentials from AWS_ACCESS_KEY_ID …); unset: files in data_dir",
    )
    object_store_endpoint: str | None = Field(
        None, description="endpoint of an S3-compatible store other than AWS (http://host:port)"
    )
    tree_disk_cache: int = Field(
        2 * 2**30,
        ge=0,
        description="bytes of tree files read from the object store kept under data_dir/tree-cache",
    )
    build_wait: float = Field(
        5.0,
        ge=0.0,
        le=300.0,
        description="seconds an upload waits for its tree build before answering 202",
    )
    build_concurrency: int = Field(1, ge=1, description="tree builds running at once")
    job_retention: float = Field(
        7 * 24 * 3600.0,
        ge=0.0,
        description="seconds a finished build job stays readable (0: forever)",
    )
    keep_large_blocks: bool = Field(
        True,
        description="keep freed blocks below 32 MiB in the allocator's heap for reuse instead of"
        " returning them to the system (glibc; mrdem_common.malloc): no page faults for every"
        " array a request makes; on a Ray cluster also one malloc arena per process"
        " (MALLOC_ARENA_MAX=1 unless set)",
    )
    idempotency_retention: float = Field(
        24 * 3600.0,
        ge=0.0,
        description="seconds the answer of a request sent with an Idempotency-Key is kept"
        " (0: forever)",
    )

    # scale-out on Ray (service.cluster; `mrdem cluster serve`)
    replicas: int = Field(
        1,
        ge=1,
        description="Serve replicas of the app (mrdem cluster serve); with MRDEM_REPLICAS_MAX,"
        " the fewest",
    )
    replicas_max: int | None = Field(
        None,
        ge=1,
        description="the most Serve replicas: above MRDEM_REPLICAS, Serve adds replicas while"
        " they average more than MRDEM_REPLICA_TARGET_REQUESTS requests in flight and removes"
        " them when the load falls (unset: always MRDEM_REPLICAS)",
    )
    replica_target_requests: float = Field(
        2.0,
        gt=0,
        description="requests in flight per replica that autoscaling aims at (Ray Serve's"
        " target_ongoing_requests)",
    )
    replica_upscale_delay: float = Field(
        30.0,
        ge=0,
        description="seconds the load must stay above the target before a replica is added",
    )
    replica_downscale_delay: float = Field(
        600.0,
        ge=0,
        description="seconds the load must stay below the target before a replica is removed",
    )
    replica_load_window: float = Field(
        30.0, gt=0, description="seconds over which the replicas' requests in flight are averaged"
    )
    replica_cpus: float = Field(
        1.0, gt=0, description="CPUs of each replica (its engine threads: this, rounded)"
    )
    scene_cpus: float = Field(1.0, gt=0, description="CPUs of each scene's actor")
    scene_start: float = Field(
        30.0,
        gt=0,
        description="seconds a scene's new actor may wait for CPUs in the cluster before the"
        " request is answered 503",
    )
    scene_idle: float = Field(
        600.0, ge=0, description="seconds a scene's actor waits for a request before it leaves"
    )
    scene_spares: int = Field(
        1,
        ge=0,
        description="scene actors started ahead, their kernels loaded, from the first scene's"
        " creation on, for the next new scenes: a new scene's first step finds its actor"
        " running (one pool for the deployment's replicas; each spare holds MRDEM_SCENE_CPUS"
        " while it waits, and leaves when idle; 0: none)",
    )
    split_pairs: int = Field(
        2000, ge=1, description="contacts requests of at least this many pairs run as Ray tasks"
    )
    split_chunks: int = Field(
        8,
        ge=1,
        description="runs a split contacts request is cut into, at most: one in the replica,"
        " the others as Ray tasks on other nodes (1: no split)",
    )
    split_pieces: int = Field(
        2,
        ge=1,
        description="pieces each task searches its run in, handing each answer over as it"
        " ends; the replica takes back pieces a node has not begun (more: finer balance, more"
        " hand-overs)",
    )
    task_cpus: float = Field(1.0, gt=0, description="CPUs of each contacts task")
    replica_access_log: bool = Field(
        False,
        description="replicas log every request (Ray Serve's access log; /metrics counts them"
        " either way): off saves a log line's work on every request",
    )

    @model_validator(mode="after")
    def _replica_range(self):
        if self.replicas_max is not None and self.replicas_max < self.replicas:
            raise ValueError(
                f"MRDEM_REPLICAS_MAX ({self.replicas_max}) is below MRDEM_REPLICAS"
                f" ({self.replicas}): set it to at least that, or unset it"
            )
        return self

    @field_validator("replicas_max", mode="before")
    @classmethod
    def _unset_when_empty(cls, value):
        return None if value == "" else value  # MRDEM_REPLICAS_MAX= (compose's default)

    @field_validator("store_url")
    @classmethod
    def _postgres(cls, value):
        if value is not None and not value.startswith(("postgresql://", "postgres://")):
            raise ValueError("the store URL is a PostgreSQL one: postgresql://user@host/db")
        return value

    @field_validator("api_keys", mode="before")
    @classmethod
    def _split_keys(cls, value):
        if isinstance(value, str):
            value = value.split(",")
        keys = tuple(k.strip() for k in value if k and k.strip())
        if any(len(k) < 8 for k in keys):
            raise ValueError("every API key must have at least 8 characters")
        return keys
