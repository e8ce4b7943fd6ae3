"""Scenes as Ray actors: each scene lives in an actor named by its id, which keeps
the engine scene (and its warm starts) between step requests, and stores the state on every
acknowledged step (:meth:`LiveScenes.saved <service.scenes.LiveScenes.saved>`, compare and
set). Any replica reaches a scene's actor by name; when the actor is gone (its node died,
or it was idle for ``MRDEM_SCENE_IDLE`` seconds and left), the next request creates it again
and it rebuilds the scene from the last stored state — what a restart of the embedded
service does.

An actor is a process: a live scene costs one (with its kernels loaded) while it is used.
So one is made only for a scene in the store (an unknown id is a 404 from the replica), and
one whose scene is gone from the store leaves after its 404.

Starting an actor takes seconds (a process, the imports, the store opened, Numba's first
dispatch and the scene's kernels loaded: a scene's first step took 2.1–2.2 s on a 2-vCPU
VM, its next ones 15–23 ms, measured). So ``MRDEM_SCENE_SPARES`` actors are started ahead
for the next new scenes, their kernels loaded (:func:`engine.warm_scene`), each named by an
id no scene has yet, and held by one :class:`SparePool` that every replica of the
deployment shares (a detached actor of no CPUs: however many replicas Serve adds under
load, the spares stay that many). The next new scene, through any replica, takes one's id
(:meth:`ActorScenes.new_id`), the spare loads the scene as soon as it is stored
(:meth:`ActorScenes.add`), and its first step finds its actor running (0.05–0.08 s,
measured, against 2 s). The pool is made, and starts its spares, on the first scene's
creation: a deployment that creates no scenes holds no spare (their CPUs stay free for
tasks and replicas). A spare not taken leaves after ``MRDEM_SCENE_IDLE`` seconds, as any idle
actor, and the pool, with its spares, after as long without a scene created.
"""

from __future__ import annotations

import contextlib
import hashlib
import threading
import time
import uuid
from collections import OrderedDict

import ray
from ray.exceptions import (
    ActorDiedError,
    ActorUnavailableError,
    GetTimeoutError,
    RayActorError,
    RayTaskError,
)

import engine

from ..errors import NotFound, Unavailable
from ..scenes import LiveScenes
from ..settings import Settings
from ..store import Store, open_store

__all__ = ["ActorScenes", "SceneActor", "SparePool", "actor_name", "pool_name"]

NAMESPACE = "mrdem"
HANDLES = 4096  # scene actors' handles a replica keeps (least recently used dropped)
LEAVE_AFTER = 0.5  # seconds an actor whose scene is gone waits to leave (its 404 sent)
SPARE_CHECK = 0.1  # seconds to wait for an actor's answer before it counts as starting
SPARE_WAIT = 0.5  # seconds a replica waits for the pool's spare (longer: none this time)
_GONE = (ActorDiedError, ActorUnavailableError)


def actor_name(scene_id: str) -> str:
    """The actor's name: the scene's id (random, made by the service: two owners' scenes
    never share one; an actor serves only its scene's owner, :meth:`SceneActor.call`)."""
    return f"scene-{scene_id}"


