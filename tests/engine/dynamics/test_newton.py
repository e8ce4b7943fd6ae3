"""Newton corrections of the Picard iteration: the linearised system is solved, and every
correction keeps momentum."""

from __future__ import annotations

import numpy as np
import pytest

from engine import PaperSpring, Scene, shapes
from engine.dynamics.evaluation import Wrench, evaluate
from engine.dynamics.newton import Linearization, _stacked
from engine.kernels.dynamics import linearized as kl


class Flat:
    def __init__(self, scene: Scene) -> None:
        self.scene = scene

    def __call__(self, positions, orientations):
        return self.scene.contacts(positions, orientations, False), None, False


def stack() -> Scene:
    """Two boxes on a plane, the upper one tilted and sliding: many acting contacts."""
    scene = Scene(contact_model=PaperSpring(damping=0.3, friction=0.5, tangential_stiffness=0))
    scene.add_plane(size=2.0, divisions=2, epsilon=0.002)
    scene.add_body(shapes.box((0.2, 0.2, 0.1)), position=(0.0, 0.0, 0.0535), epsilon=0.002)
    turn = np.array([1.0, 0.02, 0.01, 0.0])
    scene.add_body(shapes.box((0.1, 0.1, 0.1)), position=(0.01, 0.0, 0.1555),
                   orientation=turn / np.linalg.norm(turn), velocity=(0.2, 0.05, -0.1),
                   angular_velocity=(0.0, 0.0, 1.0), epsilon=0.002)  # fmt: skip
    return scene


def test_the_correction_solves_the_linearised_system():
    scene = stack()
    state = (scene.positions, scene.orientations, scene.velocities, scene.angular_velocities)
    evaluation = evaluate(scene, state, scene.positions, Flat(scene))
    assert (evaluation.terms[:, 11] > 0).sum() >= 4  # acting contacts
    h = 1e-3
    lin = Linearization(scene, state, h)
    n = len(scene)
    found = evaluation.contacts
    contacts = (found.bodies, found.offsets, found.points, found.normals, evaluation.terms)
    # the dense matrix M + h²K + hC, column by column from the products
    size = 6 * n
    matrix = np.zeros((size, size))
    for column in range(size):
        unit = np.zeros((n, 6))
        unit.flat[column] = 1.0
        out = np.zeros((n, 6))
        kl.contact_product(*contacts[:4], evaluation.terms, lin.origins, unit, h * h, h, out)
        out[:, :3] += lin.mass[:, None] * unit[:, :3]
        out[:, 3:] += np.einsum("bij,bj->bi", lin.inertia, unit[:, 3:])
        matrix[:, column] = out.ravel()
    free = np.repeat(lin.free, 6)
    block = matrix[np.ix_(free, free)]
    # the sliding friction follows the normal force: the matrix is not symmetric
    assert np.abs(block - block.T).max() > 1e-6 * np.abs(block).max()
    rhs = np.random.default_rng(3).normal(size=(n, 6))
    z, change = np.full((n, 6), np.nan), np.full((n, 6), np.nan)
    taken = kl.newton_correction(contacts, lin.origins, lin.mass, lin.inertia, lin.free, h,
                                 rhs, 1e-12, 200, z, change)  # fmt: skip
    assert 0 < taken < 200
    expected = np.linalg.solve(block, rhs.ravel()[free])
    np.testing.assert_allclose(z.ravel()[free], expected, rtol=1e-8, atol=1e-10)
    assert not z[~lin.free].any()
    # the forces' change (h·K + C)·z, as the contact products give it, on the free bodies
    products = np.zeros((n, 6))
    kl.contact_product(*contacts, lin.origins, z, h, 1.0, products)
    scale = np.abs(products).max()
    np.testing.assert_allclose(change[lin.free], products[lin.free], rtol=0, atol=1e-11 * scale)
    assert not change[~lin.free].any()


