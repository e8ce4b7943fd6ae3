"""The per-query set-up shared by the searches, and the traversal's unfold rule on the host."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from engine import InvalidArgumentError, Pose, build_tree, shapes
from engine.arguments import KERNELS
from engine.collision.query import (
    TINY,
    check_posed_pair,
    contact_constants,
    query_parameters,
    unfold_nodes,
    unfold_pairs,
    unfolded_ranges,
)
from engine.kernels.geometry import triangle_batch as tb


@pytest.fixture(scope="module")
def trees():
    """Two trees of different shapes and depths (a box's is a root over 12 leaves)."""
    return (
        build_tree(shapes.icosphere(1), 0.02, branching=3, seed=1),
        build_tree(shapes.box(), 0.01),
        build_tree(shapes.torus(major_segments=12, minor_segments=6), 0.01, seed=2),
    )


def replaced(tree, node: int) -> list[int]:
    """What a node unfolds into, from the tree's own accessors: children, or itself."""
    return [node] if tree.is_leaf[node] else tree.children(node).tolist()


def test_a_node_unfolds_into_its_children_and_a_leaf_into_itself(trees):
    for tree in trees:
        nodes = np.arange(len(tree))
        first, count = unfolded_ranges(tree, nodes)
        assert first.dtype == count.dtype == np.int64
        flat = unfold_nodes(tree, nodes)
        assert flat.dtype == np.int64
        expected = [replaced(tree, int(n)) for n in nodes]
        assert flat.tolist() == list(itertools.chain.from_iterable(expected))
        for n, kids in zip(nodes.tolist(), expected, strict=True):
            assert list(range(first[n], first[n] + count[n])) == kids


def test_a_pair_unfolds_into_every_pair_of_its_two_sides_a_major(trees):
    rng = np.random.default_rng(3)
    for ta, tb_ in itertools.permutations(trees, 2):
        pairs = np.stack(
            [rng.integers(0, len(ta), 40), rng.integers(0, len(tb_), 40)], axis=1
        ).astype(np.int64)
        children, owner = unfold_pairs(ta, tb_, pairs)
        assert children.dtype == owner.dtype == np.int64 and children.shape[1] == 2
        expected, expected_owner = [], []
        for row, (i, j) in enumerate(pairs.tolist()):
            for ca in replaced(ta, i):
                for cb in replaced(tb_, j):
                    expected.append([ca, cb])
                    expected_owner.append(row)
        assert children.tolist() == expected
        assert owner.tolist() == expected_owner


def test_unfolding_every_pair_with_a_surrogate_reaches_each_leaf_pair_once(trees):
    """From the roots, the rule keeps a complete cut: every leaf pair lies under exactly one
    entry, so unfolding until only leaf pairs remain lists every leaf pair once."""
    for ta, tb_ in itertools.product(trees, repeat=2):
        front = np.zeros((1, 2), np.int64)
        while True:
            leaf = ta.is_leaf[front[:, 0]] & tb_.is_leaf[front[:, 1]]
            if leaf.all():
                break
            children, _ = unfold_pairs(ta, tb_, front[~leaf])
            front = np.concatenate([front[leaf], children])
        got = np.stack([ta.face[front[:, 0]], tb_.face[front[:, 1]]], axis=1)
        fa, fb = int(ta.is_leaf.sum()), int(tb_.is_leaf.sum())
        everything = np.stack(np.meshgrid(np.arange(fa), np.arange(fb), indexing="ij"), -1)
        np.testing.assert_array_equal(
            got[np.lexsort((got[:, 1], got[:, 0]))], everything.reshape(-1, 2)
        )


def test_empty_input_unfolds_into_nothing(trees):
    tree = trees[0]
    assert unfold_nodes(tree, np.zeros(0, np.int64)).shape == (0,)
    children, owner = unfold_pairs(tree, tree, np.zeros((0, 2), np.int64))
    assert children.shape == (0, 2) and owner.shape == (0,)


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("kernel", sorted(KERNELS))
def test_query_parameters(kernel, dtype):
    surrogate, leaf = query_parameters(kernel, dtype, 3)
    assert surrogate[0] == (tb.EXACT if kernel == "exact" else tb.ITERATIVE)
    assert leaf[0] == KERNELS[kernel]
    for params in (surrogate, leaf):
        assert params[1] == 3 and isinstance(params[1], np.int64)
        assert all(isinstance(x, dtype) for x in params[2:])
    assert query_parameters(kernel, dtype, 3) is query_parameters(kernel, dtype, 3)


def test_contact_constants(trees):
    ta, tb_ = trees[0], trees[1]
    ea, eb, tiny, radius = contact_constants(ta, tb_)
    assert (ea, eb) == (0.02, 0.01) and radius == 0.01
    assert tiny == TINY * max(ta.bounding_radius, tb_.bounding_radius)


def test_check_posed_pair_names_the_bad_argument(trees):
    tree, pose = trees[0], Pose((0.0, 0.0, 0.0), (1.0, 0.0, 0.0, 0.0))
    check_posed_pair(tree, pose, tree, pose)
    for args, name in (
        (("tree", pose, tree, pose), "tree_a"),
        ((tree, pose, None, pose), "tree_b"),
        ((tree, (0, 0, 0), tree, pose), "pose_a"),
        ((tree, pose, tree, np.eye(4)), "pose_b"),
    ):
        with pytest.raises(InvalidArgumentError, match=name):
            check_posed_pair(*args)
