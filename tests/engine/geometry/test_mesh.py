"""Tests of engine.geometry.mesh: validation, topology, exact mass properties and file loading."""

from __future__ import annotations

import io

import numpy as np
import pytest
import trimesh
from hypothesis import given, settings
from hypothesis import strategies as st

from engine.errors import InvalidArgumentError, InvalidMeshError
from engine.geometry.mesh import MassProperties, Mesh, load_mesh
from engine.geometry.repair import RepairReport
from engine.geometry.shapes import box, noisy_sphere, plane, torus

TETRA_V = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], dtype=float)
TETRA_F = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])

finite = st.floats(-10.0, 10.0, allow_nan=False)
lengths = st.floats(0.1, 5.0)


def rotation(q) -> np.ndarray:
    """(3, 3) rotation matrix of a (not necessarily unit) quaternion (w, x, y, z)."""
    w, x, y, z = np.asarray(q, dtype=float) / np.linalg.norm(q)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def box_inertia(a: float, b: float, c: float) -> np.ndarray:
    """Unit-density inertia of an a x b x c box about its centre (closed form)."""
    m = a * b * c
    return m / 12.0 * np.diag([b * b + c * c, a * a + c * c, a * a + b * b])


def parallel_axis(inertia: np.ndarray, mass: float, d: np.ndarray) -> np.ndarray:
    """Shift an inertia tensor about the centre of mass by offset d (Steiner)."""
    return inertia + mass * (d @ d * np.eye(3) - np.outer(d, d))


# ---------------------------------------------------------------------- validation
@pytest.mark.parametrize(
    ("vertices", "faces", "match"),
    [
        ([[0, 0, 0], [1, 0, 0], [np.nan, 1, 0]], [[0, 1, 2]], "vertex 2 has a non-finite"),
        ([[0, 0, 0], [np.inf, 0, 0], [0, 1, 0]], [[0, 1, 2]], "vertex 1 has a non-finite"),
        (TETRA_V, [[0, 2, 1], [0, 1, 4]], r"face 1 \[0, 1, 4\] has an out-of-range"),
        (TETRA_V, [[0, 2, 1], [1, 2, 3], [0, -1, 3]], "face 2 .* has a negative"),
        (TETRA_V, np.zeros((0, 3), int), "no faces"),
        (np.zeros((0, 3)), [[0, 1, 2]], "no vertices"),
        (TETRA_V[:, :2], TETRA_F, r"vertices must have shape \(V, 3\)"),
        (TETRA_V.ravel(), TETRA_F, r"vertices must have shape \(V, 3\)"),
        (TETRA_V, TETRA_F[:, :2], r"faces must have shape \(F, 3\)"),
        (TETRA_V, [[0, 1, 2, 3]], r"faces must have shape \(F, 3\)"),
        (TETRA_V, [[0.0, 1.0, 2.0], [0.0, 1.5, 3.0]], "face 1 is .* non-integral"),
        (TETRA_V, [[0.0, 1.0, np.nan]], "face 0 is .* non-integral"),
        (TETRA_V, [["0", "1", "2"]], "integer vertex indices"),
        (TETRA_V, [[True, False, True]], "integer vertex indices"),
        (TETRA_V.astype(str), TETRA_F, "vertices must be numeric"),
    ],
)
def test_invalid_meshes_are_rejected_with_a_precise_message(vertices, faces, match):
    with pytest.raises(InvalidMeshError, match=match):
        Mesh(vertices, faces)