def test_the_system_blocks_are_the_linearised_matrix_and_factor_it():
    """``system_blocks``' diagonal and coupling blocks assemble M + h²K + hC as the contact
    products give it column by column, and ``block_factors``' L·U is each free body's
    diagonal block with its rows swapped."""
    scene = stack()
    state = (scene.positions, scene.orientations, scene.velocities, scene.angular_velocities)
    evaluation = evaluate(scene, state, scene.positions, Flat(scene))
    h, n = 1e-3, len(scene)
    lin = Linearization(scene, state, h)
    found = evaluation.contacts
    contacts = (found.bodies, found.offsets, found.points, found.normals, evaluation.terms)
    diagonal = np.full((n, 6, 6), np.nan)
    active = kl.coupled_pairs(found.bodies, found.offsets, lin.free)
    coupling = np.full((len(active), 2, 6, 6), np.nan)
    kl.system_blocks(
        contacts, lin.origins, lin.mass, lin.inertia, h, lin.free, active, diagonal, coupling
    )
    assembled = np.zeros((6 * n, 6 * n))
    for body in range(n):
        assembled[6 * body : 6 * body + 6, 6 * body : 6 * body + 6] = diagonal[body]
    for (a, b), block in zip(found.bodies[active], coupling, strict=True):
        assembled[6 * a : 6 * a + 6, 6 * b : 6 * b + 6] += block[0]
        assembled[6 * b : 6 * b + 6, 6 * a : 6 * a + 6] += block[1]
    expected = np.zeros((6 * n, 6 * n))
    for column in range(6 * n):
        unit = np.zeros((n, 6))
        unit.flat[column] = 1.0
        out = np.zeros((n, 6))
        kl.contact_product(*contacts, lin.origins, unit, h * h, h, out)
        out[:, :3] += lin.mass[:, None] * unit[:, :3]
        out[:, 3:] += np.einsum("bij,bj->bi", lin.inertia, unit[:, 3:])
        expected[:, column] = out.ravel()
    free = np.repeat(lin.free, 6)
    assert len(active) and np.abs(coupling).max() > 0  # box on box
    np.testing.assert_allclose(
        assembled[np.ix_(free, free)], expected[np.ix_(free, free)],
        rtol=1e-12, atol=1e-12 * np.abs(expected).max(),
    )  # fmt: skip
    assert not assembled[~free].any() and not assembled[:, ~free].any()
    factors, pivots = np.full((n, 6, 6), np.nan), np.full((n, 6), -1, np.int64)
    kl.block_factors(diagonal, lin.free, factors, pivots)
    assert not factors[~lin.free].any()
    for body in np.flatnonzero(lin.free):
        low = np.tril(factors[body], -1) + np.eye(6)
        swapped = diagonal[body].copy()
        for k, row in enumerate(pivots[body]):
            swapped[[k, row]] = swapped[[row, k]]
        np.testing.assert_allclose(
            low @ np.triu(factors[body]), swapped,
            rtol=1e-12, atol=1e-12 * np.abs(diagonal[body]).max(),
        )  # fmt: skip


def test_a_correction_is_a_sum_of_equal_and_opposite_contact_forces():
    scene = stack()
    scene.gravity[:] = 0.0
    state = (scene.positions, scene.orientations, scene.velocities, scene.angular_velocities)
    evaluation = evaluate(scene, state, scene.positions, Flat(scene))
    lin = Linearization(scene, state, 1e-3)
    applied = lin.predicted(evaluation)
    computed = _stacked(evaluation.normal.plus(evaluation.friction))
    change = _stacked(applied) - computed
    assert np.abs(change).max() > 0
    # the change on the free bodies is balanced by the plane's share: free bodies alone
    # (the plane's row is dropped) — between the two boxes it cancels exactly
    two_boxes = Scene(gravity=(0, 0, 0), contact_model=scene.contact_model)
    for body in (1, 2):
        two_boxes.add_body(
            shapes.box((0.2, 0.2, 0.1) if body == 1 else (0.1, 0.1, 0.1)),
            position=scene.positions[body],
            orientation=scene.orientations[body],
            velocity=scene.velocities[body],
            angular_velocity=scene.angular_velocities[body],
            epsilon=0.002,
        )
    state = (two_boxes.positions, two_boxes.orientations, two_boxes.velocities,
             two_boxes.angular_velocities)  # fmt: skip
    evaluation = evaluate(two_boxes, state, two_boxes.positions, Flat(two_boxes))
    lin = Linearization(two_boxes, state, 1e-3)
    applied = lin.predicted(evaluation)
    net = applied.force.sum(axis=0)
    moment = (np.cross(two_boxes.positions, applied.force) + applied.torque).sum(axis=0)
    scale = np.abs(applied.force).max()
    assert scale > 0
    np.testing.assert_allclose(net, 0.0, atol=1e-12 * scale)
    np.testing.assert_allclose(moment, 0.0, atol=1e-12 * scale)


