"""service/cluster/metrics.py on a real Ray cluster: what the replicas count reaches Ray's
metrics agents, one series per replica, so that one Prometheus scraping every node sees
the whole deployment (a scrape of ``/metrics`` through the load balancer meets one
replica)."""

from __future__ import annotations

import re
import time
import uuid

import httpx
import pytest

pytestmark = pytest.mark.cluster

ROUTE = "/v1/meshes/jobs/{job_id}"


def _exported(name: str, labels: dict[str, str]) -> dict[str, float]:
    """Per Ray worker process (``WorkerId``): the value of ``name`` with ``labels``, read
    from every alive node's metrics agent."""
    import ray

    found: dict[str, float] = {}
    wanted = [f'{k}="{v}"' for k, v in labels.items()]
    for node in ray.nodes():
        if not node["Alive"]:
            continue
        address = f"http://{node['NodeManagerAddress']}:{node['MetricsExportPort']}/metrics"
        for line in httpx.get(address, timeout=10).text.splitlines():
            if line.startswith(name + "{") and all(w in line for w in wanted):
                worker = re.search(r'WorkerId="(\w+)"', line).group(1)
                found[worker] = found.get(worker, 0.0) + float(line.rsplit(" ", 1)[1])
    return found


def test_each_replica_s_requests_reach_ray_s_metrics(ray_cluster):
    _, url, _ = ray_cluster
    labels = {"method": "GET", "route": ROUTE, "status": "404"}
    before = _exported("ray_mrdem_http_requests_total", labels)
    replicas = set()
    with httpx.Client(timeout=30) as http:
        for _ in range(20):  # unknown jobs: a route no other test asks, answered 404
            response = http.get(f"{url}/v1/meshes/jobs/{uuid.uuid4().hex}")
            assert response.status_code == 404, response.text
            replicas.add(response.headers["X-Mrdem-Replica"])
    assert len(replicas) == 2  # both replicas answered some
    deadline = time.monotonic() + 60
    while True:
        after = _exported("ray_mrdem_http_requests_total", labels)
        added = {w: n - before.get(w, 0.0) for w, n in after.items() if n > before.get(w, 0.0)}
        if sum(added.values()) == 20 and len(added) == 2:
            break  # 20 requests, counted by two processes: the two replicas
        assert time.monotonic() < deadline, (before, after)
        time.sleep(0.5)
    latency = _exported("ray_mrdem_http_request_seconds_count", {"route": ROUTE})
    assert sum(latency.values()) >= 20
