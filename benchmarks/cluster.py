"""The service scaled out on Ray (issue 18), on a real local cluster: a Ray head (no CPUs)
plus worker nodes on loopback, PostgreSQL and an S3-compatible server (moto) for the shared
store, the app deployed on Ray Serve (``service.cluster.application``).

1. **The Serve hop**: one client sending 10-pair contacts requests one after another, p50 and
   p99 through Serve (1 replica) against the plain service (``python -m service``, uvicorn)
   over the same shared store and against the embedded one (SQLite and files); then the
   plain service and Serve side by side in alternating blocks of 50 requests (the
   machine's drifting speed hits both alike).
2. **Replicas**: ``--clients`` closed-loop clients (in ``--client-processes``
   processes) sending 10-pair requests for ``--seconds``: requests/s, p50, p99 with 1, 2,
   … replicas (``--replicas``) of ``--replica-cpus`` CPUs each, and the plain service
   beside them.
3. **A 10,000-pair batch on 1 and on 2 nodes** (1 CPU each): on one node the replica
   searches it alone; on two it searches one half while a Ray task on the other node
   searches the other (``MRDEM_SPLIT_PAIRS``); medians of ``--repeats`` requests after a
   warm one: the whole request, the search alone (the answer's ``stats.seconds``: split,
   run and merged, without decoding, encoding and transfer), and the parts the answers'
   ``Server-Timing`` names (the split's: submit, here, task, wait, merge). Beside it, the
   ceiling: the same batch searched by one plain process, then as two halves by two
   processes at once (no Ray, no service) — what the machine's cores give two searches
   (vCPUs that share a core give less than 2×). Then **paired**, on one 2-node cluster:
   two apps side by side, a replica that searches alone (``MRDEM_SPLIT_CHUNKS=1``) and one
   that splits, sent the batch in turn, request by request: each round's ratio compares
   the two under the same conditions (on a VM whose speed drifts, the separate clusters'
   figures moved 1.46–1.90× between two runs of the same code). ``--pause`` waits before
   each request; with ``--idle-worker-ms 1000`` (Ray's default, not the README's) the task's
   node, which also runs the other app's replica, ends its idle worker meanwhile.
4. **A node slowed by other work** (``slowed_node``): the split's search, request by request,
   once a process spins on the CPU of the task's node.

Needs ``mrdem[cluster]`` and the PostgreSQL server binaries. The client threads run on the
same machine as the cluster: on 2 cores they take CPU from it (say so when quoting).

    .venv/bin/python benchmarks/cluster.py [--quick] [--replicas 1,2] [--clients 8] [--haproxy]
        [--only serve|batch|slow]

Writes ``bench-results/cluster.json`` (``cluster-haproxy.json`` with ``--haproxy``;
``-serve``/``-batch`` before ``.json`` with ``--only``).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import multiprocessing
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
sys.path.append(str(ROOT / "benchmarks"))  # after ROOT: benchmarks/service.py is no package
os.environ.setdefault("NUMBA_CACHE_DIR", str(ROOT / ".numba-cache"))

from common import machine  # noqa: E402

from clients import Client  # noqa: E402
from engine import shapes  # noqa: E402
from mrdem_common.loopback import PostgresServer, S3Server  # noqa: E402
from mrdem_common.serving import ServiceProcess, free_port  # noqa: E402

OUT = ROOT / "bench-results"
MESH = shapes.icosphere(3, radius=0.5)  # 1,280 triangles
COLUMNS = ("a", "position_a", "orientation_a", "b", "position_b", "orientation_b")


def columns(n: int, seed: int) -> dict:
    """``n`` pairs of the mesh near contact (centres 1.0–1.03 apart), random orientations."""
    rng = np.random.default_rng(seed)
    d = rng.normal(size=(n, 3))
    d *= rng.uniform(1.0, 1.03, (n, 1)) / np.linalg.norm(d, axis=1, keepdims=True)
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    return {
        "a": np.zeros(n, np.int64),
        "position_a": np.zeros((n, 3)),
        "orientation_a": np.tile([1.0, 0, 0, 0], (n, 1)),
        "b": np.zeros(n, np.int64),
        "position_b": d,
        "orientation_b": q,
    }


def sequential(url: str, requests: int) -> dict:
    """p50/p99 of 10-pair requests sent one after another by one client."""
    with Client(url, timeout=300) as client:
        mesh = client.upload_mesh((MESH.vertices, MESH.faces), epsilon=0.01)
        query = columns(10, seed=2)
        for _ in range(20):
            client.find_contacts([mesh], **query)
        seconds = []
        for _ in range(requests):
            start = time.perf_counter()
            client.find_contacts([mesh], **query)
            seconds.append(time.perf_counter() - start)
    ms = np.array(seconds) * 1e3
    return {
        "requests": requests,
        "p50_ms": float(np.percentile(ms, 50)),
        "p99_ms": float(np.percentile(ms, 99)),
    }


def interleaved(urls: dict, rounds: int, block: int) -> dict:
    """p50/p99 of 10-pair requests to each service, one client each, in alternating blocks
    of ``block`` requests (``rounds`` times): the machine's drifting speed hits both."""
    clients = {name: Client(url, timeout=300) for name, url in urls.items()}
    seconds: dict = {name: [] for name in urls}
    try:
        meshes = {
            name: c.upload_mesh((MESH.vertices, MESH.faces), epsilon=0.01)
            for name, c in clients.items()
        }
        query = columns(10, seed=2)
        for name, client in clients.items():
            for _ in range(20):
                client.find_contacts([meshes[name]], **query)
        for _ in range(rounds):
            for name, client in clients.items():
                for _ in range(block):
                    start = time.perf_counter()
                    client.find_contacts([meshes[name]], **query)
                    seconds[name].append(time.perf_counter() - start)
    finally:
        for client in clients.values():
            client.close()
    out = {}
    for name, values in seconds.items():
        ms = np.array(values) * 1e3
        out[name] = {
            "requests": len(ms),
            "p50_ms": float(np.percentile(ms, 50)),
            "p99_ms": float(np.percentile(ms, 99)),
        }
    return out