class SceneActor:
    """One scene in its own process: a :class:`LiveScenes` over the shared store, used
    serially (one call at a time), for the scene's ``owner`` (None: the first whose call
    finds the scene). Leaves after ``idle`` seconds without a call. A spare (``warm``)
    loads the kernels of a scene's steps first (:func:`engine.warm_scene`)."""

    def __init__(
        self, settings: Settings, idle: float, owner: str | None = None, warm: bool = False
    ) -> None:
        self.store = open_store(settings)
        self.scenes = LiveScenes(self.store, settings.engine_threads, capacity=1)
        self.owner = owner
        if warm:
            engine.warm_scene()
        self.idle, self.last = idle, time.monotonic()
        if idle > 0:
            threading.Thread(target=self._leave_when_idle, daemon=True).start()

    def _leave(self) -> None:
        self.store.close()
        ray.kill(ray.get_runtime_context().current_actor, no_restart=True)

    def _leave_when_idle(self) -> None:
        while True:
            time.sleep(min(self.idle, 5.0))
            if time.monotonic() - self.last > self.idle:
                self._leave()
                return

    def call(self, method: str, owner: str, scene_id: str, *args):
        """``LiveScenes.<method>(owner, scene_id, *args)`` (summary, put_state, step). An
        actor whose owner's scene is not there (deleted meanwhile: 404) leaves right after
        answering: it is there for that scene alone. Another owner's 404 changes nothing."""
        self.last = time.monotonic()
        try:
            answer = getattr(self.scenes, method)(owner, scene_id, *args)
        except NotFound:
            if owner == self.owner:
                threading.Timer(LEAVE_AFTER, self._leave).start()  # its answer sent first
            raise
        finally:
            self.last = time.monotonic()
        self.owner = owner  # the scene was found: it is this owner's
        return answer

    def load(self, owner: str, scene_id: str) -> None:
        """The scene built from the store ahead of its first request (a spare just taken
        for it): as :meth:`call` does for any, but without an answer to send."""
        with contextlib.suppress(NotFound):  # deleted meanwhile: the actor leaves (call)
            self.call("get", owner, scene_id)

    def node(self) -> str:
        """The id of the Ray node this actor runs on (a call: the actor is not idle)."""
        self.last = time.monotonic()
        return ray.get_runtime_context().get_node_id()


def pool_name(actor_settings: Settings, cpus: float, idle: float, spares: int) -> str:
    """The name of the spare pool of replicas whose scenes' actors are made alike (the same
    store, CPUs, idle time, spares): one deployment's replicas share one; another
    deployment on the cluster, over another store say, has its own."""
    made = f"{actor_settings.model_dump_json()}\0{cpus}\0{idle}\0{spares}"
    return f"spares-{hashlib.blake2b(made.encode(), digest_size=8).hexdigest()}"


class SparePool:
    """Spare scene actors for the replicas of a deployment: :meth:`take` hands one out (its
    scene id and actor) and starts others up to ``count``, one call at a time (an actor:
    two replicas never take the same spare). Leaves, withdrawing its spares, after
    ``idle`` seconds without a :meth:`take`; a spare not taken leaves on its own after
    ``idle`` seconds, and is not handed out then."""

    def __init__(self, actor_settings: Settings, cpus: float, idle: float, count: int) -> None:
        self.actor_settings, self.cpus, self.idle, self.count = actor_settings, cpus, idle, count
        self._remote = ray.remote(SceneActor)
        self._spares: list[tuple[str, object]] = []  # (scene id, actor), oldest first
        self._lock = threading.Lock()  # the idle thread and the calls
        self.last = time.monotonic()
        if idle > 0:
            threading.Thread(target=self._leave_when_idle, daemon=True).start()

    def take(self, until: float) -> tuple[str, object] | None:
        """A running (or starting) spare's ``(scene id, actor)``, or None (none yet, or each
        has left or died with its node, or the call came after ``until``, a ``time.time()``
        past which the replica no longer waits: a spare is not handed to no one); spares
        then started up to ``count``."""
        self.last = time.monotonic()
        taken = None
        while taken is None and time.time() < until:
            with self._lock:
                if not self._spares:
                    break
                candidate = self._spares.pop(0)
            if _alive(candidate[1]):
                taken = candidate
        with self._lock:
            while len(self._spares) < self.count:
                spare = uuid.uuid4().hex
                self._spares.append((spare, self._create(spare)))
        self.last = time.monotonic()
        return taken

    def held(self) -> list[str]:
        """The scene ids of the spares held now (some may have left since)."""
        with self._lock:
            return [spare for spare, _ in self._spares]

    def _create(self, spare: str):
        return self._remote.options(
            name=actor_name(spare),
            namespace=NAMESPACE,
            get_if_exists=True,
            lifetime="detached",  # not tied to the pool: a taken spare is a scene's actor
            num_cpus=self.cpus,
            max_restarts=0,
        ).remote(self.actor_settings, self.idle, None, True)

    def _leave_when_idle(self) -> None:
        while True:
            time.sleep(min(self.idle, 5.0))
            if time.monotonic() - self.last > self.idle:
                with self._lock:
                    spares, self._spares = self._spares, []
                for _, handle in spares:
                    with contextlib.suppress(RayActorError):  # gone already
                        ray.kill(handle, no_restart=True)
                ray.kill(ray.get_runtime_context().current_actor, no_restart=True)
                return


