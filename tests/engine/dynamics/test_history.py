"""Contact history across steps: static friction (tangential springs) and the gentle start
(allowances and the separation-speed cap), and the overlap report of ``set_state``."""

from __future__ import annotations

import math

import numpy as np
import pytest

from engine import PaperSpring, Scene, shapes
from engine.dynamics.history import ContactHistory, check_speed, overlap_report
from engine.errors import InvalidArgumentError

EPS = 0.002
G = 9.81


def box_on_ramp(angle_deg: float, mu: float, x: float = 0.0, **law) -> tuple[Scene, np.ndarray]:
    """A 20 × 20 × 10 cm box of 4 kg at rest on a plane tilted by ``angle_deg`` about x, its
    face barely inside the plane's halo, ``x`` across the slope from the plane's middle (a
    line of its triangles); returns the scene and the up-slope direction."""
    theta = math.radians(angle_deg)
    normal = np.array([0.0, -math.sin(theta), math.cos(theta)])
    scene = Scene(contact_model=PaperSpring(friction=mu, damping=0.3, **law))
    scene.add_plane(point=(0.0, 0.0, 0.0), normal=normal, size=4.0, divisions=2, epsilon=EPS)
    turn = (math.cos(theta / 2), math.sin(theta / 2), 0.0, 0.0)
    position = normal * (0.05 + 1.95 * EPS) + [x, 0.0, 0.0]
    scene.add_body(shapes.box((0.2, 0.2, 0.1)), position=position, orientation=turn,
                   mass=4.0, epsilon=EPS)  # fmt: skip
    return scene, np.array([0.0, math.cos(theta), math.sin(theta)])


def slide(scene: Scene, up: np.ndarray, steps: int, dt: float = 5e-4, strict=True):
    """(steps,) float64: the box's position along ``up`` after each step (``strict``: every
    step converged)."""
    along = []
    for _ in range(steps):
        assert scene.step(dt).converged or not strict
        along.append(float(scene.positions[1] @ up))
    return np.array(along)


@pytest.mark.parametrize("scheme", ["implicit-midpoint", "implicit"])
def test_a_box_below_the_friction_angle_stays_put(scheme):
    scene, up = box_on_ramp(20.0, 0.6)  # tan 20° = 0.36 < 0.6
    scene.scheme = scheme
    along = slide(scene, up, 800)
    creep = (along[-1] - along[400]) / (400 * 5e-4)
    assert abs(creep) <= 1e-4  # ≤ 0.1 mm/s
    assert abs(along[-1] - along[0]) < 1e-3  # it loaded its springs and stopped


def test_without_a_tangential_spring_the_same_box_creeps():
    """The regularised law (no history) has no sticking state: the oracle the spring fixes."""
    scene, up = box_on_ramp(20.0, 0.6, tangential_stiffness=0.0)
    along = slide(scene, up, 800, strict=False)
    assert (along[-1] - along[400]) / (400 * 5e-4) < -1e-3


@pytest.mark.parametrize("x", [0.0, 0.37])  # along a line of the plane's triangles, or not
def test_above_the_friction_angle_it_slides_at_coulombs_acceleration(x):
    """Over 1 s (the box slides 1.2 m, over the plane's diagonals). Picard's tolerance is 1 %
    of the forces on a body, far more than the net force of a slide: a frozen contact set
    is solved to a tenth of it, else this was 1.4 % off (x = 0.37)."""
    theta, mu, dt = math.radians(30.0), 0.3, 5e-4
    scene, up = box_on_ramp(30.0, mu, x)
    along = slide(scene, up, 2000, dt)
    t = np.arange(1, 2001) * dt
    acceleration = 2.0 * np.polyfit(t[1000:], along[1000:], 2)[0]
    expected = -G * (math.sin(theta) - mu * math.cos(theta))
    assert acceleration == pytest.approx(expected, rel=0.01)


