"""The paper's scenarios (§6) as ready-made scenes.

All bodies are spheres of unit diameter unless scaled (the paper's ε = 0.01 is relative to
the diameter), density 1, the paper's spring law (K_s = 1,000). The paper gives no time
step, speeds, tilt or friction coefficient; the values here are ours and are stated in
each docstring. Each function returns a fresh :class:`~engine.scene.Scene`.
"""

from __future__ import annotations

import math

import numpy as np

from engine.dynamics.forces import ContactModel, PaperSpring
from engine.errors import InvalidArgumentError
from engine.geometry.mesh import Mesh
from engine.geometry.shapes import PAPER_UV_SPHERES, icosphere, paper_sphere
from engine.scene import Scene
from engine.trees.halos import size_epsilon

__all__ = ["particle_on_plane", "particle_particle", "scale_difference", "sphere_grid", "sphere"]

PAPER_RELATIVE_EPSILON = 0.01
"""The paper's ε: 1 % of a sphere's diameter (given explicitly: not the scene's default)."""


def sphere(triangles: int = 1224, diameter: float = 1.0) -> Mesh:
    """The paper's sphere with ``triangles`` faces: a UV sphere for 12, 36, 140, 1,224
    triangles, an icosphere for 80·4^k."""
    if triangles in PAPER_UV_SPHERES:
        return paper_sphere(triangles, radius=diameter / 2)
    k = round(math.log(triangles / 20, 4)) if triangles >= 20 else -1
    if k < 0 or 20 * 4**k != triangles:
        raise InvalidArgumentError(
            f"no sphere with {triangles} triangles: use {sorted(PAPER_UV_SPHERES)} or 20·4^k"
        )
    return icosphere(k, radius=diameter / 2)


def particle_particle(
    triangles: int = 1224,
    speed: float = 0.5,
    offset: float = 0.0,
    gap: float = 0.05,
    scheme: str = "implicit-surrogate",
    contact_model: ContactModel | None = None,
) -> Scene:
    """Two spheres on a head-on course (no gravity): each moves at ``speed`` towards the
    other, their surfaces ``gap`` apart, B displaced sideways by ``offset`` (0: head-on).
    They bump and separate within about (gap + 0.04)/speed + 0.02 s of simulated time."""
    mesh = sphere(triangles)
    scene = Scene(gravity=(0.0, 0.0, 0.0), scheme=scheme, contact_model=contact_model)
    eps = size_epsilon(mesh, PAPER_RELATIVE_EPSILON)
    scene.add_body(mesh, (-(1 + gap) / 2, 0.0, 0.0), velocity=(speed, 0.0, 0.0), epsilon=eps)
    scene.add_body(mesh, ((1 + gap) / 2, offset, 0.0), velocity=(-speed, 0.0, 0.0), epsilon=eps)
    return scene


def particle_on_plane(
    triangles: int = 1224,
    tilt_degrees: float = 20.0,
    drop: float = 0.1,
    scheme: str = "implicit-surrogate",
    contact_model: ContactModel | None = None,
) -> Scene:
    """A sphere dropped from ``drop`` above a plane of 512 triangles (16 divisions, side
    8) tilted by ``tilt_degrees`` about y (downhill is +x), 2 uphill of its centre, under
    gravity: it hops, then rolls downhill (friction μ = 0.5, damping ratio 0.3 by default)."""
    theta = math.radians(tilt_degrees)
    normal = np.array([math.sin(theta), 0.0, math.cos(theta)])
    downhill = np.array([math.cos(theta), 0.0, -math.sin(theta)])
    model = contact_model or PaperSpring(damping=0.3, friction=0.5)
    scene = Scene(scheme=scheme, contact_model=model)
    scene.add_plane(point=(0.0, 0.0, 0.0), normal=normal, size=8.0, divisions=16, epsilon=0.01)
    # 2 uphill of the plane's centre, surfaces ``drop`` apart plus both halos
    ball = sphere(triangles)
    position = normal * (0.5 + 0.02 + drop) - 2.0 * downhill
    scene.add_body(ball, position, epsilon=size_epsilon(ball, PAPER_RELATIVE_EPSILON))
    return scene


def scale_difference(
    scale: float = 2.0,
    refine: bool = False,
    speed: float = 0.5,
    scheme: str = "implicit-surrogate",
    contact_model: ContactModel | None = None,
) -> Scene:
    """The paper's scale study: an 80-triangle unit sphere against a sphere ``scale``
    times larger, with 80 triangles (``refine=False``) or with 80·scale² triangles
    (scale 2, 4, 8 → 320, 1,280, 5,120). Head-on, no gravity; the halos (1 % of each
    diameter) start 0.05 apart."""
    small = sphere(80)
    triangles = 80 * int(round(scale)) ** 2 if refine else 80
    large = sphere(triangles, diameter=scale)
    scene = Scene(gravity=(0.0, 0.0, 0.0), scheme=scheme, contact_model=contact_model)
    reach = 0.01 * (1.0 + scale)  # ε of the two bodies
    eps_small, eps_large = (size_epsilon(m, PAPER_RELATIVE_EPSILON) for m in (small, large))
    scene.add_body(small, (-0.5, 0.0, 0.0), velocity=(speed, 0.0, 0.0), epsilon=eps_small)
    centre = scale / 2 + reach + 0.05
    scene.add_body(large, (centre, 0.0, 0.0), velocity=(-speed, 0.0, 0.0), epsilon=eps_large)
    return scene


