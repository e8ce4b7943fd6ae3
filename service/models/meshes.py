"""Models of ``/v1/meshes``: uploads, a mesh's facts, build jobs, surrogate levels."""

from __future__ import annotations

from typing import Annotated, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator

from .arrays import Points, Shape

__all__ = [
    "MAX_BRANCHING",
    "BuildJob",
    "JobList",
    "JobProgress",
    "MeshFacts",
    "MeshForm",
    "MeshList",
    "MeshUpload",
    "RepairSummary",
    "SurrogateLevel",
]

MAX_BRANCHING = 64
Faces = Annotated[np.ndarray, Shape(None, 3, integer=True)]
Epsilon = Annotated[float, Field(gt=0, allow_inf_nan=False)]
Branching = Annotated[int, Field(ge=2, le=MAX_BRANCHING)]


class MeshUpload(BaseModel):
    """A mesh as arrays (JSON or msgpack). A file goes as multipart instead."""

    model_config = ConfigDict(
        strict=True,
        extra="forbid",
        json_schema_extra={
            "examples": [
                {
                    "vertices": [[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]],
                    "faces": [[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]],
                    "epsilon": 0.01,
                }
            ]
        },
    )

    vertices: Points = Field(description="(V, 3) vertex coordinates, metres")
    faces: Faces = Field(description="(F, 3) vertex indices of the triangles, 0 … V - 1")
    epsilon: Epsilon | None = Field(
        None, description="the shell ε (m, > 0); absent: the size default"
    )
    branching: Branching | None = Field(None, description="children per tree node (default 8)")
    strict: bool = Field(False, description="refuse a mesh that needs repair instead (422)")

    @model_validator(mode="after")
    def _indices_in_range(self) -> MeshUpload:
        n = len(self.vertices)
        if len(self.faces) and (self.faces.min() < 0 or self.faces.max() >= n):
            bad = int(self.faces.max() if self.faces.max() >= n else self.faces.min())
            raise ValueError(
                f"faces refer to vertex {bad} but there are {n} vertices (indices 0 … {n - 1})"
            )
        return self


class MeshForm(BaseModel):
    """The options of a multipart upload (form fields are text: read as numbers)."""

    epsilon: Epsilon | None = None
    branching: Branching | None = None
    strict: bool = False


class RepairSummary(BaseModel):
    """What the upload's repair changed (:meth:`engine.RepairReport.summary`)."""

    changed: bool
    merge_tolerance: float
    area_tolerance: float
    input_vertices: int
    input_faces: int
    vertices: int
    faces: int
    merged_vertices: int
    merged_vertices_first: list[int]
    unreferenced_vertices: int
    unreferenced_vertices_first: list[int]
    repeated_index_faces: int
    repeated_index_faces_first: list[int]
    zero_area_faces: int
    zero_area_faces_first: list[int]


_REPAIR = {
    "changed": False,
    "merge_tolerance": 1e-9,
    "area_tolerance": 1e-18,
    "input_vertices": 4,
    "input_faces": 4,
    "vertices": 4,
    "faces": 4,
    "merged_vertices": 0,
    "merged_vertices_first": [],
    "unreferenced_vertices": 0,
    "unreferenced_vertices_first": [],
    "repeated_index_faces": 0,
    "repeated_index_faces_first": [],
    "zero_area_faces": 0,
    "zero_area_faces_first": [],
}
_FACTS = {
    "id": "3f1c0d9a6b2e4c5d8e7f60718293a4b5",
    "triangles": 4,
    "vertices": 4,
    "epsilon": 0.01,
    "branching": 8,
    "levels": 1,
    "nodes": 4,
    "nodes_per_level": [4],
    "bounds": [[0, 0, 0], [1, 1, 1]],
    "watertight": True,
    "volume": 0.16666666666666666,
    "repair": _REPAIR,
    "epsilon_given": True,
}
_JOB = {
    "id": "9b8a7c6d5e4f40312233445566778899",
    "status": "building",
    "mesh": _FACTS["id"],
    "location": "/v1/meshes/jobs/9b8a7c6d5e4f40312233445566778899",
    "triangles": 81920,
    "vertices": 40962,
    "epsilon": 0.004,
    "branching": 8,
    "progress": {"levels": 3, "nodes": 4681},
    "seconds": None,
    "error": None,
    "cause": None,
    "created": 1795000000.0,
    "updated": 1795000002.5,
    "repair": _REPAIR,
}


class MeshFacts(BaseModel):
    """A stored mesh and its surrogate tree."""

    model_config = ConfigDict(json_schema_extra={"examples": [_FACTS]})

    id: str = Field(description="content id: the repaired mesh, ε, branching, tree format")
    triangles: int
    vertices: int
    epsilon: float
    branching: int
    levels: int = Field(description="tree levels (0: the root)")
    nodes: int
    nodes_per_level: list[int]
    bounds: list[list[float]] = Field(description="(2, 3): lowest and highest corner")
    watertight: bool
    volume: float | None = Field(description="m³ when watertight, else null")
    repair: RepairSummary | None = None
    epsilon_given: bool = Field(True, description="false: ε came from the size default")


class MeshList(BaseModel):
    model_config = ConfigDict(json_schema_extra={"examples": [{"meshes": [_FACTS]}]})

    meshes: list[MeshFacts]


class JobProgress(BaseModel):
    levels: int = Field(description="tree levels built so far")
    nodes: int = Field(description="tree nodes built so far")


class BuildJob(BaseModel):
    """A tree build of an upload."""

    model_config = ConfigDict(json_schema_extra={"examples": [_JOB]})

    id: str
    status: Literal["queued", "building", "done", "failed"]
    mesh: str = Field(description="the mesh id the build makes")
    location: str = Field(description="this job's URL path")
    triangles: int
    vertices: int
    epsilon: float
    branching: int
    progress: JobProgress
    seconds: float | None = Field(None, description="build time, once finished")
    error: str | None = Field(None, description="why it failed")
    cause: str | None = Field(None, description="engine | memory | cancelled | crashed | server")
    created: float = Field(description="Unix time")
    updated: float = Field(description="Unix time")
    repair: RepairSummary | None = None
    mesh_url: str | None = Field(None, description="once done: the mesh's URL path")
    facts: MeshFacts | None = Field(None, description="once done: the mesh (null once deleted)")


class JobList(BaseModel):
    model_config = ConfigDict(json_schema_extra={"examples": [{"jobs": [_JOB]}]})

    jobs: list[BuildJob]


class SurrogateLevel(BaseModel):
    """The surrogate triangles of one tree level."""

    model_config = ConfigDict(
        json_schema_extra={
            "examples": [
                {
                    "id": _FACTS["id"],
                    "level": 0,
                    "levels": 1,
                    "triangles": [[[0, 0, 0], [1, 0, 0], [0, 1, 0]]],
                    "epsilon": [0.01],
                    "leaf": [True],
                }
            ]
        }
    )

    id: str
    level: int
    levels: int
    triangles: Annotated[np.ndarray, Shape(None, 3, 3)] = Field(description="(k, 3, 3)")
    epsilon: Annotated[np.ndarray, Shape(None)] = Field(description="(k,) each node's ε")
    leaf: list[bool] = Field(description="(k,) true where the node is an original triangle")
