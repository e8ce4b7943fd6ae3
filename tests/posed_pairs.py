"""Random posed body pairs shared by the batch tests (tests/engine/collision)."""

from __future__ import annotations

import numpy as np

from engine import Pose


def random_queries(trees, count, seed):
    """``count`` (tree_a, pose_a, tree_b, pose_b) of ``trees``, centres 0.3–1.1 bounding
    radii apart, random orientations; the same queries for the same ``seed``."""
    rng = np.random.default_rng(seed)
    queries = []
    for _ in range(count):
        a, b = (trees[i] for i in rng.integers(len(trees), size=2))
        qa, qb, direction = rng.normal(size=4), rng.normal(size=4), rng.normal(size=3)
        reach = (a.bounding_radius + b.bounding_radius) * rng.uniform(0.3, 1.1)
        pa = Pose(rng.normal(size=3), qa / np.linalg.norm(qa))
        pb = Pose(
            pa.position + reach * direction / np.linalg.norm(direction), qb / np.linalg.norm(qb)
        )
        queries.append((a, pa, b, pb))
    return queries
