"""Time stepping (engine/dynamics/picard.py): what a step reports (StepStats), the travel
bound and its TunnellingWarning or sub-steps, halving a step that does not converge, and
Picard settling on a contact-set switch (``_switch``)."""

from __future__ import annotations

import math
import pickle
import warnings

import numpy as np
import pytest

from engine import InvalidArgumentError, PaperSpring, Scene, TunnellingWarning, shapes
from engine.dynamics.picard import travel

BALL = shapes.icosphere(2, radius=0.5)  # 320 faces
EPS = 0.01


def free_flight(scheme: str = "implicit", **options) -> Scene:
    """Two balls far apart (no candidate pair), under gravity."""
    scene = Scene(scheme=scheme, **options)
    scene.add_body(BALL, position=(0, 0, 0), velocity=(0.3, 0, 0.1), epsilon=EPS)
    scene.add_body(
        BALL,
        position=(5, 0, 0),
        velocity=(0, -0.2, 0),
        angular_velocity=(0, 0, 0.4),
        epsilon=2 * EPS,
    )
    return scene


def ball_on_plane(scheme: str) -> Scene:
    """A ball resting in its halo on a plane: contacts in every step (placed a quarter of
    its reach deep, with no gentle start: the springs push from the first step)."""
    law = PaperSpring(damping=0.5, friction=0.5)
    scene = Scene(scheme=scheme, contact_model=law, separation_speed=math.inf)
    scene.add_plane(size=3.0, divisions=4, epsilon=EPS)
    scene.add_body(BALL, position=(0.1, -0.05, 0.5 + 1.5 * EPS), epsilon=EPS)
    return scene


# ------------------------------------------------------------------ StepStats
def test_an_explicit_step_is_one_evaluation_and_never_halved():
    scene = ball_on_plane("explicit")
    scene.max_halvings = 3
    stats = scene.step(1e-4)
    assert (stats.scheme, stats.dt, stats.converged) == ("explicit", 1e-4, True)
    assert (stats.picard_iterations, stats.evaluations, stats.halvings) == (1, 1, 0)
    assert stats.substeps == 1 and stats.sleeping == 0 and stats.seconds > 0
    assert scene.time == 1e-4


@pytest.mark.parametrize("scheme", ["implicit", "implicit-surrogate", "implicit-midpoint"])
def test_an_implicit_steps_stats_describe_its_last_evaluation(scheme):
    scene = ball_on_plane(scheme)
    for _ in range(5):
        stats = scene.step(1e-3)
    assert stats.converged and stats.scheme == scheme and stats.dt == 1e-3
    assert 1 <= stats.evaluations <= stats.picard_iterations <= scene.max_picard_iterations
    assert scene.time == pytest.approx(5e-3, rel=1e-15)
    if scheme == "implicit-midpoint":
        return  # its stats describe the midpoint (documented); the state is the end
    # the accepted configuration is the scene's state: search it again
    contacts = scene.contacts(scene.positions, scene.orientations, scheme != "implicit")
    assert stats.body_pairs == len(contacts.bodies) == 1
    assert stats.contacts == len(contacts.points) > 0
    assert stats.triangle_pairs == contacts.counters["triangle_pairs"]
    k = scene.contact_model.stiffness * math.sqrt(scene.masses[1]) / (2 * EPS)
    energy = 0.5 * k * float((contacts.overlaps**2).sum())  # the paper's spring, m_red = m
    assert stats.elastic_energy == pytest.approx(energy, rel=1e-9)
    assert stats.max_overlap == pytest.approx(contacts.overlaps.max() / (2 * EPS), rel=1e-12)


# ------------------------------------------------------------------ travel and tunnelling
def test_travel_is_the_largest_surface_motion_over_epsilon():
    scene = free_flight()
    dt = 0.01
    radius = [scene.trees[t].bounding_radius for t in scene.tree_index]
    speeds = [0.3**2 + 0.1**2, 0.2**2]
    ratios = [
        math.sqrt(speeds[0]) * dt / EPS,
        (math.sqrt(speeds[1]) + 0.4 * radius[1]) * dt / (2 * EPS),
    ]
    ratio, body = travel(scene, dt)
    assert ratio == pytest.approx(max(ratios), rel=1e-14)
    assert body == int(np.argmax(ratios))
    assert scene.step(dt).travel == pytest.approx(ratio, rel=1e-14)


def test_fixed_bodies_do_not_travel():
    scene = Scene()
    scene.add_plane()
    assert travel(scene, 1.0) == (0.0, -1)


def test_a_step_that_travels_more_than_epsilon_warns():
    scene = free_flight(gravity=(0, 0, 0))
    dt = 2.5 * EPS / math.hypot(0.3, 0.1)  # body 0 moves 2.5 ε (body 1 less)
    with pytest.warns(TunnellingWarning, match=r"body 0 moves 2\.5 times its ε") as caught:
        stats = scene.step(dt)
    assert f"Use dt <= {dt / 2.5:.3g} or Scene(substeps=True)" in str(caught[0].message)
    assert stats.substeps == 1 and stats.travel == pytest.approx(2.5, rel=1e-12)


