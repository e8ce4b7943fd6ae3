"""Scenes on the server: the specification a client sends, the engine scene built from it,
its state as bytes for the store, and the live scenes kept in memory.

A specification is normalised (defaults filled in, arrays as lists) before it is stored,
so a scene rebuilt after a restart is the scene the client created; its latest stepped
state is then restored on top. Rows of the state arrays: the bodies in the order given,
then the planes (fixed).

Body ε: a number in the body's spec is that body's ε (its tree shifted to it); none keeps
the ε the mesh was uploaded with, except for meshes uploaded without one, whose bodies get
``"auto"`` (the engine's default rule, :mod:`engine.trees.halos`: a fixed body takes a tenth of
the smallest free body's ε) when the scene is created (:func:`apply_mesh_defaults`). The
planes' ``"epsilon"``: a number, or none (or ``"auto"``) for the same rule. Mass
properties: ``density`` or ``mass``, with optional ``inertia`` and ``center_of_mass``
(:mod:`engine.dynamics.inertia`).
"""

from __future__ import annotations

import io
import math
import threading
import uuid
from collections import OrderedDict
from dataclasses import dataclass, field

import numpy as np

from engine import AUTO_EPSILON, DEFAULT_SEPARATION_SPEED, EngineError, Scene

from .errors import Conflict, NotFound, ServiceError, Unprocessable
from .models import LAWS, STATE, SceneSummary, StepAnswer
from .store import KeyTaken

__all__ = [
    "LiveScene",
    "LiveScenes",
    "apply_mesh_defaults",
    "build_scene",
    "pack_state",
    "restore_state",
    "state_of",
    "summary_of",
]


def _law_parameters(spec: dict) -> dict:
    return {k: v for k, v in spec["contact_model"].items() if k != "law"}


def apply_mesh_defaults(spec: dict, facts: dict) -> None:
    """Give ``"epsilon": "auto"`` to the bodies whose spec gives no ε and whose mesh was
    uploaded without one (``facts[mesh id]["epsilon_given"]`` False), so that they follow
    the engine's default rule; the stored spec then rebuilds the same scene."""
    for body in spec["bodies"]:
        if body.get("epsilon") is None and not facts[body["mesh"]].get("epsilon_given", True):
            body["epsilon"] = AUTO_EPSILON


_SHAPE_KEYS = ("mesh", "density", "mass", "fixed", "epsilon", "inertia", "center_of_mass")


def build_scene(spec: dict, tree_of, threads: int) -> Scene:
    """The engine scene of a normalised specification; ``tree_of(mesh id)`` gives trees."""
    scene = Scene(
        gravity=spec["gravity"],
        contact_model=LAWS[spec["contact_model"]["law"]](**_law_parameters(spec)),
        scheme=spec["scheme"],
        kernel=spec["kernel"],
        max_halvings=spec["max_halvings"],
        threads=threads,
        substeps=spec.get("substeps", False),
        separation_speed=_separation(spec),
    )
    bodies = spec["bodies"]
    start = 0
    while start < len(bodies):  # runs of like bodies in one call, in order
        b = bodies[start]
        key = [b.get(k) for k in _SHAPE_KEYS]
        stop = start + 1
        while stop < len(bodies) and [bodies[stop].get(k) for k in _SHAPE_KEYS] == key:
            stop += 1
        run = bodies[start:stop]
        try:
            scene.add_bodies(
                tree_of(b["mesh"]),
                [r["position"] for r in run],
                orientations=[r["orientation"] for r in run],
                velocities=[r["velocity"] for r in run],
                angular_velocities=[r["angular_velocity"] for r in run],
                density=b.get("density"),
                mass=b.get("mass"),
                fixed=b["fixed"],
                epsilon=b.get("epsilon"),
                inertia=b.get("inertia"),
                center_of_mass=b.get("center_of_mass"),
            )
        except EngineError as exc:  # e.g. a free open mesh whose hull is flat
            raise Unprocessable(f"bodies[{start}]: {exc}") from None
        start = stop
    for p in spec["planes"]:
        scene.add_plane(p["point"], p["normal"], p["size"], p["divisions"], spec["epsilon"])
    return scene


