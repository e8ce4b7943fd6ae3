"""The service on a real Ray cluster (``pytest -m cluster``; ``make test-cluster``): the
README's remote loop through the Serve endpoint; two replicas answering the contacts of the
embedded service; a big contacts request split across the nodes answering what one process
answers; a scene's node killed mid-run, and the scene going on from its stored state with no
acknowledged step lost, as an uninterrupted run."""

from __future__ import annotations

import contextlib
import logging
import os
import signal
import threading
import time
from pathlib import Path

import httpx
import numpy as np
import pytest
from harness import InProcessService, near_pairs, run_readme_loop, server_timing
from servers import descendants, until_none_titled, until_titled

from clients import Client, codec
from engine import shapes

pytestmark = pytest.mark.cluster


@pytest.fixture(scope="module")
def embedded(tmp_path_factory):
    """The embedded service (SQLite and files), the oracle of the cluster's answers."""
    with InProcessService(tmp_path_factory.mktemp("embedded") / "data") as service:
        yield service


def _upload(client: Client, mesh) -> str:
    return client.upload_mesh(mesh, epsilon=0.05).id


def _query(mesh_ids, n: int, seed: int) -> dict:
    rng = np.random.default_rng(seed)
    q = rng.normal(size=(2 * n, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    return {
        "meshes": mesh_ids,
        "a": rng.integers(0, len(mesh_ids), n),
        "b": rng.integers(0, len(mesh_ids), n),
        "position_a": rng.uniform(-0.1, 0.1, (n, 3)),
        "orientation_a": q[:n],
        "position_b": rng.uniform(-1.0, 1.0, (n, 3)),
        "orientation_b": q[n:],
    }


OPTIONS = ("hybrid", True, "float64")  # kernel, hierarchy, precision of the splitter tests


def _as_a_replica(settings, query: dict):
    """What a replica holds for ``query``, in this process: ``(its store — close it — the
    request's columns as the service reads them (unit quaternions), here(run): the search
    of a run with its banks)``."""
    from service.banks import BankCache
    from service.models import ColumnarQuery
    from service.search import find
    from service.store import open_store

    store = open_store(settings)
    banks = BankCache(store)
    valid = ColumnarQuery.model_validate(query)
    columns = tuple(getattr(valid, k) for k in ("a", "position_a", "orientation_a", "b"))
    columns += (valid.position_b, valid.orientation_b)

    def here(run: tuple) -> dict:
        return find(query["meshes"], run, *OPTIONS, 1, store, banks)

    return store, columns, here


def _box_batch(url: str, embedded, n: int, seed: int):
    """A box uploaded to the cluster and to the embedded service, ``n`` random pairs of it
    (:func:`_query`): ``(the mesh ids, the query, the embedded service's answer)``."""
    with Client(url) as client, Client(embedded.url, transport=embedded.transport) as alone:
        ids = [_upload(c, shapes.box()) for c in (client, alone)]
        query = _query(ids[:1], n, seed=seed)
        return ids, query, alone.find_contacts(**query)


def _readied_splitter(settings):
    """A replica's splitter in this process (runs from 1 pair, two runs, tasks of 0.5 CPU)
    whose nodes have all been readied."""
    from service.cluster.batches import RaySplitter

    splitter = RaySplitter(settings, 1, 2, 0.5)
    assert splitter.ready(splitter.others(), timeout=60) == splitter.others()
    return splitter


def _search_tasks(address: str, which, seconds: float = 20.0, name: str = "_search_pieces") -> list:
    """The tasks of function ``name`` (by default the contacts tasks) that ``which(tasks)``
    picks, as soon as it picks any (the state API hears of tasks a moment later), or none
    after ``seconds``."""
    from ray.util.state import list_tasks

    deadline = time.monotonic() + seconds
    while True:
        tasks = list_tasks(
            address=address,
            filters=[("func_or_class_name", "=", name)],
            detail=True,
            limit=10_000,
        )
        picked = which(tasks)
        if picked or time.monotonic() >= deadline:
            return picked
        time.sleep(0.2)


def _failed(tasks: list) -> list:
    return [t for t in tasks if t.state == "FAILED"]


def _same(found, expected) -> None:
    for name in ("offsets", "points", "normals", "overlaps", "pair_offsets", "pairs"):
        np.testing.assert_array_equal(getattr(found, name), getattr(expected, name), name)


def test_the_readme_remote_loop_runs_against_the_serve_endpoint(ray_cluster, monkeypatch, capsys):
    run_readme_loop(ray_cluster[1], monkeypatch, capsys)


def test_two_replicas_answer_the_contacts_of_the_embedded_service(ray_cluster, embedded):
    _, url, _ = ray_cluster
    meshes = [shapes.box(), shapes.icosphere(2)]
    with Client(url) as cluster, Client(embedded.url, transport=embedded.transport) as alone:
        ids = [_upload(cluster, m) for m in meshes]
        assert [_upload(alone, m) for m in meshes] == ids  # content ids: the same meshes
        query = _query(ids, 200, seed=7)
        expected = alone.find_contacts(**query)
        assert expected.offsets[-1] > 0
        replicas: list[str] = []
        while len(set(replicas)) < 2 and len(replicas) < 100:  # until both have answered
            response = httpx.post(f"{url}/v1/contacts", json=_jsonable(query), timeout=120)
            assert response.status_code == 200, response.text
            replicas.append(response.headers["X-Mrdem-Replica"])
            _same(cluster.find_contacts(**query), expected)
            time.sleep(0.05)
        assert len(set(replicas)) == 2, replicas  # both replicas answered, the same
    from ray.util.state import list_actors

    actors = list_actors(filters=[("state", "=", "ALIVE")], limit=1000, detail=True)
    replica_actors = [a for a in actors if a.class_name.startswith("ServeReplica:")]
    assert len({a.node_id for a in replica_actors}) == 2  # on two nodes, behind HAProxy
    for actor in replica_actors:  # one malloc arena (service.cluster.deployment.ARENAS)
        assert _environ(actor.pid).get("MALLOC_ARENA_MAX") == "1"


def _environ(pid: int) -> dict[str, str]:
    """A process's environment, as it started."""
    with open(f"/proc/{pid}/environ", "rb") as f:
        pairs = (v.decode().partition("=") for v in f.read().split(b"\0") if v)
    return {name: value for name, _, value in pairs}


def test_a_big_batch_split_across_the_nodes_answers_what_one_process_answers(ray_cluster, embedded):
    """A request of 3,000 pairs runs as two runs: one in the replica that took it, one as a
    Ray task (in pieces) on another node — the one that ranks first for the mesh among the
    others, so each of a replica's requests goes back to the same node (its tree on disk,
    its banks in memory; a random node would be the same one time in two) — and answers
    what the embedded service answers; its ``Server-Timing`` names the split's parts."""
    import ray
    from ray.util.state import list_actors

    from service.cluster.batches import ranked

    cluster, url, settings = ray_cluster
    n = 3 * settings.split_pairs
    address = f"http://{cluster.webui_url}"
    remote: dict[str, list[str]] = {}  # replica → the nodes of its requests' tasks
    workers: set[int] = set()  # the processes that ran the tasks
    searched: list[float] = []  # the tasks' seconds
    with Client(url) as client, Client(embedded.url, transport=embedded.transport) as alone:
        # near contact: long enough that the task hands pieces over before the replica,
        # done with its own run, takes the rest back
        ids = [_upload(c, shapes.icosphere(3)) for c in (client, alone)]
        query = near_pairs(ids[:1], n, seed=11)
        expected = alone.find_contacts(**query)
        replicas = {  # replica id → its node
            a.name.rsplit("#", 1)[-1]: a.node_id
            for a in list_actors(filters=[("state", "=", "ALIVE")], limit=1000)
            if a.class_name.startswith("ServeReplica:")
        }
        for _ in range(16):
            sent = time.time() * 1000 - 50  # ms, as the state API's times
            response = httpx.post(  # msgpack: JSON's encoding took a second of each request
                f"{url}/v1/contacts",
                content=codec.encode(query, codec.MSGPACK),
                headers={"content-type": codec.MSGPACK, "accept": codec.MSGPACK},
                timeout=120,
            )
            assert response.status_code == 200, response.text
            answer = codec.decode(response.content, response.headers["content-type"])
            for name in ("offsets", "points", "normals", "overlaps", "pair_offsets", "pairs"):
                np.testing.assert_array_equal(answer[name], getattr(expected, name), name)
            timing = server_timing(response)  # where the time went, the split's parts too
            if list(timing) == ["search", "encode"]:  # its node still starting an earlier
                continue  # task, left to end (a cold worker): searched by the replica alone
            parts = ["search", "submit", "here", "taken", "task", "wait", "merge", "encode"]
            assert list(timing) == parts
            assert timing["search"] >= timing["here"] + timing["taken"] + timing["wait"]
            new = _search_tasks(  # its task, ended or not, once on a node
                address,
                lambda ts, since=sent: [
                    t for t in ts if (t.creation_time_ms or 0) >= since and t.node_id
                ],
            )
            assert len(new) == 1, new  # one run here, one task
            replica = response.headers["X-Mrdem-Replica"]
            remote.setdefault(replica, []).append(new[0].node_id)
            workers.add(new[0].worker_pid)
            searched.append(timing["task"])  # 0 where every piece was taken back (cold)
            if sum(t > 0 for t in searched) >= 4:
                break
    assert sum(t > 0 for t in searched) >= 4, searched  # tasks searched, once warm
    alive = [pid for pid in workers if pid and os.path.exists(f"/proc/{pid}")]  # pooled
    assert alive and all(_environ(pid).get("MALLOC_ARENA_MAX") == "1" for pid in alive)
    actors = list_actors(filters=[("state", "=", "ALIVE")], detail=True)
    serving = [a.pid for a in actors if os.path.exists(f"/proc/{a.pid}")]
    assert serving and all(_nice(pid) == 0 for pid in alive + serving)  # not Ray's 15
    cpus = {n["NodeID"] for n in ray.nodes() if n["Alive"] and n["Resources"].get("CPU", 0)}
    for replica, nodes in remote.items():
        others = cpus - {replicas[replica]}
        assert nodes == [ranked(ids[:1], others)[0]] * len(nodes), (replica, nodes)


def test_a_big_batch_whose_task_node_dies_is_answered_in_full(ray_cluster, embedded):
    """The node running a split request's task is killed while the task runs: the
    replica searches the pieces the task had not handed over (Ray does not run the task
    again: its one attempt failed, none other ran) and the request answers what the
    embedded service answers, whole."""
    from ray.util.state import list_tasks

    cluster, url, settings = ray_cluster
    n = 10 * settings.split_pairs  # near contact: the task runs for a while
    with (
        Client(url, timeout=120) as client,
        Client(embedded.url, transport=embedded.transport) as alone,
    ):
        ids = [_upload(c, shapes.icosphere(3)) for c in (client, alone)]
        query = near_pairs(ids[:1], n, seed=12)
        expected = alone.find_contacts(**query)
        until_none_titled(
            "ray::_search_pieces", deadline=time.monotonic() + 30
        )  # earlier tests' tasks
        answers: dict = {}
        request = threading.Thread(
            target=lambda: answers.update(found=client.find_contacts(**query))
        )
        request.start()
        pid = until_titled("ray::_search_pieces", deadline=time.monotonic() + 60)
        (node,) = [
            w
            for w in cluster.worker_nodes
            if pid in descendants(w.all_processes["raylet"][0].process.pid)
        ]
        _kill_node(cluster, node)
        request.join(timeout=180)
    assert not request.is_alive() and "found" in answers, "the request never answered"
    _same(answers["found"], expected)
    address = f"http://{cluster.webui_url}"
    failed = _search_tasks(
        address, lambda ts: [t for t in ts if t.node_id == node.node_id and t.state == "FAILED"]
    )
    assert len(failed) == 1, "no task failed with its node"
    time.sleep(1.0)  # … and of a second attempt, were there one
    attempts = list_tasks(address=address, filters=[("task_id", "=", failed[0].task_id)])
    assert [t.state for t in attempts] == ["FAILED"], attempts
    # a node in its place, at its address, for what runs after
    cluster.add_node(num_cpus=2, object_store_memory=10**8, node_ip_address=node.node_ip_address)


def test_a_run_whose_task_fails_is_searched_where_the_request_is(ray_cluster, embedded, caplog):
    """A node that cannot search (here: its data directory cannot be made, so the task's
    store does not open) fails its task with an error (Ray runs a task again only when its
    worker or node was lost): the splitter searches that run where the request is, the
    answer is still the embedded service's, whole, and the log names the node. (The
    replica's own run ends once the task has failed: a task failing after every piece was
    taken back costs nothing, and is not logged.)"""

    from service.cluster.batches import RaySplitter, ranked
    from service.search import split

    cluster, url, settings = ray_cluster
    ids, query, expected = _box_batch(url, embedded, 2 * settings.split_pairs, seed=13)
    store, columns, here = _as_a_replica(settings, query)
    unwritable = settings.model_copy(update={"data_dir": Path("/proc/version/mrdem")})
    splitter = RaySplitter(unwritable, 1, 2, 0.5)  # its tasks get the broken settings
    address = f"http://{cluster.webui_url}"
    before = {t.task_id for t in _search_tasks(address, _failed, seconds=0.0)}

    def long_here(run: tuple) -> dict:  # a replica's run that outlasts the task's failure
        new = _search_tasks(
            address, lambda ts: [t for t in _failed(ts) if t.task_id not in before], 60.0
        )
        assert new, "the task never failed"
        return here(run)

    # its nodes' readying fails as its tasks will (it opens the store), logged; counted as
    with caplog.at_level(logging.WARNING, logger="mrdem.cluster"):  # ready
        assert splitter.ready(splitter.others(), timeout=60) == splitter.others()
    failed = [r.getMessage() for r in caplog.records if r.name == "mrdem.cluster"]
    assert len(failed) == len(splitter.others()), failed
    for node in splitter.others():
        assert any(f"readying a worker on node {node} failed" in m for m in failed), failed
    node = ranked(ids[:1], splitter.others())[0]  # where its task goes
    caplog.clear()
    try:
        with caplog.at_level(logging.WARNING, logger="mrdem.cluster"):
            found = splitter.find(ids[:1], columns, *OPTIONS, here=long_here)
    finally:
        store.close()
    for name in ("offsets", "points", "normals", "overlaps", "pair_offsets", "pairs"):
        np.testing.assert_array_equal(found[name], getattr(expected, name), name)
    (warning,) = [r for r in caplog.records if r.name == "mrdem.cluster"]
    sent = len(split(columns, [settings.engine_threads, 1])[1][0])  # the task's run
    assert f"a contacts task of {sent} pairs" in warning.getMessage()
    assert f"sent to node {node} failed; its pieces left were searched here" in (
        warning.getMessage()
    )


def test_a_node_given_too_much_has_its_pieces_taken_back(ray_cluster, embedded):
    """A node measured four times as fast as it is gets four fifths of a request: the
    replica, done with its fifth, takes back the pieces the node has not begun — the answer
    is still the embedded service's, ``Server-Timing`` counts the time taken back, and the
    node's measured speed falls."""
    from service.cluster.batches import ranked

    _, url, settings = ray_cluster
    with (
        Client(url, timeout=120) as client,
        Client(embedded.url, transport=embedded.transport) as alone,
    ):
        ids = [_upload(c, shapes.icosphere(3)) for c in (client, alone)]
        query = near_pairs(ids[:1], 4 * settings.split_pairs, seed=14)
        expected = alone.find_contacts(**query)
    store, columns, here = _as_a_replica(settings, query)
    splitter = _readied_splitter(settings)
    node = ranked(ids[:1], splitter.others())[0]
    try:  # first requests warm the banks here and the node's worker, until it searches
        deadline = time.monotonic() + 90
        while (
            splitter.find(ids[:1], columns, *OPTIONS, here=here).get("timing", {}).get("task", 0.0)
            == 0.0
        ):
            assert time.monotonic() < deadline, "the node never searched a piece"
        for _ in range(30):  # then the node is measured at 4x what it is (both 1 thread)
            splitter.speeds.update((1, 1.0), {node: (4, 1.0)}, 1.0)
        (fast,) = splitter.speeds.weights([node], 1.0)
        assert fast == pytest.approx(4.0, rel=1e-3)
        found = splitter.find(ids[:1], columns, *OPTIONS, here=here)
    finally:
        store.close()
    for name in ("offsets", "points", "normals", "overlaps", "pair_offsets", "pairs"):
        np.testing.assert_array_equal(found[name], getattr(expected, name), name)
    assert found["timing"]["taken"] > 0
    assert splitter.speeds.weights([node], 1.0)[0] < fast


def test_a_node_gets_runs_once_a_worker_is_readied_there(
    ray_cluster, embedded, tmp_path, monkeypatch
):
    """A splitter sends each alive node a task readying a worker (a fresh one takes seconds:
    imports, kernels, the store) and sends a node no run before that task has ended: until
    then its requests are searched here alone, whole; after, they are split again."""
    from service.cluster import batches

    _, url, settings = ray_cluster
    ids, query, expected = _box_batch(url, embedded, 2 * settings.split_pairs, seed=16)
    go = tmp_path / "go"

    def slow_ready(task_settings) -> tuple[float, int]:  # a local function: sent by value
        while not go.exists():
            time.sleep(0.05)
        return 0.0, 600_000  # (seconds, how long its node keeps an idle worker)

    monkeypatch.setattr(batches, "_ready_worker", slow_ready)
    store, columns, here = _as_a_replica(settings, query)
    splitter = batches.RaySplitter(settings, 1, 2, 0.5)
    try:
        assert splitter.ready(splitter.others(), timeout=1.0) == []
        found = splitter.find(ids[:1], columns, *OPTIONS, here=here)
        assert "timing" not in found  # not split: searched here alone
        for name in ("offsets", "points", "normals", "overlaps", "pair_offsets", "pairs"):
            np.testing.assert_array_equal(found[name], getattr(expected, name), name)
        go.touch()
        assert splitter.ready(splitter.others(), timeout=60) == splitter.others()
        found = splitter.find(ids[:1], columns, *OPTIONS, here=here)
        assert "timing" in found  # split
        for name in ("offsets", "points", "normals", "overlaps", "pair_offsets", "pairs"):
            np.testing.assert_array_equal(found[name], getattr(expected, name), name)
    finally:
        go.touch()
        store.close()


def test_a_run_s_task_runs_in_a_worker_readied_on_its_node(ray_cluster, embedded):
    """The readying task's worker goes back to its node's pool and the run's task takes it:
    no fresh worker starts for a request."""
    from service.cluster.batches import ranked

    cluster, url, settings = ray_cluster
    with Client(url) as client:
        ids = [_upload(client, shapes.box())]
    query = _query(ids, 2 * settings.split_pairs, seed=17)
    store, columns, here = _as_a_replica(settings, query)
    splitter = _readied_splitter(settings)
    node = ranked(ids, splitter.others())[0]
    address = f"http://{cluster.webui_url}"
    sent = time.time() * 1000 - 50  # ms, as the state API's times
    try:
        assert "timing" in splitter.find(ids, columns, *OPTIONS, here=here)
    finally:
        store.close()
    (task,) = _search_tasks(
        address, lambda ts: [t for t in ts if (t.creation_time_ms or 0) >= sent and t.worker_pid]
    )
    assert task.node_id == node
    readied = _search_tasks(  # (the state API may hear of it a moment later)
        address,
        lambda ts: [
            t
            for t in ts
            if t.node_id == node and t.state == "FINISHED" and t.worker_pid == task.worker_pid
        ],
        name="_ready_worker",
    )
    assert readied, f"no readying ran in the worker {task.worker_pid} of the run's task"


def test_a_node_still_on_a_task_left_to_end_gets_no_other(ray_cluster, embedded):
    """A task that had handed nothing over when its request ended (a cold worker starting,
    a stalled node) is not cancelled but left to end, and until it has, its node gets no
    other task of that replica's: the request is searched in the replica alone (no other
    node takes the run: the trees stay where the ranking put them); once it ended, the
    node has runs again."""
    from service.cluster.batches import _Task, ranked

    _, url, settings = ray_cluster
    ids, query, expected = _box_batch(url, embedded, 2 * settings.split_pairs, seed=15)
    store, columns, here = _as_a_replica(settings, query)
    splitter = _readied_splitter(settings)
    node = ranked(ids[:1], splitter.others())[0]
    ended = _Task(node)
    splitter._end(ended)  # a task that ended before its request decided is not left
    splitter._stop(ended, None, 0, 8)
    assert not ended.left
    left = _Task(node)
    splitter._stop(left, None, 0, 8)  # as a request whose task handed nothing over
    try:
        found = splitter.find(ids[:1], columns, *OPTIONS, here=here)
        assert "timing" not in found  # not split: searched here alone
        for name in ("offsets", "points", "normals", "overlaps", "pair_offsets", "pairs"):
            np.testing.assert_array_equal(found[name], getattr(expected, name), name)
        splitter._end(left)  # its puller saw it end
        found = splitter.find(ids[:1], columns, *OPTIONS, here=here)
        assert "timing" in found  # split again
    finally:
        store.close()


def test_a_cancelled_task_ends_at_its_next_piece_and_its_worker_lives_on(ray_cluster):
    """Ray cancels a running task by simulating SIGINT in its worker: the splitter's task
    notes it and ends before its next piece, in the same worker, which stays for the next
    request (Python's own KeyboardInterrupt, raised inside a kernel's dispatch, killed the
    worker: SIGSEGV)."""
    import ray
    from ray.exceptions import RayError

    from service.cluster.batches import _search_pieces

    _, url, settings = ray_cluster
    until_none_titled("ray::_search_pieces", deadline=time.monotonic() + 30)  # earlier tests' tasks
    with Client(url) as client:
        mesh = client.upload_mesh(shapes.icosphere(3), epsilon=0.05).id
    query = near_pairs([mesh], 1600, seed=21)
    run = tuple(query[k] for k in ("a", "position_a", "orientation_a", "b", "position_b"))
    run += (query["orientation_b"],)
    task = ray.remote(_search_pieces).options(
        num_cpus=settings.task_cpus, max_retries=0, num_returns="streaming"
    )
    pieces = 16
    answers = task.remote(settings, [mesh], run, pieces, "hybrid", True, "float64", 1)
    worker = until_titled("ray::_search_pieces", deadline=time.monotonic() + 60)
    handed = 0
    for ref in answers:
        try:
            ray.get(ref)
        except RayError:  # cancelled: the end of the stream
            break
        handed += 1
        if handed == 2:
            ray.cancel(answers)
    # the piece on its way and the one it was on, at most
    assert 2 <= handed <= 4 < pieces, handed
    time.sleep(1.0)
    assert os.path.exists(f"/proc/{worker}"), "the worker died"


@pytest.mark.parametrize("scheme", ["explicit", "implicit-midpoint"])
def test_a_scene_whose_node_dies_goes_on_from_its_stored_state(ray_cluster, embedded, scheme):
    """Steps acknowledged before the scene's node died are all there: the acknowledged
    step counts run 5, 10, …, 100 without a gap, and the final state is an uninterrupted
    run's: bit for bit with the explicit scheme; with an implicit one within what the
    Picard tolerance allows (the warm starts of the lost actor are not stored), as after a
    restart of the embedded service."""
    import ray
    from ray.util.state import list_actors

    from service.cluster import NAMESPACE, actor_name

    cluster_nodes, url, _ = ray_cluster
    spec = {
        "bodies": [
            {"mesh": None, "position": [0, 0, 1.03], "velocity": [0.2, 0, 0], "epsilon": 0.02}
        ],
        "planes": [{"point": [0, 0, 0], "normal": [0, 0, 1]}],
        "dt": 5e-4,
        "scheme": scheme,
    }
    acknowledged, states = [], {}
    for name, client in (
        ("cluster", Client(url)),
        ("alone", Client(embedded.url, transport=embedded.transport)),
    ):
        with client:
            spec["bodies"][0]["mesh"] = _upload(client, shapes.icosphere(2))
            scene = client.create_scene(**spec)
            for k in range(20):
                state = scene.step(5)
                if name == "cluster":
                    acknowledged.append(state.steps)
                    if k == 9:  # kill the node the scene's actor runs on
                        actor = ray.get_actor(actor_name(scene.id), namespace=NAMESPACE)
                        node_id = ray.get(actor.node.remote())
                        (node,) = [n for n in cluster_nodes.worker_nodes if n.node_id == node_id]
                        _kill_node(cluster_nodes, node)
            if name == "cluster":  # a new actor, on the node left, took the scene over
                actor = ray.get_actor(actor_name(scene.id), namespace=NAMESPACE)
                assert ray.get(actor.node.remote()) != node_id
                (info,) = list_actors(
                    filters=[("name", "=", actor_name(scene.id)), ("state", "=", "ALIVE")],
                    detail=True,
                )
                assert _environ(info.pid).get("MALLOC_ARENA_MAX") == "1"  # as its replica
            states[name] = state
    assert acknowledged == list(range(5, 105, 5))
    for part in ("positions", "orientations", "velocities", "angular_velocities"):
        got, expected = getattr(states["cluster"], part), getattr(states["alone"], part)
        if scheme == "explicit":
            np.testing.assert_array_equal(got, expected, part)
        else:  # 1 % of a force over 50 steps of 0.5 ms: micrometres, millimetres a second
            tolerance = 1e-5 if part in ("positions", "orientations") else 1e-3
            np.testing.assert_allclose(got, expected, rtol=0, atol=tolerance, err_msg=part)
    cluster_nodes.add_node(num_cpus=2, object_store_memory=10**8)  # for what runs after


def _kill_node(cluster, node) -> None:
    """The node dies as a machine does: every process it runs (the scene's actor, maybe a
    replica) killed at once with its raylet, not told first."""
    raylet = node.all_processes["raylet"][0].process.pid
    for pid in descendants(raylet):
        with contextlib.suppress(ProcessLookupError):
            os.kill(pid, signal.SIGKILL)
    cluster.remove_node(node, allow_graceful=False)


def _nice(pid: int) -> int:
    """The nice value of ``pid`` (``/proc/<pid>/stat``)."""
    return int(Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[16])


def _jsonable(query: dict) -> dict:
    return {k: v.tolist() if isinstance(v, np.ndarray) else v for k, v in query.items()}


def test_a_replica_that_cannot_start_fails_the_deployment_loudly(ray_cluster, tmp_path):
    """A replica's constructor raises (here: no shared store; a kernel compile failure
    raises the same way): Serve reports the application failed, with the reason, instead of
    routing to a replica that is not ready."""
    from ray import serve

    from service.cluster import application
    from service.settings import Settings

    broken = Settings(data_dir=tmp_path / "data")  # SQLite and files: not shareable
    with pytest.raises(RuntimeError, match="Deploying application broken failed"):
        serve.run(application(broken, 1, 0.1), name="broken", route_prefix="/broken")
    status = serve.status().applications["broken"]
    assert status.status == "DEPLOY_FAILED"
    reason = status.deployments["mrdem"].message
    assert "MRDEM_STORE_URL" in reason and "MRDEM_OBJECT_STORE_URL" in reason, reason
    serve.delete("broken")