def test_substeps_split_the_step_into_ceil_travel_equal_parts():
    dt = 2.5 * EPS / math.hypot(0.3, 0.1)
    whole, split = free_flight(gravity=(0, 0, 0)), free_flight(gravity=(0, 0, 0), substeps=True)
    start = split.positions.copy()
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no TunnellingWarning with sub-steps
        stats = split.step(dt)
    assert stats.substeps == 3 and stats.dt == dt and stats.travel == pytest.approx(2.5)
    assert stats.picard_iterations >= 3  # summed over the parts
    assert split.time == pytest.approx(dt, rel=1e-15)
    # force-free: the bodies move by dt·v however the step is cut
    np.testing.assert_allclose(split.positions, start + dt * split.velocities, atol=1e-14)
    with pytest.warns(TunnellingWarning):
        whole.step(dt)
    np.testing.assert_allclose(split.positions, whole.positions, atol=1e-14)


# ------------------------------------------------------------------ halving
def test_validation_of_the_picard_settings():
    for options, message in (
        ({"max_halvings": -1}, "max_halvings"),
        ({"max_picard_iterations": 0}, "max_picard_iterations"),
        ({"picard_tolerance": 0.0}, "picard_tolerance"),
        ({"picard_tolerance": 1.0}, "picard_tolerance"),
    ):
        with pytest.raises(InvalidArgumentError, match=message):
            Scene(**options)


@pytest.mark.parametrize("halvings", [0, 1, 2])
def test_a_step_that_does_not_converge_is_halved_max_halvings_deep(halvings):
    """One Picard iteration never converges (convergence compares an iteration's computed
    forces with the applied ones of the one before), so every part fails and the step is
    cut into 2^h equal parts: h levels of halving, 2^h − 1 splits. Under gravity alone,
    k backward-Euler parts of dt/k move a body by dt·v + g·dt²·(k + 1)/(2k)."""
    scene = free_flight(max_picard_iterations=1, max_halvings=halvings)
    dt = 1e-3
    x0, v0 = scene.positions.copy(), scene.velocities.copy()
    stats = scene.step(dt)
    parts = 2**halvings
    assert not stats.converged
    assert stats.halvings == parts - 1
    assert stats.picard_iterations == stats.evaluations == parts
    assert stats.dt == dt and scene.time == pytest.approx(dt, rel=1e-15)
    g = scene.gravity
    expected = x0 + dt * v0 + g * dt**2 * (parts + 1) / (2 * parts)
    np.testing.assert_allclose(scene.positions, expected, rtol=0, atol=1e-14)
    np.testing.assert_allclose(scene.velocities, v0 + dt * g, rtol=0, atol=1e-15)


def test_a_converging_step_is_not_halved():
    scene = free_flight(max_halvings=3)
    stats = scene.step(1e-3)
    assert stats.converged and stats.halvings == 0


@pytest.mark.parametrize("scheme", ["explicit", "implicit"])
def test_bodies_advanced_in_parts_on_threads_match_one_thread(scheme, monkeypatch):
    """The motion update split over worker threads (every part one body long here) gives
    the one-thread step bit for bit: each body's update is its own."""
    import engine.dynamics.picard as picard
    from engine import workers

    def run(threads: int) -> Scene:
        scene = ball_on_plane(scheme)
        scene.add_body(BALL, position=(1.0, 0.4, 0.5 + EPS), angular_velocity=(0, 2, 1))
        scene.threads = threads
        for _ in range(5):
            scene.step(1e-3)
        return scene

    one = run(1)
    monkeypatch.setattr(
        picard,
        "in_parts",
        lambda threads, rows, task, least: workers.in_parts(threads, rows, task, 1),
    )
    parts = run(3)
    for name in ("positions", "orientations", "velocities", "angular_velocities"):
        np.testing.assert_array_equal(getattr(parts, name), getattr(one, name))


