"""The traversal's root test (``roots_apart``), which the batch also runs before building a
traversal: it prunes only body pairs whose ε-regions are truly apart by more than the reach
(the exact mesh distance is the oracle), and a pruned pair's batch result is the
traversal's (no contact, an empty list, depth 0)."""

from __future__ import annotations

import numpy as np
import pytest

from engine import Pose, build_tree, shapes
from engine.collision import TreeBank
from engine.collision.pair_cache import PairCache
from engine.collision.proximity import mesh_distance
from engine.collision.query import ULP
from engine.kernels.collision import batch as kb
from engine.kernels.collision.traversal import roots_apart

EPSILON = 0.02


@pytest.fixture(scope="module")
def trees():
    return (
        build_tree(shapes.noisy_sphere(2, seed=4), EPSILON, seed=1),
        build_tree(shapes.torus(), EPSILON, seed=1),
    )


def _pose_pairs(seed: int, count: int):
    rng = np.random.default_rng(seed)
    for _ in range(count):
        qa, qb, direction = rng.normal(size=4), rng.normal(size=4), rng.normal(size=3)
        pa = Pose(rng.normal(size=3), qa / np.linalg.norm(qa))
        reach = rng.uniform(0.8, 3.0)
        position = pa.position + reach * direction / np.linalg.norm(direction)
        yield pa, Pose(position, qb / np.linalg.norm(qb))


@pytest.mark.parametrize("boxes", [True, False])
def test_roots_apart_only_when_the_surfaces_are_beyond_the_reach(trees, boxes):
    ta, tb = trees
    margin = 1e-3
    pruned = kept = 0
    for pa, pb in _pose_pairs(3, 150):
        rotation, shift = kb.relative_pose(
            pa.position, pa.orientation, pb.position, pb.orientation
        )[1:]
        box_a = ta.views.boxes if boxes else np.empty((0, 15))
        box_b = tb.views.boxes if boxes else np.empty((0, 15))
        apart = roots_apart(
            ta.views.spheres, box_a, tb.views.spheres, box_b, rotation, shift, margin
        )
        gap = mesh_distance(ta, pa, tb, pb).distance - 2 * EPSILON
        if apart:
            pruned += 1
            assert gap > margin - 1e-9, (gap, margin)
        else:
            kept += 1
    assert pruned > 10 and kept > 10  # both outcomes exercised


def test_a_pruned_pair_in_the_batch_is_the_traversals(trees):
    ta, tb = trees
    bank = TreeBank([ta, tb])
    cache = PairCache()
    checked = 0
    for pa, pb in _pose_pairs(5, 60):
        queries = (
            np.array([0]), np.array([1]),
            pa.position[None], pa.orientation[None], pb.position[None], pb.orientation[None],
        )  # fmt: skip
        cache.clear()
        found = bank.run(queries, "hybrid", 1, cache, np.array([0]))
        plain = bank.run(queries, "hybrid", 1)  # no lists: the traversal itself
        np.testing.assert_array_equal(found.points, plain.points)
        np.testing.assert_array_equal(found.overlaps, plain.overlaps)
        rotation, shift = kb.relative_pose(
            pa.position, pa.orientation, pb.position, pb.orientation
        )[1:]
        reach = cache.skin * 2 * EPSILON
        margin = kb.query_margin(bank.table.extent[0], bank.table.extent[1], shift, ULP[bank.dtype])
        apart = roots_apart(
            ta.views.spheres, ta.views.boxes, tb.views.spheres, tb.views.boxes,
            rotation, shift, margin + reach,
        )  # fmt: skip
        if apart:
            checked += 1
            assert found.counts[0, kb.COUNT_DEPTH] == 0
            assert found.counts[0, kb.COUNT_COMPARISONS] == 0
            assert len(found.points) == 0 and len(cache.near) == 0
    assert checked > 5
