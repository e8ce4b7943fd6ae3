"""Tests of engine.geometry.repair: repair by default, strict rejection, reports, round trips."""

from __future__ import annotations

import json

import numpy as np
import pytest
import trimesh
from hypothesis import given, settings
from hypothesis import strategies as st

import engine
from engine.errors import InvalidArgumentError, InvalidMeshError
from engine.geometry.mesh import Mesh, load_mesh
from engine.geometry.repair import (
    DEFAULT_MERGE_TOLERANCE,
    RepairReport,
    _weld,
    merge_equal,
    repair_mesh,
)
from engine.geometry.shapes import (
    box,
    icosphere,
    noisy_sphere,
    paper_sphere,
    plane,
    stretched_sphere,
    torus,
    uv_sphere,
)

TETRA_V = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], dtype=float)
TETRA_F = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])


# ---------------------------------------------------------------------- oracles
def diameter(v: np.ndarray, f: np.ndarray) -> float:
    """Bounding-box diagonal of the vertices used by faces without a repeated index."""
    ok = (f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 2] != f[:, 0])
    used = v[np.unique(f[ok])]
    return float(np.linalg.norm(used.max(axis=0) - used.min(axis=0)))


def greedy_oracle(points: np.ndarray, tol: float) -> np.ndarray:
    """O(n^2) statement of the merge rule: each point in order joins the earliest
    representative within `tol`, else becomes one."""
    rep = np.empty(len(points), dtype=np.int64)
    reps: list[int] = []
    for i, p in enumerate(points):
        near = [j for j in reps if ((points[j] - p) ** 2).sum() <= tol * tol]
        rep[i] = near[0] if near else i
        if not near:
            reps.append(i)
    return rep


def assert_consistent(mesh: Mesh, v_in: np.ndarray, f_in: np.ndarray) -> None:
    """face_map and vertex_map say how the input became the mesh."""
    r = mesh.repair
    assert r.face_map.dtype == r.vertex_map.dtype == np.int64
    assert r.vertex_map.shape == (len(v_in),) and r.face_map.shape == (mesh.n_faces,)
    np.testing.assert_array_equal(mesh.faces, r.vertex_map[f_in[r.face_map]])
    mapped = np.flatnonzero(r.vertex_map >= 0)
    dist = np.linalg.norm(mesh.vertices[r.vertex_map[mapped]] - v_in[mapped], axis=1)
    assert (dist <= r.merge_tolerance).all()
    # each kept vertex is the first input vertex of its cluster, coordinates unchanged
    np.testing.assert_array_equal(mesh.vertices, v_in[r.kept_vertices])
    np.testing.assert_array_equal(r.vertex_map[r.kept_vertices], np.arange(mesh.n_vertices))
    assert (np.diff(r.kept_vertices) > 0).all()  # input order
    assert r.merged_vertices + r.unreferenced_vertices + mesh.n_vertices == len(v_in)
    dropped = np.concatenate([r.repeated_index_faces, r.zero_area_faces, r.face_map])
    np.testing.assert_array_equal(np.sort(dropped), np.arange(len(f_in)))
    assert np.isin(np.arange(mesh.n_vertices), mesh.faces).all()  # no unreferenced left
    tolerances = {"merge_tolerance": r.merge_tolerance, "area_tolerance": r.area_tolerance}
    assert not Mesh(mesh.vertices, mesh.faces, **tolerances).repair.changed  # idempotent
    if r.merge_tolerance == DEFAULT_MERGE_TOLERANCE * diameter(v_in, f_in):
        assert not Mesh(mesh.vertices, mesh.faces).repair.changed  # D can only shrink


def assert_unchanged(mesh: Mesh, v_in, f_in) -> None:
    """Bit for bit the given arrays, converted to float64 / int32."""
    assert not mesh.repair.changed
    assert mesh.vertices.tobytes() == np.asarray(v_in).astype(np.float64).tobytes()
    assert mesh.faces.tobytes() == np.asarray(f_in).astype(np.int32).tobytes()
    np.testing.assert_array_equal(mesh.repair.face_map, np.arange(len(f_in)))
    np.testing.assert_array_equal(mesh.repair.vertex_map, np.arange(len(v_in)))
    assert mesh.repair.repeated_index_faces.size == mesh.repair.zero_area_faces.size == 0


