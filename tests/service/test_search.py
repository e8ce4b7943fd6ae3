"""service/search.py: a batch cut into runs of consecutive pairs, each searched apart and
merged in order, answers exactly what the whole batch answers (the cluster's chunked
contacts requests rest on it), for the multiresolution and the flat search."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from engine import build_tree, shapes
from service.banks import BankCache
from service.search import find, merge, split
from service.store import Store

NAMES = ("offsets", "points", "normals", "overlaps", "pair_offsets", "pairs")


@pytest.fixture(scope="module")
def store(tmp_path_factory):
    """The embedded store holding the two trees, under the ids the batches name."""
    store = Store(tmp_path_factory.mktemp("search"))
    store.put_tree("box", build_tree(shapes.box(), 0.05))
    store.put_tree("ball", build_tree(shapes.icosphere(2), 0.03))
    yield store
    store.close()


def _columns(n: int, seed: int):
    rng = np.random.default_rng(seed)
    q = rng.normal(size=(2 * n, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    return (
        rng.integers(0, 2, n),
        rng.uniform(-0.2, 0.2, (n, 3)),
        q[:n],
        rng.integers(0, 2, n),
        rng.uniform(-1.0, 1.0, (n, 3)) * 1.2,
        q[n:],
    )


@settings(max_examples=12, deadline=None)
@given(
    n=st.integers(1, 40),
    weights=st.lists(st.integers(1, 8), min_size=1, max_size=6),
    seed=st.integers(0, 2**31),
)
@pytest.mark.parametrize("hierarchy", [True, False])
def test_runs_merged_in_order_answer_what_the_whole_batch_answers(
    store, hierarchy, n, weights, seed
):
    """Runs in proportion to the weights (some empty when pairs are few), each searched
    apart, the non-empty ones merged in order — with triangle pairs sent as int32, as a
    cluster's tasks send them — answer the whole batch's arrays."""
    meshes, columns = ["box", "ball"], _columns(n, seed)
    banks = BankCache(store)
    options = ("exact", hierarchy, "float64", 1, store, banks)
    whole = find(meshes, columns, *options)
    runs = split(columns, weights)
    assert len(runs) == len(weights)
    for k, column in enumerate(columns):  # consecutive runs, in order
        np.testing.assert_array_equal(np.concatenate([r[k] for r in runs]), column)
    lengths = np.array([len(r[0]) for r in runs])
    assert lengths.sum() == n
    share = n * np.asarray(weights) / sum(weights)
    assert np.all(np.abs(np.cumsum(lengths) - np.cumsum(share)) <= 0.5 + 1e-9)
    parts = [find(meshes, run, *options) for run in runs if len(run[0])]
    for part in parts[1::2]:
        part["pairs"] = part["pairs"].astype(np.int32)
    merged = merge(parts)
    for name in NAMES:
        np.testing.assert_array_equal(merged[name], whole[name], err_msg=name)
        assert merged[name].dtype == whole[name].dtype, name
    assert merged["stats"] == whole["stats"]
