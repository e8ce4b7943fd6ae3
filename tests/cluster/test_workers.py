"""The nodes' workers between a replica's split requests (``pytest -m cluster``): a node
that runs more workers than CPUs keeps an idle one for the next task when started as the
README says (``RAY_idle_worker_killing_time_threshold_ms``; Ray's default ends it after
1 s, and the next task waits seconds for a fresh worker), and a replica whose node was not
started so says so in its log."""

from __future__ import annotations

import logging
import os
import time
from pathlib import Path

import pytest

pytestmark = pytest.mark.cluster


def _alive(pid: int) -> bool:
    """Whether process ``pid`` runs (not ended, nor a zombie its parent has not reaped)."""
    try:
        status = Path(f"/proc/{pid}/status").read_text()
    except OSError:
        return False
    return "\nState:\tZ" not in status and "\nState:\tX" not in status


def test_a_crowded_node_keeps_an_idle_worker_through_a_pause(ray_cluster):
    """More actors on a node than its CPUs, then a task there, then a pause of 2.5 s (Ray's
    default ends an idle worker past its node's CPUs after 1 s, checked every 0.2 s): the
    task's worker is still alive."""
    import ray
    from ray.util.scheduling_strategies import NodeAffinitySchedulingStrategy

    _, _, settings = ray_cluster
    node, cpus = max(  # an alive worker node (earlier tests kill some)
        (n["NodeID"], int(n["Resources"]["CPU"]))
        for n in ray.nodes()
        if n["Alive"] and n["Resources"].get("CPU", 0) > 0
    )
    here = NodeAffinitySchedulingStrategy(node, soft=False)

    @ray.remote(num_cpus=0)
    class Neighbour:  # a scene's actor, say: a worker of its own on the node
        def pid(self) -> int:
            return os.getpid()

    @ray.remote
    def pid() -> int:
        return os.getpid()

    task = pid.options(num_cpus=settings.task_cpus, scheduling_strategy=here)
    neighbours = [Neighbour.options(scheduling_strategy=here).remote() for _ in range(cpus + 1)]
    try:
        ray.get([n.pid.remote() for n in neighbours], timeout=120)
        worker = ray.get(task.remote(), timeout=120)
        time.sleep(2.5)
        assert _alive(worker), "the idle worker was ended"
    finally:
        for n in neighbours:
            ray.kill(n)


def test_a_replica_names_a_node_that_ends_idle_workers_soon(ray_cluster, monkeypatch, caplog):
    """The readying task reports how long its node keeps an idle worker: the fixture's nodes
    (started as the README says) draw no warning; a node that ends them after Ray's 1 s is
    named, with the variable to set."""
    from service.cluster import batches

    _, _, settings = ray_cluster
    with caplog.at_level(logging.INFO, logger="mrdem.cluster"):
        splitter = batches.RaySplitter(settings, 1, 2, 0.5)
        nodes = splitter.others()
        assert splitter.ready(nodes, timeout=60) == nodes
    said = [r.getMessage() for r in caplog.records if r.name == "mrdem.cluster"]
    assert len([m for m in said if " ready in " in m]) == len(nodes), said
    assert not [m for m in said if batches.IDLE_WORKERS in m], said

    def ready_on_ray_s_default(task_settings) -> tuple[float, int]:  # sent by value
        return 0.0, 1000

    monkeypatch.setattr(batches, "_ready_worker", ready_on_ray_s_default)
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="mrdem.cluster"):
        splitter = batches.RaySplitter(settings, 1, 2, 0.5)
        assert splitter.ready(nodes, timeout=60) == nodes
    warned = [r.getMessage() for r in caplog.records if r.name == "mrdem.cluster"]
    for node in nodes:
        assert [m for m in warned if node in m and batches.IDLE_WORKERS in m], warned