def load(url: str, mesh, threads: int, start_at: float, seconds: float) -> tuple:
    """Seconds of each 10-pair request (of the uploaded ``mesh``) sent by ``threads``
    closed-loop clients from ``start_at`` (``time.time()``) for ``seconds`` (each client
    warm before), and how many clients were not warm by then."""
    query = columns(10, seed=3)
    latencies: list[float] = []
    late = []
    lock = threading.Lock()

    def work():
        mine = []
        with Client(url, timeout=300) as client:
            client.find_contacts([mesh], **query)  # warm: connection, trees
            wait = start_at - time.time()
            if wait < 0:
                late.append(1)
            time.sleep(max(0.0, wait))
            stop = start_at + seconds
            while time.time() < stop:
                start = time.perf_counter()
                client.find_contacts([mesh], **query)
                mine.append(time.perf_counter() - start)
        with lock:
            latencies.extend(mine)

    threads_ = [threading.Thread(target=work) for _ in range(threads)]
    for t in threads_:
        t.start()
    for t in threads_:
        t.join()
    return latencies, len(late)


def loaded(url: str, clients: int, seconds: float, processes: int = 1) -> dict:
    """Throughput and latency of ``clients`` closed-loop clients of 10-pair requests, in
    ``processes`` client processes (one process's GIL caps what its threads can send)."""
    with Client(url, timeout=300) as setup:
        mesh = setup.upload_mesh((MESH.vertices, MESH.faces), epsilon=0.01)
    start_at = time.time() + (3.0 if processes == 1 else 6.0)  # every client warm by then
    shares = [clients // processes + (i < clients % processes) for i in range(processes)]
    if processes == 1:
        parts = [load(url, mesh, clients, start_at, seconds)]
    else:
        context = multiprocessing.get_context("spawn")  # no fork of a Ray driver
        with context.Pool(processes) as pool:
            parts = pool.starmap(load, [(url, mesh, n, start_at, seconds) for n in shares])
    latencies = [x for part, _ in parts for x in part]
    ms = np.array(latencies) * 1e3
    return {
        "clients": clients,
        "processes": processes,
        "late_clients": sum(late for _, late in parts),
        "requests": len(ms),
        "seconds": seconds,
        "requests_per_second": len(ms) / seconds,
        "p50_ms": float(np.percentile(ms, 50)),
        "p99_ms": float(np.percentile(ms, 99)),
    }


class _Timings(httpx.HTTPTransport):
    """An HTTP transport that keeps each answer's ``Server-Timing`` (name → ms)."""

    def __init__(self) -> None:
        super().__init__()
        self.seen: list[dict[str, float]] = []

    def handle_request(self, request: httpx.Request) -> httpx.Response:
        response = super().handle_request(request)
        header = response.headers.get("server-timing", "")
        entries = (e.strip().split(";dur=") for e in header.split(",") if e.strip())
        self.seen.append({name: float(ms) for name, ms in entries})
        return response

    def parts(self) -> dict[str, list[float]]:
        """Each name → its ms in every answer seen (NaN where an answer lacked it)."""
        names = dict.fromkeys(name for t in self.seen for name in t)  # in order, each once
        return {name: [t.get(name, np.nan) for t in self.seen] for name in names}

    def medians(self) -> dict[str, float]:
        """Each name → the median of its ms over the answers that have it."""
        return {name: float(np.nanmedian(v)) for name, v in self.parts().items()}


def _warm(client: Client, mesh: str, query: dict, timings: _Timings, splits: bool):
    """Requests until the app is warm: one, or, where it ``splits``, until a task has
    searched (a node gets runs once a worker is readied there, and none while a task of
    its is left to end); ``(the last answer, the requests sent, their seconds)``."""
    start = time.perf_counter()
    deadline = time.monotonic() + 180
    requests = 0
    while True:
        found = client.find_contacts([mesh], **query)
        requests += 1
        if not splits or timings.seen[-1].get("task", 0.0) > 0:
            return found, requests, time.perf_counter() - start
        if time.monotonic() > deadline:
            raise RuntimeError("no task searched a piece within 180 s")


def big_batch(url: str, pairs: int, repeats: int, splits: bool, settle: float = 0.0) -> dict:
    """The big batch, ``repeats`` times after the requests that warm it, which are sent
    ``settle`` seconds after the mesh is built (a deployment up for a while)."""
    timings = _Timings()
    with Client(url, timeout=600, transport=timings) as client:
        mesh = client.upload_mesh((MESH.vertices, MESH.faces), epsilon=0.01)
        query = columns(pairs, seed=5)
        time.sleep(settle)
        found, warm_requests, warm_seconds = _warm(client, mesh, query, timings, splits)
        seconds, searches = [], []
        del timings.seen[:]
        for _ in range(repeats):
            start = time.perf_counter()
            answer = client.find_contacts([mesh], **query)
            seconds.append(time.perf_counter() - start)
            searches.append(answer.stats["seconds"])  # the search (split, run, merged) alone
    return {
        "pairs": pairs,
        "contacts": int(found.offsets[-1]),
        "warm_requests": warm_requests,  # until one was answered (split: a task searched)
        "warm_seconds": warm_seconds,
        "seconds": seconds,
        "median_s": float(np.median(seconds)),
        "search_seconds": searches,
        "search_median_s": float(np.median(searches)),
        "server_timing_ms": timings.parts(),  # each request's Server-Timing entries
        "server_timing_median_ms": timings.medians(),
    }


def paired_batch(urls: dict, pairs: int, repeats: int, pause: float = 0.0) -> dict:
    """The big batch sent to each of ``urls`` (name → app) in turn, one request each per
    round, ``repeats`` rounds after a warm request each, ``pause`` seconds before each
    request: the apps see the machine alike (its drifting speed, its neighbours), so each
    round's ratio compares like with like.
    Per app: each request's seconds and search seconds, the medians; the median of the
    rounds' ratios of the first app's to the second's."""
    timings = {name: _Timings() for name in urls}
    clients = {
        name: Client(url, timeout=600, transport=timings[name]) for name, url in urls.items()
    }
    query = columns(pairs, seed=5)
    seconds: dict = {name: [] for name in urls}
    searches: dict = {name: [] for name in urls}
    try:
        meshes = {
            name: c.upload_mesh((MESH.vertices, MESH.faces), epsilon=0.01)
            for name, c in clients.items()
        }
        for name, client in clients.items():  # warm: trees and banks where they run
            _warm(client, meshes[name], query, timings[name], splits=name == "split")
            del timings[name].seen[:]
        for _ in range(repeats):
            for name, client in clients.items():
                time.sleep(pause)
                start = time.perf_counter()
                answer = client.find_contacts([meshes[name]], **query)
                seconds[name].append(time.perf_counter() - start)
                searches[name].append(answer.stats["seconds"])
    finally:
        for client in clients.values():
            client.close()
    first, second = list(urls)
    out: dict = {}
    for name in urls:
        out[name] = {
            "seconds": seconds[name],
            "median_s": float(np.median(seconds[name])),
            "search_seconds": searches[name],
            "search_median_s": float(np.median(searches[name])),
            "server_timing_ms": timings[name].parts(),  # each round's (NaN: not split)
            "server_timing_median_ms": timings[name].medians(),
            "task_rounds": sum(t.get("task", 0.0) > 0 for t in timings[name].seen),
        }
    for key, what in (("seconds", "request"), ("search_seconds", "search")):
        ratios = np.array(out[first][key]) / np.array(out[second][key])
        out[f"{what}_ratio_median"] = float(np.median(ratios))
        out[f"{what}_ratio_quartiles"] = [float(np.percentile(ratios, q)) for q in (25, 75)]
    return out


def _search_halves(part: int, parts: int, pairs: int, repeats: int, barrier, results) -> None:
    """In a process of its own: run ``part`` of ``parts`` of the big batch's pairs,
    ``repeats`` times, each after ``barrier`` (every part starts together)."""
    from engine import DEFAULT_PRECISION, TreeBank, build_tree

    bank = TreeBank([build_tree(MESH, epsilon=0.01)], DEFAULT_PRECISION)
    query = columns(pairs, seed=5)
    cut = np.linspace(0, pairs, parts + 1).round().astype(np.int64)
    run = [query[k][cut[part] : cut[part + 1]] for k in COLUMNS]
    bank.find_contacts(*run, kernel="hybrid", threads=1)  # warm: banks, pages
    seconds = []
    for _ in range(repeats):
        barrier.wait()
        start = time.perf_counter()
        bank.find_contacts(*run, kernel="hybrid", threads=1)
        seconds.append(time.perf_counter() - start)
    results.put((part, seconds))


def ceiling(pairs: int, repeats: int) -> dict:
    """What this machine gives two processes at once, without Ray or the service: the big
    batch searched whole by one process, then as two halves by two processes starting
    together (one engine thread each); medians of ``repeats``."""
    context = multiprocessing.get_context("spawn")
    out = {}
    for parts in (1, 2):
        barrier, results = context.Barrier(parts), context.Queue()
        processes = [
            context.Process(
                target=_search_halves, args=(k, parts, pairs, repeats, barrier, results)
            )
            for k in range(parts)
        ]
        for process in processes:
            process.start()
        times = [results.get(timeout=600)[1] for _ in processes]
        for process in processes:
            process.join()
        out[parts] = float(np.median(np.max(times, axis=0)))  # the slower part of each run
    return {"one_process_s": out[1], "two_processes_s": out[2], "speedup": out[1] / out[2]}


def _busy(core: int, spinning) -> None:
    """Spin on ``core``, forever: other work on a node's CPU (``spinning`` set once it
    does)."""
    os.sched_setaffinity(0, {core})
    spinning.set()
    while True:
        pass


def _tree(pid: int) -> list[int]:
    """``pid`` and every process under it (``/proc/<pid>/task/<tid>/children``)."""
    found, todo = [], [pid]
    while todo:
        found.append(pid := todo.pop())
        for children in Path(f"/proc/{pid}/task").glob("*/children"):
            with contextlib.suppress(OSError):  # gone meanwhile
                todo.extend(int(c) for c in children.read_text().split())
    return found


def slowed_node(store: dict, pairs: int, repeats: int) -> dict:
    """4. **A node slowed by other work**: a 2-node cluster, each node's processes on a CPU
    of their own (the replica's node on the first, the other node on the second), the
    batch warm while both are as fast; then a process spins on the second CPU and
    ``repeats`` requests follow: the first is cut as the nodes have been (as fast as the
    replica), the later ones by what the splitter measures. Each request's search and
    ``Server-Timing``."""
    from ray.util.state import list_actors

    cores = sorted(os.sched_getaffinity(0))[:2]
    cluster = RayCluster(2, 1, store)
    spinner = None
    try:
        url = cluster.deploy(1, 0.1, task_cpus=0.9, split_pairs=min(pairs, 2000), split_chunks=2)
        (replica,) = [
            a
            for a in list_actors(filters=[("state", "=", "ALIVE")])
            if a.class_name.startswith("ServeReplica:")
        ]
        for node in cluster.cluster.worker_nodes:
            core = cores[0] if node.node_id == replica.node_id else cores[1]
            for pid in _tree(node.all_processes["raylet"][0].process.pid):
                with contextlib.suppress(OSError):
                    os.sched_setaffinity(pid, {core})
        timings = _Timings()
        with Client(url, timeout=600, transport=timings) as client:
            mesh = client.upload_mesh((MESH.vertices, MESH.faces), epsilon=0.01)
            query = columns(pairs, seed=5)
            _warm(client, mesh, query, timings, splits=True)  # both nodes as fast:
            for _ in range(2):  # the cut learns that
                client.find_contacts([mesh], **query)
            context = multiprocessing.get_context("spawn")
            spinning = context.Event()
            spinner = context.Process(target=_busy, args=(cores[1], spinning), daemon=True)
            spinner.start()
            if not spinning.wait(60):
                raise RuntimeError("the spinning process did not start")
            time.sleep(1.0)
            del timings.seen[:]
            for _ in range(repeats):
                client.find_contacts([mesh], **query)
    finally:
        if spinner is not None:
            spinner.kill()
        cluster.close()
    return {
        "cores": cores,
        "search_ms": [t["search"] for t in timings.seen],
        "server_timing_ms": timings.seen,
    }


class RayCluster:
    """A head (no CPUs) and ``nodes`` worker nodes of ``cpus`` CPUs, the app deployed."""

    def __init__(self, nodes: int, cpus: float, store: dict) -> None:
        import ray
        from ray import serve
        from ray.cluster_utils import Cluster

        from service.cluster import NAMESPACE

        self.ray, self.serve, self.store = ray, serve, store
        self.cluster = Cluster(
            initialize_head=True,
            head_node_args={"num_cpus": 0, "object_store_memory": 10**8},
        )
        for _ in range(nodes):
            self.cluster.add_node(num_cpus=cpus, object_store_memory=10**8)
        ray.init(address=self.cluster.address, namespace=NAMESPACE)
        self.port = free_port()
        serve.start(
            proxy_location="HeadOnly", http_options={"host": "127.0.0.1", "port": self.port}
        )
        self.url = f"http://127.0.0.1:{self.port}"

    def deploy(self, replicas: int, replica_cpus: float, name: str = "", **settings) -> str:
        """The URL of the app deployed with ``settings``; a ``name`` deploys it beside the
        others, at ``/<name>``."""
        from service.cluster import APP_NAME, application
        from service.settings import Settings

        values = Settings(**self.store, replica_cpus=replica_cpus, **settings)
        start = time.perf_counter()
        app = application(values, replicas, replica_cpus)
        self.serve.run(app, name=name or APP_NAME, route_prefix=f"/{name}")
        print(f"  {replicas} replica(s) deployed in {time.perf_counter() - start:.1f} s")
        return f"{self.url}/{name}" if name else self.url

    def close(self) -> None:  # no serve.shutdown(): it can wait 30 s for the controller
        self.ray.shutdown()
        self.cluster.shutdown()


def main() -> None:
    from service.cluster.batches import IDLE_WORKERS_MS, IDLE_WORKERS_VARIABLE

    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="shorter runs")
    parser.add_argument("--replicas", default="1,2", help="replica counts to measure")
    parser.add_argument("--replica-cpus", type=float, default=1.0)
    parser.add_argument("--clients", type=int, default=8)
    parser.add_argument(
        "--client-processes", type=int, default=1, help="processes the clients are spread over"
    )
    parser.add_argument("--seconds", type=float, default=15.0)
    parser.add_argument("--requests", type=int, default=400, help="sequential requests")
    parser.add_argument("--pairs", type=int, default=10_000, help="pairs of the big batch")
    parser.add_argument("--repeats", type=int, default=5, help="big-batch requests measured")
    parser.add_argument(
        "--settle",
        type=float,
        default=0.0,
        help="seconds between the big batch's mesh built and its first request",
    )
    parser.add_argument(
        "--only",
        choices=("serve", "batch", "slow"),
        help="only the Serve measures (1, 2), the batch (3), or the slowed node (4)",
    )
    parser.add_argument(
        "--haproxy",
        action="store_true",
        help="Serve's HAProxy ingress straight to the replicas' HTTP servers"
        " (RAY_SERVE_ENABLE_HA_PROXY, RAY_SERVE_ENABLE_DIRECT_INGRESS: Ray 2.60 feature flags)",
    )
    parser.add_argument(
        "--worker-niceness",
        type=int,
        default=0,
        help="the nice value of Ray's worker processes (replicas, tasks, actors):"
        " RAY_worker_niceness, which Ray leaves at 15 unless set",
    )
    parser.add_argument(
        "--pause",
        type=float,
        default=0.0,
        help="seconds before each request of the paired batch (a node's idle worker: see"
        " --idle-worker-ms)",
    )
    parser.add_argument(
        "--idle-worker-ms",
        type=int,
        default=IDLE_WORKERS_MS,
        help="how long a node keeps an idle worker once it runs more workers than CPUs:"
        f" {IDLE_WORKERS_VARIABLE}, as the README sets it by default (Ray's default: 1000)",
    )
    args = parser.parse_args()
    os.environ["RAY_worker_niceness"] = str(args.worker_niceness)  # noqa: SIM112 (Ray spells it so)
    os.environ[IDLE_WORKERS_VARIABLE] = str(args.idle_worker_ms)
    if args.haproxy:  # before the cluster starts: its processes inherit them
        os.environ.update(
            {"RAY_SERVE_ENABLE_HA_PROXY": "1", "RAY_SERVE_ENABLE_DIRECT_INGRESS": "1"}
        )
    if args.quick:
        args.seconds, args.requests, args.repeats = 5.0, 100, 3
    counts = [int(c) for c in args.replicas.split(",")]

    def wants(part: str) -> bool:
        return args.only in (None, part)

    cpus = os.cpu_count() or 1
    out: dict = {"machine": machine(), "args": vars(args)}
    print(f"machine: {out['machine'].get('cpu')} ({cpus} CPUs)")

    postgres, s3 = PostgresServer(), S3Server()
    tmp = Path(tempfile.mkdtemp(prefix="mrdem-cluster-bench-"))
    try:
        shared = {
            "MRDEM_STORE_URL": postgres.database(),
            "MRDEM_OBJECT_STORE_URL": s3.bucket(),
            "MRDEM_OBJECT_STORE_ENDPOINT": s3.endpoint,
        }
        plain = {}
        for name, env in (("embedded", {}), ("shared", shared)) if wants("serve") else ():
            with ServiceProcess(
                tmp / f"plain-{name}",
                env={**os.environ, **env},
                settings={"engine_threads": 1, "engine_concurrency": cpus},
            ) as service:
                plain[name] = {"sequential": sequential(service.url, args.requests)}
                if name == "shared":
                    plain[name]["loaded"] = loaded(
                        service.url, args.clients, args.seconds, args.client_processes
                    )
            print(f"plain service, {name} store: {plain[name]}")
        out["plain"] = plain

        store = {
            "data_dir": tmp / "cluster",
            "store_url": postgres.database(),
            "object_store_url": s3.bucket(),
            "object_store_endpoint": s3.endpoint,
        }
        cluster = RayCluster(1, cpus, store)
        try:
            out["serve"] = {}
            for replicas in counts if wants("serve") else ():
                url = cluster.deploy(replicas, args.replica_cpus)
                row = {"loaded": loaded(url, args.clients, args.seconds, args.client_processes)}
                if replicas == 1:
                    row["sequential"] = sequential(url, args.requests)
                    with ServiceProcess(  # the plain service beside it, in alternating blocks
                        tmp / "plain-beside",
                        env={**os.environ, **shared},
                        settings={"engine_threads": 1, "engine_concurrency": cpus},
                    ) as service:
                        rounds = max(2, args.requests // 50)
                        row["interleaved"] = interleaved(
                            {"plain": service.url, "serve": url}, rounds, 50
                        )
                out["serve"][replicas] = row
                print(f"serve, {replicas} replica(s): {row}")
        finally:
            cluster.close()

        out["batch"] = {}
        if wants("batch"):
            out["batch_ceiling"] = ceiling(args.pairs, args.repeats)
            print(f"{args.pairs:,}-pair batch without Ray: {out['batch_ceiling']}")
        for nodes in (1, 2) if wants("batch") else ():
            store = {**store, "store_url": postgres.database(), "object_store_url": s3.bucket()}
            cluster = RayCluster(nodes, 1, store)
            try:
                url = cluster.deploy(
                    1, 0.1, task_cpus=0.9, split_pairs=min(args.pairs, 2000), split_chunks=nodes
                )
                out["batch"][nodes] = big_batch(
                    url, args.pairs, args.repeats, splits=nodes > 1, settle=args.settle
                )
                print(f"{args.pairs:,}-pair batch, {nodes} node(s): {out['batch'][nodes]}")
            finally:
                cluster.close()
        if wants("batch"):  # both on one 2-node cluster, request by request
            store = {**store, "store_url": postgres.database(), "object_store_url": s3.bucket()}
            cluster = RayCluster(2, 1, store)
            try:
                urls = {
                    name: cluster.deploy(
                        1,
                        0.1,
                        name=f"batch-{name}",
                        task_cpus=0.8,  # fits a node beside both replicas
                        split_pairs=min(args.pairs, 2000),
                        split_chunks=chunks,
                    )
                    for name, chunks in (("alone", 1), ("split", 2))
                }
                out["batch_paired"] = paired_batch(urls, args.pairs, args.repeats, args.pause)
                print(f"{args.pairs:,}-pair batch, paired: {out['batch_paired']}")
            finally:
                cluster.close()
        if wants("slow"):
            store = {**store, "store_url": postgres.database(), "object_store_url": s3.bucket()}
            out["slowed_node"] = slowed_node(store, args.pairs, max(args.repeats, 8))
            print(f"{args.pairs:,}-pair batch, a slowed node: {out['slowed_node']}")
    finally:
        postgres.stop()
        s3.stop()

    print("\n== summary")
    if out["serve"]:
        summarise_serve(out, plain, counts)
    if out["batch"]:
        summarise_batch(out, args.pairs)
    if "slowed_node" in out:
        search = out["slowed_node"]["search_ms"]
        print(
            f"{args.pairs:,}-pair batch, the task's node slowed: search {search[0]:.0f} ms in the"
            f" first request (cut as before), median of the last {len(search) // 2}"
            f" {np.median(search[-(len(search) // 2) :]):.0f} ms (cut by measured speeds)"
        )
    name = "cluster-haproxy.json" if args.haproxy else "cluster.json"
    if args.only:
        name = name.replace(".json", f"-{args.only}.json")
    OUT.mkdir(exist_ok=True)
    (OUT / name).write_text(json.dumps(out, indent=2, default=str))
    print(f"wrote {OUT / name}")


def summarise_serve(out: dict, plain: dict, counts: list[int]) -> None:
    hop = out["serve"][counts[0]]["sequential"]["p50_ms"] - plain["shared"]["sequential"]["p50_ms"]
    print(f"Serve hop (10 pairs, p50): {hop:+.2f} ms over the plain service (shared store)")
    if "interleaved" in out["serve"].get(1, {}):
        plain_ms, serve_ms = (
            out["serve"][1]["interleaved"][k]["p50_ms"] for k in ("plain", "serve")
        )
        print(
            f"  interleaved blocks of 50: plain {plain_ms:.2f} ms, Serve {serve_ms:.2f} ms:"
            f" {serve_ms - plain_ms:+.2f} ms"
        )
    base = out["serve"][counts[0]]["loaded"]["requests_per_second"]
    for replicas in counts:
        row = out["serve"][replicas]["loaded"]
        print(
            f"{replicas} replica(s): {row['requests_per_second']:.0f} requests/s"
            f" ({row['requests_per_second'] / base:.2f}x), p50 {row['p50_ms']:.1f} ms,"
            f" p99 {row['p99_ms']:.1f} ms"
        )


def summarise_batch(out: dict, pairs: int) -> None:
    for key, what in (("median_s", "request"), ("search_median_s", "search in the service")):
        one, two = out["batch"][1][key], out["batch"][2][key]
        print(
            f"{pairs:,}-pair batch, {what}: 1 node {one:.3f} s, 2 nodes {two:.3f} s"
            f" ({one / two:.2f}x)"
        )
    for nodes in (1, 2):
        parts = ", ".join(
            f"{name} {ms:.1f}"
            for name, ms in out["batch"][nodes]["server_timing_median_ms"].items()
        )
        print(f"{pairs:,}-pair batch, {nodes} node(s), Server-Timing medians (ms): {parts}")
    two = out["batch"][2]
    print(
        f"{pairs:,}-pair batch, 2 nodes: a task searched in the request {two['warm_requests']}"
        f" sent, {two['warm_seconds']:.2f} s after the first"
    )
    if "batch_paired" in out:
        paired = out["batch_paired"]
        for key, what in (("median_s", "request"), ("search_median_s", "search")):
            alone, split = paired["alone"][key], paired["split"][key]
            low, high = paired[f"{what}_ratio_quartiles"]
            print(
                f"{pairs:,}-pair batch, paired on 2 nodes, {what}: alone {alone:.3f} s, split"
                f" {split:.3f} s; per round {paired[f'{what}_ratio_median']:.2f}x"
                f" (quartiles {low:.2f}-{high:.2f})"
            )
        parts = ", ".join(
            f"{name} {ms:.1f}" for name, ms in paired["split"]["server_timing_median_ms"].items()
        )
        print(
            f"{pairs:,}-pair batch, paired, a task searched in {paired['split']['task_rounds']}"
            f" of {len(paired['split']['seconds'])} rounds; Server-Timing medians (ms): {parts}"
        )
    top = out["batch_ceiling"]
    print(
        f"{pairs:,}-pair batch, no Ray: 1 process {top['one_process_s']:.3f} s,"
        f" 2 processes {top['two_processes_s']:.3f} s ({top['speedup']:.2f}x: the ceiling)"
    )


if __name__ == "__main__":
    main()
