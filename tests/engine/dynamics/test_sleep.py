"""Bodies at rest sleep (no narrow phase, no integration) and wake when something moving
touches them."""

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
    box_heights = []
    for _ in range(500):
        rows["asleep"].append(asleep.step(1e-3))
        rows["awake"].append(awake.step(1e-3))
        box_heights.append(asleep.positions[1, 2])
    sleeping = [r.sleeping for r in rows["asleep"]]
    assert max(sleeping) == 4  # the four boxes slept while the ball fell
    # the hit box woke in the step whose contacts held the ball's pair with it (tested with
    # the box asleep, as a fixed body): not before, while the ball was only near it
    hit = next(i for i, r in enumerate(rows["asleep"]) if i > 60 and r.sleeping < 4)
    assert rows["asleep"][hit].body_pairs == 2 and rows["asleep"][hit].contacts >= 1
    near = [i for i in range(60, hit) if rows["asleep"][i].body_pairs == 2]
    assert near and all(sleeping[i] == 4 for i in near)
    assert np.ptp(box_heights[hit:]) > 1e-4  # it moved: pushed into the plane and back
    assert min(sleeping[hit:]) == 3 and not asleep.sleep.asleep[5]
    # the ball bounced off: with it in the air, the hit box rested and slept again, as the
    # others slept on
    assert asleep.sleep.asleep[1:5].all() and sleeping[-1] == 4
    # in every step that began with all four asleep only the falling ball's pairs were
    # tested: with the plane, and with the box it came near (without sleeping: the four
    # box-plane pairs too, every step)
    quiet = [i for i in range(1, hit) if rows["asleep"][i - 1].sleeping == 4]
    assert len(quiet) > 100
    assert all(rows["asleep"][i].body_pairs == 1 for i in quiet if i not in near)
    assert all(rows["awake"][i].body_pairs == 5 for i in quiet if i not in near)
    # the same outcome as without sleeping, to the sleep threshold's order
    np.testing.assert_allclose(asleep.positions, awake.positions, atol=2e-3)
    assert np.isfinite(asleep.velocities).all()


