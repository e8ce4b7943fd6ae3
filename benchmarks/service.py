"""HTTP transport cost and throughput of the service (issue 5).

1. A batch of 1,000 body pairs (two 1,280-triangle icospheres, poses near contact) through
   ``POST /v1/contacts`` with msgpack and with JSON, against the same in-process call
   (``engine.find_contacts_batch``); medians and minima of interleaved repeats.
2. 8 concurrent clients sending 10-pair contact requests for a fixed time: requests/s and
   p50 / p99 latency.

Starts its own server (``python -m service``) on a free port with a temporary store.
Writes ``bench-results/service.json``.

    .venv/bin/python benchmarks/service.py [--quick]
"""

from __future__ import annotations

import argparse
import json
import os
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import httpx
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from clients import Client  # noqa: E402
from engine import Pose, TreeBank, build_tree, find_contacts_batch, shapes  # noqa: E402

OUT = ROOT / "bench-results"


def start_server(data_dir: Path) -> tuple[subprocess.Popen, str]:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    env = {**os.environ, "MRDEM_PORT": str(port), "MRDEM_DATA_DIR": str(data_dir)}
    env.setdefault("NUMBA_CACHE_DIR", str(ROOT / ".numba-cache"))
    proc = subprocess.Popen(
        [sys.executable, "-m", "service"],
        cwd=ROOT,
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    url = f"http://127.0.0.1:{port}"
    start = time.perf_counter()
    while True:
        try:
            if httpx.get(f"{url}/readyz", timeout=2).status_code == 200:
                break
        except httpx.TransportError:
            pass
        if proc.poll() is not None or time.perf_counter() - start > 900:
            raise RuntimeError("server did not start")
        time.sleep(0.1)
    print(f"server ready in {time.perf_counter() - start:.1f} s at {url}")
    return proc, url


def poses(n: int, seed: int = 1) -> list[tuple[np.ndarray, np.ndarray]]:
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n):
        d = rng.normal(size=3)
        q = rng.normal(size=4)
        out.append((d / np.linalg.norm(d) * rng.uniform(1.0, 1.03), q / np.linalg.norm(q)))
    return out


def batch_overhead(url: str, mesh, repeats: int) -> dict:
    tree = build_tree(mesh, 0.01)
    pairs = poses(1000)
    queries = [(tree, Pose.identity(), tree, Pose(p, q)) for p, q in pairs]
    clients = {w: Client(url, wire=w, timeout=300) for w in ("msgpack", "json")}
    info = clients["msgpack"].upload_mesh((mesh.vertices, mesh.faces), epsilon=0.01)
    request = [(info, None, info, (p, q)) for p, q in pairs]
    bank = TreeBank([tree])
    index = np.zeros(len(pairs), np.int64)
    origin, identity = np.zeros((len(pairs), 3)), np.tile([1.0, 0, 0, 0], (len(pairs), 1))
    position = np.array([p for p, _ in pairs])
    orientation = np.array([q for _, q in pairs])
    runs = {k: [] for k in ("in-process", "find_contacts_batch", "msgpack", "json")}
    runs["msgpack, pair tuples"] = []
    calls = {
        # the fastest in-process call: a prebuilt bank, arrays in hand (what the service runs)
        "in-process": lambda: bank.find_contacts(
            index, origin, identity, index, position, orientation
        ),
        "find_contacts_batch": lambda: find_contacts_batch(queries),
        # the same arrays through HTTP (columnar request, CSR answer)
        "msgpack": lambda: clients["msgpack"].find_contacts(
            [info], index, origin, identity, index, position, orientation
        ),
        "json": lambda: clients["json"].find_contacts(
            [info], index, origin, identity, index, position, orientation
        ),
        "msgpack, pair tuples": lambda: clients["msgpack"].contacts(request),
    }
    for fn in calls.values():
        fn()  # warm: trees cached, connections open
    for _ in range(repeats):
        for name, fn in calls.items():
            start = time.perf_counter()
            fn()
            runs[name].append(time.perf_counter() - start)
    found = find_contacts_batch(queries)
    out = {
        "pairs": len(pairs),
        "contacts": int(sum(len(c.points) for c in found)),
        "repeats": repeats,
        "seconds": runs,
    }
    base_med, base_min = np.median(runs["in-process"]), min(runs["in-process"])
    print(
        f"\n== 1,000-pair contacts batch (1,280-triangle icospheres, {out['contacts']:,}"
        f" contacts), {repeats} interleaved repeats, 2 cores"
    )
    print(f"{'call':20s}{'median s':>10s}{'min s':>9s}{'overhead (median)':>20s}{'(min)':>9s}")
    for name, times in runs.items():
        med, best = float(np.median(times)), min(times)
        out[name] = {
            "median": med,
            "min": best,
            "overhead_median": med / base_med - 1,
            "overhead_min": best / base_min - 1,
        }
        print(
            f"{name:20s}{med:10.4f}{best:9.4f}{100 * (med / base_med - 1):19.1f}%"
            f"{100 * (best / base_min - 1):8.1f}%"
        )
    for c in clients.values():
        c.close()
    return out


def concurrency(url: str, mesh, seconds: float, workers: int = 8) -> dict:
    with Client(url) as setup:
        info = setup.upload_mesh((mesh.vertices, mesh.faces), epsilon=0.01)
    request = [(info, None, info, (p, q)) for p, q in poses(10, seed=2)]
    latencies: list[float] = []
    lock = threading.Lock()
    stop = time.perf_counter() + seconds

    def work():
        mine = []
        with Client(url) as client:
            while time.perf_counter() < stop:
                start = time.perf_counter()
                client.contacts(request)
                mine.append(time.perf_counter() - start)
        with lock:
            latencies.extend(mine)

    threads = [threading.Thread(target=work) for _ in range(workers)]
    begin = time.perf_counter()
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    wall = time.perf_counter() - begin
    lat = np.array(latencies)
    out = {
        "workers": workers,
        "pairs_per_request": len(request),
        "requests": len(lat),
        "seconds": wall,
        "requests_per_second": len(lat) / wall,
        "p50_ms": float(np.percentile(lat, 50) * 1e3),
        "p99_ms": float(np.percentile(lat, 99) * 1e3),
    }
    print(
        f"\n== {workers} concurrent clients, {len(request)}-pair contact requests (msgpack),"
        f" {wall:.1f} s: {out['requests_per_second']:.0f} requests/s, p50"
        f" {out['p50_ms']:.1f} ms, p99 {out['p99_ms']:.1f} ms ({len(lat):,} requests)"
    )
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true")
    args = parser.parse_args()
    OUT.mkdir(exist_ok=True)
    mesh = shapes.icosphere(3, radius=0.5)
    with tempfile.TemporaryDirectory() as tmp:
        proc, url = start_server(Path(tmp) / "data")
        try:
            results = {
                "batch": batch_overhead(url, mesh, 3 if args.quick else 25),
                "concurrency": concurrency(url, mesh, 3.0 if args.quick else 15.0),
                "cpu_count": os.cpu_count(),
            }
        finally:
            proc.terminate()
            proc.wait(30)
    (OUT / "service.json").write_text(json.dumps(results, indent=2))
    print(f"wrote {OUT / 'service.json'}")


if __name__ == "__main__":
    main()
