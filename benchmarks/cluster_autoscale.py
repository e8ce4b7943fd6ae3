"""Replicas by load on a real local Ray cluster (issue 18): ``MRDEM_REPLICAS_MAX``.

One worker node with the machine's CPUs, the shared store (PostgreSQL, moto's S3), the app
on Ray Serve with ``--min`` replicas and at most ``--max`` (``--replica-cpus`` each), Serve's
autoscaling aiming at ``--target`` requests in flight per replica, ``--up``/``--down``
seconds of delay, a ``--window``-second average, replicas reporting their load every
``--push`` seconds (``RAY_SERVE_REPLICA_AUTOSCALING_METRIC_PUSH_INTERVAL_S``; Ray's default
10). ``--clients`` closed-loop clients send 10-pair contacts requests for ``--seconds``;
then the load stops and one client checks every half second which replicas answer, until
only ``--min`` do. Printed and written: per ``--bin`` seconds of load, the requests/s, the
median latency and the replicas that answered; when each replica answered first; how long
after the load the deployment was back to ``--min``.

    .venv/bin/python benchmarks/cluster_autoscale.py [--min 1] [--max 2] [--clients 8]
        [--seconds 40] [--replica-cpus 1] [--haproxy]

Writes ``bench-results/cluster-autoscale.json``. The clients run on the same machine as
the cluster: on 2 cores more replicas cannot give more requests/s (say so when quoting).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import threading
import time
from pathlib import Path

import httpx
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.append(str(ROOT / "benchmarks"))
os.environ.setdefault("NUMBA_CACHE_DIR", str(ROOT / ".numba-cache"))

from cluster import MESH, RayCluster, columns  # noqa: E402
from common import machine  # noqa: E402

from clients import Client  # noqa: E402
from mrdem_common.loopback import PostgresServer, S3Server  # noqa: E402
from service.cluster.batches import IDLE_WORKERS_MS, IDLE_WORKERS_VARIABLE  # noqa: E402

OUT = ROOT / "bench-results"
REPLICA = "X-Mrdem-Replica"


def request_body(mesh: str, n: int = 10) -> dict:
    """A contacts request of ``n`` pairs of ``mesh`` near contact (:func:`cluster.columns`)."""
    query = columns(n, seed=3)

    def pose(k: int, side: str) -> dict:
        return {
            "position": query[f"position_{side}"][k].tolist(),
            "orientation": query[f"orientation_{side}"][k].tolist(),
        }

    pairs = [
        {"a": mesh, "pose_a": pose(k, "a"), "b": mesh, "pose_b": pose(k, "b")} for k in range(n)
    ]
    return {"pairs": pairs}


def under_load(url: str, body: dict, clients: int, seconds: float) -> list[tuple]:
    """``(start, seconds, replica)`` of every request ``clients`` closed-loop clients sent
    for ``seconds``; start relative to the load's start."""
    rows: list[tuple] = []
    lock = threading.Lock()
    begin = time.perf_counter()

    def client() -> None:
        mine = []
        with httpx.Client(timeout=120) as http:
            while (start := time.perf_counter()) - begin < seconds:
                response = http.post(f"{url}/v1/contacts", json=body)
                response.raise_for_status()
                mine.append((start - begin, time.perf_counter() - start, response.headers[REPLICA]))
        with lock:
            rows.extend(mine)

    threads = [threading.Thread(target=client) for _ in range(clients)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    return sorted(rows)


def back_to(url: str, replicas: int, timeout: float = 900.0) -> tuple[float, list]:
    """Seconds until 20 health checks one after another meet at most ``replicas`` replicas,
    and each check round's count ``(seconds, replicas)``."""
    begin = time.perf_counter()
    counts = []
    with httpx.Client(timeout=30) as http:
        while time.perf_counter() - begin < timeout:
            seen = {http.get(f"{url}/healthz").headers[REPLICA] for _ in range(20)}
            counts.append((round(time.perf_counter() - begin, 2), len(seen)))
            if len(seen) <= replicas:
                return time.perf_counter() - begin, counts
            time.sleep(0.5)
    return float("nan"), counts


def binned(rows: list[tuple], width: float, seconds: float) -> list[dict]:
    """Per ``width`` seconds of load: requests/s, median latency, replicas answering."""
    out = []
    for left in np.arange(0.0, seconds, width):
        inside = [r for r in rows if left <= r[0] < left + width]
        out.append(
            {
                "from_s": float(left),
                "requests_per_second": len(inside) / width,
                "p50_ms": float(np.median([r[1] for r in inside]) * 1e3) if inside else None,
                "replicas": len({r[2] for r in inside}),
            }
        )
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--min", type=int, default=1, help="MRDEM_REPLICAS")
    parser.add_argument("--max", type=int, default=2, help="MRDEM_REPLICAS_MAX")
    parser.add_argument("--replica-cpus", type=float, default=1.0)
    parser.add_argument("--target", type=float, default=2.0, help="requests in flight a replica")
    parser.add_argument("--up", type=float, default=5.0, help="seconds of upscale delay")
    parser.add_argument("--down", type=float, default=10.0, help="seconds of downscale delay")
    parser.add_argument("--window", type=float, default=5.0, help="seconds of load averaged")
    parser.add_argument("--push", type=float, default=1.0, help="seconds between load reports")
    parser.add_argument("--clients", type=int, default=8)
    parser.add_argument("--seconds", type=float, default=40.0)
    parser.add_argument("--bin", type=float, default=2.0)
    parser.add_argument("--haproxy", action="store_true", help="Serve's HAProxy ingress")
    args = parser.parse_args()
    os.environ["RAY_worker_niceness"] = "0"  # noqa: SIM112 (Ray spells it so) as the README
    os.environ[IDLE_WORKERS_VARIABLE] = str(IDLE_WORKERS_MS)  # as the README's ray start
    os.environ["RAY_SERVE_REPLICA_AUTOSCALING_METRIC_PUSH_INTERVAL_S"] = str(args.push)
    if args.haproxy:  # before the cluster starts: its processes inherit them
        os.environ["RAY_SERVE_ENABLE_HA_PROXY"] = "1"
        os.environ["RAY_SERVE_ENABLE_DIRECT_INGRESS"] = "1"
    out: dict = {"machine": machine(), "args": vars(args)}
    cpus = os.cpu_count() or 1
    print(f"machine: {out['machine'].get('cpu')} ({cpus} CPUs)")
    postgres, s3 = PostgresServer(), S3Server()
    store = {
        "data_dir": Path(tempfile.mkdtemp(prefix="mrdem-autoscale-")) / "cluster",
        "store_url": postgres.database(),
        "object_store_url": s3.bucket(),
        "object_store_endpoint": s3.endpoint,
    }
    try:
        cluster = RayCluster(1, cpus, store)
        try:
            url = cluster.deploy(
                args.min,
                args.replica_cpus,
                replicas_max=args.max,
                replica_target_requests=args.target,
                replica_upscale_delay=args.up,
                replica_downscale_delay=args.down,
                replica_load_window=args.window,
                split_chunks=1,  # the load stays in the replicas
            )
            with Client(url, timeout=300) as client:
                mesh = client.upload_mesh((MESH.vertices, MESH.faces), epsilon=0.01).id
            body = request_body(mesh)
            rows = under_load(url, body, args.clients, args.seconds)
            back, counts = back_to(url, args.min)
        finally:
            cluster.close()
    finally:
        postgres.stop()
        s3.stop()
    first: dict[str, float] = {}
    for start, _, replica in rows:
        first.setdefault(replica, start)
    out["bins"] = binned(rows, args.bin, args.seconds)
    out["replica_first_answer_s"] = sorted(first.values())
    out["back_to_min_s"] = back
    out["after_load"] = counts
    print(f"{'from s':>7} {'req/s':>7} {'p50 ms':>8} {'replicas':>8}")
    for row in out["bins"]:
        p50 = f"{row['p50_ms']:.1f}" if row["p50_ms"] is not None else "-"
        print(
            f"{row['from_s']:7.0f} {row['requests_per_second']:7.1f} {p50:>8} {row['replicas']:8d}"
        )
    answered = ", ".join(f"{s:.1f}" for s in out["replica_first_answer_s"])
    print(f"replicas first answered at: {answered} s of load")
    print(f"back to {args.min} replica(s) {back:.1f} s after the load")
    OUT.mkdir(exist_ok=True)
    (OUT / "cluster-autoscale.json").write_text(json.dumps(out, indent=2, default=str))
    print(f"wrote {OUT / 'cluster-autoscale.json'}")


if __name__ == "__main__":
    main()
