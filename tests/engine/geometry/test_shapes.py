"""Tests of engine.geometry.shapes: counts, closedness, orientation and analytic volumes."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from engine.errors import InvalidArgumentError, InvalidMeshError
from engine.geometry.mesh import Mesh
from engine.geometry.shapes import (
    PAPER_UV_SPHERES,
    box,
    icosphere,
    noisy_sphere,
    paper_sphere,
    plane,
    stretched_sphere,
    torus,
    uv_sphere,
)

SPHERE = 4.0 / 3.0 * np.pi


def assert_closed_outward(mesh: Mesh) -> None:
    assert mesh.is_closed and mesh.is_consistently_oriented and mesh.is_watertight
    assert mesh.volume > 0  # positive signed volume: outward winding


def radii(mesh: Mesh) -> np.ndarray:
    return np.linalg.norm(mesh.vertices, axis=1)


# ---------------------------------------------------------------------- icosphere
@pytest.mark.parametrize("k", range(5))
def test_icosphere_counts_and_radius(k):
    mesh = icosphere(k, radius=2.5)
    assert mesh.n_faces == 20 * 4**k  # 20, 80, 320, 1280, 5120
    assert mesh.n_vertices == 10 * 4**k + 2  # Euler: V - E + F = 2
    np.testing.assert_allclose(radii(mesh), 2.5, rtol=1e-14)
    assert_closed_outward(mesh)
    np.testing.assert_allclose(mesh.center_mass, 0.0, atol=1e-12)
    # icosahedral symmetry: isotropic inertia
    np.testing.assert_allclose(mesh.inertia, mesh.inertia[0, 0] * np.eye(3), atol=1e-12)


def test_icosphere_volume_converges_to_the_ball():
    errors = np.array([1.0 - icosphere(k).volume / SPHERE for k in range(6)])
    assert (errors > 0).all()  # inscribed convex polyhedron
    ratios = errors[:-1] / errors[1:]
    assert (ratios[1:] > 3.5).all() and (ratios[1:] < 4.5).all()  # second order in h
    assert errors[4] < 3e-3
    assert icosphere(3, radius=2.0).volume == pytest.approx(8 * icosphere(3).volume)


# ---------------------------------------------------------------------- UV spheres
@settings(max_examples=25, deadline=None)
@given(st.integers(3, 40), st.integers(2, 30))
def test_uv_sphere_counts_and_topology(segments, rings):
    mesh = uv_sphere(segments, rings, radius=1.5)
    assert mesh.n_faces == 2 * segments * (rings - 1)
    assert mesh.n_vertices == segments * (rings - 1) + 2
    np.testing.assert_allclose(radii(mesh), 1.5, rtol=1e-14)
    assert_closed_outward(mesh)
    assert mesh.volume < 1.5**3 * SPHERE
    np.testing.assert_allclose(mesh.bounds[:, 2], [-1.5, 1.5])


@pytest.mark.parametrize("n", [12, 36, 140, 1224])
def test_paper_spheres(n):
    segments, rings = PAPER_UV_SPHERES[n]
    assert 2 * segments * (rings - 1) == n
    mesh = paper_sphere(n)
    assert mesh.n_faces == n
    np.testing.assert_allclose(radii(mesh), 1.0, rtol=1e-14)
    assert_closed_outward(mesh)
    # each pole is a fan of `segments` triangles
    apex = np.isclose(mesh.triangles[..., 2], 1.0).any(axis=1)
    assert apex.sum() == segments


def test_paper_1224_sphere_is_36_by_18():
    assert PAPER_UV_SPHERES[1224] == (36, 18)
    with pytest.raises(InvalidArgumentError, match="no paper sphere with 100"):
        paper_sphere(100)


def test_uv_sphere_volume_converges():
    errors = [1.0 - uv_sphere(2 * n, n).volume / SPHERE for n in (8, 16, 32, 64)]
    assert all(e > 0 for e in errors)
    assert all(3.0 < a / b < 5.0 for a, b in zip(errors, errors[1:], strict=False))


# ---------------------------------------------------------------------- noisy spheres
@settings(max_examples=15, deadline=None)
@given(st.floats(1.0, 3.0), st.integers(0, 2**31), st.integers(1, 6), st.floats(0.5, 2.0))
def test_noisy_sphere_radii_lie_in_the_band(eta_r, seed, octaves, radius):
    mesh = noisy_sphere(2, eta_r=eta_r, seed=seed, octaves=octaves, radius=radius)
    r = radii(mesh)
    assert r.min() >= radius * (1 - 1e-12) and r.max() <= radius * eta_r * (1 + 1e-12)
    # the normalised noise attains both ends of [radius, radius * eta_r]
    assert r.min() == pytest.approx(radius) and r.max() == pytest.approx(radius * eta_r)
    assert_closed_outward(mesh)
    # star-shaped with every vertex radius in [r, r eta]: volume between the scaled spheres
    base = icosphere(2, radius=radius).volume
    assert base * (1 - 1e-9) <= mesh.volume <= base * eta_r**3 * (1 + 1e-9)


def test_noisy_sphere_is_deterministic_per_seed():
    a = noisy_sphere(3, eta_r=1.4, seed=7)
    b = noisy_sphere(3, eta_r=1.4, seed=7)
    c = noisy_sphere(3, eta_r=1.4, seed=8)
    np.testing.assert_array_equal(a.vertices, b.vertices)
    np.testing.assert_array_equal(a.faces, c.faces)
    assert np.abs(radii(a) - radii(c)).max() > 0.05
    directions = a.vertices / radii(a)[:, None]
    np.testing.assert_allclose(directions, icosphere(3).vertices, atol=1e-14)
    np.testing.assert_allclose(radii(noisy_sphere(2, eta_r=1.0)), 1.0, rtol=1e-14)


def test_noisy_sphere_is_smooth():
    # neighbouring vertices differ far less than the whole band (not white noise)
    mesh = noisy_sphere(4, eta_r=2.0, seed=1, octaves=3)
    r = radii(mesh)
    edges = mesh.faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
    jumps = np.abs(r[edges[:, 0]] - r[edges[:, 1]])
    assert jumps.max() < 0.25 * (r.max() - r.min())


# ---------------------------------------------------------------------- stretched spheres
@pytest.mark.parametrize("axis", [0, 1, 2])
@pytest.mark.parametrize("eta", [0.5, 1.4, 3.0])
def test_stretched_sphere_bounds_and_volume(axis, eta):
    mesh = stretched_sphere(3, eta=eta, axis=axis, radius=2.0)
    half = np.full(3, 2.0)
    half[axis] *= eta
    # subdivision puts vertices on the coordinate axes (midpoints of icosahedron edges)
    np.testing.assert_allclose(mesh.bounds, [-half, half], rtol=1e-14, atol=1e-14)
    assert_closed_outward(mesh)
    assert mesh.volume == pytest.approx(eta * icosphere(3, radius=2.0).volume, rel=1e-12)


# ---------------------------------------------------------------------- plane and box
@pytest.mark.parametrize("divisions", [1, 2, 5])
def test_plane_is_open_with_up_normals(divisions):
    mesh = plane((4.0, 6.0), divisions=divisions, center=(1.0, 2.0, -3.0))
    assert mesh.n_faces == 2 * divisions**2
    assert mesh.n_vertices == (divisions + 1) ** 2
    np.testing.assert_allclose(mesh.face_normals, np.tile([0.0, 0.0, 1.0], (mesh.n_faces, 1)))
    np.testing.assert_allclose(mesh.bounds, [[-1.0, -1.0, -3.0], [3.0, 5.0, -3.0]])
    assert mesh.areas.sum() == pytest.approx(24.0)
    assert not mesh.is_closed and mesh.is_consistently_oriented
    with pytest.raises(InvalidMeshError, match="not closed"):
        _ = mesh.volume


def test_box():
    mesh = box((2.0, 3.0, 4.0), center=(1.0, 0.0, -1.0))
    assert mesh.n_faces == 12 and mesh.n_vertices == 8
    assert_closed_outward(mesh)
    assert mesh.volume == pytest.approx(24.0)
    np.testing.assert_allclose(mesh.bounds, [[0.0, -1.5, -3.0], [2.0, 1.5, 1.0]])


# ---------------------------------------------------------------------- torus
def polygon_error(n: int) -> float:
    """Leading relative area deficit of a regular n-gon inscribed in a circle: x^2/6."""
    return (2.0 * np.pi / n) ** 2 / 6.0


def test_torus_volume_within_discretisation_error():
    big, small = 1.0, 0.3
    exact = 2.0 * np.pi**2 * big * small**2
    errors = []
    for nu, nv in ((16, 8), (32, 16), (64, 32)):
        mesh = torus(big, small, nu, nv)
        assert mesh.n_faces == 2 * nu * nv
        assert_closed_outward(mesh)
        np.testing.assert_allclose(mesh.center_mass, 0.0, atol=1e-12)
        err = 1.0 - mesh.volume / exact
        assert 0 < err <= polygon_error(nu) + polygon_error(nv)
        errors.append(err)
    assert errors[0] / errors[1] > 3.5 and errors[1] / errors[2] > 3.5


def test_torus_is_non_convex():
    mesh = torus(1.0, 0.3)
    rho = np.hypot(mesh.vertices[:, 0], mesh.vertices[:, 1])
    assert rho.min() == pytest.approx(0.7) and rho.max() == pytest.approx(1.3)
    # the segment between opposite vertices crosses the hole: the centroid is outside
    assert np.linalg.norm(mesh.center_mass) < 1e-12 and rho.min() > 0.3
    ixx, iyy, izz = np.diag(mesh.inertia)
    assert ixx == pytest.approx(iyy) and izz > ixx


# ---------------------------------------------------------------------- argument validation
@pytest.mark.parametrize(
    ("factory", "kwargs", "match"),
    [
        (icosphere, {"subdivisions": -1}, "subdivisions"),
        (icosphere, {"subdivisions": 1.5}, "subdivisions must be an integer"),
        (icosphere, {"subdivisions": 99}, "subdivisions"),
        (icosphere, {"radius": 0.0}, "radius"),
        (icosphere, {"radius": np.nan}, "radius"),
        (uv_sphere, {"segments": 2, "rings": 4}, "segments"),
        (uv_sphere, {"segments": 6, "rings": 1}, "rings"),
        (uv_sphere, {"segments": True, "rings": 4}, "segments"),
        (noisy_sphere, {"eta_r": 0.9}, "eta_r"),
        (noisy_sphere, {"seed": -1}, "seed"),
        (noisy_sphere, {"octaves": 0}, "octaves"),
        (noisy_sphere, {"eta_r": "big"}, "eta_r"),
        (stretched_sphere, {"eta": 0.0}, "eta"),
        (stretched_sphere, {"axis": 3}, "axis"),
        (plane, {"size": (1.0, -1.0)}, "size"),
        (plane, {"size": (1.0, 2.0, 3.0)}, "size"),
        (plane, {"divisions": 0}, "divisions"),
        (plane, {"center": (0.0, np.inf, 0.0)}, "center"),
        (box, {"extents": (1.0, 0.0, 1.0)}, "extents"),
        (box, {"center": (0.0, 0.0)}, "center"),
        (torus, {"minor_radius": 1.0}, "minor_radius"),
        (torus, {"major_radius": -1.0}, "major_radius"),
        (torus, {"major_segments": 2}, "major_segments"),
        (torus, {"minor_segments": 2}, "minor_segments"),
    ],
)
def test_bad_arguments_raise(factory, kwargs, match):
    with pytest.raises(InvalidArgumentError, match=match):
        factory(**kwargs)