def _separation(spec: dict) -> float:
    """The engine's ``separation_speed`` of a specification (``inf`` for null; specs
    stored before the setting existed take the default)."""
    speed = spec.get("separation_speed", DEFAULT_SEPARATION_SPEED)
    return math.inf if speed is None else float(speed)


def pack_state(scene: Scene) -> bytes:
    """The scene's state arrays, time and whether its next step starts gently (overlaps
    let go at the separation speed) as ``.npz`` bytes (no pickle)."""
    buffer = io.BytesIO()
    np.savez(
        buffer,
        time=np.float64(scene.time),
        gentle_start=np.bool_(scene.gentle_start),
        **{k: getattr(scene, k) for k in STATE},
    )
    return buffer.getvalue()


def restore_state(scene: Scene, blob: bytes) -> None:
    """Put ``scene`` back in the state of a :func:`pack_state` snapshot: a restore is not a
    change from outside, so the next step starts gently only if it would have."""
    with np.load(io.BytesIO(blob), allow_pickle=False) as data:
        scene.set_state(**{k: data[k] for k in STATE})
        scene.time = float(data["time"])
        scene.gentle_start = bool(data["gentle_start"]) if "gentle_start" in data else False


def state_of(scene: Scene) -> dict:
    return {k: getattr(scene, k).copy() for k in STATE}


def summary_of(scene_id: str, live: LiveScene, overlaps: dict | None = None) -> SceneSummary:
    """The answer describing a scene: its rows, state, mass sources, ε and specification."""
    spec = live.spec
    return SceneSummary(
        id=scene_id,
        bodies=len(spec["bodies"]),
        planes=len(spec["planes"]),
        time=live.scene.time,
        steps=live.steps,
        dt=spec["dt"],
        scheme=spec["scheme"],
        state=state_of(live.scene),
        mass_source=live.scene.mass_source.tolist(),  # mesh | convex_hull | given | fixed
        epsilon=live.scene.epsilon,  # each row's ε, after the default rule
        spec=spec,
        overlaps=overlaps,
    )


@dataclass
class LiveScene:
    """An engine scene in memory, with the lock that serialises its steps and the version
    of the stored state it holds (:meth:`Store.save_state <service.store.Store.save_state>`
    compares and sets it)."""

    scene: Scene
    spec: dict
    steps: int
    version: int = 0
    lock: threading.Lock = field(default_factory=threading.Lock)


