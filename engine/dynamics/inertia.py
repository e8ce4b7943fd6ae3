"""Mass properties of rigid bodies: exact from a closed mesh, from the convex hull of any
other mesh, or given by the user (host code; float64 throughout).

A free body needs a mass, a centre of mass (mesh frame) and an inertia tensor about it
(mesh axes). Where they come from is the body's **mass source** (``Scene.mass_source``):

* ``"mesh"`` — a closed, consistently oriented mesh of uniform density: exact
  signed-tetrahedron integration (:meth:`engine.Mesh.mass_properties`), at ``density``
  or scaled to ``mass``; bit for bit what the scene has always used.
* ``"convex_hull"`` — any other mesh (open, inconsistently oriented, inside-out, enclosing
  no volume): the same integration over its convex hull (``scipy.spatial.ConvexHull``),
  MuJoCo's default for non-watertight meshes, at ``density`` or scaled to ``mass``. A
  hull without volume (a flat mesh, collinear points) has no inertia: give ``mass`` and
  ``inertia``.
* ``"given"`` — ``mass`` and ``inertia`` (a (3, 3) tensor or 3 principal moments) from the
  user, validated: finite, symmetric, positive definite, principal moments satisfying the
  triangle inequality (every rigid body's do). ``center_of_mass`` is optional (default the
  mesh's or hull's centre, or the surface's area centroid when the hull is flat).
* ``"fixed"`` — fixed bodies (planes, walls) have infinite mass and need none.

``mass`` without ``inertia`` keeps the shape's distribution (``"mesh"`` or
``"convex_hull"``) scaled to that mass; ``center_of_mass`` alone moves the centre and
keeps the shape's inertia about it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from engine.errors import InvalidArgumentError, InvalidMeshError
from engine.geometry.mesh import Mesh

__all__ = [
    "MASS_SOURCES",
    "BodyMass",
    "body_mass",
    "check_center",
    "check_inertia",
    "fixed_center",
    "hull_properties",
]

MASS_SOURCES = ("mesh", "convex_hull", "given", "fixed")
SYMMETRY_TOLERANCE = 1e-6
"""A given inertia tensor is symmetric when ``|I − Iᵀ| ≤`` this × its largest entry."""
TRIANGLE_TOLERANCE = 1e-6
"""Principal moments may exceed the sum of the other two by this fraction of that sum
(a flat plate's I₃ = I₁ + I₂ exactly, up to rounding)."""
_FLAT = 1e-12  # a hull with volume <= this × diameter³ is flat


@dataclass(frozen=True)
class BodyMass:
    """Mass properties of one free body.

    mass : float (> 0)
    center : (3,) float64 — centre of mass in the mesh frame
    inertia : (3, 3) float64 — about the centre of mass, mesh axes (symmetric positive
        definite)
    source : str — one of :data:`MASS_SOURCES`
    """

    mass: float
    center: np.ndarray
    inertia: np.ndarray
    source: str


def body_mass(
    mesh: Mesh,
    density: float | None = None,
    mass: float | None = None,
    inertia=None,
    center_of_mass=None,
) -> BodyMass:
    """Mass properties of a free body of ``mesh`` (see the module docstring for the rules).

    Parameters
    ----------
    mesh : Mesh
    density, mass : float — at most one (default density 1); ``inertia`` and
        ``center_of_mass`` need ``mass``
    inertia : (3, 3) or (3,) array_like, optional — tensor about the centre of mass (mesh
        axes), or its principal moments along the mesh axes
    center_of_mass : (3,) array_like, optional — mesh frame

    Raises
    ------
    InvalidArgumentError
        Both density and mass, a non-positive or non-finite one, inertia or centre without
        mass, an invalid inertia (the message says what is wrong), or a mesh whose
        convex hull is flat when no inertia is given.
    """
    if density is not None and mass is not None:
        raise InvalidArgumentError("give density or mass, not both")
    given = None if inertia is None else check_inertia(inertia)
    center = None if center_of_mass is None else check_center(center_of_mass)
    if mass is None and (given is not None or center is not None):
        raise InvalidArgumentError(
            "inertia and center_of_mass need mass (a density would leave the mass undefined)"
        )
    if mass is not None:
        mass = _positive(mass, "mass")
    if given is not None:
        if center is None:
            center = _natural_center(mesh)
        return BodyMass(mass, center, given, "given")
    try:
        unit = mesh.mass_properties(1.0)
        source, volume, unit_mass, com, unit_inertia = (
            "mesh",
            unit.volume,
            unit.mass,
            unit.center_mass,
            unit.inertia,
        )
    except InvalidMeshError as exc:
        volume, com, unit_inertia = hull_properties(_used(mesh), str(exc))
        source, unit_mass = "convex_hull", volume
    scale = mass / volume if mass is not None else _positive(1.0 if density is None else density)
    return BodyMass(
        unit_mass * scale,
        np.array(com if center is None else center, dtype=np.float64),
        unit_inertia * scale,
        source,
    )


def hull_properties(points: np.ndarray, why: str = "") -> tuple[float, np.ndarray, np.ndarray]:
    """Volume, centre of mass ``(3,)`` and unit-density inertia ``(3, 3)`` (about the
    centre, float64) of the convex hull of ``points (m, 3) float64``.

    Exact integration over the hull's triangles, oriented outward (Qhull's facet normals);
    a flat or collinear point set raises :class:`InvalidArgumentError` that says to give
    ``mass`` and ``inertia`` (``why``: why the hull was needed, quoted in the message).
    """
    points = np.unique(np.asarray(points, dtype=np.float64), axis=0)
    hull, what = None, f"has only {len(points)} distinct point(s)"
    if len(points) >= 4:
        from scipy.spatial import ConvexHull, QhullError  # here: ~0.2 s of every start else

        try:
            hull = ConvexHull(points)
        except QhullError:
            hull = None
        what = "is flat (all vertices lie in a plane or on a line)"
    diameter = float(np.linalg.norm(np.ptp(points, axis=0)))
    if hull is None or not hull.volume > _FLAT * diameter**3:
        because = f" ({why})" if why else ""
        raise InvalidArgumentError(
            f"a free body takes its mass properties from its convex hull when its mesh has"
            f" none of its own{because}; this mesh's convex hull {what}, so it has no"
            " inertia: give mass and inertia (and center_of_mass) explicitly"
        )
    tris = points[hull.simplices]  # (h, 3, 3)
    normal = np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0])
    inward = np.einsum("ij,ij->i", normal, hull.equations[:, :3]) < 0
    tris[inward] = tris[inward][:, ::-1]
    return _solid(tris)


