"""Random posed body pairs shared by the batch tests (tests/engine/collision)."""

from __future__ import annotations

import numpy as np

from engine import Pose, build_tree, shapes


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


def query_arrays(trees, queries) -> tuple:
    """``(tree_a, position_a, orientation_a, tree_b, position_b, orientation_b)`` arrays of
    ``(tree_a, pose_a, tree_b, pose_b)`` queries (as :meth:`engine.TreeBank.find_contacts`
    takes them), trees numbered by their place in ``trees``."""
    index = {id(t): i for i, t in enumerate(trees)}
    return (
        np.array([index[id(q[0])] for q in queries]),
        np.array([q[1].position for q in queries]),
        np.array([q[1].orientation for q in queries]),
        np.array([index[id(q[2])] for q in queries]),
        np.array([q[3].position for q in queries]),
        np.array([q[3].orientation for q in queries]),
    )


def batch_trees() -> list:
    """The batch tests' trees: a noisy sphere, a torus and a plane (different ε)."""
    return [
        build_tree(shapes.noisy_sphere(subdivisions=1, eta_r=1.3, seed=2), epsilon=0.03),
        build_tree(shapes.torus(major_segments=12, minor_segments=6), epsilon=0.02),
        build_tree(shapes.plane(size=(3.0, 3.0), divisions=4), epsilon=0.01),
    ]
