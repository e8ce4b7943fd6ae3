"""Per-body terms of the dynamics (engine/dynamics/bodies.py): BodyTerms of a scene with free
and fixed bodies, gravity and external forces, written out here from the scene's arrays;
the scene's BodyCache, rebuilt when what the terms come from changes (arrays replaced or
edited in place) and the same object otherwise; the smallest principal moments."""

from __future__ import annotations

import math

import numpy as np
import pytest

from engine import Scene, shapes
from engine.dynamics.bodies import BodyCache, BodyTerms, body_terms, smallest_inertia
from engine.dynamics.sleep import Sleep

GRAVITY = (0.5, -1.0, -9.81)  # off the axes: every component of m·g is checked
BOX_MASS = 2.5
MOMENTS = (1.5, 2.0, 3.0)  # a valid inertia (triangle inequality), its smallest known
PUSH = np.array([0.3, -0.2, 1.0])


def rotation(axis, angle: float) -> np.ndarray:
    """(3, 3) rotation by ``angle`` about the unit vector along ``axis`` (Rodrigues)."""
    k = np.asarray(axis, float) / np.linalg.norm(axis)
    skew = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + math.sin(angle) * skew + (1 - math.cos(angle)) * skew @ skew


TURN = rotation((1.0, 2.0, -0.5), 0.7)


def small_scene() -> Scene:
    """A fixed plane (body 0), a box of given mass and a rotated inertia tensor (body 1)
    pushed by an external force, a ball of density 1 (body 2), a fixed box (body 3) with an
    external force that a fixed body ignores."""
    scene = Scene(gravity=GRAVITY)
    scene.add_plane(size=4.0, divisions=2)
    scene.add_body(
        shapes.box((1.0, 2.0, 0.5)),
        position=(0.0, 0.0, 1.0),
        mass=BOX_MASS,
        inertia=TURN @ np.diag(MOMENTS) @ TURN.T,
    )
    scene.add_body(shapes.icosphere(1, radius=0.4), position=(2.0, 0.0, 1.0))
    scene.add_body(shapes.box(), position=(-2.0, 0.0, 1.0), fixed=True)
    scene.set_external_force(1, PUSH)
    scene.set_external_force(3, (5.0, 5.0, 5.0))
    return scene


def expected_terms(scene: Scene) -> dict:
    """The documented terms, body by body, from the scene's arrays."""
    g = np.asarray(scene.gravity)
    force, size, inverse_mass, radius = [], [], [], []
    for b in range(len(scene)):
        m, push = scene.masses[b], scene.external_forces[b]
        radius.append(scene.trees[scene.tree_index[b]].bounding_radius)
        if scene.fixed[b]:
            force.append(np.zeros(3)), size.append(0.0), inverse_mass.append(0.0)
        else:
            force.append(m * g + push)
            size.append(m * np.linalg.norm(g) + np.linalg.norm(push))
            inverse_mass.append(1.0 / m)
    weights = [scene.masses[b] * np.linalg.norm(g) for b in range(len(scene)) if not scene.fixed[b]]
    return {
        "free": ~scene.fixed,
        "fixed": np.flatnonzero(scene.fixed),
        "force": np.array(force),
        "size": np.array(size),
        "weight": max(weights, default=0.0),
        "radius": np.array(radius),
        "inverse_mass": np.array(inverse_mass),
    }


def assert_terms(terms: BodyTerms, scene: Scene) -> None:
    expected = expected_terms(scene)
    np.testing.assert_array_equal(terms.free, expected["free"])
    np.testing.assert_array_equal(terms.fixed, expected["fixed"])
    assert terms.fixed.dtype == np.int64 and terms.free.dtype == bool
    for name in ("force", "size", "radius", "inverse_mass"):
        value = getattr(terms, name)
        assert value.dtype == np.float64 and value.shape == expected[name].shape, name
        np.testing.assert_allclose(value, expected[name], rtol=1e-15, atol=0, err_msg=name)
    assert terms.weight == pytest.approx(expected["weight"], rel=1e-15)


# ------------------------------------------------------------------ the terms
def test_the_terms_of_free_and_fixed_bodies():
    scene = small_scene()
    terms = body_terms(scene)
    assert_terms(terms, scene)
    # the scene as built: two fixed bodies with infinite mass and no force despite a push
    np.testing.assert_array_equal(terms.fixed, [0, 3])
    assert np.isinf(scene.masses[[0, 3]]).all()
    np.testing.assert_array_equal(terms.force[[0, 3]], 0.0)
    np.testing.assert_array_equal(terms.inverse_mass[[0, 3]], 0.0)
    assert scene.masses[1] == BOX_MASS
    np.testing.assert_allclose(terms.force[1], BOX_MASS * np.array(GRAVITY) + PUSH, rtol=1e-15)
    heavier = max(scene.masses[1], scene.masses[2])
    assert terms.weight == pytest.approx(heavier * np.linalg.norm(GRAVITY), rel=1e-15)
    # the radius is the bounding radius of each body's own tree (instancing: per tree)
    assert scene.tree_index[1] != scene.tree_index[2]
    assert terms.radius[1] != terms.radius[2]


