"""The forces of one configuration and their reuse (engine/dynamics/evaluation.py): Wrench
arithmetic against numpy; ``evaluate`` of a ball on a plane against the
contact law summed here over the contacts ``Scene.contacts`` finds (normal and friction
apart, gravity and the external force in the normal part, fixed rows zero, surrogate
contacts normal only, torques about the given origins); ``evaluation_key`` and ``reused``:
the warm start is taken only for exactly the same state and key, with its torques moved to
the new lever origins, and a converged implicit step hands its last evaluation to the next
(``StepStats.evaluations`` one less than ``picard_iterations``)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from engine import HertzSpring, LinearSpring, PaperSpring, Scene, shapes
from engine.collision.configuration import Contacts
from engine.dynamics import picard
from engine.dynamics.bodies import body_terms
from engine.dynamics.evaluation import (
    Evaluation,
    MovedContacts,
    WarmStart,
    Wrench,
    contact_forces,
    evaluate,
    evaluation_key,
    reused,
)
from engine.kernels.dynamics import contact_forces as kf

BALL = shapes.icosphere(2, radius=0.5)  # 320 faces
EPS = 0.01
LAW = PaperSpring(damping=0.5, friction=0.5, tangential_stiffness=0.0)  # regularised: by hand below
SLIDING = {"velocity": (0.2, -0.1, 0.0), "angular_velocity": (0.3, 0.5, -2.0)}


class Flat:
    """A fresh flat search of every configuration (what the ``implicit`` scheme runs)."""

    hierarchy = False

    def __init__(self, scene: Scene) -> None:
        self.scene = scene

    def __call__(self, positions, orientations):
        return self.scene.contacts(positions, orientations, False), None, False


class WithSurrogate(Flat):
    """The same contacts once more as surrogate contacts, and a front that changed."""

    def __call__(self, positions, orientations):
        contacts = self.scene.contacts(positions, orientations, False)
        return contacts, contacts, True


def ball_on_plane(velocity=(0.0, 0.0, 0.0), angular_velocity=(0.0, 0.0, 0.0)) -> Scene:
    """A fixed plane (body 0) and a ball (body 1) whose lowest vertex overlaps the halos
    by the paper spring's static deflection under the ball's weight: in contact, near
    rest."""
    scene = Scene(contact_model=LAW, scheme="implicit")
    scene.add_plane(size=3.0, divisions=4, epsilon=EPS)
    scene.add_body(
        BALL,
        position=(0.1, -0.05, 1.0),
        velocity=velocity,
        angular_velocity=angular_velocity,
        epsilon=EPS,
    )
    m = scene.masses[1]
    deflection = m * 9.81 / (LAW.stiffness * math.sqrt(m) / (2 * EPS))  # m_red = m
    lowest = float((BALL.vertices[:, 2] - scene.centers[1, 2]).min())
    positions = scene.positions.copy()
    positions[1, 2] = -lowest + 2 * EPS - deflection
    scene.set_state(positions=positions)
    return scene


def configuration(scene: Scene) -> tuple:
    return tuple(
        a.copy()
        for a in (scene.positions, scene.orientations, scene.velocities, scene.angular_velocities)
    )


def by_hand(scene: Scene, state, origins, law=LAW, found=None) -> dict:
    """The contact forces of ``state`` about ``origins``, summed here contact by contact
    from ``scene.contacts`` and the law as documented (the paper's spring, damping on the
    approach speed, at most the spring's force, regularised Coulomb friction; a fixed body's
    mass is infinite)."""
    x, q, v, w = state
    found = scene.contacts(x, q, False) if found is None else found
    return summed(found, (x, v, w, origins), (scene.masses, scene.epsilon), law)


def summed(found, state, params, law) -> dict:
    """:func:`by_hand` for any contacts ``found`` of bodies in ``state = (positions,
    velocities, angular velocities, lever origins)`` with ``params = (masses, epsilon, ...)``
    (regularised friction: the laws here have no tangential spring)."""
    x, v, w, origins = state
    masses, eps = params[:2]
    n = len(x)
    normal, friction = np.zeros((n, 2, 3)), np.zeros((n, 2, 3))  # [:, 0] force, [:, 1] torque
    stiffness, energy = np.zeros((n, 3)), 0.0
    kind, k, zeta, mu, v_slip, tangential = law.parameters()
    assert tangential == 0.0 or mu == 0.0
    for pair, (a, b) in enumerate(found.bodies):
        ma, mb = masses[a], masses[b]
        m_red = mb if math.isinf(ma) else ma if math.isinf(mb) else ma * mb / (ma + mb)
        for c in range(found.offsets[pair], found.offsets[pair + 1]):
            delta, nrm, p = found.overlaps[c], found.normals[c], found.points[c]
            if delta <= 0:
                continue
            if kind == PaperSpring.kind:  # K_s·δ/(ε_a + ε_b)·√m_red
                k_eff = k * math.sqrt(m_red) / (eps[a] + eps[b])
                energy += 0.5 * k_eff * delta**2
            elif kind == LinearSpring.kind:  # k·δ
                k_eff = k
                energy += 0.5 * k * delta**2
            else:  # k·δ^{3/2}
                k_eff = 1.5 * k * math.sqrt(delta)
                energy += 0.4 * k * delta**2.5
            u = (v[b] + np.cross(w[b], p - x[b])) - (v[a] + np.cross(w[a], p - x[a]))
            v_n = float(u @ nrm)
            spring = k_eff * delta if kind != HertzSpring.kind else k * delta**1.5
            # the dashpot never pulls, nor pushes harder than the spring
            f_n = min(max(spring - 2 * zeta * math.sqrt(k_eff * m_red) * v_n, 0.0), 2 * spring)
            if f_n == 2 * spring and zeta > 0:
                k_eff = 2 * k_eff
            elif f_n == 0.0:  # held off by the dashpot: no force, and none nearby either
                k_eff = 0.0
            slide = u - v_n * nrm
            g = -mu * f_n * slide / math.sqrt(slide @ slide + v_slip**2)
            for body, sign in ((b, 1.0), (a, -1.0)):
                normal[body, 0] += sign * f_n * nrm
                normal[body, 1] += sign * np.cross(p - origins[body], f_n * nrm)
                friction[body, 0] += sign * g
                friction[body, 1] += sign * np.cross(p - origins[body], g)
                stiffness[body] += [k_eff, mu * f_n / v_slip, f_n + np.linalg.norm(g)]
    return {
        "normal": normal,
        "friction": friction,
        "stiffness": stiffness,
        "energy": energy,
        "contacts": found,
    }


def assert_wrench(wrench: Wrench, expected: np.ndarray, scale: float) -> None:
    """``wrench`` equals ``expected (n, 2, 3)`` (force, torque) to rounding of ``scale``."""
    np.testing.assert_allclose(wrench.force, expected[:, 0], rtol=1e-12, atol=1e-13 * scale)
    np.testing.assert_allclose(wrench.torque, expected[:, 1], rtol=1e-12, atol=1e-13 * scale)


# ------------------------------------------------------------------ Wrench
def test_wrench_plus_and_minus_are_row_wise_and_keep_the_order():
    rng = np.random.default_rng(1)
    a, b, c, d = (rng.normal(size=(5, 3)) for _ in range(4))
    total = Wrench(a, b).plus(Wrench(c, d))
    difference = Wrench(a, b).minus(Wrench(c, d))
    assert isinstance(total, Wrench) and isinstance(difference, Wrench)
    np.testing.assert_array_equal(total.force, a + c)
    np.testing.assert_array_equal(total.torque, b + d)
    np.testing.assert_array_equal(difference.force, a - c)  # self − other, not the reverse
    np.testing.assert_array_equal(difference.torque, b - d)
    np.testing.assert_array_equal(Wrench(c, d).minus(Wrench(a, b)).force, c - a)
    assert total.force is not a and total.torque is not b  # new arrays, operands untouched


def test_a_ball_at_rest_on_a_plane_gets_the_laws_normal_forces_and_no_friction():
    scene = ball_on_plane()
    state = configuration(scene)
    result = evaluate(scene, state, state[0], Flat(scene))
    expected = by_hand(scene, state, state[0])
    assert isinstance(result, Evaluation) and len(result.contacts.points) > 0
    assert (result.contacts.overlaps > 0).any() and not result.changed
    gravity = body_terms(scene).force  # m·g on the ball, 0 on the plane
    expected["normal"][:, 0] += gravity
    expected["normal"][0] = 0.0  # the plane is fixed
    weight = scene.masses[1] * 9.81
    assert_wrench(result.normal, expected["normal"], weight)
    # the sum of the normal contact forces on the ball, from the contacts and the law
    push = result.normal.force[1] - scene.masses[1] * scene.gravity
    found, m = result.contacts, scene.masses[1]
    k_eff = LAW.stiffness * math.sqrt(m) / (2 * EPS)
    per_contact = k_eff * np.clip(found.overlaps, 0, None)[:, None] * found.normals
    np.testing.assert_allclose(push, per_contact.sum(0), rtol=1e-12, atol=1e-13 * weight)
    assert push[2] > 0  # the plane pushes up
    # at rest: no friction at all, anywhere
    np.testing.assert_array_equal(result.friction.force, 0.0)
    np.testing.assert_array_equal(result.friction.torque, 0.0)
    np.testing.assert_allclose(result.stiffness, expected["stiffness"], rtol=1e-12)
    np.testing.assert_array_equal(result.stiffness[0], result.stiffness[1])  # both ends
    assert result.energy == pytest.approx(expected["energy"], rel=1e-12)


def test_a_sliding_spinning_ball_with_an_external_force():
    scene = ball_on_plane(**SLIDING)
    scene.set_external_force(1, (0.4, 0.0, 1.0))
    state = configuration(scene)
    result = evaluate(scene, state, state[0], Flat(scene))
    expected = by_hand(scene, state, state[0])
    expected["normal"][1, 0] += scene.masses[1] * scene.gravity + scene.external_forces[1]
    expected["normal"][0] = expected["friction"][0] = 0.0  # fixed rows
    scale = scene.masses[1] * 9.81
    assert_wrench(result.normal, expected["normal"], scale)
    assert_wrench(result.friction, expected["friction"], scale)
    assert np.linalg.norm(result.friction.force[1]) > 1e-3 * scale  # friction acts
    # it opposes the sliding of the contact points
    slide = state[2][1] + np.cross(state[3][1], result.contacts.points - state[0][1])
    assert float((result.friction.force[1] * slide.mean(0)).sum()) < 0
    np.testing.assert_allclose(result.stiffness, expected["stiffness"], rtol=1e-12)
    assert result.energy == pytest.approx(expected["energy"], rel=1e-12)


def test_torques_are_taken_about_the_given_origins():
    scene = ball_on_plane(**SLIDING)
    state = configuration(scene)
    elsewhere = state[0] + np.array([[0.5, -1.0, 2.0], [0.03, 0.02, -0.01]])
    at_centres = evaluate(scene, state, state[0], Flat(scene))
    moved = evaluate(scene, state, elsewhere, Flat(scene))
    expected = by_hand(scene, state, elsewhere)
    expected["normal"][:, 0] += body_terms(scene).force
    expected["normal"][0] = expected["friction"][0] = 0.0
    scale = scene.masses[1] * 9.81
    assert_wrench(moved.normal, expected["normal"], scale)
    assert_wrench(moved.friction, expected["friction"], scale)
    for part in ("normal", "friction"):
        a, b = getattr(at_centres, part), getattr(moved, part)
        np.testing.assert_array_equal(a.force, b.force)  # the origins move torques only
    # the gravity at the centre of mass has no moment in an evaluation
    contact = at_centres.normal.force - body_terms(scene).force
    shifted = at_centres.normal.torque + np.cross(state[0] - elsewhere, contact)
    np.testing.assert_allclose(moved.normal.torque[1], shifted[1], rtol=1e-12, atol=1e-13 * scale)


def test_surrogate_contacts_add_normal_forces_only_and_changed_is_passed_on():
    scene = ball_on_plane(**SLIDING)
    state = configuration(scene)
    single = evaluate(scene, state, state[0], Flat(scene))
    double = evaluate(scene, state, state[0], WithSurrogate(scene))
    assert double.changed and not single.changed
    once = by_hand(scene, state, state[0])
    again = by_hand(scene, state, state[0], law=PaperSpring(damping=0.5, friction=0.0))
    expected = once["normal"] + again["normal"]
    expected[:, 0] += body_terms(scene).force
    expected[0] = 0.0
    scale = scene.masses[1] * 9.81
    assert_wrench(double.normal, expected, scale)
    np.testing.assert_array_equal(double.friction.force, single.friction.force)
    np.testing.assert_array_equal(double.friction.torque, single.friction.torque)
    np.testing.assert_allclose(double.stiffness, once["stiffness"] + again["stiffness"], rtol=1e-12)
    assert double.energy == pytest.approx(2 * single.energy, rel=1e-12)


def test_no_contact_leaves_the_constant_forces_only():
    scene = ball_on_plane(**SLIDING)
    scene.set_state(positions=scene.positions + [[0.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    scene.set_external_force(1, (0.0, 3.0, 0.0))
    state = configuration(scene)
    result = evaluate(scene, state, state[0], Flat(scene))
    assert len(result.contacts.points) == 0 and result.energy == 0.0
    np.testing.assert_array_equal(result.normal.force, body_terms(scene).force)
    for array in (result.normal.torque, *result.friction, result.stiffness):
        np.testing.assert_array_equal(array, 0.0)


def random_contacts(seed: int, n: int = 40, pairs: int = 150):
    """Contacts of ``pairs`` distinct body pairs among ``n`` bodies (0 to 3 each, some not
    overlapping), a state and ``(masses, epsilon)`` with three fixed bodies."""
    rng = np.random.default_rng(seed)
    masses = rng.uniform(0.5, 2.0, n)
    masses[:3] = np.inf  # no pair of two fixed bodies: the broad phase leaves them out
    every = np.array([(a, b) for a in range(n) for b in range(max(a + 1, 3), n)], np.int64)
    bodies = every[np.sort(rng.choice(len(every), pairs, replace=False))]
    offsets = np.concatenate([[0], np.cumsum(rng.integers(0, 4, pairs))]).astype(np.int64)
    c = int(offsets[-1])
    normals = rng.normal(size=(c, 3))
    normals /= np.linalg.norm(normals, axis=1)[:, None]
    found = Contacts(
        bodies, offsets, rng.normal(size=(c, 3)), normals, rng.uniform(-0.005, 0.02, c), {}
    )
    state = tuple(rng.normal(size=(n, 3)) for _ in range(4))
    return found, state, (masses, rng.uniform(0.005, 0.02, n), np.zeros((c, kf.HISTORY)), 0.0)


@pytest.mark.parametrize(
    "law",
    [
        PaperSpring(damping=0.3, friction=0.5, tangential_stiffness=0.0),
        LinearSpring(stiffness=500.0, damping=0.1, friction=0.0),
        HertzSpring(
            stiffness=2e4, damping=0.2, friction=0.8, slip_velocity=0.05, tangential_stiffness=0.0
        ),
    ],
)
@pytest.mark.parametrize("seed", [0, 1])
def test_contact_forces_in_parts_are_one_threads_bits_and_the_law(law, seed, monkeypatch):
    """Contact forces summed in parts of pairs and of bodies on worker threads (parts of 3
    pairs and 2 bodies here) are the one-thread sums bit for bit, and the law summed by
    hand contact by contact."""
    import engine.dynamics.evaluation as evaluation

    found, state, params = random_contacts(seed)
    n = len(state[0])

    def forces(threads: int):
        out = tuple(np.zeros((n, 3)) for _ in range(5))
        energy = contact_forces(found, state, params, law.parameters(), out, threads)
        return out, energy

    one, energy = forces(1)
    monkeypatch.setattr(evaluation, "_PAIRS_PER_PART", 3)
    monkeypatch.setattr(evaluation, "_BODIES_PER_PART", 2)
    parts, energy_parts = forces(4)
    for a, b in zip(one, parts, strict=True):
        np.testing.assert_array_equal(a, b)
    assert energy_parts == energy
    expected = summed(found, state, params, law)
    scale = np.abs(expected["normal"]).max()
    assert_wrench(Wrench(*one[:2]), expected["normal"], scale)
    assert_wrench(Wrench(*one[2:4]), expected["friction"], scale)
    np.testing.assert_allclose(one[4], expected["stiffness"], rtol=1e-12, atol=1e-12 * scale)
    assert energy == pytest.approx(expected["energy"], rel=1e-12)
    assert np.abs(one[2]).max() > 0 if law.friction > 0 else not one[2].any()


# ------------------------------------------------------------------ evaluation_key
def _gravity(scene):
    scene.gravity[2] = -9.0


def _external(scene):
    scene.external_forces[1] = (0.0, 0.0, 1.0)


def _fixed(scene):
    scene.fixed[1] = True


def _masses(scene):
    scene.masses[1] *= 1.5


def _law(scene):
    scene.contact_model = PaperSpring(damping=0.5, friction=0.4, tangential_stiffness=0.0)


def _kernel(scene):
    scene.kernel = "iterative" if scene.kernel != "iterative" else "hybrid"


def _precision(scene):
    scene.precision = "float32" if scene.precision != "float32" else "float64"


def _add_body(scene):
    scene.add_body(BALL, position=(2.0, 0.0, 2.0), epsilon=EPS)


KEY_EDITS = [_gravity, _external, _fixed, _masses, _law, _kernel, _precision, _add_body]


def test_the_key_is_stable_and_names_the_search():
    scene = ball_on_plane()
    key = evaluation_key(scene, Flat(scene))
    assert evaluation_key(scene, Flat(scene)) == key
    scene.gravity = scene.gravity.copy()  # equal values: the same forces
    assert evaluation_key(scene, Flat(scene)) == key
    scene.set_state(velocities=scene.velocities + 1.0)  # the state is not in the key
    assert evaluation_key(scene, Flat(scene)) == key
    surrogate = Flat(scene)
    surrogate.hierarchy = True
    assert evaluation_key(scene, surrogate) != key
    assert evaluation_key(scene, WithSurrogate(scene)) != key


@pytest.mark.parametrize("edit", KEY_EDITS)
def test_the_key_changes_with_whatever_the_forces_depend_on(edit):
    scene = ball_on_plane()
    key = evaluation_key(scene, Flat(scene))
    edit(scene)
    assert evaluation_key(scene, Flat(scene)) != key


# ------------------------------------------------------------------ reused
def warm_scene():
    """A sliding ball whose evaluation was made with torques about other origins (the
    start of the step that ended here), kept as the scene's warm start."""
    scene = ball_on_plane(**SLIDING)
    state = configuration(scene)
    previous = state[0] + np.array([[0.0, 0.0, 0.0], [-2e-4, 1e-4, 3e-5]])
    kept = evaluate(scene, state, previous, Flat(scene))._replace(changed=True)
    key = evaluation_key(scene, Flat(scene))
    scene.warm_start = WarmStart(key, state, previous, kept)
    return scene, key, state, kept


