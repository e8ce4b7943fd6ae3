"""Bodies at rest sleep (no narrow phase, no integration) and wake when something moving
comes near."""

from __future__ import annotations

import numpy as np
import pytest

from engine import InvalidArgumentError, PaperSpring, Scene, shapes
from engine.dynamics.sleep import Sleep


def _row_of_boxes(sleep) -> Scene:
    """Four unit boxes resting on a plane (on the edge of their halos), and a ball falling
    onto the first one from 0.6 above it."""
    scene = Scene(contact_model=PaperSpring(damping=0.5, friction=0.5), sleep=sleep)
    scene.add_plane(size=12.0, divisions=4, epsilon=0.01)
    box = shapes.box()
    low = 0.5 + 0.998 * (0.01 + 0.01 * box.diameter)
    for x in (-4.5, -1.5, 1.5, 4.5):
        scene.add_body(box, position=(x, 0.0, low), epsilon=0.01 * box.diameter)
    ball = (-4.5, 0.0, 1.0 + 0.6 + 0.3)
    scene.add_body(shapes.icosphere(2, radius=0.3), position=ball, epsilon=0.006)
    return scene


def test_resting_bodies_sleep_and_a_falling_one_wakes_what_it_hits():
    asleep = _row_of_boxes(Sleep(speed=1e-3, steps=20))
    awake = _row_of_boxes(False)
    rows = {"asleep": [], "awake": []}
    for _ in range(500):
        rows["asleep"].append(asleep.step(1e-3))
        rows["awake"].append(awake.step(1e-3))
    sleeping = [r.sleeping for r in rows["asleep"]]
    assert max(sleeping) == 4  # the four boxes slept while the ball fell
    # the hit box woke when the ball came near, and moved; the others slept on
    hit = next(i for i, r in enumerate(rows["asleep"]) if i > 60 and r.sleeping < 4)
    assert rows["asleep"][-1].sleeping == 3 and not asleep.sleep.asleep[1]
    assert asleep.sleep.asleep[2:5].all()
    # in every step that began with all four asleep only the falling ball's pair with the
    # plane was tested (without sleeping: the four box-plane pairs too, every step)
    quiet = [i for i in range(1, hit) if rows["asleep"][i - 1].sleeping == 4]
    assert len(quiet) > 100
    assert all(rows["asleep"][i].body_pairs == 1 for i in quiet)
    assert all(rows["awake"][i].body_pairs == 5 for i in quiet)
    # the same outcome as without sleeping, to the sleep threshold's order
    np.testing.assert_allclose(asleep.positions, awake.positions, atol=2e-3)
    assert np.isfinite(asleep.velocities).all()


@pytest.mark.parametrize("seed", range(6))
def test_an_update_follows_the_rule_written_out(seed):
    """``Sleep.update`` on random speeds, sleep states and counts: an awake free body below
    the speed rests one step more, every other body's count is 0; where something moves,
    the bodies of its candidate pairs wake and count from 0; those that rested ``steps``
    steps fall asleep at rest. Compared with the rule in numpy."""
    rng = np.random.default_rng(seed)
    scene = Scene(contact_model=PaperSpring(damping=0.5, friction=0.5))
    scene.add_plane(size=12.0, divisions=4, epsilon=0.01)
    for x in range(6):  # side by side: neighbours are candidate pairs
        scene.add_body(shapes.box(), position=(1.02 * x, 0.0, 0.52), epsilon=0.01)
    n = len(scene)
    sleep = Sleep(speed=1e-2, steps=3)
    sleep.wake_all(n)
    sleep.asleep[1:] = rng.random(n - 1) < 0.4
    sleep.rest[:] = rng.integers(0, 4, n)
    scene.velocities[:] = rng.normal(scale=0.01, size=(n, 3)) * (rng.random((n, 1)) < 0.5)
    scene.angular_velocities[:] = rng.normal(scale=0.005, size=(n, 3))
    radius = np.full(n, 0.9)
    # the rule, written out
    free = ~scene.fixed
    speed = np.linalg.norm(scene.velocities, axis=1)
    speed += np.linalg.norm(scene.angular_velocities, axis=1) * radius
    asleep, rest = sleep.asleep.copy(), sleep.rest.copy()
    awake = free & ~asleep
    resting = awake & (speed < sleep.speed)
    moving = awake & ~resting
    rest = np.where(resting, rest + 1, 0)
    if moving.any() and (asleep.any() or resting.any()):
        _, pairs = scene.configuration(scene.positions, scene.orientations)
        a, b = pairs[:, 0], pairs[:, 1]
        near = np.concatenate([a[moving[b]], b[moving[a]]])
        asleep[near], rest[near] = False, 0
    falling = free & ~asleep & (rest >= sleep.steps)
    asleep |= falling
    velocities = np.where(falling[:, None], 0.0, scene.velocities)
    sleep.update(scene, radius)
    np.testing.assert_array_equal(sleep.asleep, asleep)
    np.testing.assert_array_equal(sleep.rest, rest)
    np.testing.assert_array_equal(scene.velocities, velocities)
    assert not scene.angular_velocities[falling].any()


