"""Picard relaxation: the residual vector, Aitken's safeguarded weights, the first weights
from the contact stiffness, the convergence test and settling on a contact-set switch."""

from __future__ import annotations

import numpy as np
import pytest

from engine import PaperSpring, Scene, shapes
from engine.dynamics.bodies import smallest_inertia
from engine.dynamics.evaluation import Wrench
from engine.dynamics.relaxation import (
    BETA_MAX,
    BETA_MIN,
    aitken,
    first_weights,
    flat,
    settled,
    settled_cycle,
    size,
    switch,
)


def test_flat_puts_forces_then_torques_over_their_levers():
    force = np.arange(6.0).reshape(2, 3)
    torque = np.arange(6.0, 12.0).reshape(2, 3)
    radius = np.array([2.0, 4.0])
    got = flat(Wrench(force, torque), radius)
    np.testing.assert_array_equal(
        got, np.concatenate([force.ravel(), (torque / radius[:, None]).ravel()])
    )


def test_size_is_the_norm_of_flat():
    rng = np.random.default_rng(2)
    wrench = Wrench(rng.normal(size=(7, 3)), rng.normal(size=(7, 3)))
    radius = rng.uniform(0.1, 2.0, 7)
    assert size(wrench, radius) == pytest.approx(np.linalg.norm(flat(wrench, radius)), rel=1e-14)
    assert size(Wrench(np.zeros((0, 3)), np.zeros((0, 3))), np.zeros(0)) == 0.0


@pytest.mark.parametrize("beta", [0.005, 0.3, 1.0, 3.0])
def test_aitken_is_safeguarded(beta):
    rng = np.random.default_rng(5)
    previous = rng.normal(size=12)
    assert aitken(beta, None, previous) == min(max(beta, BETA_MIN), BETA_MAX)  # no history
    grown = -2.0 * previous  # swung past and grew: at most half the last weight
    assert BETA_MIN <= aitken(beta, previous, grown) <= max(0.5 * beta, BETA_MIN)
    kept = 0.5 * previous  # same direction, shrinking: at most twice
    weight = aitken(beta, previous, kept)
    assert BETA_MIN <= weight <= min(max(2.0 * beta, BETA_MIN), BETA_MAX)
    # the secant weight that cancels the swing: −β·p·(c − p)/|c − p|² = 2β here, clamped
    assert weight == pytest.approx(min(max(2.0 * beta, BETA_MIN), BETA_MAX))


def test_first_weights_are_one_over_one_plus_the_largest_gain():
    scene = _stack()
    radius = np.array([10.0, 1.0, 1.0])
    assert first_weights(scene, np.zeros((3, 3)), radius, 1e-3) == [1.0, 1.0]
    stiffness = np.array([[5.0, 5.0, 5.0], [2e5, 300.0, 1.0], [1e5, 900.0, 1.0]])
    dt = 1e-3
    free = ~scene.fixed
    mobility = 1.0 / scene.masses[free] + radius[free] ** 2 / smallest_inertia(scene)[free]
    gain_n = (dt * dt * stiffness[free, 0] * mobility).max()
    gain_t = (dt * stiffness[free, 1] * mobility).max()
    expected = [1.0 / (1.0 + gain_n), 1.0 / (1.0 + gain_t)]
    assert first_weights(scene, stiffness, radius, dt) == pytest.approx(expected, rel=1e-14)


def test_settled_is_a_tolerance_of_the_forces_on_each_body():
    scene = _stack()
    n = len(scene)
    computed = Wrench(np.tile([0.0, 0.0, 20.0], (n, 1)), np.zeros((n, 3)))
    gross, radius = np.full(n, 20.0), np.ones(n)
    small = Wrench(
        np.tile([0.0, 0.0, 0.5 * scene.picard_tolerance * 20.0], (n, 1)), np.zeros((n, 3))
    )
    large = Wrench(
        np.tile([0.0, 0.0, 3.0 * scene.picard_tolerance * 20.0], (n, 1)), np.zeros((n, 3))
    )
    assert settled(scene, computed, small, gross, radius)
    assert not settled(scene, computed, large, gross, radius)
    fixed_only = Wrench(large.force * scene.fixed[:, None], large.torque)  # the plane is fixed
    assert settled(scene, computed, fixed_only, gross, radius)


# ------------------------------------------------------------------ settling on a switch
def _stack() -> Scene:
    """A plane and two boxes on it, one on the other (only the bodies matter here)."""
    scene = Scene(scheme="implicit-surrogate", contact_model=PaperSpring(damping=0.5))
    scene.add_plane(size=6.0, divisions=2, epsilon=0.01)
    box = shapes.box()
    scene.add_body(box, position=(0.0, 0.0, 0.52), epsilon=0.017)
    scene.add_body(box, position=(0.1, 0.05, 1.55), epsilon=0.017)
    return scene


def _two_states(scene, rng):
    n = len(scene)
    base = (rng.normal(size=(n, 3)) * 5.0, rng.normal(size=(n, 3)))
    jump = (np.zeros((n, 3)), np.zeros((n, 3)))
    jump[0][1:] = rng.normal(size=(n - 1, 3))  # about 10 % of the free bodies' forces
    a = base
    b = (base[0] + jump[0], base[1] + jump[1])
    return a, b