def test_the_warm_evaluation_is_reused_with_its_torques_moved_to_the_new_origins():
    scene, key, state, kept = warm_scene()
    start = configuration(scene)  # equal values, other arrays
    result = reused(scene, key, start)
    assert result is not None and not result.changed  # this configuration is final
    assert result.contacts is kept.contacts and result.energy == kept.energy
    assert result.stiffness is kept.stiffness
    direct = evaluate(scene, start, start[0], Flat(scene))
    scale = scene.masses[1] * 9.81
    for part in ("normal", "friction"):
        got, want = getattr(result, part), getattr(direct, part)
        np.testing.assert_array_equal(got.force, getattr(kept, part).force)
        np.testing.assert_array_equal(got.force, want.force)
        np.testing.assert_allclose(got.torque, want.torque, rtol=1e-9, atol=1e-12 * scale)
        np.testing.assert_array_equal(got.torque[0], 0.0)  # the fixed plane
    # τ' = τ + (o_old − o_new) × F: the move is not nothing
    contact = kept.normal.force - body_terms(scene).force
    lever = scene.warm_start.origins - start[0]
    np.testing.assert_allclose(
        result.normal.torque[1] - kept.normal.torque[1],
        np.cross(lever[1], contact[1]),
        rtol=1e-9,
        atol=1e-12 * scale,
    )
    assert np.linalg.norm(np.cross(lever[1], contact[1])) > 1e-6 * scale
    np.testing.assert_allclose(
        result.friction.torque[1] - kept.friction.torque[1],
        np.cross(lever[1], kept.friction.force[1]),
        rtol=1e-9,
        atol=1e-12 * scale,
    )