def test_degenerate_faces_are_repaired_by_default_and_rejected_when_strict():
    v = np.vstack([TETRA_V, [[2, 0, 0], [3, 0, 0]]])  # 4, 5 collinear with 1
    f = np.vstack([TETRA_F, [[1, 4, 5]], TETRA_F[:1], [[1, 5, 4]], [[0, 0, 2]]])
    mesh = Mesh(v, f)
    report = mesh.repair
    assert isinstance(report, RepairReport) and report.changed
    np.testing.assert_array_equal(report.zero_area_faces, [4, 6])
    np.testing.assert_array_equal(report.repeated_index_faces, [7])
    assert report.zero_area_faces.dtype == report.repeated_index_faces.dtype == np.int64
    np.testing.assert_array_equal(report.face_map, [0, 1, 2, 3, 5])
    # 4 and 5 were used only by dropped faces
    np.testing.assert_array_equal(report.vertex_map, [0, 1, 2, 3, -1, -1])
    assert (report.merged_vertices, report.unreferenced_vertices) == (0, 2)
    assert mesh.n_faces == 5 and mesh.n_vertices == 4
    np.testing.assert_array_equal(mesh.faces, np.vstack([TETRA_F, TETRA_F[:1]]))
    np.testing.assert_array_equal(mesh.vertices, TETRA_V)
    with pytest.raises(InvalidMeshError) as caught:
        Mesh(v, f, strict=True)
    message = str(caught.value)
    assert message.startswith("mesh needs repair (rejected in strict mode): ")
    assert "1 face(s) (indices 7) repeat a vertex index and would be dropped" in message
    tol = 1e-12 * (3**2 + 1**2 + 1**2)  # default: 1e-12 D**2, D the diagonal of [0, 3]x[0, 1]^2
    assert f"2 face(s) (indices 4, 6) have zero area (<= {tol:.3g}) and would be dropped" in message
    assert "2 vertex/vertices (indices 4, 5) are used by no face" in message
    assert "remove_degenerate" not in message and "pass" not in message
    with pytest.raises(InvalidMeshError, match=r"1 face\(s\) \(indices 1\) repeat a vertex index"):
        Mesh(TETRA_V, [[0, 2, 1], [1, 1, 3]], strict=True)
    assert Mesh(TETRA_V, TETRA_F, strict=True).repair.changed is False


def test_area_tolerance_and_all_degenerate():
    tiny = [[0, 0, 0], [1, 0, 0], [0, 1e-3, 0]]  # area 5e-4
    assert Mesh(tiny, [[0, 1, 2]]).n_faces == 1
    assert Mesh(tiny, [[0, 1, 2]], area_tolerance=4e-4, strict=True).n_faces == 1
    for strict in (False, True):
        with pytest.raises(InvalidMeshError, match=r"1 have zero area <= 0.001.*no face is left"):
            Mesh(tiny, [[0, 1, 2]], area_tolerance=1e-3, strict=strict)
        all_repeat = r"all 1 face\(s\) are degenerate \(1 repeat a vertex"
        with pytest.raises(InvalidMeshError, match=all_repeat):
            Mesh([[0, 0, 0]] * 3, [[0, 1, 2]], strict=strict)  # merged into one vertex
    for bad in (-1.0, np.nan, np.inf):
        with pytest.raises(InvalidArgumentError, match="area_tolerance"):
            Mesh(tiny, [[0, 1, 2]], area_tolerance=bad)
        with pytest.raises(InvalidArgumentError, match="merge_tolerance"):
            Mesh(tiny, [[0, 1, 2]], merge_tolerance=bad)


def test_storage_is_typed_contiguous_and_read_only():
    mesh = Mesh(TETRA_V.astype(np.float32), TETRA_F.astype(np.float64))
    assert mesh.vertices.dtype == np.float64 and mesh.vertices.shape == (4, 3)
    assert mesh.faces.dtype == np.int32 and mesh.faces.shape == (4, 3)
    tri = mesh.triangles
    assert tri.shape == (4, 3, 3) and tri.dtype == np.float64 and mesh.triangles is tri
    for a in (mesh.vertices, mesh.faces, tri, mesh.face_normals, mesh.areas, mesh.bounds):
        assert a.flags.c_contiguous and not a.flags.writeable
        with pytest.raises(ValueError):
            a[0] = 0
    np.testing.assert_array_equal(tri[3], TETRA_V[[1, 2, 3]])


