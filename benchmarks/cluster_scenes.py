"""Scenes on a real local Ray cluster (issue 18): what a scene's actor costs its user.

On a head (no CPUs) and two worker nodes of 1 CPU, one replica (0.4 CPU), scene actors of
0.5 CPU, the shared store (PostgreSQL, moto's S3), the app on Ray Serve
(:class:`cluster.RayCluster`):

1. **Requests for unknown scene ids** (``GET /v1/scenes/<id>``, ``--unknown`` of them):
   each answer's status and seconds, and the actors alive after them named for those ids.
2. **A scene's first step** against its next steps, for ``--scenes`` one-body scenes (an
   icosphere dropped on a plane), one after another, ``--settle`` seconds apart. With
   ``--spares 0`` each first step waits for the scene's actor to start (a process, the
   imports, the kernels, the scene rebuilt from the store); with the default
   (``MRDEM_SCENE_SPARES``, 1) the first scene's does, and each later scene takes a spare
   actor started when the one before was created.

    .venv/bin/python benchmarks/cluster_scenes.py [--scenes 3] [--unknown 4] [--settle 5]
        [--spares N] [--replicas 1] [--scene-cpus 0.5] [--worker-niceness 0]

At the end: the scene actors alive (the scenes' and the spares').

Writes ``bench-results/cluster-scenes.json``.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
import uuid
from pathlib import Path

import httpx
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.append(str(ROOT / "benchmarks"))

from cluster import RayCluster  # noqa: E402
from common import machine  # noqa: E402

from clients import Client  # noqa: E402
from engine import shapes  # noqa: E402
from mrdem_common.loopback import PostgresServer, S3Server  # noqa: E402
from service.cluster.batches import IDLE_WORKERS_MS, IDLE_WORKERS_VARIABLE  # noqa: E402

OUT = ROOT / "bench-results"


def first_steps(url: str, scenes: int, settle: float, steps: int = 5) -> list[dict]:
    """Per scene (``settle`` seconds apart): seconds to create it, its first step, its next
    ``steps`` steps."""
    rows = []
    with Client(url, timeout=120) as client:
        mesh = client.upload_mesh(shapes.icosphere(2, radius=0.5), epsilon=0.05).id
        for k in range(scenes):
            if k > 0:
                time.sleep(settle)
            start = time.perf_counter()
            scene = client.create_scene(
                bodies=[{"mesh": mesh, "position": [0, 0, 0.6]}],
                planes=[{"point": [0, 0, 0], "normal": [0, 0, 1]}],
                gravity=[0, 0, -9.81],
                dt=1e-3,
            )
            created = time.perf_counter()
            scene.step(1)
            first = time.perf_counter()
            later = []
            for _ in range(steps):
                begun = time.perf_counter()
                scene.step(1)
                later.append(time.perf_counter() - begun)
            rows.append(
                {
                    "create_s": created - start,
                    "first_step_s": first - created,
                    "next_steps_s": later,
                }
            )
            print(
                f"scene {k}: created in {created - start:.3f} s, first step {first - created:.3f}"
                f" s, next {steps} steps {min(later) * 1e3:.1f}-{max(later) * 1e3:.1f} ms",
                flush=True,
            )
    return rows


def unknown_scenes(url: str, count: int, timeout: float = 30.0) -> dict:
    """``count`` GETs of scene ids that do not exist: statuses, seconds, and the actors
    alive after them named for those ids (the replica's spares are not counted)."""
    from ray.util.state import list_actors

    from service.cluster import actor_name

    statuses, seconds, names = [], [], set()
    for _ in range(count):
        scene_id = uuid.uuid4().hex
        names.add(actor_name(scene_id))
        start = time.perf_counter()
        try:
            statuses.append(httpx.get(f"{url}/v1/scenes/{scene_id}", timeout=timeout).status_code)
        except httpx.TimeoutException:
            statuses.append(f"no answer in {timeout:.0f} s")
        seconds.append(time.perf_counter() - start)
        print(f"unknown scene: {statuses[-1]} in {seconds[-1]:.3f} s", flush=True)
    time.sleep(1.0)  # the state API hears of actors a moment later
    actors = [
        a for a in list_actors(filters=[("state", "=", "ALIVE")], limit=10_000) if a.name in names
    ]
    return {"statuses": statuses, "seconds": seconds, "scene_actors_alive": len(actors)}


def scene_actors_alive(settle: float = 5.0) -> dict[str, int]:
    """The scene actors not dead ``settle`` seconds after the last scene, by state (spares
    started on its creation included): those of the scenes made, and the spares."""
    from ray.util.state import list_actors

    time.sleep(settle)
    states: dict[str, int] = {}
    for actor in list_actors(filters=[("class_name", "=", "SceneActor")], limit=10_000):
        if actor.state != "DEAD":
            states[actor.state] = states.get(actor.state, 0) + 1
    return states


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scenes", type=int, default=3)
    parser.add_argument("--unknown", type=int, default=4)
    parser.add_argument("--settle", type=float, default=5.0, help="seconds between scenes")
    parser.add_argument(
        "--spares", type=int, default=None, help="MRDEM_SCENE_SPARES (default: the setting's)"
    )
    parser.add_argument("--replicas", type=int, default=1, help="the scenes go round them")
    parser.add_argument("--replica-cpus", type=float, default=0.4)
    parser.add_argument("--scene-cpus", type=float, default=0.5)
    parser.add_argument(
        "--worker-niceness",
        type=int,
        default=0,
        help="the nice value of Ray's worker processes (the replica, the actors):"
        " RAY_worker_niceness, which Ray leaves at 15 unless set (the README sets 0)",
    )
    args = parser.parse_args()
    os.environ["RAY_worker_niceness"] = str(args.worker_niceness)  # noqa: SIM112 (Ray spells it so)
    os.environ[IDLE_WORKERS_VARIABLE] = str(IDLE_WORKERS_MS)  # as the README's ray start
    out: dict = {"machine": machine(), "args": vars(args)}
    print(f"machine: {out['machine'].get('cpu')}")
    postgres, s3 = PostgresServer(), S3Server()
    tmp = Path(tempfile.mkdtemp(prefix="mrdem-cluster-scenes-"))
    store = {
        "data_dir": tmp / "cluster",
        "store_url": postgres.database(),
        "object_store_url": s3.bucket(),
        "object_store_endpoint": s3.endpoint,
    }
    try:
        cluster = RayCluster(2, 1, store)
        try:
            spares = {} if args.spares is None else {"scene_spares": args.spares}
            url = cluster.deploy(
                args.replicas, args.replica_cpus, scene_cpus=args.scene_cpus, **spares
            )
            out["unknown"] = unknown_scenes(url, args.unknown)
            out["scenes"] = first_steps(url, args.scenes, args.settle)
            out["scene_actors_alive"] = scene_actors_alive()
        finally:
            cluster.close()
    finally:
        postgres.stop()
        s3.stop()
    print("\n== summary")
    firsts = [r["first_step_s"] for r in out["scenes"]]
    later = [t for r in out["scenes"] for t in r["next_steps_s"]]
    if firsts:
        print(
            f"first step of a scene: {min(firsts):.2f}-{max(firsts):.2f} s; later steps:"
            f" median {np.median(later) * 1e3:.1f} ms"
            f" ({min(later) * 1e3:.1f}-{max(later) * 1e3:.1f})"
        )
    print(
        f"scene actors not dead after {len(out['scenes'])} scenes through {args.replicas}"
        f" replica(s), by state: {out['scene_actors_alive']}"
    )
    unknown = out["unknown"]
    if unknown["statuses"]:
        print(
            f"{len(unknown['statuses'])} unknown scene ids: {unknown['statuses']},"
            f" {min(unknown['seconds']):.3f}-{max(unknown['seconds']):.3f} s;"
            f" actors of those ids alive after: {unknown['scene_actors_alive']}"
        )
    OUT.mkdir(exist_ok=True)
    (OUT / "cluster-scenes.json").write_text(json.dumps(out, indent=2, default=str))
    print(f"wrote {OUT / 'cluster-scenes.json'}")


if __name__ == "__main__":
    main()