def _hamilton(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    w1, v1, w2, v2 = a[0], a[1:], b[0], b[1:]
    return np.concatenate([[w1 * w2 - v1 @ v2], w1 * v2 + w2 * v1 + np.cross(v1, v2)])


def _rotation(q: np.ndarray) -> np.ndarray:
    w, x, y, z = q
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def test_the_midpoint_extrapolation_is_the_rule_written_out():
    """``motion.extrapolated`` against the rule in numpy: x, v → 2·mid − start, the turn
    from start to mid applied again, world angular momentum 2·L₁ − L₀ + dt·(x₀ − x₁) × F_c
    solved for the spin at the new orientation; a body not free keeps the midpoint."""
    from engine.kernels.dynamics.motion import extrapolated

    rng = np.random.default_rng(11)
    n, dt = 5, 1e-3
    quats = rng.normal(size=(2, n, 4))
    quats /= np.linalg.norm(quats, axis=2, keepdims=True)
    start = (rng.normal(size=(n, 3)), quats[0], rng.normal(size=(n, 3)), rng.normal(size=(n, 3)))
    mid = (rng.normal(size=(n, 3)), quats[1], rng.normal(size=(n, 3)), rng.normal(size=(n, 3)))
    shape = rng.normal(size=(n, 3, 3))
    inertia = shape @ shape.transpose(0, 2, 1) + np.eye(3)
    mass, force = rng.uniform(0.5, 2.0, n), rng.normal(size=(n, 3))
    free = np.array([True, True, False, True, True])
    out = tuple(np.full_like(a, np.nan) for a in mid)
    extrapolated(start, mid, inertia, np.linalg.inv(inertia), mass, force, free, dt, out)
    for b in range(n):
        if not free[b]:
            for got, want in zip(out, mid, strict=True):
                np.testing.assert_array_equal(got[b], want[b])
            continue
        (x0, q0, v0, w0), (x1, q1, v1, w1) = ([a[b] for a in s] for s in (start, mid))
        np.testing.assert_allclose(out[0][b], 2 * x1 - x0, rtol=1e-14, atol=1e-14)
        np.testing.assert_allclose(out[2][b], 2 * v1 - v0, rtol=1e-14, atol=1e-14)
        q2 = _hamilton(_hamilton(q1, q0 * [1, -1, -1, -1]), q1)
        np.testing.assert_allclose(out[1][b], q2 / np.linalg.norm(q2), rtol=1e-13, atol=1e-14)
        world = [_rotation(q) @ inertia[b] @ _rotation(q).T for q in (q0, q1, out[1][b])]
        contact = mass[b] * (v1 - v0) * 2 / dt - force[b]
        momentum = 2 * world[1] @ w1 - world[0] @ w0 + dt * np.cross(x0 - x1, contact)
        np.testing.assert_allclose(out[3][b], np.linalg.solve(world[2], momentum), rtol=1e-10)


def test_a_frozen_set_within_the_tolerance_is_searched_after_one_more_correction(monkeypatch):
    """A frozen evaluation within the tolerance but not within ``FROZEN_TOLERANCE`` of it
    (out of reach here: a billionth of it, with no absolute floor): one more Newton
    correction, then the search decides, with no frozen evaluation to confirm the
    correction (``FROZEN_CHECK_WITHIN``). From the same state, the same ten steps of a
    ball landing on a plane take fewer iterations with the rule than without it (0), and
    a search follows every frozen evaluation within the tolerance."""
    import engine.dynamics.picard as picard
    import engine.dynamics.relaxation as relaxation
    from engine.dynamics.evaluation import MovedContacts

    law = PaperSpring(damping=0.5, friction=0.5)
    scene = Scene(contact_model=law, separation_speed=math.inf)
    scene.add_plane(size=3.0, divisions=4, epsilon=EPS)
    scene.add_body(BALL, position=(0.1, -0.05, 0.5 + 1.5 * EPS), velocity=(0.05, 0.0, 0.0),
                   epsilon=EPS)  # fmt: skip
    for _ in range(400):  # bounced off its start, about to land again
        scene.step(5e-4)
    monkeypatch.setattr(picard, "FROZEN_TOLERANCE", 1e-9)
    monkeypatch.setattr(relaxation, "ATOL", 0.0)
    kinds = []
    evaluate, settled = picard.evaluate, relaxation.settled

    def recorded(scene_, configuration, origins, search, h, history):
        kinds.append("frozen" if isinstance(search, MovedContacts) else "search")
        return evaluate(scene_, configuration, origins, search, h, history)

    def tested(scene_, computed, mismatch, gross, radius, tighter=1.0, skip=None):
        within = settled(scene_, computed, mismatch, gross, radius, 1.0, skip)
        if kinds[-1] == "frozen" and within:
            kinds[-1] = "frozen within"
        return settled(scene_, computed, mismatch, gross, radius, tighter, skip)

    monkeypatch.setattr(picard, "evaluate", recorded)
    monkeypatch.setattr(relaxation, "settled", tested)
    iterations, after = {}, []
    for rule in (1.0, 0.0):
        monkeypatch.setattr(picard, "FROZEN_CHECK_WITHIN", rule)
        copy = pickle.loads(pickle.dumps(scene))
        iterations[rule] = 0
        for _ in range(10):
            kinds.clear()
            stats = copy.step(5e-4)
            assert stats.converged
            iterations[rule] += stats.picard_iterations
            if rule:
                after += [b for a, b in zip(kinds, kinds[1:], strict=False) if a == "frozen within"]
    assert after and all(kind == "search" for kind in after)
    assert iterations[1.0] < iterations[0.0]