def test_geometry_of_a_box():
    mesh = box((1.0, 2.0, 3.0), center=(1.0, -1.0, 0.5))
    np.testing.assert_allclose(mesh.bounds, [[0.5, -2.0, -1.0], [1.5, 0.0, 2.0]])
    assert mesh.diameter == pytest.approx(np.sqrt(14.0))
    assert mesh.areas.sum() == pytest.approx(2 * (2 + 3 + 6))
    np.testing.assert_allclose(np.linalg.norm(mesh.face_normals, axis=1), 1.0)
    # outward: the normal points away from the centre
    centroid_dir = mesh.triangles.mean(axis=1) - [1.0, -1.0, 0.5]
    assert (np.einsum("ij,ij->i", mesh.face_normals, centroid_dir) > 0).all()
    assert "n_faces=12" in repr(mesh) and "watertight=True" in repr(mesh)


# ---------------------------------------------------------------------- topology
def test_topology_flags_and_mass_property_errors():
    closed = Mesh(TETRA_V, TETRA_F)
    assert closed.is_closed and closed.is_consistently_oriented and closed.is_watertight
    flipped = Mesh(TETRA_V, np.vstack([TETRA_F[:3], TETRA_F[3, ::-1]]))
    assert flipped.is_closed and not flipped.is_consistently_oriented
    with pytest.raises(InvalidMeshError, match="not consistently oriented"):
        _ = flipped.volume
    opened = Mesh(TETRA_V, TETRA_F[:3])
    assert not opened.is_closed and opened.is_consistently_oriented
    for attr in ("volume", "center_mass", "inertia"):
        with pytest.raises(InvalidMeshError, match="not closed"):
            getattr(opened, attr)
    with pytest.raises(InvalidMeshError, match="not closed"):
        opened.mass_properties()
    inside_out = Mesh(TETRA_V, TETRA_F[:, ::-1])
    assert inside_out.is_watertight
    with pytest.raises(InvalidMeshError, match="inside-out"):
        _ = inside_out.volume
    ground = plane()
    assert ground.n_faces == 2 and not ground.is_closed
    with pytest.raises(InvalidMeshError, match="not closed"):
        _ = ground.inertia


def test_non_manifold_edge_is_not_closed():
    v = np.vstack([TETRA_V, [[1, 1, 1]]])
    f = np.vstack([TETRA_F, [[1, 2, 4]]])  # edge 1-2 now has three faces
    mesh = Mesh(v, f)
    assert not mesh.is_closed and not mesh.is_watertight


# ---------------------------------------------------------------------- mass properties
@settings(max_examples=30, deadline=None)
@given(st.tuples(lengths, lengths, lengths), st.tuples(finite, finite, finite))
def test_box_mass_properties_are_exact(extents, center):
    a, b, c = extents
    mesh = box(extents, center)
    assert mesh.volume == pytest.approx(a * b * c, rel=1e-12)
    np.testing.assert_allclose(mesh.center_mass, center, atol=1e-12)
    np.testing.assert_allclose(mesh.inertia, box_inertia(a, b, c), rtol=1e-10, atol=1e-12)


@settings(max_examples=30, deadline=None)
@given(st.tuples(lengths, lengths, lengths), st.tuples(finite, finite, finite))
def test_corner_tetrahedron_matches_closed_form(scale, offset):
    # Vertices 0, a e_x, b e_y, c e_z: V = abc/6, centroid (a, b, c)/4 and, about the
    # origin, int x^2 = V a^2/10, int xy = V ab/20 (direct integration).
    a, b, c = scale
    mesh = Mesh(TETRA_V * scale + offset, TETRA_F)
    vol = a * b * c / 6.0
    s = np.array(scale)
    com = s / 4.0
    second = vol / 20.0 * (np.outer(s, s) + np.diag(s * s))  # int x_i x_j about origin
    cov = second - vol * np.outer(com, com)
    expected = np.trace(cov) * np.eye(3) - cov  # off-diagonal: +V ab/80 etc.
    assert mesh.volume == pytest.approx(vol, rel=1e-10)
    np.testing.assert_allclose(mesh.center_mass, com + offset, rtol=1e-10, atol=1e-10)
    np.testing.assert_allclose(mesh.inertia, expected, rtol=1e-8, atol=1e-10 * vol)
    assert mesh.inertia[0, 1] == pytest.approx(vol * a * b / 80.0, rel=1e-8)
    assert mesh.inertia[0, 2] == pytest.approx(vol * a * c / 80.0, rel=1e-8)
    assert mesh.inertia[1, 2] == pytest.approx(vol * b * c / 80.0, rel=1e-8)


