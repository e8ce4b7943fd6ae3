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
from collections import OrderedDict
from dataclasses import dataclass, field

import numpy as np

from engine import (
    DEFAULT_SCHEME,
    DEFAULT_SEPARATION_SPEED,
    SCHEMES,
    EngineError,
    HertzSpring,
    LinearSpring,
    PaperSpring,
    Scene,
)
from engine.arguments import KERNELS
from engine.dynamics.inertia import check_inertia
from engine.trees.halos import AUTO

from .errors import NotFound, Unprocessable
from .inputs import array, choice, flag, number, quaternion
from .inputs import field as member

__all__ = [
    "LAWS",
    "STATE",
    "LiveScene",
    "LiveScenes",
    "apply_mesh_defaults",
    "build_scene",
    "pack_state",
    "parse_spec",
    "restore_state",
    "state_of",
]

LAWS = {"paper": PaperSpring, "linear": LinearSpring, "hertz": HertzSpring}
STATE = ("positions", "orientations", "velocities", "angular_velocities")
MAX_DT = 1.0


def parse_spec(body, max_bodies: int) -> dict:
    """The normalised specification of ``POST /v1/scenes`` (422 naming any bad field)."""
    if not isinstance(body, dict):
        raise Unprocessable("body must be an object")
    bodies = body.get("bodies", [])
    planes = body.get("planes", [])
    if not isinstance(bodies, list) or not isinstance(planes, list):
        raise Unprocessable("bodies and planes must be lists")
    if not bodies:
        raise Unprocessable("a scene needs at least one body")
    if len(bodies) + len(planes) > max_bodies:
        raise Unprocessable(
            f"{len(bodies) + len(planes):,} bodies and planes; this service takes <= {max_bodies:,}"
        )
    law = body.get("contact_model", {})
    if not isinstance(law, dict):
        raise Unprocessable("contact_model must be an object")
    spec = {
        "bodies": [_body(b, f"bodies[{i}]") for i, b in enumerate(bodies)],
        "planes": [_plane(p, f"planes[{i}]") for i, p in enumerate(planes)],
        "gravity": array(body.get("gravity", [0.0, 0.0, -9.81]), "gravity", (3,)).tolist(),
        "epsilon": _epsilon(body.get("epsilon"), "epsilon"),
        "dt": number(body.get("dt", 1e-3), "dt", 1e-12, MAX_DT),
        "scheme": choice(body.get("scheme", DEFAULT_SCHEME), "scheme", SCHEMES),
        "kernel": choice(body.get("kernel", "hybrid"), "kernel", KERNELS),
        "max_halvings": number(body.get("max_halvings", 0), "max_halvings", 0, 8, integer=True),
        "substeps": flag(body.get("substeps", False), "substeps"),
        # null: no gentle start (overlaps pushed apart at once)
        "separation_speed": _speed(body.get("separation_speed", DEFAULT_SEPARATION_SPEED)),
        "contact_model": {
            "law": choice(law.get("law", "paper"), "contact_model.law", LAWS),
            **{
                name: number(law.get(name, default), f"contact_model.{name}", 0.0)
                for name, default in (
                    ("stiffness", 1000.0),
                    ("damping", 0.0),
                    ("friction", 0.5),
                    ("slip_velocity", 1e-2),
                    ("tangential_stiffness", 2.0 / 7.0),
                )
            },
        },
    }
    LAWS[spec["contact_model"]["law"]](**_law_parameters(spec))  # the engine's own checks
    return spec


def _speed(value) -> float | None:
    """``separation_speed``: a finite number > 0 (m/s), or None (JSON null) for none."""
    if value is None:
        return None
    real = isinstance(value, int | float) and not isinstance(value, bool)
    if not (real and math.isfinite(value) and value > 0):
        raise Unprocessable(
            f"separation_speed must be a finite number > 0 (m/s), or null for no gentle"
            f" start; got {value!r}"
        )
    return float(value)


def _law_parameters(spec: dict) -> dict:
    return {k: v for k, v in spec["contact_model"].items() if k != "law"}


