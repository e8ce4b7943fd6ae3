"""Scenes: building, instancing, state, validation, the paper's scenarios."""

from __future__ import annotations

import numpy as np
import pytest

from engine import InvalidArgumentError, Scene, build_tree, scenarios, shapes
from engine.dynamics import picard
from engine.trees.halos import DEFAULT_RELATIVE_EPSILON

SPHERE = shapes.icosphere(1, radius=0.5)


def test_bodies_of_one_mesh_share_one_tree():
    scene = Scene()
    scene.add_body(SPHERE, position=(0, 0, 0))
    scene.add_bodies(SPHERE, [[2, 0, 0], [4, 0, 0]], velocities=[[1, 0, 0], [0, 1, 0]])
    scene.add_body(SPHERE, position=(6, 0, 0), epsilon=0.02)  # another ε: the tree shifted
    assert len(scene) == 4 and len(scene.trees) == 2
    np.testing.assert_array_equal(scene.tree_index, [0, 0, 0, 1])
    spread = np.linalg.norm(SPHERE.vertices - SPHERE.vertices.mean(axis=0), axis=1).max()
    default = DEFAULT_RELATIVE_EPSILON * 2 * spread  # the size default of a free body
    np.testing.assert_allclose(scene.epsilon, [default] * 3 + [0.02], rtol=1e-12)
    assert scene.trees[1].triangles is scene.trees[0].triangles  # built once
    np.testing.assert_allclose(scene.masses, SPHERE.volume)
    np.testing.assert_array_equal(scene.velocities[1:3], [[1, 0, 0], [0, 1, 0]])
    tree = build_tree(SPHERE, 0.03)
    index = scene.add_body(tree, position=(8, 0, 0), mass=2.0)
    assert scene.masses[index] == pytest.approx(2.0) and scene.epsilon[index] == 0.03
    again = scene.add_body(tree, position=(10, 0, 0), epsilon=0.05)  # a tree, shifted
    assert scene.epsilon[again] == 0.05 and scene.trees[-1].triangles is tree.triangles
    assert len(scene.trees) == 4 and scene.mass_source.tolist() == ["mesh"] * 6