@settings(max_examples=40, deadline=None)
@given(
    st.tuples(lengths, lengths, lengths),
    st.tuples(finite, finite, finite),
    st.tuples(finite, finite, finite, finite).filter(lambda q: np.linalg.norm(q) > 0.1),
)
def test_rotated_box_inertia_is_r_i_rt(extents, translation, quaternion):
    rot = rotation(quaternion)
    matrix = np.eye(4)
    matrix[:3, :3], matrix[:3, 3] = rot, translation
    mesh = box(extents).transformed(matrix)
    expected = rot @ box_inertia(*extents) @ rot.T
    scale = np.trace(expected)
    assert mesh.volume == pytest.approx(np.prod(extents), rel=1e-10)
    np.testing.assert_allclose(mesh.center_mass, translation, atol=1e-10)
    np.testing.assert_allclose(mesh.inertia, expected, atol=1e-10 * scale)
    np.testing.assert_allclose(mesh.inertia, mesh.inertia.T)
    assert np.linalg.eigvalsh(mesh.inertia).min() > 0


def test_two_offset_boxes_have_the_composite_inertia():
    # Distinct non-zero products of inertia: swapping xy/xz/yz would be caught.
    parts = [
        ((1.0, 2.0, 3.0), np.array([0.0, 0.0, 0.0])),
        ((1.0, 1.0, 1.0), np.array([3.0, 1.0, -2.0])),
    ]
    meshes = [box(e, c) for e, c in parts]
    mesh = Mesh(
        np.vstack([m.vertices for m in meshes]),
        np.vstack([meshes[0].faces, meshes[1].faces + 8]),
    )
    masses = [np.prod(e) for e, _ in parts]
    total = sum(masses)
    com = sum(m * c for m, (_, c) in zip(masses, parts, strict=True)) / total
    expected = sum(
        parallel_axis(box_inertia(*e), m, c - com) for m, (e, c) in zip(masses, parts, strict=True)
    )
    assert mesh.volume == pytest.approx(total)
    np.testing.assert_allclose(mesh.center_mass, com, atol=1e-12)
    np.testing.assert_allclose(mesh.inertia, expected, rtol=1e-12, atol=1e-12)
    off = expected[[0, 0, 1], [1, 2, 2]]
    assert len(set(np.round(off, 6))) == 3 and (off != 0).all()


@pytest.mark.parametrize(
    "mesh", [noisy_sphere(2, eta_r=1.5, seed=3), torus(), box((1, 2, 3), (1, 2, 3))]
)
def test_mass_properties_agree_with_trimesh(mesh):
    oracle = mesh.to_trimesh()
    assert mesh.volume == pytest.approx(oracle.volume, rel=1e-10)
    np.testing.assert_allclose(mesh.center_mass, oracle.center_mass, atol=1e-10)
    np.testing.assert_allclose(mesh.inertia, oracle.moment_inertia, atol=1e-10)


def test_mass_properties_scale_with_density():
    mesh = box((1.0, 2.0, 3.0), (1, 1, 1))
    props = mesh.mass_properties(density=2.5)
    assert isinstance(props, MassProperties)
    assert props.mass == pytest.approx(15.0) and props.volume == pytest.approx(6.0)
    np.testing.assert_allclose(props.center_mass, [1, 1, 1])
    np.testing.assert_allclose(props.inertia, 2.5 * box_inertia(1, 2, 3))
    with pytest.raises(AttributeError):
        props.mass = 1.0  # frozen
    for bad in (0.0, -1.0, np.nan, np.inf):
        with pytest.raises(InvalidArgumentError, match="density"):
            mesh.mass_properties(bad)