def test_anything_from_outside_wakes_every_body():
    scene = _row_of_boxes(Sleep(steps=5))
    lifted = scene.positions.copy()
    lifted[5, 2] += 5.0  # the ball far above: it falls, but nowhere near a box yet
    scene.set_state(positions=lifted)
    for _ in range(30):
        scene.step(1e-3)
    assert scene.sleep.asleep[1:5].all()
    scene.set_external_force(2, (5.0, 0.0, 0.0))
    assert not scene.sleep.asleep.any()
    scene.step(1e-3)
    assert np.linalg.norm(scene.velocities[2]) > 0  # pushed, it moves at once


def test_bad_sleep_settings():
    with pytest.raises(InvalidArgumentError):
        Sleep(speed=0)
    with pytest.raises(InvalidArgumentError):
        Sleep(steps=0)
    with pytest.raises(InvalidArgumentError):
        Scene(sleep="yes")


def test_a_damped_box_comes_to_rest_and_sleeps_under_the_default_scheme():
    """The default scheme (implicit midpoint) adds no numerical damping: the contact law's
    damping brings a dropped box to rest, and then it sleeps."""
    from engine import DEFAULT_SCHEME

    scene = Scene(sleep=True, contact_model=PaperSpring(damping=0.3))
    assert scene.scheme == DEFAULT_SCHEME == "implicit-midpoint"
    scene.add_plane(size=4.0, divisions=2)
    scene.add_body(shapes.box(), position=(0.0, 0.0, 0.6))
    slept = next((k for k in range(1500) if scene.step(1e-3).sleeping), None)
    assert slept is not None and np.isfinite(scene.positions).all()
    # asleep is at rest: from the step it fell asleep in, its velocities are zero
    assert not scene.velocities[1].any() and not scene.angular_velocities[1].any()


def _small_pile() -> tuple[Scene, float]:
    """Eight bodies (3 cm boxes and 4 cm balls, ε = 2 mm, seeded orientations, apart) in
    two layers dropped into a 14 cm bin of five planes; returns the scene and the bin's
    half width."""
    scene = Scene(sleep=True, contact_model=PaperSpring(damping=0.3))
    half, eps = 0.07, 0.002
    scene.add_plane(size=0.3, divisions=2, epsilon=eps)
    for axis in (0, 1):
        for side in (-1.0, 1.0):
            point, normal = np.zeros(3), np.zeros(3)
            point[axis], point[2], normal[axis] = side * half, 0.1, -side
            scene.add_plane(point=point, normal=normal, size=0.3, divisions=2, epsilon=eps)
    box, ball = shapes.box((0.03, 0.03, 0.02)), shapes.icosphere(1, radius=0.02)
    rng = np.random.default_rng(7)
    for k in range(8):
        q = rng.normal(size=4)
        x, y, z = -0.03 + 0.06 * (k % 2), -0.03 + 0.06 * (k // 2 % 2), 0.03 + 0.06 * (k // 4)
        mesh = box if (k + k // 2) % 2 == 0 else ball
        orientation = q / np.linalg.norm(q)
        scene.add_body(
            mesh, position=(x, y, z), orientation=orientation, density=800.0, epsilon=eps
        )
    return scene, half


def test_a_small_pile_settles_without_escape_or_deep_overlap_and_sleeps():
    """Issue 16: a pile of boxes and balls in a bin comes to rest under the default scheme,
    never deeper than a quarter of a contact's reach, every body inside the bin, and then
    every body sleeps (at rest: zero velocity)."""
    scene, half = _small_pile()
    free = ~scene.fixed
    deepest, sleeping, steps = 0.0, 0, 0
    # a ball may roll on for a while (no rolling resistance: walls stop it): up to 3 s
    while steps < 6000 and sleeping < free.sum():
        stats = scene.step(5e-4)
        deepest, sleeping, steps = max(deepest, stats.max_overlap), stats.sleeping, steps + 1
    assert scene.sleep.asleep[free].all(), f"{scene.sleep.asleep[free].sum()} of 8 asleep"
    assert deepest < 0.25
    inside = np.abs(scene.positions[free, :2]) < half
    assert inside.all() and (scene.positions[free, 2] > 0).all()
    assert scene.kinetic_energy() == 0.0  # asleep: at rest
