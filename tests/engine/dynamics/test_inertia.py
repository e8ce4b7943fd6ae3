"""Free bodies from any mesh: exact mass properties of closed meshes, the convex hull's for
open ones, user-given ones validated; the source is recorded; open meshes fall and rest."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
import trimesh

from engine import InvalidArgumentError, Mesh, PaperSpring, Scene, build_tree, shapes
from engine.dynamics.inertia import body_mass, check_inertia, hull_properties
from engine.kernels.dynamics import motion as kd


def _compact(vertices: np.ndarray, faces: np.ndarray) -> Mesh:
    """The mesh of ``faces`` with only the vertices they use."""
    used, inverse = np.unique(faces, return_inverse=True)
    return Mesh(vertices[used], inverse.reshape(-1, 3))


def open_box() -> Mesh:
    """A unit box without its top (two faces): open."""
    box = shapes.box()
    return _compact(box.vertices, box.faces[box.face_normals[:, 2] < 0.5])


def dome(segments: int = 16, rings: int = 8) -> Mesh:
    """The upper half of a UV sphere of radius 0.5: a hemisphere shell open at z = 0."""
    uv = shapes.uv_sphere(segments, rings, radius=0.5)
    return _compact(uv.vertices, uv.faces[uv.triangles.mean(axis=1)[:, 2] > 0])


def capped(shell: Mesh) -> Mesh:
    """``shell`` closed by a fan from the centre of its rim (its vertices at z ≈ 0)."""
    v = shell.vertices
    rim = np.flatnonzero(np.abs(v[:, 2]) < 1e-9)
    rim = rim[np.argsort(np.arctan2(v[rim, 1], v[rim, 0]))]  # counter-clockwise from +z
    centre = len(v)
    fan = [(centre, rim[(i + 1) % len(rim)], rim[i]) for i in range(len(rim))]  # facing -z
    return Mesh(np.vstack([v, v[rim].mean(axis=0)]), np.vstack([shell.faces, fan]))


# ---------------------------------------------------------------------- mass properties
def test_a_closed_mesh_keeps_its_exact_mass_properties_bit_for_bit():
    ball = shapes.icosphere(2, radius=0.5)
    exact = ball.mass_properties(2.5)
    scene = Scene()
    a = scene.add_body(ball, density=2.5)
    b = scene.add_body(ball, mass=3.0)
    assert scene.masses[a] == exact.mass
    np.testing.assert_array_equal(scene.inertia[a], exact.inertia)
    np.testing.assert_array_equal(scene.centers[a], exact.center_mass)
    unit = ball.mass_properties(1.0)
    assert scene.masses[b] == unit.mass * (3.0 / unit.volume)
    np.testing.assert_array_equal(scene.inertia[b], unit.inertia * (3.0 / unit.volume))
    assert scene.mass_source.tolist() == ["mesh", "mesh"]


@pytest.mark.parametrize("make", [open_box, dome])
def test_an_open_mesh_takes_the_mass_properties_of_its_convex_hull(make):
    shell = make()
    assert not shell.is_closed
    hull = shapes.box() if make is open_box else capped(shell)
    assert hull.is_watertight  # the hull, as a closed mesh (a UV sphere's quads are planar)
    exact = hull.mass_properties(2.0)
    found = body_mass(shell, density=2.0)
    assert found.source == "convex_hull"
    assert found.mass == pytest.approx(exact.mass, rel=1e-12)
    np.testing.assert_allclose(found.center, exact.center_mass, rtol=0, atol=1e-13)
    np.testing.assert_allclose(found.inertia, exact.inertia, rtol=0, atol=1e-13 * exact.mass)
    # mass given: the same distribution scaled to it
    scaled = body_mass(shell, mass=5.0)
    np.testing.assert_allclose(scaled.inertia, exact.inertia * 5.0 / exact.mass, atol=1e-13)
    assert scaled.mass == 5.0 and scaled.source == "convex_hull"


def test_hull_properties_equal_trimesh_on_an_irregular_open_mesh():
    rough = shapes.noisy_sphere(2, eta_r=1.3, seed=5)
    keep = rough.triangles.mean(axis=1) @ np.array([0.3, -0.5, 0.8]) < 0.2  # a cut-off cap
    shell = _compact(rough.vertices, rough.faces[keep])
    volume, centre, inertia = hull_properties(shell.vertices)
    oracle = trimesh.Trimesh(shell.vertices, shell.faces, process=False).convex_hull
    assert volume == pytest.approx(oracle.volume, rel=1e-12)
    np.testing.assert_allclose(centre, oracle.center_mass, rtol=0, atol=1e-12)
    np.testing.assert_allclose(inertia, oracle.moment_inertia, rtol=0, atol=1e-12)


def test_given_mass_inertia_and_centre():
    shell, box = open_box(), shapes.box()
    scene = Scene()
    moments = [0.2, 0.3, 0.4]
    tensor = [[0.3, 0.05, 0.0], [0.05, 0.3, 0.0], [0.0, 0.0, 0.4]]
    a = scene.add_body(shell, mass=2.0, inertia=moments)
    b = scene.add_body(shell, mass=2.0, inertia=tensor, center_of_mass=(0.0, 0.0, -0.2))
    c = scene.add_body(shell, mass=2.0, center_of_mass=(0.1, 0.0, 0.0))
    d = scene.add_body(box, mass=2.0, inertia=moments)  # a closed mesh: the user's wins
    e = scene.add_body(shapes.plane(), mass=1.0, inertia=moments)  # flat: given only
    f = scene.add_plane()
    np.testing.assert_array_equal(scene.inertia[a], np.diag(moments))
    np.testing.assert_array_equal(scene.inertia[b], tensor)
    np.testing.assert_array_equal(scene.centers[a], [0, 0, 0])  # the hull's centre
    np.testing.assert_array_equal(scene.centers[b], [0, 0, -0.2])
    np.testing.assert_array_equal(scene.centers[c], [0.1, 0, 0])
    hull = box.mass_properties(1.0)  # the open box's hull is the box: scaled to mass 2
    np.testing.assert_allclose(scene.inertia[c], hull.inertia * 2.0 / hull.volume, rtol=1e-12)
    np.testing.assert_array_equal(scene.inertia[d], np.diag(moments))
    np.testing.assert_allclose(scene.centers[e], [0, 0, 0], atol=1e-15)  # area centroid
    np.testing.assert_array_equal(scene.inverse_inertia[a], np.diag(1 / np.array(moments)))
    assert scene.masses[[a, b, c, d, e]].tolist() == [2.0] * 4 + [1.0]
    assert scene.mass_source.tolist() == [
        "given",
        "given",
        "convex_hull",
        "given",
        "given",
        "fixed",
    ]
    assert np.isinf(scene.masses[f])


@pytest.mark.parametrize(
    ("inertia", "message"),
    [
        ([[1, 0.5, 0], [0, 1, 0], [0, 0, 1]], r"inertia must be symmetric: \[0\]\[1\]"),
        ([1, -1, 1], "must be positive definite"),
        ([[1, 2, 0], [2, 1, 0], [0, 0, 1]], "must be positive definite"),
        ([1, 1, 3], "violate the triangle inequality: 3 > 1 \\+ 1"),
        ([1, np.nan, 1], "must be finite"),
        ([1, 1], r"\(3, 3\) tensor or 3 principal moments, got shape \[2\]"),
        ("heavy", "principal moments"),
    ],
)
def test_invalid_inertia_is_rejected_with_what_is_wrong(inertia, message):
    with pytest.raises(InvalidArgumentError, match=message):
        check_inertia(inertia)
    scene = Scene()
    with pytest.raises(InvalidArgumentError, match=message):
        scene.add_body(open_box(), mass=1.0, inertia=inertia)
    assert len(scene) == 0 and len(scene.trees) == 0


def test_a_plate_passes_the_triangle_inequality_at_equality():
    plate = np.array([1.0, 2.0, 3.0 * (1 + 1e-9)])  # I3 = I1 + I2, up to rounding
    np.testing.assert_array_equal(check_inertia(plate), np.diag(plate))


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({}, "convex hull is flat .* give mass and inertia"),
        ({"mass": 2.0}, "convex hull is flat"),
        ({"density": 1.0, "inertia": [1, 1, 1]}, "need mass"),
        ({"center_of_mass": [0, 0, 0]}, "need mass"),
        ({"mass": 1.0, "center_of_mass": [0, np.inf, 0]}, "center_of_mass must be 3 finite"),
        ({"mass": 1.0, "density": 1.0}, "density or mass"),
        ({"mass": 0.0, "inertia": [1, 1, 1]}, "mass must be finite and > 0"),
    ],
)
def test_bad_mass_arguments_name_the_problem(kwargs, message):
    scene = Scene()
    with pytest.raises(InvalidArgumentError, match=message):
        scene.add_body(shapes.plane(), **kwargs)  # flat: its hull has no volume
    assert len(scene) == 0


def test_a_tree_of_an_open_mesh_is_a_free_body_too():
    shell = open_box()
    scene = Scene()
    body = scene.add_body(build_tree(shell, 0.01), density=3.0)
    assert scene.mass_source[body] == "convex_hull"
    assert scene.masses[body] == pytest.approx(3.0)  # the unit box's volume, times 3


# ---------------------------------------------------------------------- falling and resting
def _lowest(scene: Scene, body: int, mesh: Mesh) -> float:
    """Height of the lowest vertex of ``body`` (whose mesh is ``mesh``)."""
    rot = np.empty((len(scene), 3, 3))
    kd.rotation_matrices(scene.orientations, rot)
    return float(
        ((mesh.vertices - scene.centers[body]) @ rot[body].T + scene.positions[body])[:, 2].min()
    )


@pytest.mark.parametrize("make", [open_box, dome])
def test_an_open_mesh_falls_on_a_plane_and_comes_to_rest(make):
    """Tilted, 2 cm above the halos, under a damped law: it lands, tips onto its base or rim
    and rests there, never deeper than the halos, on its hull's mass properties (a step
    whose Picard iteration does not settle on a contact switch is redone as half steps)."""
    shell = make()
    scene = Scene(contact_model=PaperSpring(damping=0.3), max_halvings=4)
    scene.add_plane(size=4.0, divisions=4)
    tilt = (np.cos(0.1), np.sin(0.1), 0.0, 0.0)
    body = scene.add_body(shell, orientation=tilt)
    assert scene.mass_source.tolist() == ["fixed", "convex_hull"]
    reach = scene.epsilon.sum()  # the halos of the body and the plane
    lifted = scene.positions.copy()
    lifted[body, 2] += reach + 0.02 - _lowest(scene, body, shell)
    scene.set_state(positions=lifted)
    deepest = 0.0
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no step may move a body by more than its ε
        for _ in range(1400):
            stats = scene.step(1e-3)
            assert stats.converged
            deepest = max(deepest, stats.max_overlap)
    assert np.isfinite(scene.positions).all() and np.isfinite(scene.velocities).all()
    assert deepest < 1.0  # never deeper than the halos: the triangles never crossed
    assert np.linalg.norm(scene.velocities[body]) < 1e-3
    assert np.linalg.norm(scene.angular_velocities[body]) < 1e-2
    gap = _lowest(scene, body, shell)
    assert 0.0 < gap <= reach  # resting in the halos, above the plane
    up = np.empty((len(scene), 3, 3))
    kd.rotation_matrices(scene.orientations, up)
    assert up[body][2, 2] > 0.999  # tipped flat onto its base or rim
