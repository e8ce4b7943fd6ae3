"""service/metrics.py: the app's Prometheus metrics, and, given ``copy_to`` (a cluster's
replicas: Ray's metrics), every record made in the copy too, with the same labels; without
it, the metrics are prometheus_client's own."""

from __future__ import annotations

import prometheus_client
import pytest

from service.metrics import Metrics


class _Recorded:
    """A copy that keeps what it was given: ``(kind, name, method, value, tags)``."""

    def __init__(self, log: list, kind: str, name: str) -> None:
        self.log, self.kind, self.name = log, kind, name

    def inc(self, value, tags):
        self.log.append((self.kind, self.name, "inc", value, tags))

    def set(self, value, tags):
        self.log.append((self.kind, self.name, "set", value, tags))

    def observe(self, value, tags):
        self.log.append((self.kind, self.name, "observe", value, tags))


@pytest.fixture
def copied():
    made, log = {}, []

    def copy_to(kind, name, documentation, labels, buckets):
        made[name] = (kind, tuple(labels), tuple(buckets))
        return _Recorded(log, kind, name)

    return Metrics(copy_to), made, log


def test_every_metric_has_a_copy_of_its_kind_labels_and_buckets(copied):
    metrics, made, _ = copied
    assert made["mrdem_http_requests"] == ("counter", ("method", "route", "status"), ())
    kind, labels, buckets = made["mrdem_http_request_seconds"]
    assert kind == "histogram" and labels == ("method", "route") and buckets[0] == 0.001
    assert made["mrdem_build_jobs"] == ("gauge", ("status",), ())
    assert {m.name for m in metrics.registry.collect()} == set(made)  # each has a copy


def test_records_go_to_both_with_the_same_labels(copied):
    metrics, _, log = copied
    log.clear()  # the start's own: the job gauges set to 0
    metrics.requests.labels("GET", "/healthz", 200).inc()
    metrics.latency.labels("GET", "/healthz").observe(0.004)
    metrics.steps.inc(3)
    metrics.comparisons.inc(0)  # kept here; a counter's copy takes increments above 0 only
    metrics.jobs.labels("queued").set(2)
    tags = {"method": "GET", "route": "/healthz", "status": "200"}
    assert log == [
        ("counter", "mrdem_http_requests", "inc", 1, tags),
        (
            "histogram",
            "mrdem_http_request_seconds",
            "observe",
            0.004,
            {k: tags[k] for k in ("method", "route")},
        ),
        ("counter", "mrdem_steps", "inc", 3, {}),
        ("gauge", "mrdem_build_jobs", "set", 2, {"status": "queued"}),
    ]
    text = metrics.exposition().decode()
    assert 'mrdem_http_requests_total{method="GET",route="/healthz",status="200"} 1.0' in text
    assert "mrdem_steps_total 3.0" in text and 'mrdem_build_jobs{status="queued"} 2.0' in text


def test_without_a_copy_the_metrics_are_prometheus_client_s():
    metrics = Metrics()
    assert isinstance(metrics.requests, prometheus_client.Counter)
    assert isinstance(metrics.latency, prometheus_client.Histogram)
    assert isinstance(metrics.jobs, prometheus_client.Gauge)
