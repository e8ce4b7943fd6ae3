"""service/cluster/scenes.py on a real Ray cluster: scenes' actors made only for scenes in
the store, leaving when their scene is gone, withdrawn when they find no CPUs, and the spares
started when a scene is created, held by a pool the replicas share, so that the next
scene's first step finds its actor running."""

from __future__ import annotations

import contextlib
import threading
import time
import uuid

import httpx
import pytest

from clients import Client
from engine import shapes

pytestmark = pytest.mark.cluster


def _upload(client: Client, mesh) -> str:
    return client.upload_mesh(mesh, epsilon=0.05).id


def _states(name: str) -> set[str]:
    """The states of the actors named ``name`` (Ray's state API; none: an empty set)."""
    from ray.util.state import list_actors

    return {a.state for a in list_actors(filters=[("name", "=", name)], limit=10_000)}


def _until_dead(name: str, why: str = "the actor stayed", seconds: float = 10.0) -> None:
    deadline = time.monotonic() + seconds
    while _states(name) - {"DEAD"}:
        assert time.monotonic() < deadline, why
        time.sleep(0.2)


def _until_alive(name: str, seconds: float = 60.0) -> None:
    """Until the actor named ``name`` runs (a start takes seconds on a busy machine)."""
    deadline = time.monotonic() + seconds
    while _states(name) != {"ALIVE"}:
        assert time.monotonic() < deadline, (name, _states(name))
        time.sleep(0.2)


def _scene(client: Client):
    """A one-body scene made through ``client``."""
    mesh = _upload(client, shapes.icosphere(1))
    return client.create_scene(bodies=[{"mesh": mesh, "position": [0, 0, 1]}], dt=1e-3)


def test_an_unknown_scene_is_answered_404_without_an_actor(ray_cluster):
    """A scene id that is not in the store is answered 404 by the replica and starts no
    actor: an actor is a process, and one made for an unknown id stayed until idle
    (``MRDEM_SCENE_IDLE``, 600 s) — four such requests held every CPU this cluster's nodes
    had for scenes, and the next one waited."""
    from ray.util.state import list_actors

    from service.cluster import actor_name

    _, url, _ = ray_cluster
    unknown = [uuid.uuid4().hex for _ in range(8)]
    for scene_id in unknown:
        for method, path, body in (("GET", "", None), ("POST", "/step", {"steps": 1})):
            response = httpx.request(
                method, f"{url}/v1/scenes/{scene_id}{path}", json=body, timeout=30
            )
            assert response.status_code == 404, response.text
            problem = response.json()
            assert problem["status"] == 404 and scene_id in problem["detail"], problem
    names = {actor_name(scene_id) for scene_id in unknown}
    assert not [a for a in list_actors(limit=10_000) if a.name in names]


def test_a_scene_actor_whose_scene_is_gone_leaves(ray_cluster):
    """An actor whose scene was removed from the store behind it (another replica's
    DELETE reached the store, not the actor) answers 404 and leaves, instead of staying
    until idle."""
    import ray

    from service.cluster import NAMESPACE, actor_name
    from service.store import open_store

    _, url, settings = ray_cluster
    with Client(url) as client:
        scene = _scene(client)
        scene.step(1)  # its actor made (or a spare's, in use)
    actor = ray.get_actor(actor_name(scene.id), namespace=NAMESPACE)
    store = open_store(settings)
    try:
        assert store.delete_scene("", scene.id)
    finally:
        store.close()
    response = httpx.post(f"{url}/v1/scenes/{scene.id}/step", json={"steps": 1}, timeout=30)
    assert response.status_code == 404, response.text
    deadline = time.monotonic() + 10
    while True:
        try:
            ray.get(actor.node.remote(), timeout=5)
        except ray.exceptions.RayActorError:
            break  # gone
        assert time.monotonic() < deadline, "the actor stayed"
        time.sleep(0.2)


