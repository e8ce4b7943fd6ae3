"""Validated, immutable triangle meshes with exact mass properties.

A :class:`Mesh` owns ``vertices (V, 3) float64`` and ``faces (F, 3) int32`` (C-contiguous,
read-only); it is validated and repaired on construction (:mod:`engine.geometry.repair`: duplicate
vertices merged, degenerate faces and unreferenced vertices dropped, all reported in
``mesh.repair``; ``strict=True`` rejects instead). :func:`load_mesh` reads any format
trimesh reads. Mass properties (volume, centre of mass, inertia tensor) come from exact
signed-tetrahedron integration and exist only for closed, consistently oriented meshes;
open meshes such as planes are valid meshes without mass properties.
"""

from __future__ import annotations

import dataclasses
import os
from functools import cached_property
from pathlib import Path
from typing import TYPE_CHECKING, Any, BinaryIO

import numpy as np

from engine.errors import InvalidArgumentError, InvalidMeshError
from engine.geometry.repair import (
    RepairReport,
    as_faces,
    as_vertices,
    merge_equal,
    readonly,
    repair_arrays,
)

if TYPE_CHECKING:  # imported where used: its import (scipy, networkx) is ~0.45 s of a start
    import trimesh

__all__ = ["MassProperties", "Mesh", "load_mesh"]


@dataclasses.dataclass(frozen=True)
class MassProperties:
    """Rigid-body mass properties of a closed mesh of uniform density.

    Attributes
    ----------
    mass : float
        ``density * volume``.
    volume : float
        Enclosed volume (positive).
    center_mass : (3,) float64
        Centre of mass in the mesh frame.
    inertia : (3, 3) float64
        Inertia tensor about the centre of mass, axes of the mesh frame, scaled by density.
    """

    mass: float
    volume: float
    center_mass: np.ndarray
    inertia: np.ndarray