def _solid(tris: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """Volume, centroid and unit-density inertia of the solid bounded by the outward
    triangles ``(h, 3, 3)``: the signed tetrahedra of :meth:`engine.Mesh.mass_properties`
    (integrated about the box centre, less cancellation)."""
    flat = tris.reshape(-1, 3)
    o = 0.5 * (flat.min(axis=0) + flat.max(axis=0))
    t = tris - o
    a, b, c = t[:, 0], t[:, 1], t[:, 2]
    vol6 = np.einsum("ij,ij->i", a, np.cross(b, c))
    volume = float(vol6.sum()) / 6.0
    s = a + b + c
    first = (vol6[:, None] * s).sum(axis=0) / 24.0
    second = sum(np.einsum("t,ti,tj->ij", vol6, p, p) for p in (a, b, c, s)) / 120.0
    com = first / volume
    cov = second - volume * np.outer(com, com)
    cov = 0.5 * (cov + cov.T)
    return volume, com + o, np.trace(cov) * np.eye(3) - cov


def check_inertia(value, name: str = "inertia") -> np.ndarray:
    """A given inertia as a symmetric positive-definite (3, 3) float64 tensor whose
    principal moments satisfy the triangle inequality; ``value`` is a (3, 3) tensor or
    (3,) principal moments. The error names ``name`` and says what is wrong."""
    try:
        raw = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise InvalidArgumentError(
            f"{name} must be a (3, 3) tensor or 3 principal moments of numbers"
        ) from None
    if raw.shape == (3,):
        raw = np.diag(raw)
    elif raw.shape != (3, 3):
        raise InvalidArgumentError(
            f"{name} must be a (3, 3) tensor or 3 principal moments, got shape {list(raw.shape)}"
        )
    if not np.isfinite(raw).all():
        raise InvalidArgumentError(f"{name} must be finite, got {raw.tolist()}")
    scale = float(np.abs(raw).max())
    skew = np.abs(raw - raw.T)
    if skew.max() > SYMMETRY_TOLERANCE * scale:
        i, j = np.unravel_index(int(skew.argmax()), (3, 3))
        raise InvalidArgumentError(
            f"{name} must be symmetric: [{i}][{j}] = {raw[i, j]:.9g} but [{j}][{i}] ="
            f" {raw[j, i]:.9g}"
        )
    tensor = 0.5 * (raw + raw.T)
    moments = np.linalg.eigvalsh(tensor)
    if not moments[0] > 0:
        raise InvalidArgumentError(
            f"{name} must be positive definite; its principal moments are"
            f" {_moments(moments)} (every one must be > 0)"
        )
    if moments[2] > (moments[0] + moments[1]) * (1 + TRIANGLE_TOLERANCE):
        raise InvalidArgumentError(
            f"{name}'s principal moments {_moments(moments)} violate the triangle inequality:"
            f" {moments[2]:.9g} > {moments[0]:.9g} + {moments[1]:.9g} (no rigid body has"
            " them; each moment must be at most the sum of the other two)"
        )
    return tensor


def check_center(value, name: str = "center_of_mass") -> np.ndarray:
    """``value`` as a finite (3,) float64 point."""
    try:
        point = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise InvalidArgumentError(f"{name} must be 3 numbers") from None
    if point.shape != (3,) or not np.isfinite(point).all():
        raise InvalidArgumentError(f"{name} must be 3 finite numbers, got {point.tolist()}")
    return point


def fixed_center(mesh: Mesh) -> np.ndarray:
    """(3,) float64 reference point of a fixed body in the mesh frame: a closed mesh's
    centre of mass, else the mesh-frame origin."""
    try:
        return np.array(mesh.center_mass)
    except InvalidMeshError:
        return np.zeros(3)


def _natural_center(mesh: Mesh) -> np.ndarray:
    """The centre of a body given its inertia: the closed mesh's centre of mass, else its
    convex hull's, else (a flat hull) the area centroid of its surface."""
    try:
        return np.array(mesh.center_mass)
    except InvalidMeshError:
        pass
    try:
        return hull_properties(_used(mesh))[1]
    except InvalidArgumentError:
        areas = mesh.areas
        return (mesh.triangles.mean(axis=1) * areas[:, None]).sum(axis=0) / areas.sum()


def _used(mesh: Mesh) -> np.ndarray:
    """(m, 3) float64 vertices that some face refers to."""
    return mesh.vertices[np.unique(mesh.faces)]


def _positive(value, name: str = "density") -> float:
    if isinstance(value, bool):
        raise InvalidArgumentError(f"{name} must be a number, got {value!r}")
    try:
        value = float(value)
    except (TypeError, ValueError):
        raise InvalidArgumentError(f"{name} must be a number, got {value!r}") from None
    if not (math.isfinite(value) and value > 0):
        raise InvalidArgumentError(f"{name} must be finite and > 0, got {value}")
    return value


def _moments(moments: np.ndarray) -> str:
    return "(" + ", ".join(f"{m:.9g}" for m in moments) + ")"
