"""Rigid-body dynamics: conservation laws, symmetry, dissipation, resting and rolling contact."""

from __future__ import annotations

import numpy as np
import pytest

from engine import LinearSpring, PaperSpring, Scene, shapes

SPHERE = shapes.icosphere(2, radius=0.5)  # 320 triangles, diameter 1: ε = 0.01
SCHEMES = ("explicit", "implicit", "implicit-surrogate", "implicit-midpoint", "multiscale")


def two_body_impact(scheme, model=None, offset=0.1, spin=1.0):
    scene = Scene(gravity=(0, 0, 0), contact_model=model or PaperSpring(friction=0.4))
    scene.add_body(SPHERE, position=(0, 0, 0), velocity=(0.5, 0, 0), density=1.0)
    scene.add_body(
        SPHERE,
        position=(1.05, offset, 0.02),
        orientation=(np.cos(0.3), 0, np.sin(0.3), 0),
        velocity=(-0.5, 0, 0),
        angular_velocity=(0, 0, spin),
        density=2.0,
    )
    return scene


@pytest.mark.parametrize("scheme", SCHEMES)
def test_free_impact_conserves_momentum(scheme):
    scene = two_body_impact(scheme)
    p0, l0 = scene.momentum()
    touched = 0
    for _ in range(120):
        stats = scene.step(1e-3, scheme)
        touched += stats.contacts > 0
        assert stats.converged
    p1, l1 = scene.momentum()
    assert touched > 5  # the bodies did collide
    assert np.linalg.norm(p1 - p0) <= 1e-9 * np.linalg.norm(p0 if p0.any() else 1.0) + 1e-12
    assert np.linalg.norm(l1 - l0) <= 1e-9 * np.linalg.norm(l0)
    np.testing.assert_allclose(np.linalg.norm(scene.orientations, axis=1), 1.0, atol=1e-12)


@pytest.mark.parametrize("scheme", SCHEMES)
def test_symmetric_head_on_impact_rebounds_symmetrically(scheme):
    scene = Scene(gravity=(0, 0, 0), contact_model=PaperSpring(friction=0.0))
    scene.add_body(SPHERE, position=(-0.52, 0, 0), velocity=(0.5, 0, 0))
    # the mirror image of the first body through the plane x = 0
    scene.add_body(SPHERE, position=(0.52, 0, 0), orientation=(0, 0, 0, 1), velocity=(-0.5, 0, 0))
    for _ in range(60):
        scene.step(1e-3, scheme)
    v = scene.velocities
    assert v[0, 0] < 0 < v[1, 0]  # rebounded
    np.testing.assert_allclose(v[0, 0], -v[1, 0], rtol=1e-9)
    np.testing.assert_allclose(scene.positions[0, 0], -scene.positions[1, 0], rtol=1e-9)


@pytest.mark.parametrize("scheme", ["implicit", "explicit"])
def test_damping_never_adds_energy(scheme):
    scene = Scene(gravity=(0, 0, 0), contact_model=PaperSpring(damping=0.3, friction=0.3))
    scene.add_body(SPHERE, position=(0, 0, 0), velocity=(0.4, 0.05, 0))
    scene.add_body(
        SPHERE, position=(1.04, 0.2, 0), velocity=(-0.4, 0, 0), angular_velocity=(0, 2, 0)
    )
    previous = scene.kinetic_energy()
    first = previous
    for _ in range(150):
        stats = scene.step(1e-3, scheme)
        energy = scene.kinetic_energy() + stats.elastic_energy
        if scheme == "implicit":  # backward Euler with damping: monotone
            assert energy <= previous * (1 + 1e-9)
        previous = energy
    assert scene.kinetic_energy() < first  # over the whole impact, energy was lost