@pytest.mark.parametrize("scheme", ["implicit", "implicit-midpoint"])
@pytest.mark.parametrize("tangential", [0.0, 2.0 / 7.0])
def test_a_free_impact_with_friction_conserves_momentum(scheme, tangential):
    law = PaperSpring(damping=0.2, friction=0.6, tangential_stiffness=tangential)
    scene = Scene(gravity=(0, 0, 0), contact_model=law, scheme=scheme)
    scene.add_body(shapes.box((0.1, 0.1, 0.1)), position=(0.0, 0.0, 0.0), velocity=(0.1, 0.05, 0.0),
                   angular_velocity=(0.0, 0.0, 3.0), epsilon=0.003, density=1000.0)  # fmt: skip
    scene.add_body(shapes.box((0.1, 0.1, 0.1)), position=(0.104, 0.03, 0.01),
                   velocity=(-0.1, 0.0, 0.0), epsilon=0.003, density=1000.0)  # fmt: skip
    linear, angular = scene.momentum()
    touched = 0
    for _ in range(200):
        stats = scene.step(2.5e-4)
        touched += stats.contacts > 0
    assert touched > 5
    after_linear, after_angular = scene.momentum()
    np.testing.assert_allclose(after_linear, linear, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(after_angular, angular, rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize(
    ("tangential", "stretch"),
    [(2.0 / 7.0, 0.2), (2.0 / 7.0, 3.0), (0.0, 0.0)],  # a spring below and beyond Coulomb's
    ids=["sticking", "sliding", "regularised"],  # cap; the regularised law (no spring)
)
def test_the_contact_slopes_are_the_derivative_of_its_force(tangential, stretch):
    """One contact of a body on a fixed one, with a tangential spring (sticking or sliding)
    or the regularised law: the change of its normal and friction force under a small
    velocity change dv of the body (its overlap closing by h·dv along the normal) is
    −(h·K + C)·dv to first order — the sliding force turns with the spring, its size stays
    μF_n, and friction proportional to the normal force follows it."""
    from engine.kernels.dynamics import contact_forces as kf

    h, mu, zeta, k_law = 1e-3, 0.5, 0.3, 1000.0
    law = (kf.PAPER, k_law, zeta, mu, 1e-2, tangential)
    bodies, offsets = np.array([[0, 1]]), np.array([0, 1])
    points, normals = np.array([[0.1, -0.2, 0.0]]), np.array([[0.0, 0.0, 1.0]])
    overlap, epsilon = 1e-4, np.array([0.002, 0.002])
    mass = np.array([np.inf, 2.0])
    k_t = tangential * k_law * np.sqrt(2.0) / 0.004
    history = np.zeros((1, kf.HISTORY))
    f_n = k_law * np.sqrt(2.0) / 0.004 * overlap
    if tangential:
        history[0, :3] = [1.0, 0.5, 0.0]  # ξ₀ along (2, 1, 0), sized against the cap
        history[0, :3] *= stretch * mu * f_n / k_t / np.linalg.norm(history[0, :3])
    positions = np.array([[0.0, 0.0, -1.0], [0.0, 0.0, 0.3]])
    spins = np.zeros((2, 3))

    def terms_at(velocity):
        velocities = np.array([[0.0, 0.0, 0.0], velocity])
        out = np.zeros((1, kf.TERMS))
        state = (positions, velocities, spins, positions)
        # B moving by h·v along the normal (from the base velocity's) opens the overlap
        overlaps = np.array([overlap - h * (velocity - v) @ normals[0]])
        kf.contact_terms(bodies, offsets, points, normals, overlaps, state,
                         (mass, epsilon, history, h), law, 0, 1, out)  # fmt: skip
        return out

    v = np.array([0.01, -0.02, -0.001])
    base = terms_at(v)
    assert base[0, kf.DAMPING_SLOPE] > 0 and base[0, kf.FRICTION_MAGNITUDE] > 0
    if tangential:
        assert (base[0, kf.TANGENT_SPRING] < k_t) == (stretch > 1.0)  # sliding
    for dv in ([1e-7, 0.0, 0.0], [0.0, 1e-7, 0.0], [0.0, 0.0, 1e-7]):
        dv = np.array(dv)
        after = terms_at(v + dv)[0]
        change = after[0:3] + after[3:6] - base[0, 0:3] - base[0, 3:6]
        z = np.zeros((2, 6))
        z[1, :3] = dv
        predicted = np.zeros((2, 6))
        kl.contact_product(bodies, offsets, points, normals, base, positions, z, h, 1.0, predicted)
        np.testing.assert_allclose(
            change, -predicted[1, :3], rtol=1e-4, atol=1e-6 * np.abs(change).max()
        )


def test_a_contact_its_dashpot_holds_off_has_no_slopes():
    """A contact separating so fast that the dashpot cancels its spring exerts no force, and
    small changes of the motion keep it so: its linearised force is zero too (a spring slope
    there made Newton's corrections push against a force that is not there)."""
    from engine.kernels.dynamics import contact_forces as kf

    law = (kf.PAPER, 1000.0, 0.3, 0.5, 1e-2, 0.0)
    bodies, offsets = np.array([[0, 1]]), np.array([0, 1])
    points, normals = np.array([[0.1, -0.2, 0.0]]), np.array([[0.0, 0.0, 1.0]])
    positions = np.array([[0.0, 0.0, -1.0], [0.0, 0.0, 0.3]])
    velocities = np.array([[0.0, 0.0, 0.0], [0.01, 0.0, 2.0]])  # B leaving A at 2 m/s
    mass, epsilon = np.array([np.inf, 2.0]), np.array([0.002, 0.002])
    terms = np.zeros((1, kf.TERMS))
    state = (positions, velocities, np.zeros((2, 3)), positions)
    params = (mass, epsilon, np.zeros((1, kf.HISTORY)), 1e-3)
    kf.contact_terms(bodies, offsets, points, normals, np.array([1e-4]), state, params, law,
                     0, 1, terms)  # fmt: skip
    assert terms[0, kf.ACTIVE] == 1.0 and terms[0, kf.NORMAL_MAGNITUDE] == 0.0
    z = np.zeros((2, 6))
    z[1] = [0.1, -0.2, 0.3, 1.0, 2.0, -1.0]
    out = np.zeros((2, 6))
    kl.contact_product(bodies, offsets, points, normals, terms, positions, z, 1e-3, 1.0, out)
    assert not out.any()


def test_the_world_inertias_are_the_body_tensors_turned():
    """``motion.world_inertias``: R·I·Rᵀ of each free body (R of its unit quaternion), zero
    for bodies not free."""
    from engine.kernels.dynamics import motion as kd

    rng = np.random.default_rng(11)
    q = rng.normal(size=(5, 4))
    q /= np.linalg.norm(q, axis=1)[:, None]
    spread = rng.normal(size=(5, 3, 3))
    inertia = spread @ spread.transpose(0, 2, 1) + np.eye(3)
    free = np.array([True, False, True, True, False])
    rot, out = np.empty((5, 3, 3)), np.full((5, 3, 3), np.nan)
    kd.rotation_matrices(q, rot)
    kd.world_inertias(q, inertia, free, out)
    expected = np.einsum("bij,bjk,blk->bil", rot, inertia, rot)
    np.testing.assert_allclose(out[free], expected[free], rtol=1e-13, atol=1e-13)
    assert not out[~free].any()


def test_a_correction_in_one_call_is_the_solve_of_its_residual():
    """``Linearization.corrected`` (one kernel call) gives F − (h·K + C)·z with z the solve of
    h·(F − A), and 0 on the fixed plane; a prediction solves h·F."""
    scene = stack()
    state = (scene.positions, scene.orientations, scene.velocities, scene.angular_velocities)
    evaluation = evaluate(scene, state, scene.positions, Flat(scene))
    h = 1e-3
    lin = Linearization(scene, state, h)
    n = len(scene)
    found = evaluation.contacts
    contacts = (found.bodies, found.offsets, found.points, found.normals, evaluation.terms)
    total = _stacked(evaluation.normal.plus(evaluation.friction))
    rng = np.random.default_rng(11)
    applied = total + rng.normal(scale=np.abs(total).max() * 0.1, size=(n, 6))
    applied_wrench = Wrench(applied[:, :3].copy(), applied[:, 3:].copy())
    for given, rhs_forces in ((applied_wrench, applied), (None, np.zeros((n, 6)))):
        if given is None:  # the prediction's form: F against zero applied forces
            zero = np.zeros((n, 3))
            got = lin._corrected(evaluation, evaluation.normal.plus(evaluation.friction),
                                 Wrench(zero, zero))  # fmt: skip
        else:
            got = lin.corrected(evaluation, given)
        z, change = np.empty((n, 6)), np.empty((n, 6))
        kl.newton_correction(contacts, lin.origins, lin.mass, lin.inertia, lin.free, h,
                             h * (total - rhs_forces), 1e-3, 100, z, change)  # fmt: skip
        expected = total - change
        expected[~lin.free] = 0.0
        np.testing.assert_array_equal(_stacked(got), expected)
        assert not _stacked(got)[~lin.free].any() and lin.free.sum() == 2