def test_the_terms_are_computed_afresh_by_of_and_kept_by_the_cache():
    scene = small_scene()
    cached = body_terms(scene)
    assert body_terms(scene) is cached
    assert scene.body_cache.terms(scene) is cached
    fresh = BodyTerms.of(scene)
    assert fresh is not cached
    for name in ("free", "fixed", "force", "size", "radius", "inverse_mass"):
        np.testing.assert_array_equal(getattr(fresh, name), getattr(cached, name))
    assert fresh.weight == cached.weight


def test_without_free_bodies_the_weight_is_zero_and_without_gravity_size_is_the_push():
    scene = Scene(gravity=(0.0, 0.0, 0.0))
    scene.add_plane()
    assert body_terms(scene).weight == 0.0
    assert_terms(body_terms(scene), scene)
    scene.add_body(shapes.box(), position=(0.0, 0.0, 2.0))
    scene.set_external_force(1, PUSH)
    terms = body_terms(scene)
    assert terms.weight == 0.0
    assert terms.size[1] == pytest.approx(np.linalg.norm(PUSH), rel=1e-15)
    assert_terms(terms, scene)


# ------------------------------------------------------------------ the cache follows the scene
def _scale_mass(scene):
    scene.masses[2] *= 3.0


def _fix(scene):
    scene.fixed[2] = True


def _gravity_in_place(scene):
    scene.gravity[:] = (0.0, 0.0, -1.62)


def _gravity_replaced(scene):
    scene.gravity = np.array([0.0, 1.0, -3.0])


def _external_row(scene):
    scene.external_forces[1] = (0.0, 0.0, 7.0)


def _external_component(scene):
    scene.external_forces[2, 0] += 0.25


def _set_external_force(scene):
    scene.set_external_force(2, (1.0, 1.0, 0.0))


def _add_body(scene):
    scene.add_body(shapes.box(), position=(0.0, 3.0, 1.0))


@pytest.mark.parametrize(
    "edit",
    [
        _scale_mass,
        _fix,
        _gravity_in_place,
        _gravity_replaced,
        _external_row,
        _external_component,
        _set_external_force,
        _add_body,
    ],
)
def test_the_terms_are_rebuilt_when_what_they_come_from_changes(edit):
    scene = small_scene()
    before = body_terms(scene)
    snapshot = expected_terms(scene)
    edit(scene)
    after = body_terms(scene)
    assert after is not before
    assert_terms(after, scene)  # the new values, not the old ones
    changed = [
        name
        for name in ("free", "force", "size", "inverse_mass", "radius")
        if getattr(after, name).shape != snapshot[name].shape
        or not np.array_equal(getattr(after, name), snapshot[name])
    ]
    assert changed, "the edit changed none of the terms"
    assert body_terms(scene) is after  # and kept again


@pytest.mark.parametrize(
    "edit",
    [
        lambda s: None,
        lambda s: s.gravity.__setitem__(slice(None), s.gravity.copy()),  # same values
        lambda s: setattr(s, "gravity", s.gravity.copy()),  # an equal array
        lambda s: s.set_external_force(1, PUSH),  # the force it already has
        lambda s: s.set_state(positions=s.positions + 0.1),  # the state is not a term
    ],
    ids=["nothing", "gravity-same-values", "gravity-equal-copy", "same-force", "state"],
)
def test_the_terms_are_the_same_object_while_nothing_they_depend_on_changed(edit):
    scene = small_scene()
    before = body_terms(scene)
    edit(scene)
    assert body_terms(scene) is before


def test_a_step_uses_gravity_edited_in_place():
    """The cache is what the time stepping reads: an in-place edit of gravity reaches the
    next step's free fall (no contact: v' = v + dt·(g + F/m))."""
    scene = Scene(gravity=(0.0, 0.0, -9.81), scheme="explicit")
    scene.add_body(shapes.box(), position=(0.0, 0.0, 0.0))
    scene.step(1e-3)
    scene.gravity[:] = (1.0, 0.0, 0.0)
    scene.external_forces[0] = (0.0, 2.0, 0.0)
    v0 = scene.velocities[0].copy()
    scene.step(1e-3)
    gained = (np.array([1.0, 0.0, 0.0]) + np.array([0.0, 2.0, 0.0]) / scene.masses[0]) * 1e-3
    np.testing.assert_allclose(scene.velocities[0] - v0, gained, rtol=1e-12, atol=1e-18)


