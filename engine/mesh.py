"""Validated, immutable triangle meshes with exact mass properties.

A :class:`Mesh` owns ``vertices (V, 3) float64`` and ``faces (F, 3) int32`` (C-contiguous,
read-only) and is validated on construction; :func:`load_mesh` reads any format trimesh
reads. Mass properties (volume, centre of mass, inertia tensor) come from exact
signed-tetrahedron integration and exist only for closed, consistently oriented meshes;
open meshes such as planes are valid meshes without mass properties.
"""

from __future__ import annotations

import dataclasses
import os
from functools import cached_property
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np
import trimesh

from engine.errors import InvalidArgumentError, InvalidMeshError

__all__ = ["MassProperties", "Mesh", "load_mesh"]

_MAX_LISTED = 5  # offending indices quoted in an error message


def _readonly(a: np.ndarray) -> np.ndarray:
    a = np.ascontiguousarray(a)
    a.flags.writeable = False
    return a


def _listing(idx: np.ndarray) -> str:
    shown = ", ".join(str(int(i)) for i in idx[:_MAX_LISTED])
    more = ", ..." if idx.size > _MAX_LISTED else ""
    return f"{idx.size} face(s) (indices {shown}{more})"


def _as_vertices(vertices: Any) -> np.ndarray:
    try:
        v = np.asarray(vertices)
    except Exception as exc:  # ragged nested sequences and the like
        raise InvalidMeshError(f"vertices cannot be read as an array: {exc}") from exc
    if v.dtype.kind not in "iuf":
        raise InvalidMeshError(f"vertices must be numeric (int or float), got dtype {v.dtype}")
    if v.ndim != 2 or v.shape[1] != 3:
        raise InvalidMeshError(f"vertices must have shape (V, 3), got {v.shape}")
    if v.shape[0] == 0:
        raise InvalidMeshError("mesh has no vertices")
    v = v.astype(np.float64)
    bad = np.flatnonzero(~np.isfinite(v).all(axis=1))
    if bad.size:
        raise InvalidMeshError(
            f"vertex {int(bad[0])} has a non-finite coordinate {v[bad[0]].tolist()} "
            f"({bad.size} non-finite vertex/vertices in total)"
        )
    return v


