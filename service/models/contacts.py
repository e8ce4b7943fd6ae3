"""Models of ``POST /v1/contacts``: a columnar batch or a list of posed pairs, and the
contacts found, in the same layout."""

from __future__ import annotations

from typing import Annotated, Literal

import numpy as np
from pydantic import (
    BaseModel,
    ConfigDict,
    Discriminator,
    Field,
    Tag,
    TypeAdapter,
    model_validator,
)

from engine import DEFAULT_PRECISION, KERNELS, PRECISIONS

from .arrays import Indices, Points, Quaternion, Quaternions, Shape, Vector3

__all__ = [
    "CONTACTS_QUERY",
    "ColumnarContacts",
    "ColumnarQuery",
    "ContactStatsOut",
    "ContactsQuery",
    "PairContacts",
    "PairQuery",
    "PerPairContacts",
    "PerPairQuery",
    "PoseIn",
]

Kernel = Literal[tuple(KERNELS)]  # type: ignore[valid-type]
Precision = Literal[tuple(PRECISIONS)]  # type: ignore[valid-type]
MeshId = Annotated[str, Field(min_length=1, max_length=200)]
Pairs = Annotated[np.ndarray, Shape(None, 2, integer=True)]
Overlaps = Annotated[np.ndarray, Shape(None)]
Offsets = Annotated[np.ndarray, Shape(None, integer=True)]


class _Options(BaseModel):
    model_config = ConfigDict(strict=True, extra="forbid")

    kernel: Kernel = Field("hybrid", description="triangle distance: exact, iterative, hybrid")
    hierarchy: bool = Field(True, description="false: the flat search over all leaf pairs")
    precision: Precision = Field(DEFAULT_PRECISION, description="of the search")


class ColumnarQuery(_Options):
    """n pairs as columns: ``a[q]``, ``b[q]`` index ``meshes``; poses row by row."""

    model_config = ConfigDict(
        json_schema_extra={
            "examples": [
                {
                    "meshes": ["<mesh id>"],
                    "a": [0],
                    "b": [0],
                    "position_a": [[0, 0, 0]],
                    "orientation_a": [[1, 0, 0, 0]],
                    "position_b": [[0, 0, 1.0]],
                    "orientation_b": [[1, 0, 0, 0]],
                }
            ]
        }
    )

    meshes: list[MeshId] = Field(min_length=1, description="mesh ids the indices refer to")
    a: Indices = Field(description="(n,) index into meshes of each pair's first body")
    b: Indices = Field(description="(n,) index into meshes of each pair's second body")
    position_a: Points = Field(description="(n, 3)")
    orientation_a: Quaternions = Field(description="(n, 4) unit quaternions (w, x, y, z)")
    position_b: Points = Field(description="(n, 3)")
    orientation_b: Quaternions = Field(description="(n, 4)")

    @model_validator(mode="after")
    def _consistent(self) -> ColumnarQuery:
        n = len(self.a)
        if n == 0:
            raise ValueError("a must name at least one pair")
        for name in ("b", "position_a", "orientation_a", "position_b", "orientation_b"):
            rows = len(getattr(self, name))
            if rows != n:
                raise ValueError(f"{name} must have {n} rows (one per pair, as a), got {rows}")
        top = len(self.meshes) - 1
        for name in ("a", "b"):
            index = getattr(self, name)
            if index.min() < 0 or index.max() > top:
                raise ValueError(f"{name} holds indices outside meshes (0 … {top})")
        return self


class PoseIn(BaseModel):
    model_config = ConfigDict(strict=True, extra="forbid")

    position: Vector3 = Field(description="(3,) metres")
    orientation: Quaternion = Field(
        default_factory=lambda: np.array([1.0, 0.0, 0.0, 0.0]),
        description="(4,) unit quaternion (w, x, y, z); default: identity",
    )


def _identity() -> PoseIn:
    return PoseIn(position=np.zeros(3))


class PairQuery(BaseModel):
    model_config = ConfigDict(strict=True, extra="forbid")

    a: MeshId
    pose_a: PoseIn = Field(default_factory=_identity, description="default: the origin")
    b: MeshId
    pose_b: PoseIn = Field(default_factory=_identity)


class PerPairQuery(_Options):
    """Readable JSON: one object per pair."""

    model_config = ConfigDict(
        json_schema_extra={
            "examples": [
                {
                    "pairs": [
                        {
                            "a": "<mesh id>",
                            "pose_a": {"position": [0, 0, 0]},
                            "b": "<mesh id>",
                            "pose_b": {"position": [0, 0, 1.0], "orientation": [1, 0, 0, 0]},
                        }
                    ]
                }
            ]
        }
    )

    pairs: list[PairQuery] = Field(min_length=1)


def _layout(body) -> str:
    return "per_pair" if isinstance(body, dict) and "pairs" in body else "columnar"


ContactsQuery = Annotated[
    Annotated[ColumnarQuery, Tag("columnar")] | Annotated[PerPairQuery, Tag("per_pair")],
    Discriminator(_layout),
]
CONTACTS_QUERY = TypeAdapter(ContactsQuery)  # validates either layout


_STATS = {
    "pairs": 1,
    "contacts": 1,
    "comparisons": 16,
    "iterative": 16,
    "fallbacks": 0,
    "sphere_pruned": 0,
    "seconds": 0.0004,
}
_ONE = {
    "points": [[0.5, 0.25, 0.99]],
    "normals": [[0.0, 0.0, 1.0]],
    "overlaps": [0.012],
    "pairs": [[3, 0]],
}


class ContactStatsOut(BaseModel):
    pairs: int
    contacts: int
    comparisons: int = Field(description="triangle pairs compared")
    iterative: int
    fallbacks: int
    sphere_pruned: int
    seconds: float = Field(description="search time on the server")


class ColumnarContacts(BaseModel):
    """Pair q owns contact rows ``offsets[q]:offsets[q + 1]`` and face-pair rows
    ``pair_offsets[q]:pair_offsets[q + 1]``."""

    model_config = ConfigDict(
        json_schema_extra={
            "examples": [{"offsets": [0, 1], "pair_offsets": [0, 1], **_ONE, "stats": _STATS}]
        }
    )

    offsets: Offsets = Field(description="(n + 1,)")
    points: Points = Field(description="(c, 3) world frame")
    normals: Points = Field(description="(c, 3) unit, from A to B")
    overlaps: Overlaps = Field(description="(c,) ε_a + ε_b − distance")
    pair_offsets: Offsets = Field(description="(n + 1,)")
    pairs: Pairs = Field(description="(m, 2) (face of A, face of B)")
    stats: ContactStatsOut


class PairContacts(BaseModel):
    points: Points
    normals: Points
    overlaps: Overlaps
    pairs: Pairs


class PerPairContacts(BaseModel):
    model_config = ConfigDict(
        json_schema_extra={"examples": [{"results": [_ONE], "stats": _STATS}]}
    )

    results: list[PairContacts]
    stats: ContactStatsOut
