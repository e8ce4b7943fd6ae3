"""The README's two commands of a scale-out, for real: ``ray start --head`` (a Ray cluster of
one node) and ``mrdem cluster serve --detach`` deploy the service over a PostgreSQL server
and an S3-compatible server; it answers through Serve's HAProxy ingress, as in
docker/compose.cluster.yaml. Without the shared store's
settings the command refuses, saying which to set."""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import httpx
import pytest
from servers import HAPROXY_INGRESS, descendants, free_port, process_name

from clients import Client
from engine import shapes

pytestmark = pytest.mark.cluster

BIN = Path(sys.executable).parent


def test_mrdem_cluster_serve_deploys_on_a_ray_cluster(postgres, s3, tmp_path):
    port, http_port = free_port(), free_port()
    env = {
        **os.environ,
        **HAPROXY_INGRESS,  # what docker/compose.cluster.yaml sets
        "RAY_worker_niceness": "0",  # and this (the README's ray start)
        "MRDEM_STORE_URL": postgres.database(),
        "MRDEM_OBJECT_STORE_URL": s3.bucket(),
        "MRDEM_OBJECT_STORE_ENDPOINT": s3.endpoint,
        "MRDEM_REPLICA_CPUS": "0.5",
        "MRDEM_DATA_DIR": str(tmp_path / "data"),
    }
    head = subprocess.Popen(
        [BIN / "ray", "start", "--head", "--port", str(port), "--num-cpus", "2"]
        + ["--include-dashboard", "false", "--object-store-memory", "100000000", "--block"],
        env=env,
        start_new_session=True,  # its group: stopped with every process it started
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    try:
        deploy = subprocess.run(
            [BIN / "mrdem", "cluster", "serve", "--address", f"127.0.0.1:{port}"]
            + ["--port", str(http_port), "--detach"],
            env=env,
            capture_output=True,
            text=True,
            timeout=300,
        )
        assert deploy.returncode == 0, deploy.stderr[-2000:]
        url = f"http://127.0.0.1:{http_port}"
        assert httpx.get(f"{url}/readyz", timeout=30).status_code == 200
        with Client(url) as client:
            mesh = client.upload_mesh(shapes.box(), epsilon=0.05)
            assert client.mesh(mesh.id).id == mesh.id
        assert "X-Mrdem-Replica" in httpx.get(f"{url}/healthz").headers  # a replica answered
        names = [process_name(pid) for pid in descendants(head.pid)]
        assert "haproxy" in names  # … through Serve's HAProxy ingress
    finally:  # every process of this Ray cluster, at once (a graceful stop takes 30 s)
        for pid in [*descendants(head.pid), head.pid]:
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)
        head.wait(60)


def test_mrdem_cluster_serve_needs_the_shared_store(tmp_path):
    env = {k: v for k, v in os.environ.items() if not k.startswith("MRDEM_")}
    started = time.monotonic()
    refused = subprocess.run(
        [BIN / "mrdem", "cluster", "serve", "--address", "127.0.0.1:1"],
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert refused.returncode == 2
    assert "MRDEM_STORE_URL" in refused.stderr and "MRDEM_OBJECT_STORE_URL" in refused.stderr
    assert time.monotonic() - started < 60  # refused before reaching for a cluster