def _as_faces(faces: Any, n_vertices: int) -> np.ndarray:
    try:
        f = np.asarray(faces)
    except Exception as exc:
        raise InvalidMeshError(f"faces cannot be read as an array: {exc}") from exc
    if f.ndim != 2 or f.shape[1] != 3:
        raise InvalidMeshError(f"faces must have shape (F, 3), got {f.shape}")
    if f.shape[0] == 0:
        raise InvalidMeshError("mesh has no faces")
    if f.dtype.kind == "f":
        ok = np.isfinite(f).all(axis=1) & (f == np.round(f)).all(axis=1)
        bad = np.flatnonzero(~ok)
        if bad.size:
            raise InvalidMeshError(
                f"faces must hold integer vertex indices; face {int(bad[0])} is "
                f"{f[bad[0]].tolist()} ({bad.size} non-integral face(s))"
            )
    elif f.dtype.kind not in "iu":
        raise InvalidMeshError(f"faces must hold integer vertex indices, got dtype {f.dtype}")
    if n_vertices > np.iinfo(np.int32).max:
        raise InvalidMeshError(f"too many vertices for int32 indices: {n_vertices}")
    for cond, what in ((f < 0, "a negative"), (f >= n_vertices, "an out-of-range")):
        bad = np.flatnonzero(cond.any(axis=1))
        if bad.size:
            raise InvalidMeshError(
                f"face {int(bad[0])} {f[bad[0]].astype(np.int64).tolist()} has {what} vertex "
                f"index (valid: 0..{n_vertices - 1}); {bad.size} such face(s)"
            )
    return f.astype(np.int32)


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
    """An immutable, validated triangle mesh.

    Parameters
    ----------
    vertices : (V, 3) array_like of int or float
        Vertex coordinates; stored as float64. All must be finite. Unreferenced vertices
        are allowed.
    faces : (F, 3) array_like of int, or of integral float
        Vertex indices per triangle, in ``0..V-1``; stored as int32. Counter-clockwise
        seen from outside for closed meshes.
    remove_degenerate : bool, default False
        Drop degenerate faces (a repeated vertex index or area <= `area_tolerance`)
        instead of rejecting the mesh; their original indices go to `removed_faces`.
    area_tolerance : float, optional
        Faces with area <= this are degenerate. Default ``1e-12 * diameter**2`` where
        `diameter` is the bounding-box diagonal of the referenced vertices.

    Raises
    ------
    InvalidMeshError
        Wrong shape or dtype, non-finite coordinates, indices out of range, degenerate
        faces (unless removed) or no faces left; the message says which and where.
    InvalidArgumentError
        `area_tolerance` negative or not finite.

    Attributes
    ----------
    vertices : (V, 3) float64, read-only
    faces : (F, 3) int32, read-only
    removed_faces : (R,) int64, read-only
        Original indices of the faces dropped by ``remove_degenerate=True`` (else empty).
    """

    def __init__(
        self,
        vertices: Any,
        faces: Any,
        *,
        remove_degenerate: bool = False,
        area_tolerance: float | None = None,
    ) -> None:
        v = _as_vertices(vertices)
        f = _as_faces(faces, v.shape[0])
        repeated = (f[:, 0] == f[:, 1]) | (f[:, 1] == f[:, 2]) | (f[:, 2] == f[:, 0])
        tri = v[f]
        area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
        if area_tolerance is None:
            used = tri[~repeated].reshape(-1, 3)
            diag = float(np.linalg.norm(np.ptp(used, axis=0))) if used.size else 0.0
            tol = 1e-12 * diag**2
        else:
            tol = float(area_tolerance)
            if not np.isfinite(tol) or tol < 0:
                raise InvalidArgumentError(f"area_tolerance must be finite and >= 0, got {tol}")
        zero = ~repeated & (area <= tol)
        if not remove_degenerate:
            if repeated.any():
                raise InvalidMeshError(
                    f"{_listing(np.flatnonzero(repeated))} repeat a vertex index "
                    "(pass remove_degenerate=True to drop them)"
                )
            if zero.any():
                raise InvalidMeshError(
                    f"{_listing(np.flatnonzero(zero))} have zero area (<= {tol:.3g}) "
                    "(pass remove_degenerate=True to drop them)"
                )
        removed = np.flatnonzero(repeated | zero).astype(np.int64)
        if removed.size == f.shape[0]:
            raise InvalidMeshError(f"all {f.shape[0]} face(s) are degenerate; no face is left")
        keep = np.ones(f.shape[0], dtype=bool)
        keep[removed] = False
        self.vertices = _readonly(v)
        self.faces = _readonly(f[keep])
        self.removed_faces = _readonly(removed)
        self._areas = _readonly(area[keep])

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
        return _readonly(self.vertices[self.faces])

    @property
    def areas(self) -> np.ndarray:
        """(F,) float64, read-only: face areas."""
        return self._areas

    @cached_property
    def face_normals(self) -> np.ndarray:
        """(F, 3) float64, read-only: unit normals by the right-hand rule on the winding."""
        t = self.triangles
        n = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
        return _readonly(n / np.linalg.norm(n, axis=1, keepdims=True))

    @cached_property
    def bounds(self) -> np.ndarray:
        """(2, 3) float64, read-only: min and max corner of the referenced vertices."""
        p = self.triangles.reshape(-1, 3)
        return _readonly(np.stack([p.min(axis=0), p.max(axis=0)]))

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
        return volume, _readonly(com + o), _readonly(inertia)

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
        return MassProperties(density * volume, volume, com, _readonly(density * inertia))

    # ------------------------------------------------------------------ conversions
    def to_trimesh(self) -> trimesh.Trimesh:
        """A ``trimesh.Trimesh`` copy (``process=False``: same vertices and faces)."""
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
        if merge:  # exact duplicates only: STL stores a triangle soup
            v, inverse = np.unique(v, axis=0, return_inverse=True)
            f = inverse.reshape(-1)[f]
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
    merge_vertices: bool = True,
    remove_degenerate: bool = False,
    area_tolerance: float | None = None,
) -> Mesh:
    """Read a mesh file (STL, OBJ, PLY, OFF, GLB/GLTF, ... anything trimesh reads).

    Parameters
    ----------
    source : str, os.PathLike or binary file-like
        A path, or an open binary stream (then `file_type` is required).
    file_type : str, optional
        Format name such as ``"stl"``; by default taken from the path's suffix.
    merge_vertices : bool, default True
        Merge vertices with bit-identical coordinates within each geometry, so that
        triangle soups (STL) become closed meshes. No face is dropped by merging.
    remove_degenerate, area_tolerance
        Passed to :class:`Mesh`.

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
    try:
        scene = trimesh.load_scene(file_obj, file_type=file_type, process=False)
        vertices, faces = _scene_arrays(scene, merge_vertices)
    except InvalidMeshError as exc:
        raise InvalidMeshError(f"cannot read {file_type} mesh {where}: {exc}") from exc
    except Exception as exc:  # trimesh raises many types; none may escape
        raise InvalidMeshError(
            f"cannot read {file_type} mesh {where}: {type(exc).__name__}: {exc}"
        ) from exc
    try:
        return Mesh(
            vertices, faces, remove_degenerate=remove_degenerate, area_tolerance=area_tolerance
        )
    except InvalidMeshError as exc:
        raise InvalidMeshError(f"invalid {file_type} mesh {where}: {exc}") from exc
