"""Models of ``/v1/scenes``: a scene's specification, state updates, steps, and answers.

A specification validates into :class:`SceneSpec`; :meth:`SceneSpec.normalised` is the
plain dict the store keeps (defaults filled in, arrays as lists), from which
:func:`service.scenes.build_scene` builds the engine scene, after a restart too.
"""

from __future__ import annotations

import math
from typing import Annotated, Any, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator
from pydantic_core import PydanticCustomError, core_schema

from engine import (
    DEFAULT_SCHEME,
    DEFAULT_SEPARATION_SPEED,
    KERNELS,
    SCHEMES,
    EngineError,
    HertzSpring,
    LinearSpring,
    PaperSpring,
    StepStats,
    check_inertia,
)

from .arrays import Points, Quaternion, Shape, Vector3

__all__ = [
    "LAWS",
    "MAX_DT",
    "STATE",
    "BodySpec",
    "ContactModelSpec",
    "OverlapsOut",
    "PlaneSpec",
    "SceneSpec",
    "SceneState",
    "SceneSummary",
    "StateUpdate",
    "StepAnswer",
    "StepRequest",
]

LAWS = {"paper": PaperSpring, "linear": LinearSpring, "hertz": HertzSpring}
STATE = ("positions", "orientations", "velocities", "angular_velocities")
MAX_DT = 1.0

Finite = Annotated[float, Field(allow_inf_nan=False)]
NonNegative = Annotated[float, Field(ge=0, allow_inf_nan=False)]
Positive = Annotated[float, Field(ge=1e-300, allow_inf_nan=False)]
TimeStep = Annotated[float, Field(ge=1e-12, le=MAX_DT, allow_inf_nan=False)]
Scheme = Literal[tuple(SCHEMES)]  # type: ignore[valid-type]
Kernel = Literal[tuple(KERNELS)]  # type: ignore[valid-type]


def _zeros() -> np.ndarray:
    return np.zeros(3)


class AutoOrPositive:
    """An ε field: a finite number > 0 (m), or ``"auto"`` for the engine's default rule."""

    def __get_pydantic_core_schema__(self, source, handler) -> core_schema.CoreSchema:
        return core_schema.no_info_plain_validator_function(self.validate)

    def __get_pydantic_json_schema__(self, schema, handler) -> dict:
        return {
            "anyOf": [{"type": "number", "exclusiveMinimum": 0}, {"const": "auto"}],
            "description": "ε in metres (> 0), or 'auto' for the default rule",
        }

    def validate(self, value) -> float | str:
        if value == "auto" and isinstance(value, str):
            return value
        number = isinstance(value, int | float) and not isinstance(value, bool)
        if not (number and math.isfinite(value) and value > 0):
            raise PydanticCustomError(
                "epsilon",
                "must be a finite number > 0 or 'auto' (the default rule), got {got}",
                {"got": repr(value)[:60]},
            )
        return float(value)


EpsilonSpec = Annotated[float | str, AutoOrPositive()]


class Inertia:
    """An inertia field: a (3, 3) tensor or 3 principal moments, checked by the engine."""

    tensor, moments = Shape(3, 3), Shape(3)

    def __get_pydantic_core_schema__(self, source, handler) -> core_schema.CoreSchema:
        return core_schema.no_info_plain_validator_function(
            self.validate,
            serialization=core_schema.plain_serializer_function_ser_schema(
                lambda v: np.asarray(v).tolist(), when_used="json"
            ),
        )

    def __get_pydantic_json_schema__(self, schema, handler) -> dict:
        return {
            "anyOf": [
                self.tensor.__get_pydantic_json_schema__(schema, handler),
                self.moments.__get_pydantic_json_schema__(schema, handler),
            ],
            "description": "a (3, 3) inertia tensor about the centre of mass, or 3 principal"
            " moments (kg m²)",
        }

    def validate(self, value) -> np.ndarray:
        try:
            rank = np.ndim(value)
        except (ValueError, TypeError):
            rank = None
        if rank not in (1, 2) or isinstance(value, str | dict):
            raise PydanticCustomError("inertia", "must be a (3, 3) tensor or 3 principal moments")
        checked = (self.moments if rank == 1 else self.tensor).validate(value)
        try:
            check_inertia(checked, "@")  # the engine's message, named by the field's path
        except EngineError as exc:
            message = str(exc).replace("@ ", "", 1).replace("@", "", 1)
            raise PydanticCustomError("inertia", message) from None
        return checked


