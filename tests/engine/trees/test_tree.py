"""Surrogate trees: statistics, persistence and its validation."""

from __future__ import annotations

import io

import numpy as np
import pytest

from engine import InvalidArgumentError, shapes
from engine.trees.build import build_tree
from engine.trees.tree import TREE_FORMAT, SurrogateTree


def test_statistics(built):
    mesh, tree = built
    stats = tree.stats
    assert sum(stats.nodes_per_level) == len(tree) == stats.surrogates + stats.leaves
    assert stats.leaves == mesh.n_faces and stats.depth == int(tree.level.max())
    assert stats.root_epsilon == tree.epsilon[0] > 0.01
    assert stats.root_diameter > 0 and stats.volume_ratio > 0


def test_save_and_load_round_trip(tmp_path):
    tree = build_tree(shapes.torus(major_segments=16, minor_segments=8), 0.01, seed=3)
    path = tmp_path / "tree.npz"
    tree.save(path)
    assert not (tmp_path / "tree.npz.tmp").exists()
    buffer = io.BytesIO()
    tree.save(buffer)
    buffer.seek(0)
    for loaded in (SurrogateTree.load(path), SurrogateTree.load(buffer)):
        for name in ("triangles", "epsilon", "level", "parent", "first_child", "child_count"):
            np.testing.assert_array_equal(getattr(loaded, name), getattr(tree, name))
        assert (loaded.leaf_epsilon, loaded.branching, loaded.seed) == (0.01, 8, 3)


def test_load_rejects_garbage_and_other_versions(tmp_path):
    bad = tmp_path / "bad.npz"
    bad.write_bytes(b"not a tree")
    with pytest.raises(InvalidArgumentError, match="not a surrogate tree"):
        SurrogateTree.load(bad)
    tree = build_tree(shapes.box(), 0.01)
    buffer = io.BytesIO()
    arrays = {
        name: getattr(tree, name)
        for name in (
            "triangles",
            "epsilon",
            "level",
            "parent",
            "first_child",
            "child_count",
            "face",
        )
    }
    np.savez(buffer, meta=np.array([TREE_FORMAT + 1, 0.01, 8, 0, 1.0]), **arrays)
    buffer.seek(0)
    with pytest.raises(InvalidArgumentError, match="format"):
        SurrogateTree.load(buffer)