@pytest.mark.parametrize("row", range(4), ids=["x", "q", "v", "w"])
def test_a_different_state_is_not_reused(row):
    scene, key, state, _ = warm_scene()
    start = list(configuration(scene))
    start[row][1, 0] = np.nextafter(start[row][1, 0], np.inf)  # one ulp
    assert reused(scene, key, tuple(start)) is None


@pytest.mark.parametrize("edit", KEY_EDITS)
def test_a_different_key_is_not_reused(edit):
    scene, key, _, _ = warm_scene()
    edit(scene)
    if edit is _add_body:
        assert scene.warm_start is None  # adding bodies clears it
        return
    assert reused(scene, evaluation_key(scene, Flat(scene)), configuration(scene)) is None


def test_nothing_is_reused_without_a_warm_start():
    scene = ball_on_plane()
    assert scene.warm_start is None
    assert reused(scene, evaluation_key(scene, Flat(scene)), configuration(scene)) is None


def test_an_evaluation_without_contact_forces_is_reused_as_it_is():
    scene = ball_on_plane(**SLIDING)
    scene.set_state(positions=scene.positions + [[0.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    state = configuration(scene)
    kept = evaluate(scene, state, state[0] - 1.0, Flat(scene))
    key = evaluation_key(scene, Flat(scene))
    scene.warm_start = WarmStart(key, state, state[0] - 1.0, kept)
    result = reused(scene, key, configuration(scene))
    assert result.normal is kept.normal and result.friction is kept.friction


# ------------------------------------------------------------------ across time steps
def stepped(steps: int = 4):
    """A damped ball settling on a plane, stepped implicitly (flat search)."""
    scene = ball_on_plane()
    stats = [scene.step(1e-3) for _ in range(steps)]
    return scene, stats


def test_a_converged_step_leaves_its_last_evaluation_for_the_next():
    scene, stats = stepped()
    # the first step searches its start and the answer it found on that frozen set
    assert 2 <= stats[0].evaluations < stats[0].picard_iterations
    assert all(s.converged and s.contacts > 0 for s in stats)
    # each later step's first iteration is the last one's final evaluation: one search
    # fewer; a step ends on a search of the configuration it accepts
    assert all(1 <= s.evaluations <= s.picard_iterations - 1 for s in stats[1:])
    start = configuration(scene)
    stats = scene.step(1e-3)
    assert 1 <= stats.evaluations <= stats.picard_iterations - 1
    warm = scene.warm_start
    # it is the evaluation of the configuration the step accepted, about the step's start
    for kept, now in zip(warm.state, configuration(scene), strict=True):
        np.testing.assert_array_equal(kept, now)
    np.testing.assert_array_equal(warm.origins, start[0])
    again = evaluate(scene, warm.state, warm.origins, Flat(scene))
    for part in ("normal", "friction"):
        for got, want in zip(getattr(warm.evaluation, part), getattr(again, part), strict=True):
            np.testing.assert_array_equal(got, want)
    # what the next step takes: the same forces, torques about the new start
    now = configuration(scene)
    taken = reused(scene, warm.key, now)
    direct = evaluate(scene, now, now[0], Flat(scene))
    scale = scene.masses[1] * 9.81
    for part in ("normal", "friction"):
        got, want = getattr(taken, part), getattr(direct, part)
        np.testing.assert_array_equal(got.force, want.force)
        np.testing.assert_allclose(got.torque, want.torque, rtol=1e-9, atol=1e-12 * scale)


def _positions(scene):
    scene.positions[1, 0] += 1e-7


def _velocities(scene):
    scene.set_state(velocities=scene.velocities * 0.5)


def _external_by_setter(scene):
    scene.set_external_force(1, (0.1, 0.0, 0.0))


@pytest.mark.parametrize(
    "edit", [_positions, _velocities, _gravity, _external, _external_by_setter, _masses, _law]
)
def test_a_change_from_outside_makes_the_next_step_search_again(edit, monkeypatch):
    monkeypatch.setattr(picard, "MAX_FREEZES", 0)  # every iteration searches: counts tell
    scene, stats = stepped(3)
    assert stats[-1].converged and scene.warm_start is not None
    edit(scene)
    after = scene.step(1e-3)
    assert after.evaluations == after.picard_iterations
    follow = scene.step(1e-3)  # and the warm start works again after a converged step
    assert follow.evaluations == follow.picard_iterations - int(after.converged)


@pytest.mark.parametrize("scheme", ["explicit", "implicit-midpoint"])
def test_steps_that_end_elsewhere_leave_no_warm_start(scheme):
    """Explicit keeps nothing; the midpoint rule keeps its midpoint's evaluation, whose
    contacts the next step carries on (frozen), but never its forces as the new start's."""
    scene, _ = stepped(2)
    assert scene.warm_start is not None
    scene.step(1e-3, scheme)
    if scheme == "explicit":
        assert scene.warm_start is None
    else:
        key = evaluation_key(scene, Flat(scene))
        assert scene.warm_start is not None
        assert reused(scene, scene.warm_start.key, configuration(scene)) is None
        assert key != scene.warm_start.key  # a hierarchical search made it, not a flat one


def test_moved_contacts_follow_the_bodies_rigidly():
    """A frozen contact set: at the configuration it was found in, the same contacts;
    with B moved by d along a contact's normal, that overlap is d smaller and the point
    d/2 further; turned with A, normals turn with it."""
    scene = ball_on_plane()
    x, q = scene.positions.copy(), scene.orientations.copy()
    found = scene.contacts(x, q, False)
    assert len(found.points) > 0
    moved = MovedContacts(scene, found, x, q)
    same = moved(x, q)[0]
    np.testing.assert_allclose(same.points, found.points, atol=1e-15)
    np.testing.assert_allclose(same.overlaps, found.overlaps, rtol=1e-12)
    d = 1e-4
    lifted = x.copy()
    lifted[1] += d * found.normals[0]
    up = moved(lifted, q)[0]
    np.testing.assert_allclose(up.overlaps[0], found.overlaps[0] - d, rtol=0, atol=1e-15)
    np.testing.assert_allclose(up.points[0], found.points[0] + 0.5 * d * found.normals[0])
    turned = q.copy()
    turned[0] = [np.cos(0.05), np.sin(0.05), 0.0, 0.0]  # the plane (A) turns about x
    rot = np.array([[1, 0, 0], [0, np.cos(0.1), -np.sin(0.1)], [0, np.sin(0.1), np.cos(0.1)]])
    np.testing.assert_allclose(moved(x, turned)[0].normals, found.normals @ rot.T, atol=1e-15)


def test_adding_a_body_clears_the_warm_start():
    scene, _ = stepped(2)
    assert scene.warm_start is not None
    _add_body(scene)
    assert scene.warm_start is None
