"""Prometheus metrics of one app (its own registry): request latency, engine counters and
tree-build jobs."""

from __future__ import annotations

from prometheus_client import CollectorRegistry, Counter, Gauge, Histogram, generate_latest

__all__ = ["Metrics"]

_LATENCY = (0.001, 0.0025, 0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1, 2.5, 5, 10, 30, 60)
_BUILD = (0.01, 0.05, 0.1, 0.25, 0.5, 1, 2.5, 5, 10, 30, 60, 120, 300, 600, 1800)


class Metrics:
    def __init__(self) -> None:
        self.registry = CollectorRegistry()
        r = self.registry
        self.requests = Counter(
            "mrdem_http_requests", "HTTP requests", ["method", "route", "status"], registry=r
        )
        self.latency = Histogram(
            "mrdem_http_request_seconds",
            "HTTP request latency",
            ["method", "route"],
            buckets=_LATENCY,
            registry=r,
        )
        self.engine_seconds = Histogram(
            "mrdem_engine_seconds", "engine call time", ["call"], buckets=_LATENCY, registry=r
        )
        self.comparisons = Counter(
            "mrdem_triangle_comparisons", "triangle-pair comparisons", registry=r
        )
        self.iterative = Counter("mrdem_iterative_evaluations", "iterative kernel runs", registry=r)
        self.fallbacks = Counter("mrdem_exact_fallbacks", "exact-kernel fallbacks", registry=r)
        self.contact_pairs = Counter("mrdem_contact_body_pairs", "body pairs queried", registry=r)
        self.meshes_built = Counter("mrdem_meshes_built", "surrogate trees built", registry=r)
        self.build_seconds = Histogram(
            "mrdem_build_seconds", "tree build job time (done jobs)", buckets=_BUILD, registry=r
        )
        self.jobs = Gauge(
            "mrdem_build_jobs", "unfinished tree build jobs by status", ["status"], registry=r
        )
        self.jobs_finished = Counter(
            "mrdem_build_jobs_finished",
            "finished tree build jobs by status",
            ["status"],
            registry=r,
        )
        for status in ("queued", "building"):
            self.jobs.labels(status).set(0)
        for status in ("done", "failed"):
            self.jobs_finished.labels(status)
        self.steps = Counter("mrdem_steps", "time steps", registry=r)
        self.picard = Counter("mrdem_picard_iterations", "Picard iterations", registry=r)

    def exposition(self) -> bytes:
        return generate_latest(self.registry)