def test_picard_settles_on_a_contact_set_switch_and_only_there():
    """Computed forces that alternate between two states A and B, with the applied forces
    between them, are a settled step; a third state, too few iterations, or applied forces
    off the segment A–B are not."""
    scene = _stack()
    rng = np.random.default_rng(3)
    a, b = _two_states(scene, rng)
    gross, radius = np.full(len(scene), 9.81), np.ones(len(scene))
    middle = tuple(0.3 * x + 0.7 * y for x, y in zip(a, b, strict=True))
    assert switch(scene, [a, b, a, b], middle, gross, radius)
    assert switch(scene, [b, b, a, a, b, b], a, gross, radius)  # period 4, an end
    assert not switch(scene, [a, a, b, b], middle, gross, radius)  # one change: a transition
    assert not switch(scene, [a, a, a, a, b, b], middle, gross, radius)
    assert not switch(scene, [a, b, a], middle, gross, radius)  # too few
    off = (middle[0] + 3.0, middle[1])
    assert not switch(scene, [a, b, a, b], off, gross, radius)
    c = (b[0] + 2.0 * (b[0] - a[0]), b[1])
    assert not switch(scene, [a, b, c, b], middle, gross, radius)  # three states
    assert not switch(scene, [a, a, a, b], middle, gross, radius)  # B seen once


def test_a_cycle_of_contact_sets_is_a_to_b_and_back():
    """``cycling``: the last three computed totals go from A to B and back to A (frozen
    contact sets that alternate); not a transition, not three states, not too few."""
    from engine.dynamics.relaxation import cycling

    scene = _stack()
    a, b = _two_states(scene, np.random.default_rng(5))
    gross, radius = np.full(len(scene), 9.81), np.ones(len(scene))
    assert cycling(scene, [a, b, a], gross, radius)
    assert cycling(scene, [b, b, a, b], gross, radius)  # the last three
    assert not cycling(scene, [a, a, b], gross, radius)  # a transition
    assert not cycling(scene, [a, b, b], gross, radius)
    assert not cycling(scene, [a, a, a], gross, radius)  # no change
    assert not cycling(scene, [b, a], gross, radius)  # too few
    c = (b[0] + 2.0 * (b[0] - a[0]), b[1])
    assert not cycling(scene, [a, b, c], gross, radius)  # three states


def test_a_cycle_of_frozen_sets_settles_between_its_two_sides():
    """``settled_cycle``: A, B and back to A (three searches) with the applied forces on
    the segment from A to B is settled; applied forces off it, a transition, or three
    states are not."""
    scene = _stack()
    a, b = _two_states(scene, np.random.default_rng(7))
    gross, radius = np.full(len(scene), 9.81), np.ones(len(scene))
    middle = tuple(0.4 * x + 0.6 * y for x, y in zip(a, b, strict=True))
    assert settled_cycle(scene, [a, b, a], middle, gross, radius)
    assert settled_cycle(scene, [b, a, b, a], b, gross, radius)  # the last three; an end
    off = (middle[0] + 3.0, middle[1])
    assert not settled_cycle(scene, [a, b, a], off, gross, radius)
    assert not settled_cycle(scene, [a, a, b], middle, gross, radius)  # a transition
    c = (b[0] + 2.0 * (b[0] - a[0]), b[1])
    assert not settled_cycle(scene, [a, b, c], middle, gross, radius)  # three states
    assert not settled_cycle(scene, [b, a], middle, gross, radius)  # too few


def test_two_bodies_each_on_their_own_switch_settle_body_by_body():
    """Two bodies that each flip between two values on their own (four combinations over
    the scene) with each one's applied forces on its own segment: settled when the bodies
    are tested one by one (``groups``, as Picard tests them), not as one scene; a body
    whose applied forces are off its segment is not."""
    scene = _stack()
    n = len(scene)
    rng = np.random.default_rng(11)
    base = (rng.normal(size=(n, 3)) * 5.0, rng.normal(size=(n, 3)))
    jumps = [np.zeros((n, 3)), np.zeros((n, 3))]
    jumps[0][1], jumps[1][2] = rng.normal(size=3), rng.normal(size=3)  # body 1, body 2

    def state(first: bool, second: bool):
        return (base[0] + first * jumps[0] + second * jumps[1], base[1])

    # body 1: A B A B A B; body 2: A A B B A B
    recent = [state(f, s) for f, s in ((0, 0), (1, 0), (0, 1), (1, 1), (0, 0), (1, 1))]
    applied = (base[0] + 0.3 * jumps[0] + 0.8 * jumps[1], base[1])  # a weight per body
    gross, radius = np.full(n, 9.81), np.ones(n)
    each = np.arange(n)
    assert switch(scene, recent, applied, gross, radius, each)
    assert not switch(scene, recent, applied, gross, radius)  # one scene: four states
    assert not switch(scene, recent, applied, gross, radius, np.zeros(n, np.int64))
    off = (applied[0].copy(), base[1])
    off[0][2] += (3.0, 0.0, 0.0)  # body 2 off its segment
    assert not switch(scene, recent, off, gross, radius, each)