def test_the_spring_history_follows_the_contacts_and_is_dropped_on_set_state():
    scene, up = box_on_ramp(20.0, 0.6)
    slide(scene, up, 20)
    history = scene.contact_history
    assert isinstance(history, ContactHistory) and len(history.keys) == 1
    assert np.abs(history.values[:, :3]).max() > 0  # the springs hold the box
    scene.set_state(velocities=scene.velocities)  # velocities only: the springs stay
    assert scene.contact_history is history
    scene.set_state(positions=scene.positions)
    assert scene.contact_history is None and scene.gentle_start


def small_box_in_a_plane(speed: float) -> Scene:
    """A 4 g box placed 40 % of its reach into a plane."""
    scene = Scene(separation_speed=speed)
    scene.add_plane(size=1.0, divisions=2, epsilon=0.0005)
    eps = 0.001
    depth = 0.4 * (eps + 0.0005)
    scene.add_body(shapes.box((0.02, 0.02, 0.02)), position=(0.0, 0.0, 0.0115 - depth),
                   mass=0.004, epsilon=eps)  # fmt: skip
    return scene


@pytest.mark.parametrize(
    ("scheme", "dt"), [("implicit-midpoint", 5e-4), ("implicit", 5e-4), ("explicit", 1e-4)]
)
@pytest.mark.parametrize("speed", [0.5, 0.1])
def test_an_overlapping_start_separates_no_faster_than_the_separation_speed(scheme, dt, speed):
    scene = small_box_in_a_plane(speed)
    fastest = 0.0
    for _ in range(round(0.01 / dt)):
        scene.step(dt, scheme)
        fastest = max(fastest, float(np.linalg.norm(scene.velocities[1])))
    assert 0.2 * speed < fastest <= speed * (1 + 1e-12)


def test_without_a_gentle_start_the_same_box_is_launched():
    scene = small_box_in_a_plane(math.inf)
    scene.step(5e-4, "implicit")
    assert scene.velocities[1, 2] > 1.0


def test_the_gentle_start_is_the_default_and_spares_a_collision_under_way():
    """By default overlaps are let go at 0.5 m/s; a box placed in the halos while it
    closes on the plane (a collision under way) gets no allowance: its first step is the
    same as without a gentle start, bit for bit."""
    assert Scene().separation_speed == 0.5
    runs = []
    for speed in (0.5, math.inf):
        scene = small_box_in_a_plane(speed)
        scene.set_state(velocities=[[0.0, 0.0, 0.0], [0.0, 0.0, -0.2]])  # closing
        scene.step(5e-4, "implicit")
        runs.append(scene.velocities[1].copy())
    np.testing.assert_array_equal(runs[0], runs[1])
    resting = small_box_in_a_plane(0.5)  # not closing: an allowance, so no launch
    resting.step(5e-4, "implicit")
    assert np.linalg.norm(resting.velocities[1]) <= 0.5


def test_set_state_reports_the_pairs_whose_surfaces_cross():
    scene = Scene()
    scene.add_plane(size=1.0, divisions=2, epsilon=0.001)
    for x in (0.0, 0.3):
        scene.add_body(shapes.box((0.1, 0.1, 0.1)), position=(x, 0.0, 0.2), epsilon=0.001)
    apart = scene.set_state(positions=scene.positions)
    assert apart.pairs.shape == (0, 2) and apart.largest == 0.0
    positions = scene.positions.copy()
    positions[1, 2] = 0.03  # 2 cm into the plane
    positions[2, 2] = 0.0505  # inside the halos, surfaces apart
    report = scene.set_state(positions=positions)
    np.testing.assert_array_equal(report.pairs, [[0, 1]])
    assert report.largest == 1.0
    assert scene.set_state(velocities=np.zeros((3, 3))) is None


def test_overlap_report_of_no_contacts_and_speed_checks():
    scene = Scene()
    scene.add_body(shapes.box(), position=(0.0, 0.0, 0.0))
    contacts = scene.contacts(scene.positions, scene.orientations)
    assert overlap_report(contacts, scene.epsilon).pairs.shape == (0, 2)
    assert check_speed(0.5) == 0.5 and check_speed(math.inf) == math.inf
    for bad in (0, -1.0, True, "fast", math.nan):
        with pytest.raises(InvalidArgumentError, match="separation_speed"):
            Scene(separation_speed=bad)