class BodySpec(BaseModel):
    model_config = ConfigDict(strict=True, extra="forbid")

    mesh: str = Field(min_length=1, description="an uploaded mesh's id")
    position: Vector3 = Field(default_factory=_zeros, description="(3,) m")
    orientation: Quaternion = Field(
        default_factory=lambda: np.array([1.0, 0.0, 0.0, 0.0]),
        description="(4,) unit quaternion (w, x, y, z)",
    )
    velocity: Vector3 = Field(default_factory=_zeros, description="(3,) m/s")
    angular_velocity: Vector3 = Field(default_factory=_zeros, description="(3,) rad/s")
    fixed: bool = False
    density: Positive | None = Field(None, description="kg/m³ (default 1); or give mass")
    mass: Positive | None = Field(None, description="kg; then inertia, center_of_mass too")
    inertia: Annotated[np.ndarray, Inertia()] | None = None
    center_of_mass: Vector3 | None = Field(None, description="(3,) mesh frame; needs mass")
    epsilon: EpsilonSpec | None = Field(
        None, description="this body's ε (m), or 'auto' for the default rule"
    )

    @model_validator(mode="after")
    def _mass(self) -> BodySpec:
        if self.density is not None and self.mass is not None:
            raise ValueError("give density or mass, not both")
        for name in ("inertia", "center_of_mass"):
            if getattr(self, name) is not None and self.mass is None:
                raise PydanticCustomError(
                    "needs_mass",
                    "needs mass (a density leaves the mass undefined)",
                    {"field": name},
                )
        return self

    def normalised(self) -> dict:
        out = {
            "mesh": self.mesh,
            "position": self.position.tolist(),
            "orientation": self.orientation.tolist(),
            "velocity": self.velocity.tolist(),
            "angular_velocity": self.angular_velocity.tolist(),
            "fixed": self.fixed,
        }
        if self.mass is not None:
            out["mass"] = self.mass
        else:
            out["density"] = 1.0 if self.density is None else self.density
        for name in ("inertia", "center_of_mass"):
            if getattr(self, name) is not None:
                out[name] = getattr(self, name).tolist()
        if self.epsilon is not None:
            out["epsilon"] = self.epsilon
        return out


class PlaneSpec(BaseModel):
    model_config = ConfigDict(strict=True, extra="forbid")

    point: Vector3 = Field(default_factory=_zeros, description="(3,) a point of the plane")
    normal: Vector3 = Field(
        default_factory=lambda: np.array([0.0, 0.0, 1.0]), description="(3,) not zero"
    )
    size: Annotated[float, Field(ge=1e-9, allow_inf_nan=False)] = Field(
        10.0, description="edge of the square patch (m)"
    )
    divisions: Annotated[int, Field(ge=1, le=256)] = 16

    @field_validator("normal")
    @classmethod
    def _nonzero(cls, normal: np.ndarray) -> np.ndarray:
        if not np.linalg.norm(normal) > 0:
            raise ValueError("must not be zero")
        return normal

    def normalised(self) -> dict:
        return {
            "point": self.point.tolist(),
            "normal": self.normal.tolist(),
            "size": self.size,
            "divisions": self.divisions,
        }


class ContactModelSpec(BaseModel):
    model_config = ConfigDict(strict=True, extra="forbid")

    law: Literal["paper", "linear", "hertz"] = "paper"
    stiffness: NonNegative = 1000.0
    damping: NonNegative = 0.0
    friction: NonNegative = 0.5
    slip_velocity: NonNegative = 1e-2
    tangential_stiffness: NonNegative = Field(
        2.0 / 7.0, description="k_t/k_n of the static-friction spring; 0: regularised law"
    )

    @model_validator(mode="after")
    def _engine_checks(self) -> ContactModelSpec:
        try:
            LAWS[self.law](**self.parameters())
        except EngineError as exc:
            raise ValueError(str(exc)) from None
        return self

    def parameters(self) -> dict:
        return self.model_dump(exclude={"law"})


class SceneSpec(BaseModel):
    """Bodies (rows 0 … n - 1) and planes (after them), gravity, the scheme and its step."""

    model_config = ConfigDict(
        strict=True,
        extra="forbid",
        json_schema_extra={
            "examples": [
                {
                    "bodies": [{"mesh": "<mesh id>", "position": [0, 0, 0.5], "density": 1000.0}],
                    "planes": [{"point": [0, 0, 0], "normal": [0, 0, 1]}],
                    "dt": 0.001,
                    "scheme": "implicit-midpoint",
                }
            ]
        },
    )

    bodies: list[BodySpec] = Field(min_length=1)
    planes: list[PlaneSpec] = Field(default_factory=list)
    gravity: Vector3 = Field(default_factory=lambda: np.array([0.0, 0.0, -9.81]))
    epsilon: EpsilonSpec | None = Field(
        None, description="the planes' ε (m); absent or 'auto': the default rule"
    )
    dt: TimeStep = 1e-3
    scheme: Scheme = DEFAULT_SCHEME
    kernel: Kernel = "hybrid"
    max_halvings: Annotated[int, Field(ge=0, le=8)] = 0
    substeps: bool = Field(False, description="split a step that moves a body beyond its ε")
    separation_speed: Annotated[float, Field(gt=0, allow_inf_nan=False)] | None = Field(
        DEFAULT_SEPARATION_SPEED,
        description="m/s at which overlaps present at placement are let go; null: at once",
    )
    contact_model: ContactModelSpec = Field(default_factory=ContactModelSpec)

    def normalised(self) -> dict:
        return {
            "bodies": [b.normalised() for b in self.bodies],
            "planes": [p.normalised() for p in self.planes],
            "gravity": self.gravity.tolist(),
            "epsilon": self.epsilon,
            "dt": self.dt,
            "scheme": self.scheme,
            "kernel": self.kernel,
            "max_halvings": self.max_halvings,
            "substeps": self.substeps,
            "separation_speed": self.separation_speed,
            "contact_model": {"law": self.contact_model.law, **self.contact_model.parameters()},
        }


