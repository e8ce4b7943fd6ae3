"""The README's two commands of a scale-out, for real: ``ray start --head`` (a Ray cluster of
one node) and ``mrdem cluster serve --detach`` deploy the service over a PostgreSQL server
and an S3-compatible server; it answers through Serve's HAProxy ingress, as in
docker/compose.cluster.yaml, and, given ``--replicas-max``, adds a replica under load and
removes it when the load ends. Without the shared store's settings, or with settings it
cannot use, the command refuses, saying which to set."""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
import threading
import time
from collections import Counter
from pathlib import Path

import httpx
import pytest
from servers import HAPROXY_INGRESS, IDLE_WORKERS, descendants, free_port, process_name

from clients import Client
from engine import shapes

pytestmark = pytest.mark.cluster

BIN = Path(sys.executable).parent


def _replicas_seen(url: str, load: dict, until: int, timeout: float = 120.0) -> Counter:
    """Requests answered per replica (``X-Mrdem-Replica``) while four clients send ``load``
    (a contacts request) one after another, until ``until`` replicas have answered."""
    seen: Counter = Counter()
    failed: list[str] = []
    stop = threading.Event()

    def client() -> None:
        with httpx.Client(timeout=60) as http:
            while not stop.is_set():
                try:
                    response = http.post(f"{url}/v1/contacts", json=load)
                except httpx.HTTPError as error:  # said below, not lost with the thread
                    failed.append(repr(error))
                    return
                if response.status_code != 200:
                    failed.append(response.text[:500])
                    return
                seen[response.headers["X-Mrdem-Replica"]] += 1

    clients = [threading.Thread(target=client, daemon=True) for _ in range(4)]
    for thread in clients:
        thread.start()
    deadline = time.monotonic() + timeout
    while len(seen) < until and not failed and time.monotonic() < deadline:
        time.sleep(0.2)
    stop.set()
    for thread in clients:
        thread.join(60)
    assert not failed, failed
    return seen


def _replicas_idle(url: str, requests: int = 20) -> set[str]:
    """The replicas that answer ``requests`` health checks sent one after another (each
    answered: none is lost while a replica is being removed)."""
    seen = set()
    with httpx.Client(timeout=30) as http:
        for _ in range(requests):
            response = http.get(f"{url}/healthz")
            assert response.status_code == 200, response.text
            seen.add(response.headers["X-Mrdem-Replica"])
    return seen


def _forget_cluster(port: int) -> None:
    """Remove the note ``ray start --head`` left of its cluster (``ray stop`` would): killed,
    the cluster leaves it behind, and a later ``ray.init()`` on this machine reaches for
    the dead cluster instead of starting its own."""
    from ray._common.utils import get_ray_address_file

    note = Path(get_ray_address_file(None))  # /tmp/ray/ray_current_cluster
    with contextlib.suppress(OSError):
        if note.read_text().strip().endswith(f":{port}"):
            note.unlink()


def test_mrdem_cluster_serve_deploys_on_a_ray_cluster_and_scales_with_the_load(
    postgres, s3, tmp_path
):
    port, http_port = free_port(), free_port()
    env = {
        **os.environ,
        **HAPROXY_INGRESS,  # what docker/compose.cluster.yaml sets
        "RAY_worker_niceness": "0",  # and these (the README's ray start)
        **IDLE_WORKERS,
        # replicas report their load every half second (Ray's default: 10 s)
        "RAY_SERVE_REPLICA_AUTOSCALING_METRIC_PUSH_INTERVAL_S": "0.5",
        "MRDEM_STORE_URL": postgres.database(),
        "MRDEM_OBJECT_STORE_URL": s3.bucket(),
        "MRDEM_OBJECT_STORE_ENDPOINT": s3.endpoint,
        "MRDEM_REPLICA_CPUS": "0.5",
        "MRDEM_DATA_DIR": str(tmp_path / "data"),
        "MRDEM_REPLICA_TARGET_REQUESTS": "1",
        "MRDEM_REPLICA_UPSCALE_DELAY": "0",
        "MRDEM_REPLICA_DOWNSCALE_DELAY": "2",
        "MRDEM_REPLICA_LOAD_WINDOW": "2",
        "MRDEM_SPLIT_CHUNKS": "1",  # the load stays in the replicas
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
            + ["--port", str(http_port), "--replicas-max", "2", "--detach"],
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
        assert len(_replicas_idle(url)) == 1  # one replica to begin with …
        names = [process_name(pid) for pid in descendants(head.pid)]
        assert "haproxy" in names  # … behind Serve's HAProxy ingress
        pose = {"position": [0.0, 0.0, 0.0], "orientation": [1.0, 0.0, 0.0, 0.0]}
        near = {"position": [0.9, 0.0, 0.0], "orientation": [1.0, 0.0, 0.0, 0.0]}
        pair = {"a": mesh.id, "pose_a": pose, "b": mesh.id, "pose_b": near}
        seen = _replicas_seen(url, {"pairs": [pair] * 200}, until=2)
        assert len(seen) == 2, f"no second replica under load: {dict(seen)}"
        deadline = time.monotonic() + 120  # the load ended: back to one, every check answered
        while len(idle := _replicas_idle(url)) > 1:
            assert time.monotonic() < deadline, f"still {len(idle)} replicas without load"
    finally:  # every process of this Ray cluster, at once (a graceful stop takes 30 s)
        for pid in [*descendants(head.pid), head.pid]:
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)
        head.wait(60)
        _forget_cluster(port)


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


@pytest.mark.parametrize(
    ("given", "said"),
    [
        (["--replicas", "3", "--replicas-max", "2"], "MRDEM_REPLICAS_MAX (2) is below"),
        (["--replicas", "0"], "MRDEM_REPLICAS: Input should be greater than or equal to 1"),
        (["--replicas-max", "2", "--replica-cpus", "1"], "set it to 8 or less"),
    ],
)
def test_mrdem_cluster_serve_refuses_settings_it_cannot_use(given, said):
    """Before it reaches for the cluster or the store, with the variable to change."""
    env = {
        **{k: v for k, v in os.environ.items() if not k.startswith("MRDEM_")},
        "MRDEM_REPLICA_TARGET_REQUESTS": "9",  # above what a 1-CPU replica takes at once
    }
    refused = subprocess.run(
        [BIN / "mrdem", "cluster", "serve", "--address", "127.0.0.1:1", *given],
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert refused.returncode == 2
    assert said in refused.stderr and "Traceback" not in refused.stderr
