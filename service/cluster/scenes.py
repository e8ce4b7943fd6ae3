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
VM, its next ones 15–23 ms, measured). So a replica that creates a scene starts
``MRDEM_SCENE_SPARES`` actors ahead for its next ones, their kernels loaded
(:func:`engine.warm_scene`), each named by an id no scene has yet; the next new scene takes
one's id (:meth:`ActorScenes.new_id`), the spare loads the scene as soon as it is stored
(:meth:`ActorScenes.add`), and its first step finds its actor running (0.05–0.08 s,
measured, against 2 s). A spare not taken leaves after ``MRDEM_SCENE_IDLE`` seconds, as any idle
actor: a deployment that creates no scenes holds no spare (their CPUs stay free for tasks
and replicas), and a replica gone leaves none behind for long.
"""

from __future__ import annotations

import contextlib
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

__all__ = ["ActorScenes", "SceneActor", "actor_name"]

NAMESPACE = "mrdem"
HANDLES = 4096  # scene actors' handles a replica keeps (least recently used dropped)
LEAVE_AFTER = 0.5  # seconds an actor whose scene is gone waits to leave (its 404 sent)
SPARE_CHECK = 0.1  # seconds a replica waits for a spare's answer before it counts as starting
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
        self._spares: list[tuple[str, object]] = []  # (scene id, actor), started ahead
        self._taken: OrderedDict[str, object] = OrderedDict()  # spares handed out: id → actor
        self._closed = False

    def new_id(self) -> str:
        """The id of a scene about to be created: a spare's (its actor running, or starting),
        else a random one (no spare yet; or each has left, idle, or died with its node);
        spares then started up to ``spares`` for the next scenes."""
        scene_id = None
        while scene_id is None:
            with self._lock:
                if not self._spares:
                    break
                candidate, handle = self._spares.pop(0)
            if _alive(handle):
                scene_id = candidate
        with self._lock:
            if scene_id is not None:  # its scene's add() hands it the scene to load
                self._taken[scene_id] = handle
                while len(self._taken) > HANDLES:  # scenes never added (a replayed key)
                    self._taken.popitem(last=False)
            while len(self._spares) < self.spares and not self._closed:
                spare = uuid.uuid4().hex
                self._spares.append((spare, self._create(actor_name(spare), warm=True)))
        return scene_id or uuid.uuid4().hex

    def close(self) -> None:
        """The spares withdrawn (the replica stops); the scenes' actors stay."""
        with self._lock:
            self._closed = True
            spares, self._spares = self._spares, []
        for _, handle in spares:
            with contextlib.suppress(RayActorError):  # gone already
                ray.kill(handle, no_restart=True)

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

    def _create(self, name: str, owner: str | None = None, warm: bool = False):
        """The actor named ``name``, created (or the one another replica created just
        before) for ``owner``'s scene (None: a spare, see :class:`SceneActor`)."""
        return self._remote.options(
            name=name,
            namespace=NAMESPACE,
            get_if_exists=True,
            lifetime="detached",  # not tied to the replica that made it
            num_cpus=self.cpus,
            max_restarts=0,  # a dead actor is recreated by the next request, from the store
        ).remote(self.actor_settings, self.idle, owner, warm)

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
