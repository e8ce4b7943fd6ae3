"""Validation and repair of triangle-mesh arrays: what :class:`engine.Mesh` does on input.

Repair, in this order (every index below is an index of the *input* arrays):

1. **Merge duplicate vertices.** Among the vertices used by faces that do not repeat a
   vertex index, each vertex in input order is merged into the earliest kept vertex
   within `merge_tolerance` (Euclidean), else kept. So every vertex lies within the
   tolerance of the vertex it was merged into, kept vertices are more than the tolerance
   apart, and each kept vertex is the smallest input index of its cluster, with its own
   coordinates (bit for bit; no averaging). Exact duplicates always merge together.
2. **Drop faces that repeat a vertex index**, in the input or after merging.
3. **Drop zero-area faces**: area ``<= area_tolerance``, measured after merging.
4. **Drop unreferenced vertices**: those no kept face uses.

Kept vertices and faces stay in input order. A mesh that needs none of this comes back
as the very arrays given. Open edges, flipped faces and non-manifold edges are not
repaired: they are valid input (the mesh is then not watertight).

Default tolerances, relative to the mesh size ``D``, the bounding-box diagonal of the
vertices used by faces that do not repeat an index:

* ``merge_tolerance = 2**-21 * D`` (≈ 4.77e-7 D): four float32 rounding steps of a
  coordinate as large as ``D`` (a float32 step at ``|x| <= D`` is at most
  ``2**-23 D``). STL stores float32, and CAD exporters that compute a shared corner
  twice write copies a few steps apart: in robosuite's ``can.stl`` such copies are
  0.5-3 steps (up to 1.03e-7 D) apart; merging them closes the mesh (8 open edges
  remain at 1e-7 D, none from 2e-7 D). The closest distinct vertices in the shared real
  meshes (OBJ files written with 6 decimals) are 1.73e-6 D apart, 3.6 times the default,
  and stay apart.
* ``area_tolerance = 1e-12 * D**2``.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from engine.errors import InvalidArgumentError, InvalidMeshError
from engine.kernels.geometry.weld import weld_kernel

__all__ = [
    "DEFAULT_AREA_TOLERANCE",
    "DEFAULT_MERGE_TOLERANCE",
    "RepairReport",
    "repair_mesh",
]

DEFAULT_MERGE_TOLERANCE = 2.0**-21  # times the diameter D: four float32 steps at |x| = D
DEFAULT_AREA_TOLERANCE = 1e-12  # times D**2
_MAX_LISTED = 5  # offending indices quoted in an error message
_COORDINATE_LIMIT = 1e100  # |x|: squared differences and diameters stay finite (1e308)


def readonly(a: np.ndarray) -> np.ndarray:
    """`a` as a C-contiguous array with ``writeable = False`` (a copy if not contiguous)."""
    a = np.ascontiguousarray(a)
    a.flags.writeable = False
    return a


def _listing(idx: np.ndarray, what: str = "face(s)") -> str:
    shown = ", ".join(str(int(i)) for i in idx[:_MAX_LISTED])
    more = ", ..." if idx.size > _MAX_LISTED else ""
    return f"{idx.size} {what} (indices {shown}{more})"


# ---------------------------------------------------------------------- validation
def as_vertices(vertices: Any) -> np.ndarray:
    """Validated ``(V, 3) float64`` copy of `vertices` (numeric, finite, ``V >= 1``)."""
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
    if np.isfinite(v).all() and float(np.abs(v).max()) <= _COORDINATE_LIMIT:  # fast path
        return v
    bad = np.flatnonzero(~np.isfinite(v).all(axis=1))
    if bad.size:
        raise InvalidMeshError(
            f"vertex {int(bad[0])} has a non-finite coordinate {v[bad[0]].tolist()} "
            f"({bad.size} non-finite vertex/vertices in total)"
        )
    far = np.flatnonzero((np.abs(v) > _COORDINATE_LIMIT).any(axis=1))
    raise InvalidMeshError(
        f"vertex {int(far[0])} has a coordinate beyond ±{_COORDINATE_LIMIT:.3g} "
        f"({v[far[0]].tolist()}; {far.size} such vertex/vertices): squared distances would "
        "overflow; scale the mesh to other units"
    )


def as_faces(faces: Any, n_vertices: int) -> np.ndarray:
    """Validated ``(F, 3) int32`` copy of `faces` (integral, in ``0..n_vertices-1``, F >= 1)."""
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
    if f.min() < 0 or f.max() >= n_vertices:
        for cond, what in ((f < 0, "a negative"), (f >= n_vertices, "an out-of-range")):
            bad = np.flatnonzero(cond.any(axis=1))
            if bad.size:
                raise InvalidMeshError(
                    f"face {int(bad[0])} {f[bad[0]].astype(np.int64).tolist()} has {what} "
                    f"vertex index (valid: 0..{n_vertices - 1}); {bad.size} such face(s)"
                )
    return f.astype(np.int32)


def _tolerance(name: str, value: float | None, default: float) -> float:
    if value is None:
        return default
    try:
        tol = float(value)
    except (TypeError, ValueError) as exc:
        raise InvalidArgumentError(f"{name} must be a number, got {value!r}") from exc
    if not np.isfinite(tol) or tol < 0:
        raise InvalidArgumentError(f"{name} must be finite and >= 0, got {tol}")
    return tol


# ---------------------------------------------------------------------- report
@dataclasses.dataclass(frozen=True, eq=False)
class RepairReport:
    """What repair changed in a mesh; indices are those of the input arrays.

    Attributes
    ----------
    merge_tolerance : float
        Absolute distance within which vertices were merged.
    area_tolerance : float
        Faces with area ``<=`` this (after merging) had zero area.
    merged_vertices : int
        Input vertices merged into another (kept) vertex.
    unreferenced_vertices : int
        Input vertices dropped because no kept face uses them (or their cluster).
    repeated_index_faces : (k,) int64, read-only
        Input faces dropped for a repeated vertex index, in the input or after merging.
    zero_area_faces : (k,) int64, read-only
        Input faces dropped for zero area (and no repeated index).
    face_map : (F_kept,) int64, read-only
        Input index of each kept face.
    vertex_map : (V_in,) int64, read-only
        Kept index of each input vertex (its cluster's), -1 if dropped.

    ``merged_vertices + unreferenced_vertices + V_kept == V_in`` and the kept faces are
    ``vertex_map[input_faces[face_map]]``.
    """

    merge_tolerance: float
    area_tolerance: float
    merged_vertices: int
    unreferenced_vertices: int
    repeated_index_faces: np.ndarray
    zero_area_faces: np.ndarray
    face_map: np.ndarray
    vertex_map: np.ndarray

    @property
    def changed(self) -> bool:
        """True if repair changed the arrays (a vertex merged or dropped, a face dropped)."""
        return bool(
            self.merged_vertices
            or self.unreferenced_vertices
            or self.repeated_index_faces.size
            or self.zero_area_faces.size
        )

    @property
    def n_input_vertices(self) -> int:
        """Vertices in the input (int)."""
        return int(self.vertex_map.size)

    @property
    def n_input_faces(self) -> int:
        """Faces in the input (int)."""
        return int(self.face_map.size + self.repeated_index_faces.size + self.zero_area_faces.size)

    @property
    def kept_vertices(self) -> np.ndarray:
        """(V_kept,) int64: input index of each kept vertex (the first of its cluster)."""
        mapped = np.flatnonzero(self.vertex_map >= 0)
        _, first = np.unique(self.vertex_map[mapped], return_index=True)
        return mapped[first]

    @property
    def merged_vertex_indices(self) -> np.ndarray:
        """(merged_vertices,) int64: input indices of the vertices merged into another."""
        merged = self.vertex_map >= 0
        merged[self.kept_vertices] = False
        return np.flatnonzero(merged)

    @property
    def unreferenced_vertex_indices(self) -> np.ndarray:
        """(unreferenced_vertices,) int64: input indices of the dropped vertices."""
        return np.flatnonzero(self.vertex_map < 0)

    def summary(self, limit: int = 5) -> dict[str, Any]:
        """JSON-ready dict: tolerances, ``changed``, input and kept counts, and for each of
        ``merged_vertices``, ``unreferenced_vertices``, ``repeated_index_faces`` and
        ``zero_area_faces`` its count and, under ``<name>_first``, its first `limit`
        input indices (ascending)."""
        if isinstance(limit, bool) or not isinstance(limit, int | np.integer) or limit < 0:
            raise InvalidArgumentError(f"limit must be an int >= 0, got {limit!r}")
        lists = {
            "merged_vertices": self.merged_vertex_indices,
            "unreferenced_vertices": self.unreferenced_vertex_indices,
            "repeated_index_faces": self.repeated_index_faces,
            "zero_area_faces": self.zero_area_faces,
        }
        out: dict[str, Any] = {
            "changed": self.changed,
            "merge_tolerance": float(self.merge_tolerance),
            "area_tolerance": float(self.area_tolerance),
            "input_vertices": self.n_input_vertices,
            "input_faces": self.n_input_faces,
            "vertices": self.n_input_vertices - self.merged_vertices - self.unreferenced_vertices,
            "faces": int(self.face_map.size),
        }
        for name, idx in lists.items():
            out[name] = int(idx.size)
            out[f"{name}_first"] = [int(i) for i in idx[: int(limit)]]
        return out

    def describe(self) -> str:
        """One sentence per change, as the strict-mode error states them ("" if none)."""
        parts = []
        if self.merged_vertices:
            parts.append(
                f"{_listing(self.merged_vertex_indices, 'vertex/vertices')} lie within "
                f"{self.merge_tolerance:.3g} of an earlier vertex and would be merged into it"
            )
        if self.repeated_index_faces.size:
            after = " (after merging)" if self.merged_vertices else ""
            parts.append(
                f"{_listing(self.repeated_index_faces)} repeat a vertex index{after} "
                "and would be dropped"
            )
        if self.zero_area_faces.size:
            parts.append(
                f"{_listing(self.zero_area_faces)} have zero area "
                f"(<= {self.area_tolerance:.3g}) and would be dropped"
            )
        if self.unreferenced_vertices:
            parts.append(
                f"{_listing(self.unreferenced_vertex_indices, 'vertex/vertices')} are used by "
                "no face that is kept and would be dropped"
            )
        return "; ".join(parts)


# ---------------------------------------------------------------------- repair
def _bounds(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-axis min and max ``(3,)`` of ``points (n, 3)`` (column by column: a reduction
    along axis 0 of an (n, 3) array is several times slower)."""
    lo = np.array([points[:, k].min() for k in range(3)])
    hi = np.array([points[:, k].max() for k in range(3)])
    return lo, hi


def _areas(v: np.ndarray, f: np.ndarray) -> np.ndarray:
    """(F,) float64 areas of faces `f` (F, 3) over vertices `v` (V, 3): half the norm of
    the cross product of the edges from the first vertex (the same arithmetic as
    ``np.linalg.norm(np.cross(...), axis=1)``, without its slow axis reductions)."""
    a = v[f[:, 0]]
    u, w = v[f[:, 1]] - a, v[f[:, 2]] - a
    c0 = u[:, 1] * w[:, 2] - u[:, 2] * w[:, 1]
    c1 = u[:, 2] * w[:, 0] - u[:, 0] * w[:, 2]
    c2 = u[:, 0] * w[:, 1] - u[:, 1] * w[:, 0]
    return 0.5 * np.sqrt(c0 * c0 + c1 * c1 + c2 * c2)


def _weld(points: np.ndarray, tol: float) -> tuple[np.ndarray, int]:
    """Greedy merge of ``points (n, 3) float64`` within `tol`: ``(rep (n,) int64, count)``,
    ``rep[i]`` the index (into `points`) of the representative of point ``i``."""
    n = points.shape[0]
    lo, hi = _bounds(points)
    extent = float((hi - lo).max())
    cell = max(3.0 * tol, extent * 2.0**-40)  # >= 3 tol; cell indices stay below 2**41
    if not cell <= 4.0 * extent:  # one cell holds every point (or all coincide)
        cell = 4.0 * extent if extent > 0 else 1.0
    head = np.full(1 << (2 * n - 1).bit_length(), -1, dtype=np.int64)  # >= 2n slots
    link = np.empty(n, dtype=np.int64)
    rep = np.empty(n, dtype=np.int64)
    salt = int(np.random.default_rng().integers(0, 2**62))  # table layout only
    count = weld_kernel(points, tol, cell, lo - cell, head, link, rep, salt)
    return rep, int(count)


def merge_equal(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Merge points with equal coordinates (``-0.0 == 0.0``) in linear time: what loading
    does to a triangle soup (STL); not repair, and not reported.

    Parameters
    ----------
    points : (n, 3) float64

    Returns
    -------
    first : (k,) int64
        Index of the first occurrence of each distinct point, ascending (input order).
    inverse : (n,) int64
        Index into `first` of each point: ``points[first][inverse] == points``.

    Points with a non-finite coordinate are left as they are (:class:`engine.Mesh` then
    rejects them).
    """
    n = points.shape[0]
    identity = np.arange(n, dtype=np.int64)
    if n == 0 or not np.isfinite(points).all():
        return identity, identity
    rep = _equal_representatives(np.asarray(points, dtype=np.float64))
    first = np.flatnonzero(rep == identity)
    if first.size == n:
        return identity, identity
    index = np.empty(n, dtype=np.int64)
    index[first] = np.arange(first.size)
    return first, index[rep]


def _equal_representatives(points: np.ndarray) -> np.ndarray:
    """``rep (n,) int64``: the first index whose coordinates equal point ``i``'s (``-0.0 ==
    0.0``). A stable lexicographic sort, O(n log n) whatever the input: a hashed grid with
    no tolerance lets an upload crowd any number of distinct points into one cell."""
    p = points + 0.0  # -0.0 becomes 0.0
    order = np.lexsort((p[:, 2], p[:, 1], p[:, 0]))  # stable: a run starts at its first index
    sorted_points = p[order]
    starts = np.ones(len(p), dtype=bool)
    starts[1:] = (sorted_points[1:] != sorted_points[:-1]).any(axis=1)
    run_first = order[starts]
    rep = np.empty(len(p), dtype=np.int64)
    rep[order] = run_first[np.cumsum(starts) - 1]
    return rep


def repair_arrays(
    v: np.ndarray,
    f: np.ndarray,
    merge_tolerance: float | None = None,
    area_tolerance: float | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, RepairReport]:
    """Repair validated arrays (see :func:`repair_mesh`); also returns the kept faces'
    areas: ``(vertices (V', 3) float64, faces (F', 3) int32, areas (F',) float64, report)``.

    `v` and `f` must come from :func:`as_vertices` and :func:`as_faces`; a mesh that
    needs no repair returns them themselves.
    """
    n_v, n_f = v.shape[0], f.shape[0]
    repeated = (f[:, 0] == f[:, 1]) | (f[:, 1] == f[:, 2]) | (f[:, 2] == f[:, 0])
    used = np.zeros(n_v, dtype=bool)
    used[f[~repeated] if repeated.any() else f] = True
    members = np.flatnonzero(used)
    points = v if members.size == n_v else v[members]  # in input order
    diameter = 0.0
    if members.size:
        lo, hi = _bounds(points)
        diameter = float(np.linalg.norm(hi - lo))
    merge_tol = _tolerance("merge_tolerance", merge_tolerance, DEFAULT_MERGE_TOLERANCE * diameter)
    area_tol = _tolerance("area_tolerance", area_tolerance, DEFAULT_AREA_TOLERANCE * diameter**2)

    g = f
    if members.size:
        if merge_tol > 0:
            rep_local, count = _weld(points, merge_tol)
        else:  # exact duplicates only
            rep_local = _equal_representatives(points)
            count = int(np.count_nonzero(rep_local == np.arange(members.size)))
        if count < members.size:
            rep = np.arange(n_v, dtype=np.int32)
            rep[members] = members[rep_local]
            g = rep[f]
            repeated = (g[:, 0] == g[:, 1]) | (g[:, 1] == g[:, 2]) | (g[:, 2] == g[:, 0])
    area = _areas(v, g)
    zero = ~repeated & (area <= area_tol)
    keep = ~(repeated | zero)
    n_kept = int(np.count_nonzero(keep))
    if n_kept == 0:
        raise InvalidMeshError(
            f"all {n_f} face(s) are degenerate ({int(repeated.sum())} repeat a vertex index, "
            f"{int(zero.sum())} have zero area <= {area_tol:.3g}, after merging vertices "
            f"within {merge_tol:.3g}); no face is left"
        )
    if g is f and n_kept == n_f and members.size == n_v:  # nothing to repair
        report = RepairReport(
            merge_tol,
            area_tol,
            0,
            0,
            readonly(np.zeros(0, dtype=np.int64)),
            readonly(np.zeros(0, dtype=np.int64)),
            readonly(np.arange(n_f, dtype=np.int64)),
            readonly(np.arange(n_v, dtype=np.int64)),
        )
        return v, f, area, report

    face_map = np.flatnonzero(keep)
    kept_faces = g[face_map]
    referenced = np.zeros(n_v, dtype=bool)
    referenced[kept_faces] = True  # only representatives: faces were mapped through rep
    kept = np.flatnonzero(referenced)
    new_index = np.full(n_v, -1, dtype=np.int64)
    new_index[kept] = np.arange(kept.size)
    vertex_map = new_index if g is f else new_index[rep]
    n_mapped = int(np.count_nonzero(vertex_map >= 0))
    report = RepairReport(
        merge_tol,
        area_tol,
        n_mapped - kept.size,
        n_v - n_mapped,
        readonly(np.flatnonzero(repeated)),
        readonly(np.flatnonzero(zero)),
        readonly(face_map),
        readonly(vertex_map),
    )
    return v[kept], new_index[kept_faces].astype(np.int32), area[face_map], report


def repair_mesh(
    vertices: Any,
    faces: Any,
    *,
    merge_tolerance: float | None = None,
    area_tolerance: float | None = None,
) -> tuple[np.ndarray, np.ndarray, RepairReport]:
    """Validate and repair triangle-mesh arrays (what :class:`engine.Mesh` does by default).

    Parameters
    ----------
    vertices : (V, 3) array_like of int or float
        Finite coordinates.
    faces : (F, 3) array_like of int, or of integral float
        Vertex indices in ``0..V-1``.
    merge_tolerance : float, optional
        Absolute merge distance (``>= 0``; 0 merges exact duplicates only). Default
        ``2**-21 * D`` (module docstring).
    area_tolerance : float, optional
        Faces with area ``<=`` this are dropped (``>= 0``). Default ``1e-12 * D**2``.

    Returns
    -------
    vertices : (V', 3) float64
    faces : (F', 3) int32
    report : RepairReport
        ``report.changed`` is False exactly when the arrays are the input's, converted.

    Raises
    ------
    InvalidMeshError
        Wrong shape or dtype, non-finite coordinates, indices out of range, or no face
        left after repair.
    InvalidArgumentError
        A tolerance negative or not finite.
    """
    v = as_vertices(vertices)
    f = as_faces(faces, v.shape[0])
    v, f, _, report = repair_arrays(v, f, merge_tolerance, area_tolerance)
    return v, f, report