def _body(value, where: str) -> dict:
    if not isinstance(value, dict):
        raise Unprocessable(f"{where} must be an object")
    mesh = member(value, "mesh", where)
    if not isinstance(mesh, str):
        raise Unprocessable(f"{where}.mesh must be a mesh id (string)")
    out = {
        "mesh": mesh,
        "position": array(value.get("position", [0.0] * 3), f"{where}.position", (3,)).tolist(),
        "orientation": quaternion(value.get("orientation", [1.0, 0, 0, 0]), where).tolist(),
        "velocity": array(value.get("velocity", [0.0] * 3), f"{where}.velocity", (3,)).tolist(),
        "angular_velocity": array(
            value.get("angular_velocity", [0.0] * 3), f"{where}.angular_velocity", (3,)
        ).tolist(),
        "fixed": flag(value.get("fixed", False), f"{where}.fixed"),
    }
    if "density" in value and "mass" in value:
        raise Unprocessable(f"{where}: give density or mass, not both")
    if "mass" in value:
        out["mass"] = number(value["mass"], f"{where}.mass", 1e-300)
    else:
        out["density"] = number(value.get("density", 1.0), f"{where}.density", 1e-300)
    for name in ("inertia", "center_of_mass"):
        if name in value and "mass" not in value:
            raise Unprocessable(
                f"{where}.{name} needs {where}.mass (a density leaves the mass undefined)"
            )
    if "inertia" in value:
        out["inertia"] = _inertia(value["inertia"], f"{where}.inertia")
    if "center_of_mass" in value:
        center = array(value["center_of_mass"], f"{where}.center_of_mass", (3,))
        out["center_of_mass"] = center.tolist()
    if value.get("epsilon") is not None:
        out["epsilon"] = _epsilon(value["epsilon"], f"{where}.epsilon")
    return out


def _epsilon(value, name: str) -> float | str | None:
    """An ε field: absent (None) or ``"auto"`` for the default rule, else a number > 0."""
    if value is None or (isinstance(value, str) and value == AUTO):
        return value
    eps = number(value, name, 0.0)
    if not eps > 0:
        raise Unprocessable(f"{name} must be > 0 (or {AUTO!r} for the default rule), got {value!r}")
    return eps


def _inertia(value, name: str) -> list:
    """A (3, 3) inertia tensor or 3 principal moments, checked by the engine's rules."""
    try:
        rank = np.ndim(value)
    except ValueError:
        rank = None
    if rank not in (1, 2):
        raise Unprocessable(f"{name} must be a (3, 3) tensor or 3 principal moments")
    checked = array(value, name, (3,) if rank == 1 else (3, 3))
    try:
        check_inertia(checked, name)
    except EngineError as exc:
        raise Unprocessable(str(exc)) from None
    return checked.tolist()


def apply_mesh_defaults(spec: dict, facts: dict) -> None:
    """Give ``"epsilon": "auto"`` to the bodies whose spec gives no ε and whose mesh was
    uploaded without one (``facts[mesh id]["epsilon_given"]`` False), so that they follow
    the engine's default rule; the stored spec then rebuilds the same scene."""
    for body in spec["bodies"]:
        if body.get("epsilon") is None and not facts[body["mesh"]].get("epsilon_given", True):
            body["epsilon"] = AUTO


def _plane(value, where: str) -> dict:
    if not isinstance(value, dict):
        raise Unprocessable(f"{where} must be an object")
    normal = array(value.get("normal", [0.0, 0.0, 1.0]), f"{where}.normal", (3,))
    if not np.linalg.norm(normal) > 0:
        raise Unprocessable(f"{where}.normal must not be zero")
    return {
        "point": array(value.get("point", [0.0] * 3), f"{where}.point", (3,)).tolist(),
        "normal": normal.tolist(),
        "size": number(value.get("size", 10.0), f"{where}.size", 1e-9),
        "divisions": number(value.get("divisions", 16), f"{where}.divisions", 1, 256, True),
    }


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


@dataclass
class LiveScene:
    """An engine scene in memory, with the lock that serialises its steps."""

    scene: Scene
    spec: dict
    steps: int
    lock: threading.Lock = field(default_factory=threading.Lock)


class LiveScenes:
    """Scenes kept in memory (least recently used dropped first; the store has them)."""

    def __init__(self, store, threads: int, capacity: int = 64) -> None:
        self.store, self.threads, self.capacity = store, threads, capacity
        self._live: OrderedDict[tuple[str, str], LiveScene] = OrderedDict()
        self._lock = threading.Lock()

    def add(self, owner: str, scene_id: str, live: LiveScene) -> None:
        with self._lock:
            self._live[(owner, scene_id)] = live
            while len(self._live) > self.capacity:
                self._live.popitem(last=False)

    def get(self, owner: str, scene_id: str) -> LiveScene:
        """The live scene (rebuilt from the store when not in memory), or 404."""
        key = (owner, scene_id)
        with self._lock:
            if key in self._live:
                self._live.move_to_end(key)
                return self._live[key]
        stored = self.store.scene(owner, scene_id)
        if stored is None:
            raise NotFound(f"no scene {scene_id!r}")
        spec, blob, steps = stored
        scene = build_scene(spec, self.store.tree, self.threads)
        restore_state(scene, blob)
        live = LiveScene(scene, spec, steps)
        self.add(owner, scene_id, live)
        return live

    def drop(self, owner: str, scene_id: str) -> None:
        with self._lock:
            self._live.pop((owner, scene_id), None)
