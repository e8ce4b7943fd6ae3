"""The multiscale scheme's contract (engine/collision/multiscale.py), through
``Scene(scheme="multiscale")``: every body pair's front is a complete cut of the pair's
tree product and persists across steps, and a converged step's forces come from exactly
the leaf contacts that the flat search finds at the accepted configuration.
(Warm against cold fronts, and the multiscale trajectory against the implicit one: in
tests/engine/test_scene.py and tests/engine/dynamics/test_dynamics.py.)"""

from __future__ import annotations

import math

import numpy as np
import pytest

from engine import PaperSpring, Scene, shapes

SPHERE = shapes.icosphere(2, radius=0.5)  # 320 faces
TORUS = shapes.torus(0.6, 0.2, 16, 8)  # 256 faces, non-convex


def spheres() -> Scene:
    """Two spheres, 0.02 apart, meeting off-centre with a spin (a soft spring: a long
    contact)."""
    model = PaperSpring(stiffness=100.0)
    scene = Scene(gravity=(0, 0, 0), scheme="multiscale", contact_model=model)
    scene.add_body(SPHERE, position=(0, 0, 0), velocity=(0.5, 0, 0))
    scene.add_body(
        SPHERE,
        position=(1.02, 0.1, 0.02),
        orientation=(math.cos(0.3), 0, math.sin(0.3), 0),
        velocity=(-0.5, 0, 0),
        angular_velocity=(0, 0, 1.0),
        density=2.0,
    )
    return scene


def sphere_on_torus() -> Scene:
    """A small sphere falling onto the rim of a lying torus."""
    scene = Scene(gravity=(0, 0, -9.81), scheme="multiscale", contact_model=PaperSpring())
    scene.add_body(TORUS, position=(0, 0, 0), fixed=True)
    small = shapes.icosphere(2, radius=0.15)
    scene.add_body(small, position=(0.6, 0.05, 0.2 + 0.15 + 0.01), velocity=(0, 0, -0.3))
    return scene


SCENES = {"spheres": spheres, "sphere-on-torus": sphere_on_torus}


def leaf_faces(tree) -> list[np.ndarray]:
    """The original faces under every node of ``tree``."""
    return [tree.covered_faces(node) for node in range(len(tree))]


def assert_complete_cut(nodes: np.ndarray, faces_a, faces_b, n_a: int, n_b: int) -> None:
    """Every leaf pair of the tree product lies under exactly one entry of ``nodes``."""
    count = np.zeros((n_a, n_b), np.int64)
    for i, j in nodes.tolist():
        count[np.ix_(faces_a[i], faces_b[j])] += 1
    assert (count == 1).all(), (
        f"{(count == 0).sum()} leaf pairs uncovered, {(count > 1).sum()} twice"
    )


def hand_energy(scene: Scene, contacts) -> float:
    """Σ ½·k·δ² over the contacts, k = K_s·√m_red/(ε_a + ε_b) (the paper's law)."""
    masses, eps = scene.masses, scene.epsilon
    total = 0.0
    for q, (a, b) in enumerate(contacts.bodies.tolist()):
        ma, mb = masses[a], masses[b]
        m_red = mb if math.isinf(ma) else ma if math.isinf(mb) else ma * mb / (ma + mb)
        k = scene.contact_model.stiffness * math.sqrt(m_red) / (eps[a] + eps[b])
        delta = contacts.overlaps[contacts.offsets[q] : contacts.offsets[q + 1]]
        total += 0.5 * k * float((delta * delta).sum())
    return total


@pytest.fixture(scope="module", params=sorted(SCENES))
def run(request):
    """The scene and, after each of 70 steps: its stats, the fronts (id, a copy of the
    nodes), the flat search's contacts at the accepted configuration and the evaluation
    the step handed on."""
    scene = SCENES[request.param]()
    rows = []
    for _ in range(70):
        stats = scene.step(1e-3)
        fronts = {k: (id(f), f.nodes.copy()) for k, f in scene.multiscale.fronts.items()}
        flat = scene.contacts(scene.positions, scene.orientations, hierarchy=False)
        rows.append((stats, fronts, flat, scene.warm_start))
    return scene, rows


def test_the_scenario_touches_and_unfolds(run):
    _, rows = run
    assert all(stats.converged for stats, *_ in rows)
    assert sum(stats.contacts > 0 for stats, *_ in rows) >= 10
    assert sum(stats.unfoldings for stats, *_ in rows) > 0


def test_every_front_is_a_complete_cut_after_every_step(run):
    scene, rows = run
    trees = [scene.trees[k] for k in scene.tree_index]
    faces = [leaf_faces(t) for t in trees]
    deepest = 0
    for _, fronts, _, _ in rows:
        for (a, b), (_, nodes) in fronts.items():
            sizes = (len(faces[a][0]), len(faces[b][0]))  # the roots cover every face
            assert_complete_cut(nodes, faces[a], faces[b], *sizes)
            deepest = max(deepest, len(nodes))
    assert deepest > 1  # the fronts left the roots


def test_fronts_persist_across_steps(run):
    _, rows = run
    first = next(i for i, (_, fronts, _, _) in enumerate(rows) if (0, 1) in fronts)
    ids = {fronts[(0, 1)][0] for _, fronts, _, _ in rows[first:] if (0, 1) in fronts}
    assert len(ids) == 1  # one front object for the pair, kept from step to step
    # a step that unfolds nothing and folds nothing ends with the front it started from
    kept = 0
    steps = zip(rows[first:-1], rows[first + 1 :], strict=True)
    for (_, before, _, _), (stats, after, _, _) in steps:
        if (0, 1) in after and stats.unfoldings == 0 and stats.folds == 0:
            np.testing.assert_array_equal(after[(0, 1)][1], before[(0, 1)][1])
            kept += 1
    assert kept > 0


def test_a_converged_step_uses_exactly_the_flat_searchs_leaf_contacts(run):
    scene, rows = run
    compared = 0
    for stats, _, flat, handed in rows:
        assert stats.converged
        assert stats.contacts == len(flat.points)
        assert stats.triangle_pairs == flat.counters["triangle_pairs"]
        assert stats.elastic_energy == pytest.approx(hand_energy(scene, flat), rel=1e-9, abs=1e-300)
        evaluation = handed.evaluation  # what the step evaluated last: its final configuration
        assert not evaluation.changed  # nothing unfolded in the last iteration
        leaf = evaluation.contacts
        np.testing.assert_array_equal(leaf.bodies, flat.bodies)
        np.testing.assert_array_equal(leaf.offsets, flat.offsets)
        np.testing.assert_allclose(leaf.points, flat.points, rtol=0, atol=1e-12)
        np.testing.assert_allclose(leaf.normals, flat.normals, rtol=0, atol=1e-12)
        np.testing.assert_allclose(leaf.overlaps, flat.overlaps, rtol=0, atol=1e-12)
        if len(flat.points):
            reach = scene.epsilon[flat.bodies[:, 0]] + scene.epsilon[flat.bodies[:, 1]]
            ratio = flat.overlaps / np.repeat(reach, np.diff(flat.offsets))
            assert stats.max_overlap == pytest.approx(ratio.max(), rel=1e-9)
            compared += 1
    assert compared >= 10
