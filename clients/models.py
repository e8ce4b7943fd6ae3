"""What the client returns: numpy arrays, not dicts of lists."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["BuildJob", "ContactResult", "Contacts", "MeshInfo", "Overlaps", "SceneState"]

STATE = ("positions", "orientations", "velocities", "angular_velocities")


@dataclass(frozen=True)
class MeshInfo:
    """An uploaded mesh: ``id`` for scenes and contact queries, and its facts.

    ``triangles`` and ``vertices`` count the stored (repaired) mesh; ``repair`` is the
    service's report of what the upload's repair changed (``{"changed": False, …}`` for a
    clean mesh; counts and the first indices of merged vertices and dropped faces)."""

    id: str
    triangles: int
    vertices: int
    epsilon: float
    levels: int
    bounds: np.ndarray  # (2, 3) min and max corner
    watertight: bool
    volume: float | None
    created: bool  # False when the service had this mesh already
    facts: dict = field(repr=False, default_factory=dict)
    repair: dict = field(repr=False, default_factory=dict)

    @classmethod
    def from_payload(cls, payload: dict, created: bool) -> MeshInfo:
        return cls(
            id=payload["id"],
            triangles=int(payload["triangles"]),
            vertices=int(payload["vertices"]),
            epsilon=float(payload["epsilon"]),
            levels=int(payload["levels"]),
            bounds=np.asarray(payload["bounds"], float),
            watertight=bool(payload["watertight"]),
            volume=payload.get("volume"),
            created=created,
            facts=payload,
            repair=dict(payload.get("repair") or {}),
        )


@dataclass(frozen=True)
class BuildJob:
    """The service's build of an uploaded mesh's tree (``GET /v1/meshes/jobs/{id}``).

    ``status``: "queued", "building", "done" or "failed"; ``levels`` and ``nodes``: tree
    levels and nodes built so far (of a mesh of ``triangles`` triangles); ``error`` and
    ``cause`` ("engine", "memory", "cancelled", "lost", "internal") say why a job failed;
    ``url``: the job's address, to poll with :meth:`clients.Client.job`."""

    id: str
    status: str
    mesh: str  # the mesh id it builds
    url: str
    triangles: int
    levels: int
    nodes: int
    error: str | None
    cause: str | None
    seconds: float | None
    payload: dict = field(repr=False, default_factory=dict)

    @property
    def finished(self) -> bool:
        return self.status in ("done", "failed")

    @classmethod
    def from_payload(cls, payload: dict, url: str | None = None) -> BuildJob:
        progress = payload.get("progress") or {}
        return cls(
            id=payload["id"],
            status=payload["status"],
            mesh=payload["mesh"],
            url=url or payload["location"],
            triangles=int(payload["triangles"]),
            levels=int(progress.get("levels", 0)),
            nodes=int(progress.get("nodes", 0)),
            error=payload.get("error"),
            cause=payload.get("cause"),
            seconds=payload.get("seconds"),
            payload=payload,
        )


@dataclass(frozen=True)
class ContactResult:
    """Contacts of one body pair (world frame): ``points (k, 3)``, ``normals (k, 3)``
    (unit, from A to B), ``overlaps (k,)`` and triangle ``pairs (m, 2)`` in contact."""

    points: np.ndarray
    normals: np.ndarray
    overlaps: np.ndarray
    pairs: np.ndarray


@dataclass(frozen=True)
class Contacts:
    """Contacts of every queried pair, in order: ``contacts[q]`` is a
    :class:`ContactResult`. The same data as flat arrays (CSR): pair q owns rows
    ``offsets[q]:offsets[q + 1]`` of ``points (c, 3)``, ``normals (c, 3)``, ``overlaps
    (c,)`` and rows ``pair_offsets[q]:pair_offsets[q + 1]`` of ``pairs (m, 2)``; ``stats``
    the summed counters."""

    offsets: np.ndarray
    points: np.ndarray
    normals: np.ndarray
    overlaps: np.ndarray
    pair_offsets: np.ndarray
    pairs: np.ndarray
    stats: dict

    @classmethod
    def from_payload(cls, payload: dict) -> Contacts:
        return cls(
            np.asarray(payload["offsets"], np.int64),
            np.asarray(payload["points"], float).reshape(-1, 3),
            np.asarray(payload["normals"], float).reshape(-1, 3),
            np.asarray(payload["overlaps"], float).reshape(-1),
            np.asarray(payload["pair_offsets"], np.int64),
            np.asarray(payload["pairs"], np.int64).reshape(-1, 2),
            payload["stats"],
        )

    def __len__(self) -> int:
        return len(self.offsets) - 1

    def __getitem__(self, q: int) -> ContactResult:
        if not -len(self) <= q < len(self):
            raise IndexError(q)
        q %= len(self)
        c0, c1 = self.offsets[q], self.offsets[q + 1]
        p0, p1 = self.pair_offsets[q], self.pair_offsets[q + 1]
        return ContactResult(
            self.points[c0:c1], self.normals[c0:c1], self.overlaps[c0:c1], self.pairs[p0:p1]
        )

    @property
    def results(self) -> list[ContactResult]:
        return [self[q] for q in range(len(self))]


@dataclass(frozen=True)
class Overlaps:
    """What ``set_state`` found when it moved bodies: ``pairs (k, 2)`` int64, the body
    pairs whose surfaces cross (overlap beyond the reach ε_a + ε_b), and ``largest``, the
    largest overlap of any contact relative to its pair's reach (1: the surfaces meet)."""

    pairs: np.ndarray
    largest: float

    @classmethod
    def from_payload(cls, payload: dict | None) -> Overlaps | None:
        if payload is None:
            return None
        pairs = np.asarray(payload["pairs"], np.int64).reshape(-1, 2)
        return cls(pairs=pairs, largest=float(payload["largest"]))


@dataclass(frozen=True)
class SceneState:
    """A scene's state: ``positions (n, 3)``, ``orientations (n, 4)`` (w, x, y, z),
    ``velocities``, ``angular_velocities (n, 3)`` (rows: bodies, then planes), its
    ``time`` and ``steps`` so far, and the statistics of the steps just taken."""

    positions: np.ndarray
    orientations: np.ndarray
    velocities: np.ndarray
    angular_velocities: np.ndarray
    time: float
    steps: int
    stats: list = field(default_factory=list)
    overlaps: Overlaps | None = None

    @classmethod
    def from_payload(cls, payload: dict) -> SceneState:
        state = payload["state"]
        widths = {"orientations": 4}
        arrays = {k: np.asarray(state[k], float).reshape(-1, widths.get(k, 3)) for k in STATE}
        return cls(
            **arrays,
            time=float(payload["time"]),
            steps=int(payload["steps"]),
            stats=list(payload.get("stats", [])),
            overlaps=Overlaps.from_payload(payload.get("overlaps")),
        )
