"""Contacts of a scene configuration (engine/collision/configuration.py): the batched
multiresolution search and the flat search find the same contacts, pair by pair, with the
counters summed over the body pairs."""

from __future__ import annotations

import numpy as np
import pytest

from engine import InvalidArgumentError, Pose, Scene, find_contacts, shapes
from engine.collision.configuration import (
    SEARCH_COUNTERS,
    Contacts,
    batched_contacts,
    flat_contacts,
)
from engine.collision.pair_cache import PairCache


def pile() -> Scene:
    """Three noisy spheres (radii 0.5–0.525) and a box, each pressed into its neighbours and
    the balls into a plane (random orientations)."""
    rng = np.random.default_rng(7)
    scene = Scene()
    ball = shapes.noisy_sphere(2, eta_r=1.05, seed=1, radius=0.5)
    quaternions = rng.normal(size=(3, 4))
    quaternions /= np.linalg.norm(quaternions, axis=1)[:, None]
    scene.add_bodies(
        ball, [[0.0, 0.0, 0.48], [0.96, 0.0, 0.48], [0.48, 0.83, 0.48]], orientations=quaternions
    )
    scene.add_body(shapes.box((0.6, 0.6, 0.6)), position=(0.48, 0.28, 1.25))
    scene.add_plane()
    return scene


def searched(scene: Scene, hierarchy: bool) -> Contacts:
    origins, pairs = scene.configuration(scene.positions, scene.orientations)
    if hierarchy:
        return batched_contacts(
            scene.bank,
            scene.tree_index,
            pairs,
            origins,
            scene.orientations,
            scene.kernel,
            1,
            PairCache(0.5),
        )
    return flat_contacts(
        scene.trees,
        scene.tree_index,
        pairs,
        origins,
        scene.orientations,
        scene.kernel,
        scene.precision,
    )


@pytest.mark.parametrize("kernel", ["hybrid", "exact"])
def test_batched_and_flat_searches_find_the_same_contacts(kernel):
    scene = pile()
    scene.kernel = kernel
    batched, flat = searched(scene, True), searched(scene, False)
    np.testing.assert_array_equal(batched.bodies, flat.bodies)
    assert len(batched.bodies) >= 6  # ball–ball, ball–plane, box–ball pairs at least
    np.testing.assert_array_equal(batched.offsets, flat.offsets)
    assert batched.offsets[-1] > 0
    np.testing.assert_allclose(batched.points, flat.points, rtol=0, atol=1e-12)
    np.testing.assert_allclose(batched.normals, flat.normals, rtol=0, atol=1e-12)
    np.testing.assert_allclose(batched.overlaps, flat.overlaps, rtol=0, atol=1e-12)
    assert batched.counters["triangle_pairs"] == flat.counters["triangle_pairs"] > 0
    for found in (batched, flat):
        assert set(found.counters) == {*SEARCH_COUNTERS, "triangle_pairs"}


def test_each_body_pair_owns_the_rows_of_its_own_query():
    scene = pile()
    found = searched(scene, False)
    origins, _ = scene.configuration(scene.positions, scene.orientations)
    comparisons = 0
    for q, (a, b) in enumerate(found.bodies):
        alone = find_contacts(
            scene.trees[scene.tree_index[a]],
            Pose(origins[a], scene.orientations[a]),
            scene.trees[scene.tree_index[b]],
            Pose(origins[b], scene.orientations[b]),
            kernel=scene.kernel,
            hierarchy=False,
        )
        rows = slice(found.offsets[q], found.offsets[q + 1])
        np.testing.assert_array_equal(found.points[rows], alone.points)
        np.testing.assert_array_equal(found.overlaps[rows], alone.overlaps)
        comparisons += alone.stats.comparisons
    assert found.counters["comparisons"] == comparisons


def test_the_batched_search_names_an_orientation_that_is_not_a_unit_quaternion():
    scene = pile()
    origins, pairs = scene.configuration(scene.positions, scene.orientations)
    bad = scene.orientations.copy()
    bad[2] *= 1.01
    with pytest.raises(InvalidArgumentError, match=r"orientations\[2\].*norm is 1\.01"):
        batched_contacts(scene.bank, scene.tree_index, pairs, origins, bad, "hybrid", 1, None)


@pytest.mark.parametrize("seed", range(4))
def test_queries_are_gathered_and_renormalised_as_numpy_does(seed, monkeypatch):
    """The gather of a configuration's queries, in parts on worker threads (parts of 37
    pairs here), gives numpy's bits: norms within 1e-6 of 1 divided out as
    ``q / np.linalg.norm(q, axis=1)``, rows gathered per pair; the first NaN or off-unit
    orientation is named."""
    import engine.collision.configuration as configuration

    monkeypatch.setattr(configuration, "_ROWS_PER_PART", 37)  # parts of 37 pairs
    rng = np.random.default_rng(seed)
    n, k = 500, 2000
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    q *= 1 + rng.uniform(-9e-7, 9e-7, (n, 1))  # off by up to 0.9e-6: renormalised
    origins, tree_index = rng.normal(size=(n, 3)), rng.integers(0, 7, n)
    pairs = np.sort(rng.integers(0, n, (k, 2)), axis=1)
    out = configuration.gathered_queries(pairs, tree_index, origins, q, 3)
    unit = q / np.linalg.norm(q, axis=1)[:, None]
    a, b = pairs[:, 0], pairs[:, 1]
    want = (tree_index[a], tree_index[b], origins[a], unit[a], origins[b], unit[b])
    for got, expected in zip(out, want, strict=True):
        np.testing.assert_array_equal(got, expected)
    for bad, value in ((17, np.nan), (400, 1.01)):
        off = q.copy()
        off[bad] *= value
        off[bad + 60] *= value  # a later one
        with pytest.raises(InvalidArgumentError, match=rf"orientations\[{bad}\]"):
            configuration.gathered_queries(pairs, tree_index, origins, off, 3)


def test_bodies_are_placed_at_x_minus_r_c_and_the_first_bad_one_is_named():
    """Each body's mesh-frame origin is x − R·c; the first body of several whose position
    is not finite is named."""
    from engine.kernels.dynamics.motion import rotation_matrices

    scene = pile()
    x, q = scene.positions, scene.orientations
    origins, pairs = scene.configuration(x, q)
    rot = np.empty((len(scene), 3, 3))
    rotation_matrices(q, rot)
    np.testing.assert_allclose(origins, x - (rot @ scene.centers[:, :, None])[:, :, 0], atol=1e-15)
    assert len(pairs) >= 4
    x = x.copy()
    x[3, 1], x[1, 2] = np.inf, np.nan
    with pytest.raises(InvalidArgumentError, match="body 1 is not at a finite position"):
        scene.configuration(x, q)


def test_no_candidate_pairs_give_empty_contacts():
    scene = Scene()
    scene.add_bodies(shapes.icosphere(1), [[0.0, 0.0, 0.0], [5.0, 0.0, 0.0]])
    for hierarchy in (True, False):
        found = searched(scene, hierarchy)
        assert found.bodies.shape == (0, 2)
        np.testing.assert_array_equal(found.offsets, [0])
        assert found.points.shape == (0, 3) and found.overlaps.shape == (0,)
        assert found.counters["triangle_pairs"] == 0