def sphere_grid(
    shape=(4, 4, 4),
    triangles: int = 1224,
    spacing: float | None = None,
    scheme: str = "implicit-surrogate",
    contact_model: ContactModel | None = None,
    orientations: str = "aligned",
    seed: int = 0,
) -> Scene:
    """A cubic grid of spheres at rest, no gravity (nothing confines the grid, so it
    slowly expands). The paper's run is 32 × 32 × 24 = 24,576 spheres of 1,224
    triangles; all share one tree.

    ``orientations``:

    - ``"aligned"``: every sphere unrotated, centres 1.0195 apart by default: the halos of
      face neighbours (0.01 each) overlap by 0.0005, 2.5 % of their reach — "barely
      overlapping" — vertex to vertex. A UV sphere's poles then face each other along z,
      where 36 triangles meet in one vertex: 36 × 36 triangle pairs touch at each such
      contact (a worst case for the leaf work, not a generic contact).
    - ``"vertices"``: one common orientation that puts three mutually orthogonal ordinary
      vertices (not the poles; at most six triangles meet there) on the grid's axes, so
      that face neighbours again meet vertex to vertex on the line of centres, 0.0195
      apart at the default spacing — the same barely overlapping grid with generic
      vertex contacts. Raises :class:`InvalidArgumentError` for a mesh without such a
      vertex triple (the 1,224-triangle sphere has one).
    - ``"random"``: uniformly random orientations (seeded), the paper's "sphere-like
      particle shapes from a randomised parameterisation"; the default spacing is twice
      the mesh's inradius + 0.0195, so that every neighbour pair's halos overlap, by
      0.0005 … 0.0081 whatever the orientations (up to 40 % of the reach: this grid is
      not at rest; under the paper's spring law it needs dt ≲ 1e-4 for Picard).
    """
    shape = tuple(int(n) for n in shape)
    if len(shape) != 3 or min(shape) < 1:
        raise InvalidArgumentError(f"shape must be three positive counts, got {shape!r}")
    if orientations not in ("aligned", "vertices", "random"):
        raise InvalidArgumentError(
            f"orientations must be 'aligned', 'vertices' or 'random', got {orientations!r}"
        )
    mesh = sphere(triangles)
    if spacing is None:
        spacing = 2 * _inradius(mesh) + 0.0195 if orientations == "random" else 1.0195
    scene = Scene(gravity=(0.0, 0.0, 0.0), scheme=scheme, contact_model=contact_model)
    positions = np.array(list(np.ndindex(*shape)), dtype=np.float64) * float(spacing)
    quaternions = None
    if orientations == "vertices":
        quaternions = np.tile(_vertex_axes(mesh), (len(positions), 1))
    if orientations == "random":
        quaternions = np.random.default_rng(seed).normal(size=(len(positions), 4))
        quaternions /= np.linalg.norm(quaternions, axis=1)[:, None]
    eps = size_epsilon(mesh, PAPER_RELATIVE_EPSILON)
    scene.add_bodies(mesh, positions, orientations=quaternions, epsilon=eps)
    return scene


def _vertex_axes(mesh: Mesh, tolerance: float = 1e-9) -> np.ndarray:
    """(4,) unit quaternion (w, x, y, z) of a rotation taking three mutually orthogonal
    vertex directions of ``mesh`` — vertices at its largest distance r from the origin,
    shared by at most six faces, whose antipodes are vertices too — onto x, y and z."""
    v = mesh.vertices
    radius = np.linalg.norm(v, axis=1)
    valence = np.bincount(mesh.faces.ravel(), minlength=len(v))
    unit = v / np.maximum(radius, 1e-300)[:, None]
    outer = np.abs(radius - radius.max()) <= tolerance * radius.max()
    antipodal = (np.abs(unit @ unit.T + 1.0) <= tolerance).any(axis=1)
    pick = np.flatnonzero(outer & antipodal & (valence <= 6))
    d = unit[pick]
    cosines = np.abs(d @ d.T)
    for i, j in zip(*np.nonzero(np.triu(cosines <= tolerance)), strict=True):
        third = np.cross(d[i], d[j])
        if (d @ third >= 1.0 - tolerance).any():
            rotation = np.eye(4)
            rotation[:3, :3] = np.stack([d[i], d[j], third])  # rows: the vertex directions
            import trimesh

            q = trimesh.transformations.quaternion_from_matrix(rotation)
            return q / np.linalg.norm(q)
    raise InvalidArgumentError(
        "orientations='vertices' needs three mutually orthogonal vertices of at most six "
        "faces on the mesh's outer sphere, with their antipodes; this mesh has none"
    )


def _inradius(mesh: Mesh) -> float:
    """Smallest distance from the origin to the plane of a face of ``mesh``."""
    tri = mesh.vertices[mesh.faces]
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    normal /= np.linalg.norm(normal, axis=1)[:, None]
    return float(np.abs(np.einsum("ij,ij->i", normal, tri[:, 0])).min())