def _quaternion_product(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    w = p[:, 0] * q[:, 0] - (p[:, 1:] * q[:, 1:]).sum(1)
    u = p[:, :1] * q[:, 1:] + q[:, :1] * p[:, 1:] + np.cross(p[:, 1:], q[:, 1:])
    return np.column_stack([w, u])


def _unit(rows: np.ndarray) -> np.ndarray:
    return rows / np.linalg.norm(rows, axis=1, keepdims=True)


@pytest.mark.parametrize("seed", range(8))
def test_an_update_follows_the_rule_written_out(seed):
    """``Sleep.update`` on random poses, sleep states and counts: an awake free body whose
    count is 0 begins one at the step's start; while no point of it is ``speed × steps ×
    dt`` from there (|Δx| + θ·R) it rests one step more, else it is moving and its count
    is 0, as every other body's; where something moves, the bodies of its pairs in
    contact (or, with no contacts given, of its candidate pairs) wake and count from 0;
    those that rested ``steps`` steps fall asleep at rest. Compared with the rule in
    numpy."""
    rng = np.random.default_rng(seed)
    scene = Scene(contact_model=PaperSpring(damping=0.5, friction=0.5))
    scene.add_plane(size=12.0, divisions=4, epsilon=0.01)
    for x in range(6):  # side by side: neighbours are candidate pairs
        scene.add_body(shapes.box(), position=(1.02 * x, 0.0, 0.52), epsilon=0.01)
    n, dt = len(scene), 1e-3
    sleep = Sleep(speed=1e-2, steps=3)
    reach = sleep.speed * sleep.steps * dt  # 30 µm
    sleep.wake_all(n)
    sleep.asleep[1:] = rng.random(n - 1) < 0.3
    sleep.rest[:] = rng.integers(0, 4, n)
    # each pose a little (a tenth of the reach) or far (two reaches) from the scene's
    scale = np.where(rng.random((n, 1)) < 0.5, 0.1 * reach, 2 * reach) / np.sqrt(3)

    def pose():
        turned = scene.orientations + rng.normal(scale=1e-3 * reach, size=(n, 4))
        return scene.positions + rng.normal(size=(n, 3)) * scale, _unit(turned)

    sleep.anchor, start = pose(), pose()
    scene.velocities[:] = rng.normal(size=(n, 3))  # any: the rule reads the poses only
    radius = np.full(n, 0.9)
    touching = None if seed % 2 else np.array([[0, 1], [2, 3], [3, 4]], np.int64)
    # the rule, written out
    free = ~scene.fixed
    asleep, rest = sleep.asleep.copy(), sleep.rest.copy()
    awake = free & ~asleep
    begins = awake & (rest == 0)
    anchor_x = np.where(begins[:, None], start[0], sleep.anchor[0])
    anchor_q = np.where(begins[:, None], start[1], sleep.anchor[1])
    turn = _quaternion_product(scene.orientations, anchor_q * [1, -1, -1, -1])
    angle = 2 * np.arctan2(np.linalg.norm(turn[:, 1:], axis=1), np.abs(turn[:, 0]))
    moved = np.linalg.norm(scene.positions - anchor_x, axis=1) + angle * radius
    resting = awake & (moved < reach)
    moving = awake & ~resting
    rest = np.where(resting, rest + 1, 0)
    if moving.any() and (asleep.any() or resting.any()):
        pairs = touching
        if pairs is None:
            _, pairs = scene.configuration(scene.positions, scene.orientations)
        a, b = pairs[:, 0], pairs[:, 1]
        near = np.concatenate([a[moving[b]], b[moving[a]]])
        asleep[near], rest[near] = False, 0
    falling = free & ~asleep & (rest >= sleep.steps)
    asleep |= falling
    velocities = np.where(falling[:, None], 0.0, scene.velocities)
    sleep.update(scene, radius, start, dt, touching)
    np.testing.assert_array_equal(sleep.asleep, asleep)
    np.testing.assert_array_equal(sleep.rest, rest)
    np.testing.assert_array_equal(sleep.anchor[0][begins], start[0][begins])
    np.testing.assert_array_equal(sleep.anchor[1][begins], start[1][begins])
    np.testing.assert_array_equal(scene.velocities, velocities)


@pytest.mark.parametrize("period", [2, 3])
def test_a_body_that_rings_in_place_sleeps_and_one_that_creeps_does_not(period):
    """A body whose velocity rings from step to step while it stays where it is (the
    implicit midpoint rule's stiff contact modes: +v, −v, … at the step's frequency; a
    body on a switch of its contact set: a cycle of a few steps) is at rest: it sleeps
    after ``steps`` steps, however fast its velocity reads. One that creeps at twice the
    sleep speed never sleeps, even though no single step is far from the last."""
    scene = Scene()
    scene.add_body(shapes.box(), position=(0.0, 0.0, 0.0))
    scene.add_body(shapes.box(), position=(5.0, 0.0, 0.0))
    sleep, dt = Sleep(speed=1e-3, steps=20), 1e-3
    radius = np.full(2, 0.9)
    home = scene.positions.copy()
    for k in range(3 * sleep.steps):
        start = (scene.positions.copy(), scene.orientations.copy())
        ring = 0.4 * sleep.speed * dt * (k % period)  # within a step's speed of home
        scene.positions = home + [[0.0, 0.0, ring], [2 * sleep.speed * dt * (k + 1), 0, 0]]
        scene.velocities[:] = 0.5 * (-1) ** k  # what a ringing velocity reads
        sleep.update(scene, radius, start, dt, np.zeros((0, 2), np.int64))
        if k + 1 < sleep.steps:
            assert not sleep.asleep.any()
    assert sleep.asleep[0] and not sleep.asleep[1]


def test_a_body_near_a_moving_one_but_not_touching_it_sleeps():
    """Only contacts wake: a resting body that a moving one passes near (a candidate pair
    of the broad phase) sleeps; given the pair as a contact, it is kept awake."""
    for touching, slept in ((np.zeros((0, 2), np.int64), True), (np.array([[0, 1]]), False)):
        scene = Scene()
        scene.add_body(shapes.box(), position=(0.0, 0.0, 0.0))
        scene.add_body(shapes.box(), position=(1.05, 0.0, 0.0))
        _, candidates = scene.configuration(scene.positions, scene.orientations)
        assert len(candidates) == 1
        sleep, dt = Sleep(speed=1e-3, steps=10), 1e-3
        for _ in range(12):
            start = (scene.positions.copy(), scene.orientations.copy())
            scene.positions = scene.positions + [[0, 0, 0], [0, 0.01, 0]]  # body 1 moves
            sleep.update(scene, np.full(2, 0.9), start, dt, touching)
        assert sleep.asleep[0] == slept and not sleep.asleep[1]


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
