"""Prometheus metrics of one app (its own registry): request latency, engine counters and
tree-build jobs; ``/metrics`` answers them. On a cluster each replica has its own (a scrape
through the load balancer meets one replica), so the replicas also record every metric in
a copy that their cluster collects (``copy_to``: :mod:`service.cluster.metrics`, Ray's
metrics, exported by every node)."""

from __future__ import annotations

from collections.abc import Callable

from prometheus_client import CollectorRegistry, Counter, Gauge, Histogram, generate_latest

__all__ = ["CopyTo", "Metrics"]

_LATENCY = (0.001, 0.0025, 0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1, 2.5, 5, 10, 30, 60)
_BUILD = (0.01, 0.05, 0.1, 0.25, 0.5, 1, 2.5, 5, 10, 30, 60, 120, 300, 600, 1800)

#: ``copy_to(kind, name, documentation, labels, buckets)`` → a metric recording the same
#: values (kind: "counter", "gauge" or "histogram"; buckets: a histogram's upper bounds),
#: whose ``inc``/``set``/``observe`` take ``(value, tags)`` (tags: label name → value)
CopyTo = Callable[[str, str, str, tuple[str, ...], tuple[float, ...]], object]


class _Copied:
    """A prometheus_client metric (or one label set's child) and its copy, recorded
    together: the methods the app uses, ``labels``, ``inc``, ``set`` and ``observe``."""

    __slots__ = ("_copy", "_metric", "_names", "_tags")

    def __init__(self, metric, copy, names: tuple[str, ...], tags: dict | None = None) -> None:
        self._metric, self._copy, self._names, self._tags = metric, copy, names, tags or {}

    def labels(self, *values: str) -> _Copied:
        tags = dict(zip(self._names, (str(v) for v in values), strict=True))
        return _Copied(self._metric.labels(*values), self._copy, self._names, tags)

    def inc(self, amount: float = 1) -> None:
        self._metric.inc(amount)
        if amount > 0:  # a counter's copy takes increments above 0 only (Ray's do)
            self._copy.inc(amount, self._tags)

    def set(self, value: float) -> None:
        self._metric.set(value)
        self._copy.set(value, self._tags)

    def observe(self, value: float) -> None:
        self._metric.observe(value)
        self._copy.observe(value, self._tags)


class Metrics:
    """The app's metrics; with ``copy_to``, each one also recorded in a copy (see
    :data:`CopyTo`)."""

    def __init__(self, copy_to: CopyTo | None = None) -> None:
        self.registry = CollectorRegistry()
        self._copy_to = copy_to
        self.requests = self._counter(
            "mrdem_http_requests", "HTTP requests", ("method", "route", "status")
        )
        self.latency = self._histogram(
            "mrdem_http_request_seconds", "HTTP request latency", ("method", "route"), _LATENCY
        )
        self.engine_seconds = self._histogram(
            "mrdem_engine_seconds", "engine call time", ("call",), _LATENCY
        )
        self.comparisons = self._counter("mrdem_triangle_comparisons", "triangle-pair comparisons")
        self.iterative = self._counter("mrdem_iterative_evaluations", "iterative kernel runs")
        self.fallbacks = self._counter("mrdem_exact_fallbacks", "exact-kernel fallbacks")
        self.contact_pairs = self._counter("mrdem_contact_body_pairs", "body pairs queried")
        self.meshes_built = self._counter("mrdem_meshes_built", "surrogate trees built")
        self.build_seconds = self._histogram(
            "mrdem_build_seconds", "tree build job time (done jobs)", (), _BUILD
        )
        self.jobs = self._gauge(
            "mrdem_build_jobs", "unfinished tree build jobs by status", ("status",)
        )
        self.jobs_finished = self._counter(
            "mrdem_build_jobs_finished", "finished tree build jobs by status", ("status",)
        )
        for status in ("queued", "building"):
            self.jobs.labels(status).set(0)
        for status in ("done", "failed"):
            self.jobs_finished.labels(status)
        self.steps = self._counter("mrdem_steps", "time steps")
        self.picard = self._counter("mrdem_picard_iterations", "Picard iterations")

    def _made(self, kind: str, metric, name: str, doc: str, labels, buckets=()):
        if self._copy_to is None:
            return metric
        return _Copied(metric, self._copy_to(kind, name, doc, labels, buckets), labels)

    def _counter(self, name: str, doc: str, labels: tuple[str, ...] = ()):
        metric = Counter(name, doc, labels, registry=self.registry)
        return self._made("counter", metric, name, doc, labels)

    def _gauge(self, name: str, doc: str, labels: tuple[str, ...] = ()):
        metric = Gauge(name, doc, labels, registry=self.registry)
        return self._made("gauge", metric, name, doc, labels)

    def _histogram(self, name: str, doc: str, labels: tuple[str, ...], buckets):
        metric = Histogram(name, doc, labels, buckets=buckets, registry=self.registry)
        return self._made("histogram", metric, name, doc, labels, buckets)

    def exposition(self) -> bytes:
        return generate_latest(self.registry)