class LiveScenes:
    """Scenes kept in memory (least recently used dropped first; the store has them). On a
    store other processes share, a scene in memory is used only while its version is the
    stored one; another replica's step or state makes it rebuild from the store."""

    def __init__(self, store, threads: int, capacity: int = 64) -> None:
        self.store, self.threads, self.capacity = store, threads, capacity
        self._live: OrderedDict[tuple[str, str], LiveScene] = OrderedDict()
        self._lock = threading.Lock()

    def new_id(self) -> str:
        """An id for a scene about to be created (random: a uuid4, 122 random bits)."""
        return uuid.uuid4().hex

    def add(self, owner: str, scene_id: str, live: LiveScene) -> None:
        with self._lock:
            self._live[(owner, scene_id)] = live
            while len(self._live) > self.capacity:
                self._live.popitem(last=False)

    def get(self, owner: str, scene_id: str) -> LiveScene:
        """The live scene (rebuilt from the store when not in memory), or 404."""
        key = (owner, scene_id)
        with self._lock:
            live = self._live.get(key)
            if live is not None:
                self._live.move_to_end(key)
        if live is not None:
            if not self.store.shared:
                return live
            version = self.store.scene_version(owner, scene_id)
            if version is None:
                self.drop(owner, scene_id)
                raise NotFound(f"no scene {scene_id!r}")
            if version == live.version:
                return live
        stored = self.store.scene_row(owner, scene_id)
        if stored is None:
            raise NotFound(f"no scene {scene_id!r}")
        spec, blob, steps, version = stored
        scene = build_scene(spec, self.store.tree, self.threads)
        restore_state(scene, blob)
        live = LiveScene(scene, spec, steps, version)
        self.add(owner, scene_id, live)
        return live

    def saved(
        self, owner: str, scene_id: str, live: LiveScene, state: bytes, steps: int, remember=None
    ) -> None:
        """Store ``live``'s new state (``steps`` in all, with an idempotency key's row) if
        the stored state is still the one ``live`` holds, and count its version up
        (``live.lock`` held). Otherwise nothing is stored, the copy in memory is dropped
        and 404 (the scene is gone) or 409 (another request changed it meanwhile) raised;
        :class:`~service.store.KeyTaken` as :meth:`~service.store.Store.save_state`."""
        if self.store.save_state(owner, scene_id, state, steps, remember, after=live.version):
            live.version += 1
            live.steps = steps
            return
        self.drop(owner, scene_id)
        if self.store.scene_version(owner, scene_id) is None:
            raise NotFound(f"no scene {scene_id!r}")
        raise Conflict(
            f"scene {scene_id!r} was stepped or changed by another request while this one"
            " ran; nothing was stored: send this request again",
            {"Retry-After": "0"},
        )

    def drop(self, owner: str, scene_id: str) -> None:
        with self._lock:
            self._live.pop((owner, scene_id), None)

    def close(self) -> None:
        """The scenes in memory dropped (the app stops; the store keeps them)."""
        with self._lock:
            self._live.clear()

    # the operations of the routes (blocking: run them in a worker thread); a cluster's
    # scene actors offer the same three (service.cluster.scenes)
    def summary(self, owner: str, scene_id: str) -> SceneSummary:
        """The scene's answer, or 404."""
        return summary_of(scene_id, self.get(owner, scene_id))

    def put_state(self, owner: str, scene_id: str, new: dict) -> SceneSummary:
        """Overwrite the state arrays in ``new`` (each ``(n, k)``, n: bodies then planes),
        store the state, and answer the scene with the overlaps the new poses make (None
        when no pose changed); 404, 409, or 422 for arrays of the wrong length."""
        live = self.get(owner, scene_id)
        n = len(live.scene)
        for name, value in new.items():
            if len(value) != n:
                shape = f"({n}, {value.shape[1]})"
                message = f"must have shape {shape} (bodies, then planes), got {list(value.shape)}"
                raise Unprocessable(
                    f"{name} {message}", errors=[{"path": name, "message": message}]
                )
        with live.lock:
            before = pack_state(live.scene)
            report = live.scene.set_state(**new)
            try:
                self.saved(owner, scene_id, live, pack_state(live.scene), live.steps)
            except ServiceError:
                restore_state(live.scene, before)
                raise
            overlaps = None
            if report is not None:
                overlaps = {"pairs": report.pairs.tolist(), "largest": report.largest}
            return summary_of(scene_id, live, overlaps)

    def step(self, owner: str, scene_id: str, steps: int, dt: float | None, key=None):
        """Take ``steps`` steps of ``dt`` (None: the scene's) and store the new state (with
        the answer under the idempotency ``key``, :class:`~service.store.Key`, in
        the same transaction): ``(answer, each step's statistics)``, or ``(None, …)`` when
        another process stored the key meanwhile (nothing stored: answer the stored one).
        A step leaving a non-finite state undoes the request (422)."""
        live = self.get(owner, scene_id)
        dt = live.spec["dt"] if dt is None else dt
        with live.lock:
            scene = live.scene
            before = pack_state(scene)
            stats = []
            for k in range(steps):
                stats.append(scene.step(dt))
                if not all(np.isfinite(a).all() for a in state_of(scene).values()):
                    restore_state(scene, before)
                    raise Unprocessable(
                        f"step {k + 1} of {steps} left a non-finite state (the simulation"
                        " diverged); the scene keeps the state it had before this"
                        " request. Try a smaller dt or a softer contact model"
                    )
            answer = StepAnswer(
                id=scene_id,
                time=scene.time,
                steps=live.steps + steps,
                state=state_of(scene),
                stats=stats,
            )
            remember = None if key is None else key.remember(200, answer.model_dump())
            try:
                self.saved(owner, scene_id, live, pack_state(scene), live.steps + steps, remember)
            except KeyTaken:  # stored by a request in another process meanwhile
                restore_state(scene, before)
                return None, stats
            except ServiceError:  # the scene is gone, or changed by another replica
                restore_state(scene, before)
                raise
            return answer, stats