def test_sphere_dropped_on_a_plane_comes_to_rest():
    scene = Scene(contact_model=PaperSpring(damping=0.5, friction=0.5))
    scene.add_plane(point=(0, 0, 0), normal=(0, 0, 1), size=3.0, divisions=8)
    ball = scene.add_body(SPHERE, position=(0.1, -0.05, 0.56))
    overlaps = []
    for _ in range(600):
        stats = scene.step(2e-3, "implicit-surrogate")
        assert stats.converged
        overlaps.append(stats.max_overlap)
    assert max(overlaps) < 1.0  # never deeper than the halos: surfaces never cross
    rest = scene.positions[ball].copy()
    for _ in range(50):
        scene.step(2e-3, "implicit-surrogate")
    assert np.linalg.norm(scene.velocities[ball]) < 1e-3
    assert np.linalg.norm(scene.positions[ball] - rest) < 1e-4  # no drift
    assert 0.49 < rest[2] < 0.52 and abs(rest[0] - 0.1) < 1e-2 and abs(rest[1] + 0.05) < 1e-2


@pytest.mark.parametrize("friction", [0.0, 0.8])
def test_sphere_on_a_tilted_plane_accelerates_with_g_sin_theta(friction):
    """Frictionless, the ball slides at g·sin θ; with friction it rolls without slipping at
    5/7·g·sin θ, less what the 1,280 facets lose at every edge they tip over (~11 %)."""
    theta, g = np.radians(20), 9.81
    normal = np.array([np.sin(theta), 0.0, np.cos(theta)])  # downhill is +x
    model = LinearSpring(stiffness=2e4, damping=0.7, friction=friction)
    scene = Scene(gravity=(0, 0, -g), contact_model=model, max_halvings=3)
    scene.add_plane(point=(0, 0, 0), normal=normal, size=6.0, divisions=12)
    # halos (0.01 each) just touching: the ball starts at rest on the slope
    ball = scene.add_body(shapes.icosphere(3, radius=0.5), position=normal * 0.52)
    dt, steps = 1e-3, 400
    for _ in range(100):  # settle onto the slope
        assert scene.step(dt, "implicit-surrogate").converged
    x0, v0 = scene.positions[ball].copy(), scene.velocities[ball].copy()
    touching = 0
    for _ in range(steps):
        stats = scene.step(dt, "implicit-surrogate")
        assert stats.converged
        touching += stats.contacts > 0
    assert touching > 0.9 * steps  # stays on the slope
    downhill = np.array([np.cos(theta), 0.0, -np.sin(theta)])
    accel = (scene.velocities[ball] - v0) @ downhill / (steps * dt)
    v, w = scene.velocities[ball], scene.angular_velocities[ball]
    slip = np.linalg.norm(v + np.cross(w, -0.5 * normal)) / np.linalg.norm(v)
    if friction == 0:
        assert accel == pytest.approx(g * np.sin(theta), rel=0.03)
        assert slip > 0.9  # slides (facet contacts off the centre spin it a little)
    else:
        assert 0.8 < accel / (5 / 7 * g * np.sin(theta)) < 1.02
        assert slip < 0.1  # rolls
    assert (scene.positions[ball] - x0) @ downhill > 0


def test_explicit_and_implicit_agree_as_dt_shrinks():
    def run(scheme, dt):
        scene = two_body_impact(scheme, PaperSpring(friction=0.0), offset=0.05, spin=0.0)
        for _ in range(int(round(0.1 / dt))):
            scene.step(dt, scheme)
        return scene.positions.copy(), scene.velocities.copy()

    gaps = []
    for dt in (1e-3, 2.5e-4):
        (xe, ve), (xi, vi) = run("explicit", dt), run("implicit", dt)
        gaps.append((np.abs(xe - xi).max(), np.abs(ve - vi).max()))
    # first-order methods: positions and velocities converge as dt shrinks
    assert gaps[1][0] < gaps[0][0] / 2 and gaps[1][1] < gaps[0][1] / 2