def test_a_scene_whose_actor_finds_no_cpus_is_answered_503_and_the_actor_withdrawn(ray_cluster):
    """A scene's new actor that waits ``MRDEM_SCENE_START`` seconds for CPUs (here: more
    than any node has) makes the request a 503 that says what to do, and is withdrawn — not
    left to start later, unasked (a request used to wait for as long as it took)."""
    import ray

    from service.cluster import ActorScenes, actor_name
    from service.errors import Unavailable
    from service.store import open_store

    _, url, settings = ray_cluster
    with Client(url) as client:
        scene = _scene(client)
    name = actor_name(scene.id)
    with contextlib.suppress(ValueError):  # its actor (a spare's) gone, as when a node dies
        ray.kill(ray.get_actor(name))
    _until_dead(name)
    store = open_store(settings)
    scenes = ActorScenes(store, settings.model_copy(update={"scene_start": 2.0}), cpus=64)
    raised: list[Exception] = []

    def step() -> None:
        try:
            scenes.step("", scene.id, 1, None)
        except Exception as error:  # noqa: BLE001 - checked below
            raised.append(error)

    request = threading.Thread(target=step, daemon=True)
    request.start()
    request.join(timeout=30)
    try:
        assert not request.is_alive(), "the request waited on for CPUs"
    finally:
        if request.is_alive():
            ray.kill(ray.get_actor(name))
        store.close()
    (error,) = raised
    assert isinstance(error, Unavailable), error
    assert "the scene's actor (64 CPUs) did not start within 2 s" in str(error)
    assert "DELETE /v1/scenes/{id}" in str(error)
    assert error.headers == {"Retry-After": "10"}
    _until_dead(name, "the actor was left waiting")
    with pytest.raises(ValueError):
        ray.get_actor(name)


def _loaded(name: str, seconds: float = 30.0) -> None:
    """Until the actor named ``name`` has run a ``load`` (Ray's state API hears late)."""
    from ray.util.state import list_actors, list_tasks

    (actor,) = list_actors(filters=[("name", "=", name)], limit=10)
    filters = [("actor_id", "=", actor.actor_id), ("name", "=", "SceneActor.load")]
    deadline = time.monotonic() + seconds
    while "FINISHED" not in {t.state for t in list_tasks(filters=filters, limit=100)}:
        assert time.monotonic() < deadline, f"{name} was not handed its scene to load"
        time.sleep(0.2)


def _until_a_pool_holds_a_spare(seconds: float = 60.0) -> None:
    """Until a pool of spares (:class:`SparePool`) runs and holds one."""
    import ray
    from ray.util.state import list_actors

    from service.cluster import NAMESPACE

    deadline = time.monotonic() + seconds
    while True:
        filters = [("class_name", "=", "SparePool"), ("state", "=", "ALIVE")]
        for pool in list_actors(filters=filters, limit=100):
            with contextlib.suppress(ValueError):  # left meanwhile
                if ray.get(ray.get_actor(pool.name, namespace=NAMESPACE).held.remote()):
                    return
        assert time.monotonic() < deadline, "no pool of spares holds one"
        time.sleep(0.2)


def test_a_new_scene_takes_an_actor_started_before_it(ray_cluster):
    """The first scene made starts a spare actor for the next (``MRDEM_SCENE_SPARES``, held
    by the replicas' pool): of two scenes made then through two replicas, one takes a
    spare's id — its actor exists before any request for the scene — loads the scene before
    such a request, and answers its first step."""
    import ray

    from service.cluster import NAMESPACE, actor_name

    _, url, _ = ray_cluster
    with Client(url) as client:
        made = [_scene(client)]
        _until_a_pool_holds_a_spare()  # started by the first scene's creation
        made += [_scene(client) for _ in range(2)]
        taken = []
        for scene in made:
            with contextlib.suppress(ValueError):  # none: the scene's actor comes with a request
                ray.get_actor(actor_name(scene.id), namespace=NAMESPACE)
                taken.append(scene)
        assert taken, "no scene took a spare"
        for scene in taken:
            _loaded(actor_name(scene.id))  # handed the scene when it was created
            assert scene.step(1).steps == 1
        for scene in made:
            scene.delete()  # their actors too: the CPUs back for the tests after


