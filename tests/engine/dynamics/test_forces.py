"""Contact laws (engine/dynamics/forces.py): parameters and validation of each ContactModel,
and the force of a single contact, read off one explicit step of a Scene, against the
law written out by hand here.

The configuration: a tetrahedron standing on its apex (the mesh origin) a gap ``GAP`` above
a fixed plane, ε = ``EPS_BODY`` and ``EPS_PLANE``: one contact, overlap δ = ε_a + ε_b − GAP,
normal +z (from the plane, body 0, to the tetrahedron, body 1). Given mass and isotropic
inertia J, and no gravity, one explicit step (``v' = v + dt·F/m``, ``L' = L + dt·τ``) gives
the contact force F = m·Δv/dt and its torque about the centre of mass τ = J·Δω/dt.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from engine import (
    ContactModel,
    HertzSpring,
    InvalidArgumentError,
    LinearSpring,
    Mesh,
    PaperSpring,
    Scene,
)

TETRA = Mesh(
    np.array([[0, 0, 0], [1, 0, 0.8], [-0.5, 0.8, 0.8], [-0.5, -0.8, 0.8]], float),
    np.array([[0, 2, 1], [0, 3, 2], [0, 1, 3], [1, 2, 3]]),
)
EPS_PLANE, EPS_BODY, GAP = 0.01, 0.02, 0.005
DELTA = EPS_PLANE + EPS_BODY - GAP  # the overlap of the apex with the plane
MASS, J = 2.0, 0.5
COM = np.array([0.2, -0.1, 0.4])  # mesh frame: off the apex, so that forces have a lever
DT = 1e-4
LAWS = (PaperSpring, LinearSpring, HertzSpring)


def on_plane(model, velocity=(0.0, 0.0, 0.0)) -> Scene:
    # overlaps pushed apart at once (no gentle start): the first step shows the law
    scene = Scene(gravity=(0, 0, 0), contact_model=model, separation_speed=math.inf)
    scene.add_plane(point=(0.3, 0.2, 0.0), size=4.0, divisions=1, epsilon=EPS_PLANE)
    scene.add_body(
        TETRA,
        position=COM + [0.0, 0.0, GAP],  # the apex at (0, 0, GAP)
        velocity=velocity,
        mass=MASS,
        inertia=(J, J, J),
        center_of_mass=COM,
        epsilon=EPS_BODY,
    )
    return scene


def the_contact(scene: Scene, overlap: float = DELTA) -> np.ndarray:
    """The single contact's point; checks its overlap and normal (the law's inputs)."""
    contacts = scene.contacts(scene.positions, scene.orientations)
    assert len(contacts.points) == 1
    assert contacts.overlaps[0] == pytest.approx(overlap, rel=1e-12)
    np.testing.assert_allclose(contacts.normals[0], [0.0, 0.0, 1.0], atol=1e-12)
    return contacts.points[0]


def kick(scene: Scene, body: int = 1):
    """One explicit step: (force, torque about the centre of mass) on ``body``, stats."""
    v0, w0 = scene.velocities[body].copy(), scene.angular_velocities[body].copy()
    stats = scene.step(DT, "explicit")
    force = scene.masses[body] * (scene.velocities[body] - v0) / DT
    torque = J * (scene.angular_velocities[body] - w0) / DT
    return force, torque, stats


def spring(model: ContactModel, delta: float, m_red: float, reach: float):
    """(F_n, ∂F_n/∂δ, stored energy) of the laws as documented, written out here."""
    k = model.stiffness
    if isinstance(model, PaperSpring):  # K_s·δ/(ε_a + ε_b)·√m_red
        k_eff = k * math.sqrt(m_red) / reach
        return k_eff * delta, k_eff, 0.5 * k_eff * delta**2
    if isinstance(model, LinearSpring):  # k·δ
        return k * delta, k, 0.5 * k * delta**2
    assert isinstance(model, HertzSpring)  # k·δ^{3/2}, energy ∫ k·x^{3/2} dx = k·δ^{5/2}/(5/2)
    return k * delta**1.5, 1.5 * k * math.sqrt(delta), k * delta**2.5 / 2.5


STIFF = {PaperSpring: 1000.0, LinearSpring: 300.0, HertzSpring: 4e4}


# ------------------------------------------------------------------ parameters
@pytest.mark.parametrize("law", LAWS)
def test_parameters_are_the_kernel_tuple(law):
    model = law(stiffness=250, damping=0.3, friction=0.6, slip_velocity=0.02)
    kind, stiffness, damping, friction, slip, tangential = model.parameters()
    expected = (law.kind, 250.0, 0.3, 0.6, 0.02, 2.0 / 7.0)
    assert (kind, stiffness, damping, friction, slip, tangential) == expected
    assert all(type(v) is float for v in (stiffness, damping, friction, slip, tangential))
    assert type(kind) is int


def test_each_law_has_its_own_kernel_branch():
    assert len({law.kind for law in LAWS}) == len(LAWS)
    assert ContactModel().kind == PaperSpring().kind  # the base class is the paper's law


def test_defaults_are_the_documented_ones():
    # the paper's K_s = 1,000; no damping; μ = 0.5; friction fades in below 1 cm/s
    for law in LAWS:
        assert law().parameters()[1:] == (1000.0, 0.0, 0.5, 1e-2, 2.0 / 7.0)


@pytest.mark.parametrize("law", LAWS)
@pytest.mark.parametrize(
    ("field", "value", "message"),
    [
        ("stiffness", "100", "stiffness must be a number"),
        ("damping", True, "damping must be a number"),
        ("friction", None, "friction must be a number"),
        ("slip_velocity", [0.1], "slip_velocity must be a number"),
        ("stiffness", float("nan"), "stiffness must be finite and >= 0"),
        ("damping", float("inf"), "damping must be finite and >= 0"),
        ("friction", -0.1, "friction must be finite and >= 0"),
        ("slip_velocity", -1e-3, "slip_velocity must be finite and >= 0"),
        ("stiffness", 0.0, "stiffness and slip_velocity must be > 0"),
        ("slip_velocity", 0, "stiffness and slip_velocity must be > 0"),
    ],
)
def test_bad_parameters_are_rejected(law, field, value, message):
    with pytest.raises(InvalidArgumentError, match=message):
        law(**{field: value})


@pytest.mark.parametrize("law", LAWS)
def test_zero_damping_and_friction_and_integers_are_accepted(law):
    model = law(stiffness=5, damping=0, friction=0, slip_velocity=1, tangential_stiffness=0)
    assert model.parameters()[1:] == (5.0, 0.0, 0.0, 1.0, 0.0)


def test_models_are_frozen_and_the_scene_takes_only_models():
    with pytest.raises(dataclasses.FrozenInstanceError):
        PaperSpring().stiffness = 5.0
    with pytest.raises(InvalidArgumentError, match="contact_model"):
        Scene(contact_model=(1000.0, 0.0, 0.5, 1e-2))


# ------------------------------------------------------------------ the force of one contact
@pytest.mark.parametrize("law", LAWS)
def test_the_normal_force_of_one_contact_follows_the_law(law):
    model = law(stiffness=STIFF[law], friction=0.0)
    scene = on_plane(model)
    point, centre = the_contact(scene), scene.positions[1].copy()
    # the plane is fixed (infinite mass): m_red = the body's mass
    f_n, _, energy = spring(model, DELTA, MASS, EPS_PLANE + EPS_BODY)
    force, torque, stats = kick(scene)
    np.testing.assert_allclose(force, [0.0, 0.0, f_n], rtol=1e-12, atol=1e-12 * f_n)
    np.testing.assert_allclose(torque, np.cross(point - centre, force), atol=1e-12 * f_n)
    assert stats.contacts == 1
    assert stats.elastic_energy == pytest.approx(energy, rel=1e-12)
    assert stats.max_overlap == pytest.approx(DELTA / (EPS_PLANE + EPS_BODY), rel=1e-12)


def test_the_paper_law_uses_the_reduced_mass_and_acts_equally_on_both_bodies():
    """Two free bodies: the apex of one tetrahedron a gap above the top face of another
    (upside down: apex at the origin, top face at z = 0.8 covering the axis)."""
    model = PaperSpring(friction=0.0)
    scene = Scene(gravity=(0, 0, 0), contact_model=model, separation_speed=math.inf)
    m_low, m_up = 3.0, 1.5
    scene.add_body(
        TETRA, position=COM, mass=m_low, inertia=(J, J, J), center_of_mass=COM, epsilon=EPS_PLANE
    )
    scene.add_body(
        TETRA,
        position=COM + [0.0, 0.0, 0.8 + GAP],
        mass=m_up,
        inertia=(J, J, J),
        center_of_mass=COM,
        epsilon=EPS_BODY,
    )
    point = the_contact(scene)
    centres = scene.positions.copy()
    m_red = m_low * m_up / (m_low + m_up)
    f_n = model.stiffness * math.sqrt(m_red) / (EPS_PLANE + EPS_BODY) * DELTA
    v0, w0 = scene.velocities.copy(), scene.angular_velocities.copy()
    scene.step(DT, "explicit")
    forces = scene.masses[:, None] * (scene.velocities - v0) / DT
    torques = J * (scene.angular_velocities - w0) / DT
    np.testing.assert_allclose(forces, [[0, 0, -f_n], [0, 0, f_n]], atol=1e-12 * f_n)
    for body in (0, 1):
        lever = np.cross(point - centres[body], forces[body])
        np.testing.assert_allclose(torques[body], lever, atol=1e-12 * f_n)


@pytest.mark.parametrize("law", LAWS)
def test_damping_adds_two_zeta_sqrt_k_eff_m_red_times_the_approach_speed(law):
    zeta, speed = 0.4, 0.05  # the body moves towards the plane
    model = law(stiffness=STIFF[law], damping=zeta, friction=0.0)
    scene = on_plane(model, velocity=(0.0, 0.0, -speed))
    the_contact(scene)
    f_spring, k_eff, _ = spring(model, DELTA, MASS, EPS_PLANE + EPS_BODY)
    f_n = f_spring + 2 * zeta * math.sqrt(k_eff * MASS) * speed  # v_n = −speed
    force, _, _ = kick(scene)
    np.testing.assert_allclose(force, [0.0, 0.0, f_n], rtol=1e-12, atol=1e-12 * f_n)


@pytest.mark.parametrize("law", LAWS)
def test_the_damped_normal_force_never_pulls(law):
    zeta = 1.0
    model = law(stiffness=STIFF[law], damping=zeta, friction=0.5)
    f_spring, k_eff, _ = spring(model, DELTA, MASS, EPS_PLANE + EPS_BODY)
    speed = 2 * f_spring / (2 * zeta * math.sqrt(k_eff * MASS))  # twice what cancels it
    scene = on_plane(model, velocity=(0.0, 0.0, speed))  # moving away from the plane
    the_contact(scene)
    force, torque, _ = kick(scene)
    assert np.all(force == 0.0) and np.all(torque == 0.0)  # no pull, and no friction either


@pytest.mark.parametrize("law", LAWS)
def test_the_dashpot_never_pushes_harder_than_the_spring(law):
    """Approaching fast, the damped force stops at twice the spring's: it goes to zero
    with the overlap, so it is continuous at contact onset."""
    zeta = 0.5
    model = law(stiffness=STIFF[law], damping=zeta, friction=0.0)
    f_spring, k_eff, _ = spring(model, DELTA, MASS, EPS_PLANE + EPS_BODY)
    cancel = f_spring / (2 * zeta * math.sqrt(k_eff * MASS))  # the speed whose dashpot = spring
    for speed, expected in ((0.5 * cancel, 1.5 * f_spring), (3.0 * cancel, 2.0 * f_spring)):
        scene = on_plane(model, velocity=(0.0, 0.0, -speed))  # towards the plane
        the_contact(scene)
        force, _, _ = kick(scene)
        np.testing.assert_allclose(force, [0.0, 0.0, expected], rtol=1e-12, atol=1e-12 * f_spring)


@pytest.mark.parametrize("slide", [0.002, 0.5])  # below and above the slip velocity
@pytest.mark.parametrize("law", LAWS)
def test_friction_is_the_regularised_coulomb_law(law, slide):
    mu, slip = 0.6, 0.01
    model = law(stiffness=STIFF[law], friction=mu, slip_velocity=slip, tangential_stiffness=0)
    scene = on_plane(model, velocity=(0.0, slide, 0.0))  # sliding along +y, no spin
    point, centre = the_contact(scene), scene.positions[1].copy()
    f_n = spring(model, DELTA, MASS, EPS_PLANE + EPS_BODY)[0]
    friction = -mu * f_n * slide / math.sqrt(slide**2 + slip**2)  # along y, against the slide
    assert abs(friction) < mu * f_n  # capped by Coulomb's law
    force, torque, _ = kick(scene)
    expected = np.array([0.0, friction, f_n])
    np.testing.assert_allclose(force, expected, rtol=1e-12, atol=1e-12 * f_n)
    np.testing.assert_allclose(torque, np.cross(point - centre, expected), atol=1e-12 * f_n)