# ---------------------------------------------------------------------- the merge rule
@settings(max_examples=60, deadline=None)
@given(
    st.integers(1, 120),
    st.integers(0, 2**32 - 1),
    st.sampled_from([0.0, 1e-9, 0.01, 0.05, 0.2, 0.5, 2.0]),
    st.sampled_from([1.0, 1e-4, 1e6]),
    st.booleans(),
)
def test_weld_follows_the_greedy_rule(n, seed, rel_tol, scale, on_grid):
    rng = np.random.default_rng(seed)
    points = rng.random((n, 3)) * scale - 0.3 * scale
    if on_grid:  # exact duplicates and exact ties at the tolerance
        points = np.round(points / scale * 10) * scale / 10
    copies = rng.integers(0, n, n // 3)
    points[rng.integers(0, n, n // 3)] = points[copies]
    tol = rel_tol * scale
    rep, count = _weld(points, tol)
    np.testing.assert_array_equal(rep, greedy_oracle(points, tol))
    assert count == np.count_nonzero(rep == np.arange(n))


def test_weld_merges_across_cell_boundaries():
    # a pair within the tolerance merges wherever it sits in the grid (anchored at the
    # lowest point), also across cell faces, edges and corners: a quantise-and-unique
    # would split pairs that straddle a cell boundary
    tol = 1e-3
    anchor = np.zeros(3)
    for o in np.array([[1, 0, 0], [0, -1, 0], [0, 0, 1], [1, 1, 1], [-1, 1, -1]], float):
        o *= 0.999 * tol / np.linalg.norm(o)
        for shift in np.linspace(0.5, 0.5 + 3 * tol, 31):  # through a whole cell (3 tol)
            p = np.full(3, shift)
            rep, count = _weld(np.stack([anchor, p, p + o]), tol)
            np.testing.assert_array_equal(rep, [0, 1, 1])
            rep, count = _weld(np.stack([anchor, p, p + 1.002 * o]), tol)
            np.testing.assert_array_equal(rep, [0, 1, 2])


@settings(max_examples=30, deadline=None)
@given(st.integers(1, 200), st.integers(0, 2**32 - 1))
def test_merge_equal_keeps_first_occurrences(n, seed):
    rng = np.random.default_rng(seed)
    points = np.round(rng.normal(size=(n, 3)), 1)  # many equal points
    points[rng.random((n, 3)) < 0.2] *= -0.0  # and signed zeros, equal to zeros
    first, inverse = merge_equal(points)
    _, index = np.unique(points, axis=0, return_index=True)
    np.testing.assert_array_equal(first, np.sort(index))
    np.testing.assert_array_equal(points[first][inverse], points)
    assert first.dtype == inverse.dtype == np.int64


def test_merge_equal_leaves_non_finite_points_alone():
    points = np.array([[0.0, 0.0, 0.0], [np.nan, 0.0, 0.0], [0.0, 0.0, 0.0]])
    first, inverse = merge_equal(points)
    np.testing.assert_array_equal(first, [0, 1, 2])
    np.testing.assert_array_equal(inverse, [0, 1, 2])


# ---------------------------------------------------------------------- clean meshes
CLEAN = {
    "icosphere": lambda: icosphere(3),
    "uv_sphere": lambda: uv_sphere(24, 12, radius=0.5),
    "paper_sphere": lambda: paper_sphere(1224),
    "noisy_sphere": lambda: noisy_sphere(3, eta_r=1.5, seed=2),
    "stretched_sphere": lambda: stretched_sphere(2, eta=3.0),
    "plane": lambda: plane((4.0, 2.0), divisions=9),
    "box": lambda: box((1.0, 2.0, 3.0), center=(1e3, -5.0, 0.25)),
    "torus": lambda: torus(major_segments=24, minor_segments=12),
}


@pytest.mark.parametrize("name", sorted(CLEAN))
def test_clean_shapes_are_unchanged_bit_for_bit(name):
    shape = CLEAN[name]()
    assert_unchanged(shape, shape.vertices, shape.faces)  # the shapes are built by Mesh
    v, f = np.array(shape.vertices), np.array(shape.faces)
    assert_unchanged(Mesh(v, f), v, f)
    assert_unchanged(Mesh(v, f, strict=True), v, f)
    out_v, out_f, report = repair_mesh(v, f)
    assert out_v.tobytes() == v.tobytes() and out_f.tobytes() == f.tobytes()
    assert not report.changed


def test_clean_meshes_of_other_dtypes_are_unchanged():
    sphere = icosphere(2)
    v32 = sphere.vertices.astype(np.float32)  # float32-representable coordinates
    for f in (sphere.faces.astype(np.int64), sphere.faces.astype(np.uint16), sphere.faces + 0.0):
        assert_unchanged(Mesh(v32, f, strict=True), v32, f)
    ints = (box((2.0, 4.0, 6.0)).vertices).astype(np.int64)  # integer coordinates
    assert_unchanged(Mesh(ints, box().faces, strict=True), ints, box().faces)
    signed_zeros = TETRA_V * [[-1.0, 1.0, 1.0]]  # -0.0 stays -0.0
    mesh = Mesh(signed_zeros, TETRA_F[:, ::-1])
    assert_unchanged(mesh, signed_zeros, TETRA_F[:, ::-1])
    assert np.signbit(mesh.vertices[0, 0])


def test_transformed_meshes_stay_clean():
    rot = np.eye(4)
    rot[:3, :3] = trimesh.transformations.rotation_matrix(0.7, [1, 2, 3])[:3, :3]
    rot[:3, 3] = [10.0, -3.0, 0.5]
    for shape in (torus(), plane(divisions=4), box((1.0, 2.0, 3.0))):
        moved = shape.transformed(rot)
        assert not moved.repair.changed and moved.n_faces == shape.n_faces


# ---------------------------------------------------------------------- each defect
def test_near_duplicates_within_the_tolerance_merge_and_just_outside_do_not():
    tol = DEFAULT_MERGE_TOLERANCE * diameter(TETRA_V, TETRA_F)  # sqrt(3) * 2**-21
    direction = np.array([3.0, 4.0, -12.0]) / 13.0  # into the box: the same diameter
    for factor, merged in ((0.0, True), (0.99, True), (1.01, False)):
        v = np.vstack([TETRA_V, TETRA_V[3] + factor * tol * direction])
        f = np.vstack([TETRA_F[:3], [[1, 2, 4]]])  # the last face uses the copy of 3
        mesh = Mesh(v, f)
        assert mesh.repair.merge_tolerance == pytest.approx(tol, rel=1e-12)
        assert_consistent(mesh, v, f)
        assert mesh.repair.merged_vertices == int(merged)
        assert mesh.is_watertight == merged  # merging closes the tetrahedron
        if merged:
            np.testing.assert_array_equal(mesh.faces, TETRA_F)
            np.testing.assert_array_equal(mesh.repair.vertex_map, [0, 1, 2, 3, 3])
            with pytest.raises(InvalidMeshError, match=r"1 vertex/vertices \(indices 4\) lie "):
                Mesh(v, f, strict=True)
        else:
            assert_unchanged(Mesh(v, f, strict=True), v, f)


def test_merge_tolerance_zero_merges_exact_duplicates_only():
    v = np.vstack([TETRA_V, TETRA_V[3], TETRA_V[2] + [0.0, 1e-12, 0.0]])
    f = np.vstack([TETRA_F[:2], [[0, 4, 5]], [[1, 2, 3]]])  # copies of 3 and (near) 2
    mesh = Mesh(v, f, merge_tolerance=0.0)
    assert mesh.repair.merge_tolerance == 0.0
    np.testing.assert_array_equal(mesh.repair.vertex_map, [0, 1, 2, 3, 3, 4])
    assert_consistent(mesh, v, f)
    merged_all = Mesh(v, f)  # default: 1e-12 is within 2**-21 * sqrt(3)
    np.testing.assert_array_equal(merged_all.faces, [[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])


def test_faces_that_repeat_an_index_after_merging_are_dropped():
    v = np.vstack([TETRA_V, TETRA_V[1] + [0.0, 0.0, 1e-9]])  # 4 merges into 1
    f = np.vstack([TETRA_F, [[0, 1, 4]], [[4, 1, 2]], [[2, 2, 3]]])
    mesh = Mesh(v, f)
    np.testing.assert_array_equal(mesh.repair.repeated_index_faces, [4, 5, 6])
    assert mesh.repair.zero_area_faces.size == 0
    np.testing.assert_array_equal(mesh.faces, TETRA_F)
    assert mesh.repair.merged_vertices == 1 and mesh.repair.unreferenced_vertices == 0
    assert_consistent(mesh, v, f)
    with pytest.raises(InvalidMeshError) as caught:
        Mesh(v, f, strict=True)
    assert "3 face(s) (indices 4, 5, 6) repeat a vertex index (after merging)" in str(caught.value)


def test_unreferenced_vertices_are_dropped_and_fail_strict_mode():
    v = np.vstack([[[9.0, 9.0, 9.0]], TETRA_V, [[-7.0, 0.0, 0.0]]])  # 0 and 5 unused
    f = TETRA_F + 1
    mesh = Mesh(v, f)
    assert mesh.repair.changed and mesh.repair.unreferenced_vertices == 2
    np.testing.assert_array_equal(mesh.repair.vertex_map, [-1, 0, 1, 2, 3, -1])
    np.testing.assert_array_equal(mesh.vertices, TETRA_V)
    assert mesh.diameter == pytest.approx(np.sqrt(3.0))  # the unused ones never counted
    assert_consistent(mesh, v, f)
    with pytest.raises(InvalidMeshError) as caught:
        Mesh(v, f, strict=True)
    message = str(caught.value)
    assert "2 vertex/vertices (indices 0, 5) are used by no face" in message
    assert "strict" in message and "pass " not in message


def test_strict_message_lists_counts_and_first_indices():
    v = np.vstack([TETRA_V, [[2, 0, 0], [3, 0, 0]]])
    f = np.vstack([TETRA_F] + [[[1, 4, 5]]] * 7 + [[[0, 0, 2]]])
    with pytest.raises(InvalidMeshError) as caught:
        Mesh(v, f, strict=True)
    message = str(caught.value)
    assert "7 face(s) (indices 4, 5, 6, 7, 8, ...) have zero area" in message
    assert "1 face(s) (indices 11) repeat a vertex index and would be dropped" in message
    # what strict rejects is exactly what repair would change
    assert message.endswith(Mesh(v, f).repair.describe())


def test_open_flipped_and_non_manifold_meshes_are_not_changed():
    v = np.vstack([TETRA_V, [[1.0, 1.0, 1.0]]])
    cases = {
        "open": TETRA_F[:3],
        "flipped": np.vstack([TETRA_F[:3], TETRA_F[3, ::-1]]),
        "non-manifold": np.vstack([TETRA_F, [[1, 2, 4]]]),
    }
    for name, f in cases.items():
        used = v[: f.max() + 1]
        mesh = Mesh(used, f, strict=True)
        assert_unchanged(mesh, used, f)
        assert not mesh.is_watertight, name


def test_all_degenerate_after_merging_is_an_error():
    v = [[0.0, 0.0, 0.0], [1e-9, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1e-9, 0.0]]
    with pytest.raises(InvalidMeshError, match=r"all 2 face\(s\) are degenerate.*no face is left"):
        Mesh(v, [[0, 1, 2], [0, 2, 3]], merge_tolerance=1e-6)


def test_tolerances_are_validated():
    for name in ("merge_tolerance", "area_tolerance"):
        for bad in (-1e-9, np.nan, np.inf, "x"):
            with pytest.raises(InvalidArgumentError, match=name):
                Mesh(TETRA_V, TETRA_F, **{name: bad})
            with pytest.raises(InvalidArgumentError, match=name):
                repair_mesh(TETRA_V, TETRA_F, **{name: bad})


# ---------------------------------------------------------------------- report
def test_report_is_frozen_read_only_and_summarises_to_json():
    v = np.vstack([TETRA_V, TETRA_V[2], [[5.0, 5.0, 5.0]]])
    f = np.vstack([TETRA_F, [[4, 1, 3]], [[0, 0, 1]]])
    report = Mesh(v, f).repair
    assert isinstance(report, RepairReport) and engine.RepairReport is RepairReport
    assert engine.repair_mesh is repair_mesh
    with pytest.raises(AttributeError):
        report.merged_vertices = 0
    for a in (report.face_map, report.vertex_map, report.repeated_index_faces):
        with pytest.raises(ValueError):
            a[0] = 0
    summary = report.summary(limit=1)
    assert json.loads(json.dumps(summary)) == summary
    assert summary == {
        "changed": True,
        "merge_tolerance": report.merge_tolerance,
        "area_tolerance": report.area_tolerance,
        "input_vertices": 6,
        "input_faces": 6,
        "vertices": 4,
        "faces": 5,
        "merged_vertices": 1,
        "merged_vertices_first": [4],
        "unreferenced_vertices": 1,
        "unreferenced_vertices_first": [5],
        "repeated_index_faces": 1,
        "repeated_index_faces_first": [5],
        "zero_area_faces": 0,
        "zero_area_faces_first": [],
    }
    assert report.summary(0)["repeated_index_faces_first"] == []
    for bad in (-1, 1.5, True):
        with pytest.raises(InvalidArgumentError, match="limit"):
            report.summary(bad)
    clean = Mesh(TETRA_V, TETRA_F).repair
    assert not clean.changed and clean.describe() == ""
    assert clean.summary()["changed"] is False


# ---------------------------------------------------------------------- random defects
@settings(max_examples=40, deadline=None)
@given(
    st.sampled_from(["icosphere", "torus", "plane", "box", "noisy_sphere"]),
    st.integers(0, 2**32 - 1),
    st.integers(0, 4),
    st.integers(0, 4),
    st.integers(0, 4),
    st.integers(0, 3),
)
def test_random_defects_are_found_exactly(shape, seed, n_repeated, n_zero, n_near, n_unused):
    rng = np.random.default_rng(seed)
    clean = CLEAN[shape]()
    scale = 10.0 ** rng.uniform(-3, 3)
    shift = rng.normal(size=3) * scale * 10.0 ** rng.uniform(-2, 1)
    v0, f0 = clean.vertices * scale + shift, clean.faces.astype(np.int64)
    if rng.random() < 0.5:  # an open part of the mesh, compacted
        part = f0[rng.random(len(f0)) < 0.7]
        f0 = part if len(part) else f0
        used, inverse = np.unique(f0, return_inverse=True)
        v0, f0 = v0[used], inverse.reshape(-1, 3)
    assert_unchanged(Mesh(v0, f0, strict=True), v0, f0)
    tol = DEFAULT_MERGE_TOLERANCE * diameter(v0, f0)
    lo, hi = v0.min(axis=0), v0.max(axis=0)
    v, f, extra, kinds = [v0], f0.copy(), [], []
    n = len(v0)
    for _ in range(n_repeated):  # a repeated index in the input
        a, b = rng.integers(0, len(v0), 2)
        extra.append([a, a, b])
        kinds.append("repeated")
    for _ in range(n_near):  # a near copy of a vertex, within tol / 2
        k = int(rng.choice(f0.ravel()))
        u = rng.normal(size=3)
        v.append(v0[k] + 0.5 * tol * u / np.linalg.norm(u))
        j = (k + 1 + rng.integers(0, len(v0) - 1)) % len(v0)
        extra.append([k, n, j])  # repeats an index once the copy is merged
        kinds.append("repeated")
        if rng.random() < 0.5:  # a kept face goes through the copy
            face = rng.choice(np.flatnonzero((f == k).any(axis=1)))
            f[face][f[face] == k] = n
        n += 1
    for _ in range(n_zero):  # three collinear points inside the box
        p, q = lo + (hi - lo) * rng.uniform(0.2, 0.8, (2, 3))
        v.append(np.stack([p, 0.5 * (p + q), q]))
        extra.append([n, n + 1, n + 2])
        kinds.append("zero")
        n += 3
    for _ in range(n_unused):
        v.append(hi + rng.uniform(1, 2, 3) * (hi - lo + 1))
        n += 1
    v = np.vstack(v)
    f = np.vstack([f, np.array(extra, dtype=np.int64).reshape(-1, 3)])
    order = rng.permutation(len(f))
    f = f[order]  # injected faces anywhere in the list
    position = np.argsort(order)  # where each face went
    kinds = np.array(kinds, dtype=object)
    expected = {k: np.sort(position[len(f0) + np.flatnonzero(kinds == k)]) for k in kinds}

    mesh = Mesh(v, f)
    report = mesh.repair
    np.testing.assert_array_equal(report.repeated_index_faces, expected.get("repeated", []))
    np.testing.assert_array_equal(report.zero_area_faces, expected.get("zero", []))
    assert report.merge_tolerance == pytest.approx(tol, rel=1e-6)  # copies may widen D
    assert report.merged_vertices == n_near
    assert report.unreferenced_vertices == 3 * n_zero + n_unused
    assert_consistent(mesh, v, f)
    # what is kept is the clean mesh: its faces, in their new order, on its vertices
    np.testing.assert_array_equal(report.face_map, np.sort(position[: len(f0)]))
    np.testing.assert_array_equal(mesh.triangles, v0[f0[order[report.face_map]]])
    assert report.changed == bool(n_repeated + n_zero + n_near + n_unused)
    if report.changed:
        with pytest.raises(InvalidMeshError, match="mesh needs repair"):
            Mesh(v, f, strict=True)


# ---------------------------------------------------------------------- files
def dirty_arrays():
    """An icosphere (float32 coordinates) with every kind of defect; what repair must find.

    Returns ``(vertices, faces, expected)``; `expected` holds the input indices of the
    faces repair drops, and the merged and unreferenced vertex counts when the exact
    duplicate survives (in memory) and when loading merged it (every file format).
    """
    sphere = icosphere(2)
    v0 = sphere.vertices.astype(np.float32).astype(np.float64)
    f0 = sphere.faces.astype(np.int64)
    tol = DEFAULT_MERGE_TOLERANCE * diameter(v0, f0)
    n = len(v0)
    a, b, c = (int(i) for i in f0[10])  # the vertices of one face
    d, e = int(f0[100, 0]), int(f0[200, 0])  # and of others
    inward = -v0[b] / np.linalg.norm(v0[b])  # copies inside the box keep the diameter
    extra_v = np.array(
        [
            v0[a],  # n: exact copy of a
            v0[b] + 0.5 * tol * inward,  # n + 1: near copy of b, merged
            v0[c] - 1.5 * tol * v0[c] / np.linalg.norm(v0[c]),  # n + 2: just outside
            [0.125, 0.25, 0.0],  # n + 3 .. n + 5: collinear (exact in every format)
            [0.25, 0.25, 0.0],
            [0.5, 0.25, 0.0],
            [0.0, 0.0, 0.125],  # n + 6: apex of a face on an existing edge (non-manifold)
            [4.0, 4.0, 4.0],  # n + 7: used by no face
        ]
    ).astype(np.float32)
    v = np.vstack([v0, extra_v.astype(np.float64)])
    f = f0.copy()
    uses = np.flatnonzero((f == a).any(axis=1))
    f[uses[0]][f[uses[0]] == a] = n  # a kept face through the exact copy
    uses = np.flatnonzero((f == b).any(axis=1))
    f[uses[0]][f[uses[0]] == b] = n + 1  # ... through the near copy
    uses = np.flatnonzero((f == c).any(axis=1))
    f[uses[0]][f[uses[0]] == c] = n + 2  # ... through the far copy: a crack
    f[30] = f[30, ::-1]  # a flipped face
    p, q = f0[40, 0], f0[40, 1]
    kept = np.delete(f, 50, axis=0)  # a hole
    injected = {
        7: [d, d, e],  # repeated index
        60: [b, n + 1, e],  # repeated once n + 1 merges into b
        100: [n + 3, n + 4, n + 5],  # zero area
        150: [p, q, n + 6],  # a third face on edge p-q: not repaired
    }
    for at in sorted(injected):
        kept = np.insert(kept, at, injected[at], axis=0)
    expected = {
        "repeated": [7, 60],
        "zero": [100],
        "kept_special": [150, 30 + (30 >= 7)],  # the non-manifold and the flipped face
        "merged": {"memory": 2, "file": 1},  # the exact copy merges on loading
        "unreferenced": {"memory": 4, "ply": 4, "obj": 3, "stl": 3},  # 3 collinear + 1
        "tolerance": tol,
        "copies": {n: a, n + 1: b},  # the copies repair merges, and their originals
    }
    return v, kept, expected


def test_dirty_arrays_in_memory():
    v, f, expected = dirty_arrays()
    mesh = Mesh(v, f)
    r = mesh.repair
    np.testing.assert_array_equal(r.repeated_index_faces, expected["repeated"])
    np.testing.assert_array_equal(r.zero_area_faces, expected["zero"])
    assert r.merged_vertices == expected["merged"]["memory"]
    assert r.unreferenced_vertices == expected["unreferenced"]["memory"]
    assert r.merge_tolerance == pytest.approx(expected["tolerance"], rel=1e-12)
    assert np.isin(expected["kept_special"], r.face_map).all()
    assert not mesh.is_closed  # hole, crack and non-manifold edge stay
    assert_consistent(mesh, v, f)
    with pytest.raises(InvalidMeshError) as caught:
        Mesh(v, f, strict=True)
    message = str(caught.value)
    for part in (
        "2 vertex/vertices (indices 162, 163) lie within",
        "2 face(s) (indices 7, 60) repeat a vertex index (after merging)",
        "1 face(s) (indices 100) have zero area",
        "4 vertex/vertices (indices 165, 166, 167, 169) are used by no face",
    ):
        assert part in message


FORMATS = [("stl", "stl"), ("stl", "stl_ascii"), ("obj", "obj"), ("ply", "ply")]


@pytest.mark.parametrize(("ext", "file_type"), FORMATS)
def test_dirty_files_load_repaired_with_a_report(tmp_path, ext, file_type):
    v, f, expected = dirty_arrays()
    path = tmp_path / f"dirty.{ext}"
    trimesh.Trimesh(v, f, process=False).export(path, file_type=file_type)
    mesh = load_mesh(path)
    r = mesh.repair
    np.testing.assert_array_equal(r.repeated_index_faces, expected["repeated"])
    np.testing.assert_array_equal(r.zero_area_faces, expected["zero"])
    assert r.merged_vertices == expected["merged"]["file"]
    assert r.unreferenced_vertices == expected["unreferenced"][ext]
    assert r.merge_tolerance == pytest.approx(expected["tolerance"], rel=1e-6)
    assert r.merged_vertices + r.unreferenced_vertices + mesh.n_vertices == r.vertex_map.size
    np.testing.assert_array_equal(
        np.sort(np.concatenate([r.face_map, [7, 60, 100]])), np.arange(len(f))
    )
    # the kept faces are the input's, through face_map, within the merge tolerance
    np.testing.assert_allclose(mesh.triangles, v[f[r.face_map]], atol=r.merge_tolerance + 1e-8)
    assert not mesh.is_closed
    summary = r.summary()
    assert summary["repeated_index_faces_first"] == [7, 60]
    assert summary["zero_area_faces_first"] == [100]
    with pytest.raises(InvalidMeshError) as caught:
        load_mesh(path, strict=True)
    message = str(caught.value)
    assert message.startswith(f"invalid {ext} mesh {str(path)!r}: mesh needs repair")
    assert "2 face(s) (indices 7, 60) repeat a vertex index" in message
    assert "remove_degenerate" not in message


@pytest.mark.parametrize(("ext", "file_type"), FORMATS)
def test_open_flipped_and_non_manifold_files_load_unchanged(tmp_path, ext, file_type):
    v, f, expected = dirty_arrays()
    f = f[np.setdiff1d(np.arange(len(f)), [7, 60, 100])]  # the faces repair keeps
    original = np.arange(len(v))
    for copy, vertex in expected["copies"].items():
        original[copy] = vertex  # route the faces through the originals, not the copies
    used, inverse = np.unique(original[f], return_inverse=True)
    v, f = v[used], inverse.reshape(-1, 3)  # and drop unused vertices
    path = tmp_path / f"open.{ext}"
    trimesh.Trimesh(v, f, process=False).export(path, file_type=file_type)
    for mesh in (load_mesh(path), load_mesh(path, strict=True)):
        assert not mesh.repair.changed
        assert mesh.n_faces == len(f) and not mesh.is_closed
        np.testing.assert_array_equal(mesh.repair.face_map, np.arange(len(f)))
        np.testing.assert_allclose(mesh.triangles, v[f], atol=1e-8)


def test_clean_files_pass_strict_mode(tmp_path):
    for ext in ("stl", "obj", "ply"):
        path = tmp_path / f"torus.{ext}"
        torus(major_segments=12, minor_segments=6).to_trimesh().export(path)
        mesh = load_mesh(path, strict=True)  # STL's soup is merged by loading, not repair
        assert mesh.is_watertight and not mesh.repair.changed


def test_loading_merges_equal_corners_in_file_order(tmp_path):
    shape = box((1.0, 2.0, 4.0), center=(0.5, 1.0, -2.0))  # float32-exact corners
    path = tmp_path / "box.stl"
    shape.to_trimesh().export(path)
    mesh = load_mesh(path, strict=True)
    corners = shape.triangles.reshape(-1, 3)  # the soup, in file order
    _, index = np.unique(corners, axis=0, return_index=True)
    np.testing.assert_array_equal(mesh.vertices, corners[np.sort(index)])
    np.testing.assert_array_equal(mesh.triangles, shape.triangles)
    assert not mesh.repair.changed  # loading's merge is not repair
    soup = load_mesh(path, merge_vertices=False)  # then repair merges, and says so
    assert soup.repair.merged_vertices == 36 - 8 and soup.is_watertight


def test_a_non_finite_vertex_in_a_file_is_rejected(tmp_path):
    path = tmp_path / "nan.obj"
    path.write_text("v 0 0 0\nv 1 0 0\nv nan 1 0\nv 0 0 0\nf 1 2 3\nf 4 2 3\n")
    with pytest.raises(InvalidMeshError, match="non-finite"):
        load_mesh(path)


def test_exact_merging_compares_coordinates_not_cells():
    """Distinct points crowded into a 1e-13 box (every one in one grid cell of a
    tolerance-free weld) stay distinct, equal ones merge, and a difference far below
    the square root of the smallest double (1e-170: its square underflows) is a
    difference."""
    rng = np.random.default_rng(5)
    crowd = rng.uniform(0.0, 1e-13, size=(3000, 3))
    points = np.vstack([crowd, crowd[::7], [[1.0, 1.0, 1.0]], [[1e-170, 0.0, 0.0]], [[0.0] * 3]])
    first, inverse = merge_equal(points)
    distinct = np.unique(points, axis=0)
    assert len(first) == len(distinct)
    np.testing.assert_array_equal(points[first][inverse], points)
    tiny = Mesh([[0.0, 0, 0], [1e-170, 0, 0], [1, 0, 0], [0, 1, 0]], [[1, 2, 3]], merge_tolerance=0)
    assert tiny.repair.merged_vertices == 0 and tiny.repair.unreferenced_vertices == 1


def test_coordinates_too_large_to_square_are_rejected():
    with pytest.raises(InvalidMeshError, match="beyond"):
        Mesh(icosphere(1).vertices * 1e160, icosphere(1).faces)