def _held(pool: str, count: int, seconds: float = 60.0) -> list[str]:
    """The scene ids of the spares the pool named ``pool`` holds, once it holds ``count``."""
    import ray

    from service.cluster import NAMESPACE

    deadline = time.monotonic() + seconds
    while True:
        with contextlib.suppress(ValueError):  # no such actor yet
            held = ray.get(ray.get_actor(pool, namespace=NAMESPACE).held.remote(), timeout=30)
            if len(held) == count:
                return held
        assert time.monotonic() < deadline, f"the pool does not hold {count} spare(s)"
        time.sleep(0.2)


def test_the_replicas_share_their_spares_which_leave_when_idle(ray_cluster):
    """Spares are started when a scene is first created (none before: no CPUs held by a
    deployment that makes no scenes) and held by one pool that the deployment's replicas
    share: through two replicas' scenes there is still one spare (``spares=1``), and the
    other replica's next scene takes the spare the first one's started. One that has left
    is not handed out. The pool, idle, leaves and withdraws its spare."""
    import ray

    from service.cluster import NAMESPACE, ActorScenes, actor_name
    from service.store import open_store

    _, _, settings = ray_cluster
    store = open_store(settings)
    one, two = (
        ActorScenes(store, settings, settings.scene_cpus, idle=5.0, spares=1) for _ in range(2)
    )
    try:
        assert one.pool == two.pool  # the same deployment's replicas
        assert _states(one.pool) == set()  # no pool, no spare: no scene made yet
        cold = one.new_id()
        assert _states(actor_name(cold)) == set()  # no spare yet: an id of no actor
        (spare,) = _held(one.pool, 1)  # started for the next scene
        _until_alive(actor_name(spare))
        taken = two.new_id()  # through the other replica
        if taken != spare:  # its first call waits 0.1 s for the pool: a loaded machine
            taken = two.new_id()
        assert taken == spare
        (left,) = _held(one.pool, 1)  # one again, not one a replica
        _until_alive(actor_name(left))
        ray.kill(ray.get_actor(actor_name(left), namespace=NAMESPACE), no_restart=True)
        _until_dead(actor_name(left))
        assert one.new_id() not in (left, spare)  # gone: not handed out (and a fresh id)
        (last,) = _held(one.pool, 1)
        _until_dead(one.pool, "the pool outlived its idle time", seconds=30)
        _until_dead(actor_name(last), "a spare outlived its pool", seconds=30)
    finally:
        store.close()


def test_another_owner_s_request_leaves_a_scene_s_actor_in_place(ray_cluster):
    """An actor serves its scene's owner: another owner's request for the same id is a 404
    (the store has no such scene of theirs), and the actor stays for its own."""
    import ray

    from service.cluster import NAMESPACE, actor_name
    from service.cluster.scenes import LEAVE_AFTER
    from service.errors import NotFound

    _, url, _ = ray_cluster
    with Client(url) as client:
        scene = _scene(client)
        assert scene.step(1).steps == 1
        actor = ray.get_actor(actor_name(scene.id), namespace=NAMESPACE)
        node = ray.get(actor.node.remote())
        with pytest.raises(ray.exceptions.RayTaskError) as raised:
            ray.get(actor.call.remote("summary", "another-owner", scene.id))
        assert isinstance(raised.value.cause, NotFound)
        time.sleep(LEAVE_AFTER + 1.0)
        assert ray.get(actor.node.remote(), timeout=10) == node, "the actor left"
        assert scene.step(1).steps == 2
        scene.delete()