class ActorScenes:
    """What a replica's routes use in place of :class:`LiveScenes`: the same operations,
    each a call to the scene's actor (created when missing, again when it died)."""

    def __init__(
        self,
        store: Store,
        settings: Settings,
        cpus: float = 1.0,
        idle: float = 600.0,
        spares: int = 0,
    ) -> None:
        self.store, self.cpus, self.idle, self.spares = store, cpus, idle, spares
        self.start = settings.scene_start  # seconds a new actor may wait for CPUs
        threads = max(1, int(round(cpus)))
        self.actor_settings = settings.model_copy(
            update={"engine_threads": threads, "engine_concurrency": 1, "warmup": False}
        )
        self._remote = ray.remote(SceneActor)
        self._handles: OrderedDict[str, object] = OrderedDict()  # actor name → handle
        self._lock = threading.Lock()
        self.recreate_for = 120.0  # seconds a call goes on recreating a scene's dead actor
        self.pool = pool_name(self.actor_settings, cpus, idle, spares)  # the spares' holder
        self._pool_handle = None
        self._pool_answer = None  # the pool's first answer to this replica, until it came
        self._taken: OrderedDict[str, object] = OrderedDict()  # spares handed out: id → actor

    def new_id(self) -> str:
        """The id of a scene about to be created: a spare's from the deployment's pool (its
        actor running, or starting), else a random one (no spare yet; or each has left,
        idle, or died with its node; or the pool is starting, or could not be reached)."""
        if self.spares <= 0:
            return uuid.uuid4().hex
        taken = None
        for _ in range(2):  # a pool that died (with its node) is made again, once
            pool = self._spare_pool()
            if pool is None:  # not answered yet (starting, its spares too): not waited for
                break
            try:
                until = time.time() + SPARE_WAIT / 2  # after that, the pool hands none
                taken = ray.get(pool.take.remote(until), timeout=SPARE_WAIT)
                break
            except _GONE:
                with self._lock:
                    self._pool_handle = self._pool_answer = None
            except GetTimeoutError:  # busy: none this time
                break
        if taken is None:
            return uuid.uuid4().hex
        scene_id, handle = taken
        with self._lock:  # its scene's add() hands it the scene to load
            self._taken[scene_id] = handle
            while len(self._taken) > HANDLES:  # scenes never added (a replayed key)
                self._taken.popitem(last=False)
        return scene_id

    def _spare_pool(self):
        """The deployment's :class:`SparePool` once it has answered this replica, else None:
        the first call gets the pool (made by the first replica that asks) and asks it to
        start its spares (``take`` of nothing), waiting ``SPARE_CHECK`` seconds for a pool
        that runs already, not for one to start (a process: seconds)."""
        with self._lock:
            wait = 0.0
            if self._pool_handle is None:
                self._pool_handle = self._make_pool()
                self._pool_answer = self._pool_handle.take.remote(0.0)
                wait = SPARE_CHECK
            if self._pool_answer is not None:
                done, _ = ray.wait([self._pool_answer], timeout=wait)
                if not done:
                    return None
                self._pool_answer = None  # answered (or died: the next take finds out)
            return self._pool_handle

    def _make_pool(self):
        return (
            ray.remote(SparePool)
            .options(
                name=self.pool,
                namespace=NAMESPACE,
                get_if_exists=True,
                lifetime="detached",  # shared by the replicas, not tied to one
                num_cpus=0,
                max_restarts=0,  # one that died is made again by the next replica that asks
            )
            .remote(self.actor_settings, self.cpus, self.idle, self.spares)
        )

    def close(self) -> None:
        """Nothing to withdraw: the scenes' actors stay, and the spares are the pool's
        (shared by the deployment's replicas; they leave when idle)."""

    def actor(self, owner: str, scene_id: str):
        """The scene's actor (the handle this replica holds; else found by name, or created
        for a scene in the store — :class:`NotFound` for one that is not: an actor is a
        process, and would stay until idle for ``MRDEM_SCENE_IDLE`` seconds)."""
        name = actor_name(scene_id)
        with self._lock:
            if name in self._handles:
                self._handles.move_to_end(name)
                return self._handles[name]
        try:
            handle = ray.get_actor(name, namespace=NAMESPACE)
        except ValueError:  # none alive: created, if there is such a scene
            if self.store.scene_version(owner, scene_id) is None:
                raise NotFound(f"no scene {scene_id!r}") from None
            handle = self._create(name, owner)
        self._started(handle)
        with self._lock:
            self._handles[name] = handle
            while len(self._handles) > HANDLES:
                self._handles.popitem(last=False)
        return handle

    def _started(self, handle) -> None:
        """Once ``handle``'s actor runs; :class:`Unavailable` (503) when it has waited
        ``MRDEM_SCENE_START`` seconds for CPUs (every CPU held by other scenes' actors,
        replicas, tasks): the actor is withdrawn, not left to start later unasked."""
        try:
            ray.get(handle.node.remote(), timeout=self.start)
        except GetTimeoutError:
            ray.kill(handle, no_restart=True)
            raise Unavailable(
                f"the scene's actor ({self.cpus:g} CPUs) did not start within"
                f" {self.start:g} s: most likely no node has that many CPUs free (other"
                f" scenes hold theirs until idle for {self.idle:g} s; replicas and tasks"
                " too); delete the scenes you no longer step (DELETE /v1/scenes/{id}), or"
                " retry later",
                {"Retry-After": "10"},
            ) from None

    def _create(self, name: str, owner: str):
        """The actor named ``name``, created (or the one another replica created just
        before) for ``owner``'s scene."""
        return self._remote.options(
            name=name,
            namespace=NAMESPACE,
            get_if_exists=True,
            lifetime="detached",  # not tied to the replica that made it
            num_cpus=self.cpus,
            max_restarts=0,  # a dead actor is recreated by the next request, from the store
        ).remote(self.actor_settings, self.idle, owner)

    def _forget(self, scene_id: str) -> None:
        with self._lock:
            self._handles.pop(actor_name(scene_id), None)

    def _call(self, owner: str, scene_id: str, method: str, *args):
        deadline = time.monotonic() + self.recreate_for
        pause = 0.05
        while True:
            try:
                actor = self.actor(owner, scene_id)
                return ray.get(actor.call.remote(method, owner, scene_id, *args))
            except RayTaskError as exc:  # the scene's own answer: 404, 409, 422 …
                raise exc.cause from None
            except _GONE:  # its node died or it left: the next actor loads the stored state
                self._forget(scene_id)
                if time.monotonic() > deadline:
                    raise
            time.sleep(pause)
            pause = min(1.0, pause * 2)

    def summary(self, owner: str, scene_id: str):
        return self._call(owner, scene_id, "summary")

    def put_state(self, owner: str, scene_id: str, new: dict):
        return self._call(owner, scene_id, "put_state", new)

    def step(self, owner: str, scene_id: str, steps: int, dt, key=None):
        return self._call(owner, scene_id, "step", steps, dt, key)

    def add(self, owner: str, scene_id: str, live) -> None:
        """A new scene, stored: a spare's (:meth:`new_id`) starts loading it now, while the
        answer goes back to the client (its first request then finds the actor as any
        other: :meth:`actor`); any other scene's actor is made, and loads it, on its first
        request."""
        with self._lock:
            handle = self._taken.pop(scene_id, None)
        if handle is not None:  # not waited for: the actor takes calls one after another
            handle.load.remote(owner, scene_id)

    def drop(self, owner: str, scene_id: str) -> None:
        """The scene was deleted: its actor goes."""
        self._forget(scene_id)
        try:
            actor = ray.get_actor(actor_name(scene_id), namespace=NAMESPACE)
        except ValueError:  # no such actor
            return
        ray.kill(actor, no_restart=True)


def _alive(handle) -> bool:
    """Whether ``handle``'s actor is alive: it answers within ``SPARE_CHECK`` seconds, or is
    still starting (no answer yet, no failure)."""
    answer = handle.node.remote()
    done, _ = ray.wait([answer], timeout=SPARE_CHECK)
    if not done:
        return True
    try:
        ray.get(answer)
    except RayActorError:
        return False
    return True