# ------------------------------------------------------------------ smallest principal moment
def test_the_smallest_principal_moment_of_each_free_body():
    scene = small_scene()
    smallest = smallest_inertia(scene)
    assert smallest.shape == (4,) and smallest.dtype == np.float64
    assert np.isnan(smallest[[0, 3]]).all()  # fixed bodies
    # body 1: its tensor is diag(MOMENTS) turned, so its smallest moment is min(MOMENTS)
    assert smallest[1] == pytest.approx(min(MOMENTS), rel=1e-12)
    # body 2: the ball's own tensor from the mesh
    assert smallest[2] == pytest.approx(np.linalg.eigvalsh(scene.inertia[2]).min(), rel=1e-12)
    assert scene.body_cache.smallest_inertia(scene) is smallest


def test_the_smallest_moments_are_kept_until_inertia_or_fixed_is_replaced():
    scene = small_scene()
    first = smallest_inertia(scene)
    assert smallest_inertia(scene) is first
    scene.set_state(velocities=scene.velocities + 1.0)
    assert smallest_inertia(scene) is first
    # sleeping bodies are frozen by replacing ``fixed``: body 2 is then NaN, and back after
    sleep = Sleep()
    sleep.wake_all(len(scene))
    sleep.asleep[2] = True
    with sleep.frozen(scene):
        frozen = smallest_inertia(scene)
        assert frozen is not first and np.isnan(frozen[2])
        np.testing.assert_allclose(frozen[[0, 1, 3]], first[[0, 1, 3]], rtol=1e-15)
    thawed = smallest_inertia(scene)
    assert thawed is not frozen
    np.testing.assert_allclose(thawed, first, rtol=1e-15)
    # adding a body replaces ``inertia``
    scene.add_body(shapes.box(), position=(0.0, 3.0, 1.0), mass=1.0, inertia=(0.2, 0.3, 0.4))
    grown = smallest_inertia(scene)
    assert grown.shape == (5,) and grown[4] == pytest.approx(0.2, rel=1e-12)


def test_the_smallest_moments_follow_fixed_flags_edited_in_place():
    scene = small_scene()
    scene.fixed[1] = True  # in place, as tests/engine/test_scene.py edits it
    assert np.isnan(smallest_inertia(scene)[1])
    scene.fixed[1] = False
    assert smallest_inertia(scene)[1] == pytest.approx(min(MOMENTS), rel=1e-12)


def test_a_new_cache_starts_empty():
    scene = small_scene()
    cache = BodyCache()
    terms = cache.terms(scene)
    assert terms is not body_terms(scene)  # its own, not the scene's
    assert cache.terms(scene) is terms
    assert_terms(terms, scene)


def test_the_terms_of_two_fixed_masks_are_both_kept():
    """A scene with sleeping bodies fixes them around each step: its terms alternate
    between two masks, and both stay cached (the same objects, no rebuild)."""
    scene = small_scene()
    awake = body_terms(scene)
    scene.fixed[2] = True
    asleep = body_terms(scene)
    assert asleep is not awake and asleep.free[2] == np.False_
    scene.fixed[2] = False
    assert body_terms(scene) is awake
    scene.fixed[2] = True
    assert body_terms(scene) is asleep
    assert_terms(asleep, scene)


def test_held_terms_are_the_blocks_start_and_checked_again_after_it():
    scene = small_scene()
    before = body_terms(scene)
    with scene.body_cache.held(scene) as held:
        assert held is before
        scene.gravity[:] = (0.0, 0.0, -1.0)  # not looked at while held
        assert body_terms(scene) is before
        with scene.body_cache.held(scene) as inner:  # nested: the outer block's
            assert inner is before
        assert body_terms(scene) is before
    after = body_terms(scene)
    assert after is not before
    assert_terms(after, scene)


def test_the_terms_of_a_replaced_mask_with_the_same_values_are_kept():
    """Sleep replaces ``scene.fixed`` around each step (a new array, the values of one of
    two masks): the terms are found by value."""
    scene = small_scene()
    awake = body_terms(scene)
    original = scene.fixed
    scene.fixed = original | (np.arange(len(scene)) == 2)
    asleep = body_terms(scene)
    scene.fixed = original.copy()
    assert body_terms(scene) is awake
    scene.fixed = original | (np.arange(len(scene)) == 2)
    assert body_terms(scene) is asleep
