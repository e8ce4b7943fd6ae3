"""HTTP transport cost and throughput of the service (issue 5).

1. A batch of 1,000 body pairs (two 1,280-triangle icospheres, poses near contact) through
   ``POST /v1/contacts`` with msgpack and with JSON, against the same in-process call
   (``engine.find_contacts_batch``); medians and minima of interleaved repeats.
2. 8 concurrent clients sending 10-pair contact requests for a fixed time: requests/s and
   p50 / p99 latency.
3. ``/healthz`` latency (p50 / p99 / max, one probe every 20 ms) alone, and while uploads
   (an 81,920-triangle mesh as JSON and as msgpack, each with a new ε: a tree build each),
   long steps (200 steps of a 24-body scene a request) and 1,000-pair contact batches run
   (issue 17: nothing blocks the event loop).

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
from mrdem_common.malloc import keep_large_blocks  # noqa: E402

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


def probe(url: str, stop: threading.Event, every: float = 0.02) -> np.ndarray:
    """``/healthz`` latencies (s), one request every ``every`` seconds until ``stop``."""
    seen = []
    with httpx.Client(base_url=url, timeout=30) as client:
        while not stop.is_set():
            start = time.perf_counter()
            assert client.get("/healthz").status_code == 200
            seen.append(time.perf_counter() - start)
            time.sleep(every)
    return np.array(seen)


def _latency(seen: np.ndarray) -> dict:
    return {
        "probes": len(seen),
        "p50_ms": float(np.percentile(seen, 50) * 1e3),
        "p99_ms": float(np.percentile(seen, 99) * 1e3),
        "max_ms": float(seen.max() * 1e3),
    }


def healthz_under_load(url: str, seconds: float) -> dict:
    """``/healthz`` alone, then beside uploads, long steps and contact batches."""
    stop = threading.Event()
    quiet: list[np.ndarray] = []
    prober = threading.Thread(target=lambda: quiet.append(probe(url, stop)))
    prober.start()
    time.sleep(min(seconds, 5.0))
    stop.set()
    prober.join()

    big = shapes.icosphere(6, radius=0.5)  # 81,920 triangles
    ball = shapes.icosphere(2, radius=0.05)
    counts = {"uploads": 0, "steps": 0, "contacts": 0}
    stop = threading.Event()

    def uploads():
        k = 0
        with httpx.Client(base_url=url, timeout=600) as http, Client(url, timeout=600) as client:
            while not stop.is_set():
                k += 1
                epsilon = 0.004 + 1e-6 * k  # a new tree every time
                if k % 2:
                    body = {"vertices": big.vertices.tolist(), "faces": big.faces.tolist()}
                    answer = http.post("/v1/meshes", json={**body, "epsilon": epsilon})
                    assert answer.status_code in (200, 201, 202), answer.text
                else:
                    client.upload_mesh((big.vertices, big.faces), epsilon=epsilon, wait=False)
                counts["uploads"] += 1

    def steps():
        with Client(url, timeout=600) as client:
            info = client.upload_mesh((ball.vertices, ball.faces), epsilon=0.005)
            grid = [
                [0.12 * (i % 4), 0.12 * (i // 4 % 3), 0.06 + 0.12 * (i // 12)] for i in range(24)
            ]
            scene = client.create_scene(
                [{"mesh": info.id, "position": p} for p in grid],
                planes=[{"point": [0, 0, 0], "normal": [0, 0, 1]}],
                dt=1e-3,
                scheme="implicit-midpoint",
            )
            while not stop.is_set():
                scene.step(200)
                counts["steps"] += 200

    def contacts():
        with Client(url, timeout=600) as client:
            info = client.upload_mesh((ball.vertices, ball.faces), epsilon=0.005)
            pairs = [(info, None, info, (0.1 * p, q)) for p, q in poses(1000, seed=3)]
            while not stop.is_set():
                client.contacts(pairs)
                counts["contacts"] += 1

    loaded: list[np.ndarray] = []
    workers = [threading.Thread(target=f) for f in (uploads, steps, contacts)]
    for w in workers:
        w.start()
    time.sleep(2.0)  # the load under way
    prober = threading.Thread(target=lambda: loaded.append(probe(url, stop)))
    prober.start()
    time.sleep(seconds)
    stop.set()
    for w in [*workers, prober]:
        w.join()
    out = {"alone": _latency(quiet[0]), "loaded": _latency(loaded[0]), **counts}
    for name in ("alone", "loaded"):
        r = out[name]
        print(
            f"\n== /healthz {name}: p50 {r['p50_ms']:.2f} ms, p99 {r['p99_ms']:.2f} ms,"
            f" max {r['max_ms']:.1f} ms ({r['probes']} probes)"
        )
    print(
        f"   load: {counts['uploads']} uploads of 81,920 triangles, {counts['steps']} steps"
        f" of 24 bodies, {counts['contacts']} batches of 1,000 pairs in {seconds:.0f} s"
    )
    return out


def main() -> None:
    keep_large_blocks()  # as the service does (MRDEM_KEEP_LARGE_BLOCKS): the in-process side too
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--only", choices=("batch", "concurrency", "healthz"), default=None)
    args = parser.parse_args()
    OUT.mkdir(exist_ok=True)
    mesh = shapes.icosphere(3, radius=0.5)
    with tempfile.TemporaryDirectory() as tmp:
        proc, url = start_server(Path(tmp) / "data")
        try:
            parts = {
                "batch": lambda: batch_overhead(url, mesh, 3 if args.quick else 25),
                "concurrency": lambda: concurrency(url, mesh, 3.0 if args.quick else 15.0),
                "healthz": lambda: healthz_under_load(url, 10.0 if args.quick else 40.0),
            }
            results = {k: f() for k, f in parts.items() if args.only in (None, k)}
            results["cpu_count"] = os.cpu_count()
        finally:
            proc.terminate()
            proc.wait(30)
    name = "service.json" if args.only is None else f"service-{args.only}.json"
    (OUT / name).write_text(json.dumps(results, indent=2))
    print(f"wrote {OUT / name}")


if __name__ == "__main__":
    main()