# ---------------------------------------------------------------------- conversions
def test_transformed_handles_reflection_and_rejects_bad_matrices():
    mesh = box((1.0, 2.0, 3.0))
    mirror = np.diag([-1.0, 1.0, 1.0, 1.0])
    image = mesh.transformed(mirror)
    assert image.is_watertight and image.volume == pytest.approx(6.0)
    np.testing.assert_array_equal(image.vertices[:, 0], -mesh.vertices[:, 0])
    np.testing.assert_array_equal(mesh.transformed(np.eye(4)).faces, mesh.faces)
    projective = np.eye(4)
    projective[3, 0] = 1.0
    for bad in (np.eye(3), projective, np.full((4, 4), np.nan)):
        with pytest.raises(InvalidArgumentError, match="matrix"):
            mesh.transformed(bad)


def test_to_trimesh_keeps_vertices_and_faces():
    mesh = torus(major_segments=8, minor_segments=4)
    tm = mesh.to_trimesh()
    assert isinstance(tm, trimesh.Trimesh)
    np.testing.assert_array_equal(tm.vertices, mesh.vertices)
    np.testing.assert_array_equal(tm.faces, mesh.faces)


# ---------------------------------------------------------------------- loading
@pytest.mark.parametrize("ext", ["stl", "obj", "ply", "off", "glb"])
def test_load_round_trip(tmp_path, ext):
    mesh = torus(major_segments=12, minor_segments=6)
    path = tmp_path / f"torus.{ext}"
    mesh.to_trimesh().export(path)
    for loaded in (load_mesh(path), load_mesh(str(path))):
        assert loaded.n_faces == mesh.n_faces
        assert loaded.is_watertight  # STL's triangle soup is merged
        assert loaded.volume == pytest.approx(mesh.volume, rel=1e-6)
    with open(path, "rb") as stream:
        loaded = load_mesh(stream, file_type=ext)
    assert loaded.volume == pytest.approx(mesh.volume, rel=1e-6)


def test_load_from_bytes_stream():
    data = box((1.0, 2.0, 3.0)).to_trimesh().export(file_type="stl")
    mesh = load_mesh(io.BytesIO(data), file_type="STL")
    assert mesh.n_faces == 12 and mesh.n_vertices == 8
    assert mesh.volume == pytest.approx(6.0)
    with pytest.raises(InvalidArgumentError, match="file_type is required"):
        load_mesh(io.BytesIO(data))


@pytest.mark.parametrize("ext", ["glb", "obj"])
def test_load_scene_concatenates_geometries(tmp_path, ext):
    shifted = np.eye(4)
    shifted[:3, 3] = [5.0, 0.0, 0.0]
    scene = trimesh.Scene()
    scene.add_geometry(box((1.0, 1.0, 1.0)).to_trimesh(), geom_name="a")
    scene.add_geometry(box((1.0, 2.0, 3.0)).to_trimesh(), geom_name="b", transform=shifted)
    path = tmp_path / f"scene.{ext}"
    scene.export(path)
    mesh = load_mesh(path)
    assert mesh.n_faces == 24 and mesh.is_watertight
    assert mesh.volume == pytest.approx(7.0)
    np.testing.assert_allclose(mesh.center_mass, [30.0 / 7.0, 0.0, 0.0], atol=1e-6)


@pytest.mark.parametrize("ext", ["stl", "obj", "ply", "off", "glb"])
def test_garbage_raises_invalid_mesh_error(tmp_path, ext):
    path = tmp_path / f"garbage.{ext}"
    path.write_bytes(b"\x00\x17not a mesh\xff" * 37)
    with pytest.raises(InvalidMeshError, match="cannot read"):
        load_mesh(path)
    with pytest.raises(InvalidMeshError, match="cannot read"):
        load_mesh(io.BytesIO(path.read_bytes()), file_type=ext)


def test_missing_unknown_and_invalid_sources(tmp_path):
    with pytest.raises(InvalidMeshError, match="no such file"):
        load_mesh(tmp_path / "missing.stl")
    odd = tmp_path / "mesh.nosuchformat"
    odd.write_bytes(b"solid x\nendsolid x\n")
    with pytest.raises(InvalidMeshError, match="cannot read"):
        load_mesh(odd)
    empty = tmp_path / "empty.stl"
    empty.write_bytes(b"solid x\nendsolid x\n")
    with pytest.raises(InvalidMeshError, match="no faces"):
        load_mesh(empty)
    with pytest.raises(InvalidArgumentError, match="source"):
        load_mesh(42)