def test_add_bodies_equals_add_body_one_by_one():
    rng = np.random.default_rng(0)
    positions, q = rng.normal(size=(5, 3)) * 3, rng.normal(size=(5, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    one, many = Scene(), Scene()
    for p, o in zip(positions, q, strict=True):
        one.add_body(SPHERE, position=p, orientation=o, density=2.0)
    many.add_bodies(SPHERE, positions, orientations=q, density=2.0)
    for name in ("positions", "orientations", "masses", "inertia", "centers", "tree_index"):
        np.testing.assert_array_equal(getattr(one, name), getattr(many, name))


def test_fixed_bodies_and_planes_never_move():
    scene = Scene()
    plane = scene.add_plane(point=(0, 0, -1), normal=(0, 0, 1), size=4, divisions=4)
    wall = scene.add_body(shapes.box((1, 1, 1)), position=(3, 0, 0), fixed=True)
    ball = scene.add_body(SPHERE, position=(0, 0, 1))
    before = scene.state
    for _ in range(5):
        scene.step(1e-3)
    after = scene.state
    for body in (plane, wall):
        np.testing.assert_array_equal(after.positions[body], before.positions[body])
        np.testing.assert_array_equal(after.orientations[body], before.orientations[body])
    assert np.isinf(after.masses[plane]) and after.positions[ball, 2] < 1  # falls
    assert after.time == pytest.approx(5e-3)


@pytest.mark.parametrize(
    ("call", "message"),
    [
        (lambda s: s.add_body(SPHERE, orientation=(1, 1, 0, 0)), "unit quaternion"),
        (lambda s: s.add_body(SPHERE, position=(0, np.nan, 0)), "finite"),
        (lambda s: s.add_body(SPHERE, density=1, mass=1), "density or mass"),
        (lambda s: s.add_body(SPHERE, mass=-1), "mass"),
        (lambda s: s.add_body(shapes.plane(), fixed=False), "convex hull is flat"),
        (lambda s: s.add_body(SPHERE, epsilon=-1.0), "epsilon must be finite and > 0"),
        (lambda s: s.add_body(SPHERE, epsilon="thin"), "epsilon must be a number or 'auto'"),
        (lambda s: s.add_body("sphere"), "Mesh or an engine.SurrogateTree"),
        (lambda s: s.add_bodies(SPHERE, [[0, 0, 0]], orientations=[[2, 0, 0, 0]]), "unit"),
        (lambda s: s.step(0.0), "dt"),
        (lambda s: s.step(1e-3, scheme="rk4"), "scheme"),
        (lambda s: s.set_state(positions=np.zeros((3, 3))), r"\(1, 3\)"),
        (lambda s: s.set_external_force(5, (0, 0, 1)), "no body 5"),
    ],
)
def test_bad_input_is_rejected_and_changes_nothing(call, message):
    scene = Scene()
    scene.add_body(SPHERE, position=(0, 0, 0))
    before = scene.state
    with pytest.raises(InvalidArgumentError, match=message):
        call(scene)
    assert len(scene) == 1 and len(scene.trees) == 1
    np.testing.assert_array_equal(scene.state.positions, before.positions)


def test_set_state_validates_everything_before_changing_anything():
    scene = Scene(gravity=(0, 0, 0))
    scene.add_bodies(SPHERE, [[0, 0, 0], [3, 0, 0]], epsilon=0.05)  # 1 m/s: 0.01 a step
    with pytest.raises(InvalidArgumentError):
        scene.set_state(positions=[[1, 1, 1], [2, 2, 2]], orientations=[[1, 0, 0, 0], [0, 0, 0, 0]])
    np.testing.assert_array_equal(scene.positions, [[0, 0, 0], [3, 0, 0]])
    scene.set_state(velocities=[[1, 0, 0], [0, 0, 0]], orientations=[[1, 0, 0, 1e-7], [0, 1, 0, 0]])
    np.testing.assert_allclose(np.linalg.norm(scene.orientations, axis=1), 1.0, atol=1e-15)
    scene.step(1e-2)
    assert scene.positions[0, 0] == pytest.approx(1e-2)


@pytest.mark.parametrize("scheme", ["implicit-surrogate", "multiscale"])
def test_a_grid_with_overlapping_halos_expands_symmetrically(scheme):
    scene = scenarios.sphere_grid(shape=(2, 2, 2), scheme=scheme)  # 1,224-triangle spheres
    centre = scene.positions.mean(0)
    for _ in range(5):
        stats = scene.step(1e-3)
        assert stats.converged and stats.body_pairs == 12  # face neighbours only
    linear, _ = scene.momentum()
    assert np.abs(linear).max() < 1e-12
    np.testing.assert_allclose(scene.positions.mean(0), centre, atol=1e-12)
    outward = np.einsum("bi,bi->b", scene.velocities, scene.positions - centre)
    assert (outward > 0).all()  # every sphere moves away from the centre, all alike
    # multiscale converges to within the Picard tolerance, from surrogate-level forces
    tolerance = 1e-6 if scheme != "multiscale" else scene.picard_tolerance
    np.testing.assert_allclose(outward, outward[0], rtol=tolerance)


def test_scenarios_build_the_paper_setups():
    pp = scenarios.particle_particle(triangles=140)
    assert len(pp) == 2 and len(pp.trees) == 1 and (pp.gravity == 0).all()
    assert pp.velocities[0, 0] > 0 > pp.velocities[1, 0]
    plane = scenarios.particle_on_plane(triangles=80)
    assert plane.fixed.tolist() == [True, False]
    assert sum(len(t.covered_faces(0)) for t in plane.trees) == 512 + 80
    big = scenarios.scale_difference(scale=4, refine=True)
    assert [len(t.covered_faces(0)) for t in big.trees] == [80, 1280]
    assert big.positions[1, 0] - big.positions[0, 0] == pytest.approx(0.5 + 2 + 0.05 + 0.05)
    with pytest.raises(InvalidArgumentError):
        scenarios.sphere(100)


def test_the_dropped_sphere_starts_above_the_tilted_plane():
    scene = scenarios.particle_on_plane(triangles=80, drop=0.1)
    theta = np.radians(20)
    normal = np.array([np.sin(theta), 0.0, np.cos(theta)])
    height = scene.positions[1] @ normal
    assert height == pytest.approx(0.5 + 0.02 + 0.1)
    first = scene.step(1e-3)
    assert first.contacts == 0  # it falls freely first


def test_the_pair_cache_changes_no_bit_of_a_trajectory():
    """Stepping with the pair cache's lists gives exactly the trajectory of searching every
    configuration from the roots; a resting contact is then served from the lists."""
    runs = []
    for skin in (0.0, 0.5):
        scene = scenarios.particle_on_plane(triangles=320)
        scene.pair_cache.skin = skin
        listed = 0
        for _ in range(120):
            listed += scene.step(2e-3).listed
        runs.append((scene.state, listed))
    (plain, none), (cached, some) = runs
    assert none == 0 and some > 0
    for name in ("positions", "orientations", "velocities", "angular_velocities"):
        np.testing.assert_array_equal(getattr(plain, name), getattr(cached, name))


def test_a_converged_step_hands_its_last_evaluation_to_the_next(monkeypatch):
    monkeypatch.setattr(picard, "MAX_FREEZES", 0)  # every iteration searches: counts tell
    scene = scenarios.particle_particle(triangles=320, gap=0.005)
    stats = [scene.step(1e-3) for _ in range(20)]
    assert stats[0].evaluations == stats[0].picard_iterations  # nothing to reuse yet
    later = stats[1:]
    assert all(s.converged for s in later)
    assert all(s.evaluations == s.picard_iterations - 1 for s in later)
    # anything the forces depend on invalidates it
    scene.set_state(velocities=scene.velocities * 0.5)
    after = scene.step(1e-3)
    assert after.evaluations == after.picard_iterations


def test_multiscale_without_warm_start_restarts_at_the_roots_every_step():
    warm = scenarios.particle_on_plane(triangles=140, drop=0.0, scheme="multiscale")
    cold = scenarios.particle_on_plane(triangles=140, drop=0.0, scheme="multiscale")
    cold.multiscale.warm = False
    rows = {"warm": [], "cold": []}
    for _ in range(120):
        rows["warm"].append(warm.step(1e-3))
        rows["cold"].append(cold.step(1e-3))
    touching = [i for i, r in enumerate(rows["cold"]) if r.contacts > 0]
    assert len(touching) > 10
    # cold: every step in contact unfolds from the roots again; warm: only the first ones
    assert all(rows["cold"][i].unfoldings > 0 for i in touching)
    warm_unfold = sum(rows["warm"][i].unfoldings for i in touching[5:])
    cold_unfold = sum(rows["cold"][i].unfoldings for i in touching[5:])
    assert 10 * warm_unfold < cold_unfold
    warm_cmp = sum(rows["warm"][i].comparisons for i in touching[5:])
    cold_cmp = sum(rows["cold"][i].comparisons for i in touching[5:])
    assert cold_cmp > 2 * warm_cmp
    # the same trajectory within the Picard tolerance (Corollary 1)
    np.testing.assert_allclose(warm.positions, cold.positions, atol=1e-4)
    np.testing.assert_allclose(warm.velocities, cold.velocities, atol=1e-2)


def test_multiscale_fronts_are_warm_started_across_steps():
    scene = scenarios.particle_particle(triangles=320, gap=0.03, scheme="multiscale")
    first = scene.step(1e-3)
    while first.unfoldings == 0:  # until the fronts first leave the roots
        first = scene.step(1e-3)
    assert first.converged
    front = scene.multiscale.fronts[(0, 1)]
    size = len(front.nodes)
    second = scene.step(1e-3)
    # the step starts from the front the last one ended with, not from the roots
    assert second.converged and second.unfoldings < first.unfoldings
    assert scene.multiscale.fronts[(0, 1)] is front and len(front.nodes) >= size // 2
    # once apart, the pair's front is dropped
    scene.set_state(positions=scene.positions + np.array([[-5.0, 0, 0], [5.0, 0, 0]]))
    scene.step(1e-3)
    scene.step(1e-3)
    assert (0, 1) not in scene.multiscale.fronts


def test_a_vertex_oriented_grid_meets_vertex_to_vertex_on_the_lines_of_centres():
    scene = scenarios.sphere_grid(shape=(2, 2, 2), orientations="vertices")
    q = scene.orientations
    np.testing.assert_allclose(np.linalg.norm(q, axis=1), 1.0, atol=1e-12)
    assert (q == q[0]).all() and abs(q[0, 0]) < 1.0  # one common, non-trivial rotation
    found = scene.contacts(scene.positions, scene.orientations)
    assert len(found.bodies) == 12 and (np.diff(found.offsets) == 1).all()
    # each face-neighbour pair: one merged contact at the midpoint of the centres, its
    # halos overlapping by 0.02 - 0.0195, as in the aligned grid but away from the poles
    a, b = found.bodies[:, 0], found.bodies[:, 1]
    midpoints = 0.5 * (scene.positions[a] + scene.positions[b])
    np.testing.assert_allclose(found.points, midpoints, atol=1e-9)
    np.testing.assert_allclose(found.overlaps, 0.0005, atol=1e-9)
    aligned = scenarios.sphere_grid(shape=(1, 1, 2))
    poles = aligned.contacts(aligned.positions, aligned.orientations).counters
    generic = scenarios.sphere_grid(shape=(1, 1, 2), orientations="vertices")
    ordinary = generic.contacts(generic.positions, generic.orientations).counters
    assert ordinary["comparisons"] < poles["comparisons"] / 4  # no 36-triangle fans
    with pytest.raises(InvalidArgumentError, match="vertices"):
        scenarios.sphere_grid(shape=(1, 1, 2), triangles=140, orientations="vertices")


def test_a_randomly_oriented_grid_touches_every_face_neighbour():
    scene = scenarios.sphere_grid(shape=(2, 2, 1), orientations="random", seed=3)
    np.testing.assert_allclose(np.linalg.norm(scene.orientations, axis=1), 1.0, atol=1e-12)
    assert len(np.unique(scene.orientations.round(6), axis=0)) == 4
    found = scene.contacts(scene.positions, scene.orientations)
    per_pair = np.diff(found.offsets)
    assert len(found.bodies) == 4 and (per_pair > 0).all()  # face neighbours, all touching
    assert (found.overlaps <= 0.02).all()
    with pytest.raises(InvalidArgumentError, match="orientations"):
        scenarios.sphere_grid(shape=(1, 1, 2), orientations="tilted")


@pytest.mark.parametrize("scheme", ["explicit", "implicit-surrogate", "implicit-midpoint"])
def test_masses_and_fixed_flags_edited_in_place_take_effect(scheme):
    """The per-body terms a step caches follow in-place edits of ``masses`` and ``fixed``."""
    scene = Scene(gravity=(0.0, 0.0, 0.0), scheme=scheme)
    for x in (0.0, 5.0):
        scene.add_body(shapes.box(), position=(x, 0.0, 0.0))
    for body in (0, 1):
        scene.set_external_force(body, (1.0, 0.0, 0.0))
    scene.step(1e-3)
    scene.masses[1] *= 4.0  # a quarter of the acceleration from now on
    scene.fixed[0] = True  # body 0 stops where it is
    before = scene.state
    for _ in range(10):
        scene.step(1e-3)
    np.testing.assert_array_equal(scene.positions[0], before.positions[0])
    gained = scene.velocities[1, 0] - before.velocities[1, 0]
    assert gained == pytest.approx(10 * 1e-3 * 1.0 / scene.masses[1], rel=1e-9)


def test_contacts_rejects_orientations_that_are_not_unit_quaternions():
    scene = scenarios.particle_particle(triangles=80)
    orientations = scene.orientations.copy()
    orientations[1] = 0.0
    with pytest.raises(InvalidArgumentError, match=r"orientations\[1\]"):
        scene.contacts(scene.positions, orientations)