def test_implicit_midpoint_is_second_order_and_keeps_the_bounce():
    """Against a fine explicit reference (dt 2e-5) through a head-on bounce: halving dt cuts
    the midpoint rule's error about four times (backward Euler's about twice), and at the
    same dt it is far closer than backward Euler, which loses energy in the bounce."""

    def run(scheme, dt, span=0.1):
        scene = two_body_impact(scheme, PaperSpring(friction=0.0), offset=0.0, spin=0.0)
        for _ in range(int(round(span / dt))):
            scene.step(dt, scheme)
        return scene.positions.copy(), scene

    reference, _ = run("explicit", 2e-5)
    error = {
        (scheme, dt): np.abs(run(scheme, dt)[0] - reference).max()
        for scheme in ("implicit-midpoint", "implicit-surrogate")
        for dt in (2e-3, 1e-3)
    }
    midpoint = error["implicit-midpoint", 2e-3] / error["implicit-midpoint", 1e-3]
    backward = error["implicit-surrogate", 2e-3] / error["implicit-surrogate", 1e-3]
    assert midpoint > 3.0 and backward < 2.5, (midpoint, backward)
    assert error["implicit-midpoint", 1e-3] < error["implicit-surrogate", 1e-3] / 10
    # the relative speed after the bounce (undamped spring): backward Euler loses some
    speeds = {
        scheme: np.linalg.norm(np.diff(run(scheme, dt)[1].velocities, axis=0))
        for scheme, dt in (("explicit", 2e-5), ("implicit-midpoint", 1e-3), ("implicit", 1e-3))
    }
    assert abs(speeds["implicit-midpoint"] - speeds["explicit"]) < 0.01, speeds
    assert speeds["implicit"] < speeds["explicit"] - 0.1, speeds


def test_implicit_and_implicit_surrogate_give_the_same_trajectory():
    """Corollary 1: both find the same contact pairs in every iteration (Lemma 1); contact
    points may differ in the last bits (a pair's iterative result is computed in a vector
    lane in one search and in a loop remainder in the other), so the trajectories agree
    to rounding, far inside the Picard tolerance."""
    a, b = two_body_impact("implicit"), two_body_impact("implicit-surrogate")
    iterations = np.zeros(2)
    for _ in range(80):
        sa, sb = a.step(1e-3, "implicit"), b.step(1e-3, "implicit-surrogate")
        iterations += sa.picard_iterations, sb.picard_iterations
        assert sa.triangle_pairs == sb.triangle_pairs
        assert sb.comparisons < sa.comparisons or sa.body_pairs == 0
    np.testing.assert_allclose(a.positions, b.positions, rtol=0, atol=1e-9)
    np.testing.assert_allclose(a.velocities, b.velocities, rtol=0, atol=1e-9)
    # a step at the contact's edge may take a few more iterations in one of them
    assert abs(iterations[0] - iterations[1]) <= 0.05 * iterations[0]


def test_multiscale_follows_the_implicit_trajectory_within_the_picard_tolerance():
    a, b = two_body_impact("implicit-surrogate"), two_body_impact("multiscale")
    unfolded = 0
    for _ in range(100):
        sa, sb = a.step(1e-3, "implicit-surrogate"), b.step(1e-3, "multiscale")
        assert sa.converged and sb.converged
        unfolded += sb.unfoldings
    assert unfolded > 0
    scale = np.abs(a.velocities).max()
    np.testing.assert_allclose(b.velocities, a.velocities, rtol=0, atol=0.01 * scale)
    np.testing.assert_allclose(b.positions, a.positions, rtol=0, atol=1e-3 * scale)


def test_multiscale_converges_to_the_leaf_contacts_of_the_accepted_configuration():
    """At convergence no surrogate entry is in contact: the forces come from exactly the
    finest-level contacts that a flat search finds at the accepted poses."""
    from engine.collision.multiscale import MultiscaleSearch

    scene = two_body_impact("multiscale")
    touching = 0
    while touching < 5:  # a few steps into the impact
        touching += scene.step(1e-3, "multiscale").contacts > 0
    search = MultiscaleSearch(scene)
    for _ in range(12):  # evaluate the final configuration until the fronts settle
        leaf, surrogate, changed = search(scene.positions, scene.orientations)
        if not changed:
            break
    assert not changed and surrogate is None  # no surrogate pair in contact
    flat = scene.contacts(scene.positions, scene.orientations, hierarchy=False)
    assert len(flat.points) > 0
    np.testing.assert_allclose(leaf.points, flat.points, atol=1e-12)
    np.testing.assert_allclose(leaf.overlaps, flat.overlaps, atol=1e-12)