class Mesh:
    """An immutable, validated triangle mesh, repaired by default.

    Parameters
    ----------
    vertices : (V, 3) array_like of int or float
        Vertex coordinates; stored as float64. All must be finite.
    faces : (F, 3) array_like of int, or of integral float
        Vertex indices per triangle, in ``0..V-1``; stored as int32. Counter-clockwise
        seen from outside for closed meshes.
    strict : bool, default False
        Reject, instead of repairing, a mesh that repair would change: vertices within
        `merge_tolerance` of another used vertex, faces that repeat a vertex index (in
        the input or after merging) or have zero area, and unreferenced vertices (repair
        drops them too, so the arrays would not be the caller's). A mesh that passes has
        exactly the arrays given (converted).
    merge_tolerance : float, optional
        Absolute distance (``>= 0``) within which vertices are merged; 0 merges exact
        duplicates only. Default ``2**-21 * D`` (≈ 4.77e-7 D, four float32 steps of a
        coordinate the size of the mesh; why: :mod:`engine.geometry.repair`), ``D`` the
        bounding-box diagonal of the vertices used by faces that do not repeat an index.
    area_tolerance : float, optional
        Faces with area ``<=`` this (after merging) have zero area. Default
        ``1e-12 * D**2``.

    By default the mesh is repaired (:mod:`engine.geometry.repair`): duplicate vertices merged,
    faces that repeat a vertex index or have zero area dropped, unreferenced vertices
    dropped; `repair` says what changed and maps kept faces and vertices to the input's.
    A mesh that needs no repair keeps the given arrays bit for bit. Open edges, flipped
    faces and non-manifold edges are valid (the mesh is then not watertight).

    Raises
    ------
    InvalidMeshError
        Wrong shape or dtype, non-finite coordinates, indices out of range, no face left
        after repair, or (`strict`) anything repair would change; the message says what
        and where (counts and the first input indices).
    InvalidArgumentError
        A tolerance negative or not finite.

    Attributes
    ----------
    vertices : (V', 3) float64, read-only
    faces : (F', 3) int32, read-only
    repair : RepairReport
        What repair changed (``repair.changed`` is False for a clean mesh), with
        ``repair.face_map (F',)`` and ``repair.vertex_map (V,)`` to the input's indices.
    """

    def __init__(
        self,
        vertices: Any,
        faces: Any,
        *,
        strict: bool = False,
        merge_tolerance: float | None = None,
        area_tolerance: float | None = None,
    ) -> None:
        v = as_vertices(vertices)
        f = as_faces(faces, v.shape[0])
        v, f, area, report = repair_arrays(v, f, merge_tolerance, area_tolerance)
        if strict and report.changed:
            raise InvalidMeshError(
                f"mesh needs repair (rejected in strict mode): {report.describe()}"
            )
        self.vertices = readonly(v)
        self.faces = readonly(f)
        self._areas = readonly(area)
        self.repair: RepairReport = report

    # ------------------------------------------------------------------ geometry
    @property
    def n_vertices(self) -> int:
        """Number of vertices ``V`` (including unreferenced ones)."""
        return int(self.vertices.shape[0])

    @property
    def n_faces(self) -> int:
        """Number of faces ``F``."""
        return int(self.faces.shape[0])

    @cached_property
    def triangles(self) -> np.ndarray:
        """(F, 3, 3) float64, read-only: ``triangles[f, k]`` is vertex ``k`` of face ``f``."""
        return readonly(self.vertices[self.faces])

    @property
    def areas(self) -> np.ndarray:
        """(F,) float64, read-only: face areas."""
        return self._areas

    @cached_property
    def face_normals(self) -> np.ndarray:
        """(F, 3) float64, read-only: unit normals by the right-hand rule on the winding."""
        t = self.triangles
        n = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
        return readonly(n / np.linalg.norm(n, axis=1, keepdims=True))

    @cached_property
    def bounds(self) -> np.ndarray:
        """(2, 3) float64, read-only: min and max corner of the referenced vertices."""
        p = self.triangles.reshape(-1, 3)
        return readonly(np.stack([p.min(axis=0), p.max(axis=0)]))

    @property
    def diameter(self) -> float:
        """Length of the bounding-box diagonal (float)."""
        return float(np.linalg.norm(self.bounds[1] - self.bounds[0]))

    # ------------------------------------------------------------------ topology
    @cached_property
    def _edge_counts(self) -> tuple[bool, bool]:
        f = self.faces.astype(np.int64)
        directed = f[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
        n = self.n_vertices
        _, d_count = np.unique(directed[:, 0] * n + directed[:, 1], return_counts=True)
        und = np.sort(directed, axis=1)
        _, u_count = np.unique(und[:, 0] * n + und[:, 1], return_counts=True)
        return bool((u_count == 2).all()), bool((d_count == 1).all())

    @property
    def is_closed(self) -> bool:
        """True if every undirected edge is shared by exactly two faces."""
        return self._edge_counts[0]

    @property
    def is_consistently_oriented(self) -> bool:
        """True if no directed edge occurs twice (adjacent faces wind oppositely)."""
        return self._edge_counts[1]

    @property
    def is_watertight(self) -> bool:
        """Closed and consistently oriented: each edge used once in each direction."""
        return self.is_closed and self.is_consistently_oriented

    # ------------------------------------------------------------------ mass properties
    @cached_property
    def _unit_mass(self) -> tuple[float, np.ndarray, np.ndarray]:
        need = "volume, centre of mass and inertia need a closed, consistently oriented mesh"
        if not self.is_closed:
            raise InvalidMeshError(f"mesh is not closed (an edge lacks two faces); {need}")
        if not self.is_consistently_oriented:
            raise InvalidMeshError(f"mesh is not consistently oriented (an edge repeats); {need}")
        # Integrate over the tetrahedra (o, a, b, c), o the box centre (less cancellation).
        o = 0.5 * (self.bounds[0] + self.bounds[1])
        t = self.triangles - o
        a, b, c = t[:, 0], t[:, 1], t[:, 2]
        vol6 = np.einsum("ij,ij->i", a, np.cross(b, c))  # 6 x signed tetra volume
        volume = float(vol6.sum()) / 6.0
        if not volume > 1e-12 * self.diameter**3:
            if volume < 0:
                raise InvalidMeshError(
                    f"mesh is inside-out: signed volume {volume:.6g} < 0 "
                    "(faces wind clockwise seen from outside; reverse them)"
                )
            raise InvalidMeshError(f"mesh encloses no volume (signed volume {volume:.3g})")
        s = a + b + c  # sum of the tetra's vertices (the fourth is the origin)
        first = (vol6[:, None] * s).sum(axis=0) / 24.0  # int x dV = vol * s / 4
        # int x_i x_j dV = vol/20 * (sum_k v_ki v_kj + s_i s_j) over the 4 vertices
        second = sum(np.einsum("t,ti,tj->ij", vol6, p, p) for p in (a, b, c, s)) / 120.0
        com = first / volume
        cov = second - volume * np.outer(com, com)  # second moments about the centre of mass
        cov = 0.5 * (cov + cov.T)
        inertia = np.trace(cov) * np.eye(3) - cov
        return volume, readonly(com + o), readonly(inertia)

    @property
    def volume(self) -> float:
        """Enclosed volume (float, > 0); raises InvalidMeshError for open/unoriented meshes."""
        return self._unit_mass[0]

    @property
    def center_mass(self) -> np.ndarray:
        """(3,) float64: centre of mass (uniform density); closed meshes only."""
        return self._unit_mass[1]

    @property
    def inertia(self) -> np.ndarray:
        """(3, 3) float64: unit-density inertia tensor about the centre of mass."""
        return self._unit_mass[2]

    def mass_properties(self, density: float = 1.0) -> MassProperties:
        """Mass, volume, centre of mass and inertia for a uniform `density` (> 0)."""
        density = float(density)
        if not (np.isfinite(density) and density > 0):
            raise InvalidArgumentError(f"density must be finite and > 0, got {density}")
        volume, com, inertia = self._unit_mass
        return MassProperties(density * volume, volume, com, readonly(density * inertia))

    # ------------------------------------------------------------------ conversions
    def to_trimesh(self) -> trimesh.Trimesh:
        """A ``trimesh.Trimesh`` copy (``process=False``: same vertices and faces)."""
        import trimesh

        return trimesh.Trimesh(
            vertices=self.vertices.copy(), faces=self.faces.copy(), process=False
        )

    def transformed(self, matrix: Any) -> Mesh:
        """A new Mesh with vertices mapped by a (4, 4) affine `matrix` (float64).

        The last row must be ``[0, 0, 0, 1]``. A reflection (negative determinant)
        reverses the winding so closed meshes stay outward-oriented.
        """
        m = np.asarray(matrix, dtype=np.float64)
        if m.shape != (4, 4) or not np.isfinite(m).all():
            raise InvalidArgumentError(f"matrix must be a finite (4, 4) array, got {m.shape}")
        if not np.array_equal(m[3], [0.0, 0.0, 0.0, 1.0]):
            raise InvalidArgumentError(f"matrix must be affine (last row 0 0 0 1), got {m[3]}")
        v = self.vertices @ m[:3, :3].T + m[:3, 3]
        faces = self.faces[:, ::-1] if np.linalg.det(m[:3, :3]) < 0 else self.faces
        return Mesh(v, faces)

    def __repr__(self) -> str:
        return (
            f"Mesh(n_vertices={self.n_vertices}, n_faces={self.n_faces}, "
            f"watertight={self.is_watertight}, diameter={self.diameter:.6g})"
        )


# ---------------------------------------------------------------------- loading
def _scene_arrays(scene: trimesh.Scene, merge: bool) -> tuple[np.ndarray, np.ndarray]:
    """Concatenate every Trimesh of `scene` in world coordinates; (V,3) float64, (F,3) int64."""
    import trimesh

    verts, faces, offset = [], [], 0
    for node in scene.graph.nodes_geometry:
        transform, name = scene.graph[node]
        geom = scene.geometry.get(name)
        if not isinstance(geom, trimesh.Trimesh) or len(geom.faces) == 0:
            continue
        v = np.asarray(geom.vertices, dtype=np.float64)
        f = np.asarray(geom.faces, dtype=np.int64)
        t = np.asarray(transform, dtype=np.float64)
        v = v @ t[:3, :3].T + t[:3, 3]
        if np.linalg.det(t[:3, :3]) < 0:
            f = f[:, ::-1]
        if merge:  # equal coordinates only (STL stores a triangle soup), in file order
            first, inverse = merge_equal(v)
            v, f = v[first], inverse[f]
        verts.append(v)
        faces.append(f + offset)
        offset += len(v)
    if not faces:
        raise InvalidMeshError("file holds no triangle mesh (no faces found)")
    return np.concatenate(verts), np.concatenate(faces)


def load_mesh(
    source: str | os.PathLike[str] | BinaryIO,
    file_type: str | None = None,
    *,
    strict: bool = False,
    merge_tolerance: float | None = None,
    area_tolerance: float | None = None,
    merge_vertices: bool = True,
) -> Mesh:
    """Read a mesh file (STL, OBJ, PLY, OFF, GLB/GLTF, ... anything trimesh reads).

    Parameters
    ----------
    source : str, os.PathLike or binary file-like
        A path, or an open binary stream (then `file_type` is required).
    file_type : str, optional
        Format name such as ``"stl"``; by default taken from the path's suffix.
    strict, merge_tolerance, area_tolerance
        Passed to :class:`Mesh`: the loaded arrays are repaired (or, `strict`, rejected
        if they need repair) and ``mesh.repair`` reports the changes, with indices into
        the loaded arrays (after `merge_vertices`).
    merge_vertices : bool, default True
        Part of loading, not of repair (not reported, and allowed in strict mode): merge
        vertices with equal coordinates within each geometry, so that triangle soups
        (STL) become connected meshes; vertices keep the order of their first occurrence.
        No face is dropped by this merge.

    Returns
    -------
    Mesh
        All triangle geometries of the file (scene graphs are flattened with their
        transforms) concatenated into one mesh.

    Raises
    ------
    InvalidMeshError
        Missing or unreadable file, unknown format, no triangles, or an invalid mesh.
    InvalidArgumentError
        A stream given without `file_type`, or a `source` of the wrong type.
    ImportError, MemoryError
        Passed through: a missing reader dependency or exhausted memory is not the file's
        fault.
    """
    if isinstance(source, (str, os.PathLike)):
        path = Path(source)
        if not path.is_file():
            raise InvalidMeshError(f"cannot read mesh: no such file {str(path)!r}")
        file_obj: Any = path
        file_type = file_type or path.suffix.lstrip(".").lower()
        where = repr(str(path))
    elif hasattr(source, "read"):
        if not file_type:
            raise InvalidArgumentError("file_type is required when reading from a stream")
        file_obj, where = source, "stream"
    else:
        raise InvalidArgumentError(
            f"source must be a path or a binary file-like, got {type(source).__name__}"
        )
    if not file_type:
        raise InvalidMeshError(f"cannot read mesh {where}: unknown file type (no suffix)")
    file_type = file_type.lower().lstrip(".")
    import trimesh

    try:
        scene = trimesh.load_scene(file_obj, file_type=file_type, process=False)
        vertices, faces = _scene_arrays(scene, merge_vertices)
    except InvalidMeshError as exc:
        raise InvalidMeshError(f"cannot read {file_type} mesh {where}: {exc}") from exc
    except (ImportError, MemoryError):  # the installation or the machine, not the file
        raise
    except Exception as exc:  # trimesh raises many types for a bad file; none may escape
        raise InvalidMeshError(
            f"cannot read {file_type} mesh {where}: {type(exc).__name__}: {exc}"
        ) from exc
    try:
        return Mesh(
            vertices,
            faces,
            strict=strict,
            merge_tolerance=merge_tolerance,
            area_tolerance=area_tolerance,
        )
    except InvalidMeshError as exc:
        raise InvalidMeshError(f"invalid {file_type} mesh {where}: {exc}") from exc