class StateUpdate(BaseModel):
    """Any of the state arrays; n rows: bodies, then planes."""

    model_config = ConfigDict(
        strict=True,
        extra="forbid",
        json_schema_extra={"examples": [{"velocities": [[0, 0, -1.0]]}]},
    )

    positions: Points | None = Field(None, description="(n, 3)")
    orientations: Annotated[np.ndarray, Shape(None, 4)] | None = Field(
        None, description="(n, 4) unit quaternions"
    )
    velocities: Points | None = Field(None, description="(n, 3)")
    angular_velocities: Points | None = Field(None, description="(n, 3)")

    @model_validator(mode="after")
    def _some(self) -> StateUpdate:
        if not self.given():
            raise ValueError(f"give any of {list(STATE)}")
        return self

    def given(self) -> dict[str, np.ndarray]:
        return {k: getattr(self, k) for k in STATE if getattr(self, k) is not None}


class StepRequest(BaseModel):
    model_config = ConfigDict(
        strict=True, extra="forbid", json_schema_extra={"examples": [{"steps": 10}]}
    )

    steps: Annotated[int, Field(ge=1)] = Field(1, description="steps to take")
    dt: TimeStep | None = Field(None, description="this request's step; default: the scene's")


class SceneState(BaseModel):
    positions: Points
    orientations: Annotated[np.ndarray, Shape(None, 4)]
    velocities: Points
    angular_velocities: Points


class OverlapsOut(BaseModel):
    pairs: list[list[int]] = Field(description="body pairs whose surfaces cross")
    largest: float = Field(description="largest overlap relative to its pair's reach")


_STATE = {
    "positions": [[0.0, 0.0, 0.5], [0.0, 0.0, 0.0]],
    "orientations": [[1.0, 0.0, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0]],
    "velocities": [[0.0, 0.0, 0.0], [0.0, 0.0, 0.0]],
    "angular_velocities": [[0.0, 0.0, 0.0], [0.0, 0.0, 0.0]],
}
_STEP = {
    "scheme": "implicit-midpoint",
    "dt": 0.001,
    "converged": True,
    "picard_iterations": 3,
    "evaluations": 1,
    "body_pairs": 1,
    "contacts": 4,
    "triangle_pairs": 6,
    "comparisons": 120,
    "iterative": 120,
    "fallbacks": 0,
    "sphere_pruned": 8,
    "unfoldings": 12,
    "folds": 0,
    "listed": 0,
    "max_overlap": 0.08,
    "elastic_energy": 0.0004,
    "halvings": 0,
    "seconds": 0.0012,
    "travel": 0.1,
    "substeps": 1,
    "sleeping": 0,
}
_SCENE = {
    "id": "5d41402abc4b2a76b9719d911017c592",
    "bodies": 1,
    "planes": 1,
    "time": 0.0,
    "steps": 0,
    "dt": 0.001,
    "scheme": "implicit-midpoint",
    "state": _STATE,
    "mass_source": ["mesh", "fixed"],
    "epsilon": [0.01, 0.001],
    "spec": {"bodies": [{"mesh": "3f1c0d9a6b2e4c5d8e7f60718293a4b5"}], "planes": [{}]},
    "overlaps": None,
}


class SceneSummary(BaseModel):
    model_config = ConfigDict(json_schema_extra={"examples": [_SCENE]})

    id: str
    bodies: int
    planes: int
    time: float
    steps: int
    dt: float
    scheme: str
    state: SceneState
    mass_source: list[str] = Field(description="mesh | convex_hull | given | fixed, per row")
    epsilon: Annotated[np.ndarray, Shape(None)] = Field(description="each row's ε")
    spec: dict[str, Any] = Field(description="the normalised specification")
    overlaps: OverlapsOut | None = Field(
        None, description="PUT state: crossings after new positions or orientations"
    )


class StepAnswer(BaseModel):
    model_config = ConfigDict(
        json_schema_extra={
            "examples": [
                {"id": _SCENE["id"], "time": 0.001, "steps": 1, "state": _STATE, "stats": [_STEP]}
            ]
        }
    )

    id: str
    time: float
    steps: int = Field(description="steps taken since creation")
    state: SceneState
    stats: list[StepStats]
