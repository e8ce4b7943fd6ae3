"""A real Ray cluster on this machine for the ``cluster`` tests (``make test-cluster``): a
head (no CPUs: Ray's control processes and Serve's HAProxy ingress) and three worker nodes
on loopback, each at an address of its own (127.0.0.2–4), a PostgreSQL server and an
S3-compatible server (moto), and the service deployed on Serve (two replicas) over them —
the configuration of docker/compose.cluster.yaml."""

from __future__ import annotations

import os
import time

import httpx
import pytest
from servers import HAPROXY_INGRESS, IDLE_WORKERS, descendants, free_port, missing, process_name

NODE = {"num_cpus": 2, "object_store_memory": 10**8}


@pytest.fixture(scope="session")
def ray_cluster(postgres, s3, tmp_path_factory):
    """``(cluster, url, settings)``: the Ray cluster (``cluster.worker_nodes``), the Serve
    endpoint's URL and the deployment's settings."""
    try:
        import ray
    except ImportError:
        missing("ray (pip install 'mrdem[cluster]')")
    from ray import serve
    from ray.cluster_utils import Cluster

    from service.cluster import APP_NAME, NAMESPACE, application
    from service.settings import Settings

    os.environ.setdefault("NUMBA_CACHE_DIR", str(tmp_path_factory.mktemp("numba")))
    os.environ.update(HAPROXY_INGRESS)  # before the nodes start: their processes read it
    os.environ.update(IDLE_WORKERS)
    cluster = Cluster(
        initialize_head=True,
        head_node_args={
            "num_cpus": 0,
            "object_store_memory": 10**8,
            "include_dashboard": True,  # Ray's state API (where tasks ran) needs it
            "dashboard_host": "127.0.0.1",
            "dashboard_port": free_port(),
            # a dead node is noticed within about a second, not fifteen
            "_system_config": {
                "worker_niceness": 0,  # as the README says (service.cluster.deployment.NICENESS)
                "health_check_period_ms": 300,
                "health_check_failure_threshold": 3,
                "health_check_timeout_ms": 300,
                "metrics_report_interval_ms": 1000,  # Ray's metrics exported within ~1 s
            },
        },
    )
    # Serve hands each node's replicas ports from 30000 up: nodes sharing one address would
    # collide (the second replica bound 30001, HAProxy listed 30000), as separate machines
    # or containers do not
    for k in range(3):
        cluster.add_node(**NODE, node_ip_address=f"127.0.0.{k + 2}")
    ray.init(address=cluster.address, namespace=NAMESPACE)
    port = free_port()
    settings = Settings(
        data_dir=tmp_path_factory.mktemp("cluster") / "data",
        store_url=postgres.database(),
        object_store_url=s3.bucket(),
        object_store_endpoint=s3.endpoint,
        replica_cpus=0.5,
        # a quarter CPU: scenes' actors (the README loop's, replicas' spares) stay until
        # idle, and at 0.5 a node could hold 2 CPUs of them and a replica, with no room left
        # for the contacts tasks (and their nodes' readying) that the split tests wait for
        scene_cpus=0.25,
        task_cpus=0.5,
        split_pairs=1000,
        split_chunks=2,  # two runs among three nodes: where they go is a choice
    )
    serve.start(proxy_location="HeadOnly", http_options={"host": "127.0.0.1", "port": port})
    serve.run(application(settings, 2, 0.5), name=APP_NAME, route_prefix="/")
    url = f"http://127.0.0.1:{port}"
    deadline = time.monotonic() + 120
    while httpx.get(f"{url}/readyz", timeout=30).status_code != 200:
        assert time.monotonic() < deadline, "the Serve endpoint never became ready"
        time.sleep(0.5)
    assert "haproxy" in [process_name(pid) for pid in descendants(os.getpid())]
    try:
        yield cluster, url, settings
    finally:  # every process of the cluster stopped at once (Serve's drain takes 20-30 s)
        ray.shutdown()
        cluster.shutdown()
