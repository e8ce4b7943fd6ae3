"""Batched contacts: every pair's result equals the single query's, bit for bit."""

from __future__ import annotations

import numpy as np
import pytest
from posed_pairs import batch_trees, query_arrays, random_queries

from engine import (
    InvalidArgumentError,
    Pose,
    TreeBank,
    find_contacts,
    find_contacts_batch,
)
from engine.collision.contacts import FAR_APART, far_apart


@pytest.fixture(autouse=True)
def small_tasks(monkeypatch):
    """Worker chunks of 64 pairs (the default, 256, keeps these few hundred pairs on one
    thread): the threaded paths stay tested."""
    from engine.collision import batch

    monkeypatch.setattr(batch, "_PAIRS_PER_TASK", 64)


@pytest.fixture(scope="module")
def trees():
    return batch_trees()


@pytest.mark.parametrize("precision", ["float64", "float32"])
@pytest.mark.parametrize("threads", [1, 2])
def test_batch_equals_single_queries(trees, precision, threads):
    queries = random_queries(trees, 300, seed=threads)
    batch = find_contacts_batch(queries, precision=precision, threads=threads)
    assert len(batch) == len(queries)
    touching = settled = 0
    for got, query in zip(batch, queries, strict=True):
        want = find_contacts(*query, precision=precision)
        np.testing.assert_array_equal(got.pairs, want.pairs)
        np.testing.assert_array_equal(got.points, want.points)
        np.testing.assert_array_equal(got.normals, want.normals)
        np.testing.assert_array_equal(got.overlaps, want.overlaps)
        # both prune node pairs by their spheres and boxes: the same search, counters
        # included, unless the single query's early-out settled it (the batch has none)
        if far_apart(*query):
            assert want.stats == FAR_APART.stats and not len(got.pairs)
            settled += 1
        else:
            assert got.stats == want.stats
        touching += len(want.pairs) > 0
    assert 0 < touching < len(queries) - settled


def test_flat_batch_equals_flat_queries(trees):
    queries = random_queries(trees, 20, seed=7)
    batch = find_contacts_batch(queries, kernel="exact", hierarchy=False)
    for got, query in zip(batch, queries, strict=True):
        np.testing.assert_array_equal(got.pairs, find_contacts(*query, hierarchy=False).pairs)


def bank_arguments(trees, queries) -> tuple:
    """``TreeBank.find_contacts``' six columns (tree indices, positions, orientations of A
    and of B) for ``(tree_a, pose_a, tree_b, pose_b)`` queries."""
    index = {id(t): i for i, t in enumerate(trees)}
    return (
        [index[id(q[0])] for q in queries],
        [q[1].position for q in queries],
        [q[1].orientation for q in queries],
        [index[id(q[2])] for q in queries],
        [q[3].position for q in queries],
        [q[3].orientation for q in queries],
    )


def test_bank_results_are_ragged_and_counted(trees):
    bank = TreeBank(trees)
    result = bank.find_contacts(*bank_arguments(trees, random_queries(trees, 50, seed=3)))
    assert len(result) == 50
    assert result.pair_offsets[-1] == len(result.pairs)
    assert result.contact_offsets[-1] == len(result.points) == len(result.overlaps)
    assert (np.diff(result.pair_offsets) >= np.diff(result.contact_offsets)).all()
    assert result.comparisons == sum(result[q].stats.comparisons for q in range(50))
    np.testing.assert_allclose(np.linalg.norm(result.normals, axis=1), 1.0, atol=1e-12)
    assert result[-1].pairs.shape == (
        result.pair_offsets[-1] - result.pair_offsets[-2],
        2,
    )


def test_threaded_pairs_are_joined_on_first_access(trees):
    """With worker chunks, ``pairs`` is held as the chunks' rows and joined once, when
    read: the same rows, in the same order, as one thread's."""
    bank = TreeBank(trees)
    args = bank_arguments(trees, random_queries(trees, 300, seed=5))
    threaded = bank.find_contacts(*args, threads=2)
    single = bank.find_contacts(*args, threads=1)
    assert len(threaded.pair_chunks) > 1 and len(single.pair_chunks) == 1
    assert "pairs" not in vars(threaded)  # not joined yet
    assert sum(len(c) for c in threaded.pair_chunks) == threaded.pair_offsets[-1] > 0
    np.testing.assert_array_equal(threaded.pairs, single.pairs)
    assert threaded.pairs is threaded.pairs  # joined once
    np.testing.assert_array_equal(threaded.pair_offsets, single.pair_offsets)
    for q in (0, 150, 299):
        np.testing.assert_array_equal(threaded[q].pairs, single[q].pairs)


def test_run_takes_read_only_arrays_without_compiling_for_them(trees):
    """``TreeBank.run`` of a Pose's read-only arrays answers what writable copies answer,
    with the kernel compiled for writable arrays (Numba compiles a variant for every
    read-only/writable combination: 23 s of a cold CI run went to one)."""
    from engine.kernels.collision import batch as kb

    bank = TreeBank(trees)
    a, pa, qa, b, pb, qb = (np.array(c) for c in bank_arguments(trees, random_queries(trees, 8, 3)))
    frozen = []
    for column in (pa, qa, pb, qb):
        column = column.copy()
        column.flags.writeable = False
        frozen.append(column)
    plain = bank.run((a, b, pa, qa, pb, qb), "hybrid", 1)
    seen = set(kb.batch_kernel.signatures)
    read_only = bank.run((a, b, *frozen), "hybrid", 1)
    assert set(kb.batch_kernel.signatures) == seen
    assert not any("readonly" in str(s) for s in kb.batch_kernel.signatures)
    np.testing.assert_array_equal(read_only.points, plain.points)
    np.testing.assert_array_equal(read_only.pairs, plain.pairs)


@pytest.mark.parametrize("threads", [1, 2])
def test_counted_pairs_give_the_same_counts_and_contacts(trees, threads):
    """``keep_pairs=False`` (a scene step) counts the face pairs without writing them,
    through a traversal and through the pair cache's lists: the same offsets and contacts
    as a call that keeps them, bit for bit; reading its pairs says how to get them."""
    from engine import PairCache

    bank = TreeBank(trees)
    ta, pa, qa, tb, pb, qb = bank_arguments(trees, random_queries(trees, 300, seed=8))
    index = np.array(ta, np.int64), np.array(tb, np.int64)
    queries = (index[0], index[1], np.array(pa), np.array(qa), np.array(pb), np.array(qb))
    keys = np.arange(300, dtype=np.int64)
    caches = PairCache(0.5), PairCache(0.5)
    for _ in range(2):  # lists made, then lists served
        kept = bank.run(queries, "hybrid", threads, caches[0], keys)
        counted = bank.run(queries, "hybrid", threads, caches[1], keys, keep_pairs=False)
        assert kept.pair_offsets[-1] > 0 and counted.pair_chunks == ()
        for name in ("pair_offsets", "contact_offsets", "points", "normals", "overlaps"):
            np.testing.assert_array_equal(getattr(counted, name), getattr(kept, name))
        np.testing.assert_array_equal(counted.counts, kept.counts)
    with pytest.raises(InvalidArgumentError, match="keep_pairs=True"):
        counted.pairs  # noqa: B018


@pytest.mark.parametrize(
    ("field", "value", "message"),
    [
        ("tree_a", [0, 5], "outside the bank"),
        ("tree_a", [0.5, 1.0], "integer tree positions"),
        ("position_a", [[0, 0, 0], [0, np.nan, 0]], "finite"),
        ("orientation_b", [[1, 0, 0, 0], [2, 0, 0, 0]], "unit quaternion"),
        ("position_b", [[0, 0, 0]], r"\(2, 3\)"),
    ],
)
def test_bank_rejects_bad_queries(trees, field, value, message):
    args = {
        "tree_a": [0, 1],
        "position_a": [[0, 0, 0], [0, 0, 0]],
        "orientation_a": [[1, 0, 0, 0], [1, 0, 0, 0]],
        "tree_b": [1, 2],
        "position_b": [[1, 0, 0], [2, 0, 0]],
        "orientation_b": [[1, 0, 0, 0], [1, 0, 0, 0]],
    }
    args[field] = value
    with pytest.raises(InvalidArgumentError, match=message):
        TreeBank(trees).find_contacts(**args)


def test_batch_rejects_malformed_queries(trees):
    with pytest.raises(InvalidArgumentError, match=r"queries\[1\]"):
        find_contacts_batch([(trees[0], Pose.identity(), trees[1], Pose.identity()), (1, 2)])
    with pytest.raises(InvalidArgumentError, match="at least one tree"):
        TreeBank([])
    assert find_contacts_batch([]) == []


@pytest.mark.parametrize("keys_order", ["sorted", "shuffled"])
@pytest.mark.parametrize("precision", ["float64", "float32"])
def test_pair_cache_gives_the_traversal_bits_while_bodies_move(trees, precision, keys_order):
    """A random walk of many body pairs through contact: with the cache's lists (and
    their renewals, kept and new lists joined in the order of the keys) every step's
    contacts equal a fresh traversal's, bit for bit."""
    from engine import PairCache

    bank = TreeBank(trees, precision)
    rng = np.random.default_rng(7)
    queries = random_queries(trees, 40, seed=3)
    ta, pa, qa, tb, pb, qb = query_arrays(trees, queries)
    cache = PairCache(skin=0.5)
    keys = np.arange(len(queries)) * 3 + 1
    if keys_order == "shuffled":
        keys = rng.permutation(keys)
    listed = rebuilt = touching = 0
    for _ in range(60):
        got = bank.find_contacts(ta, pa, qa, tb, pb, qb, cache=cache, keys=keys, threads=2)
        want = bank.find_contacts(ta, pa, qa, tb, pb, qb, threads=2)
        for name in ("pair_offsets", "pairs", "contact_offsets", "points", "normals", "overlaps"):
            np.testing.assert_array_equal(getattr(got, name), getattr(want, name))
        served = got.counts[:, 6]
        listed += int(served.sum())
        rebuilt += int((1 - served).sum())
        touching += int((np.diff(got.pair_offsets) > 0).sum())
        # small steps: B drifts and turns a little relative to A
        pb = pb + rng.normal(scale=0.004, size=pb.shape)
        turn = np.concatenate(
            [np.ones((len(qb), 1)), rng.normal(scale=0.002, size=(len(qb), 3))], 1
        )
        qb = np.array([_quat_mul(q, t / np.linalg.norm(t)) for q, t in zip(qb, turn, strict=True)])
    assert listed > 0 and rebuilt > len(queries) and touching > 0
    assert len(cache) == len(queries) and np.array_equal(cache.keys, np.sort(keys))


def _quat_mul(p, q):
    w1, x1, y1, z1 = p
    w2, x2, y2, z2 = q
    return np.array(
        [
            w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
            w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
            w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
            w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
        ]
    )


def test_pair_cache_rejects_bad_keys_and_skins(trees):
    from engine import PairCache

    bank = TreeBank(trees)
    one = (np.zeros(2, int), np.zeros((2, 3)), np.tile([1.0, 0, 0, 0], (2, 1)))
    args = (one[0], one[1], one[2], one[0], one[1] + 5.0, one[2])
    with pytest.raises(InvalidArgumentError, match="distinct"):
        bank.find_contacts(*args, cache=PairCache(), keys=np.array([1, 1]))
    with pytest.raises(InvalidArgumentError, match="keys must be 2 integers"):
        bank.find_contacts(*args, cache=PairCache(), keys=np.array([1.5, 2.5]))
    with pytest.raises(InvalidArgumentError, match="skin"):
        PairCache(skin=-1.0)


@pytest.mark.parametrize("precision", ["float64", "float32"])
def test_pair_cache_keeps_exact_distances_and_evaluates_only_pairs_within_reach(trees, precision):
    """The cache keeps each listed leaf pair's exact distance at its reference pose; a
    query served by its list evaluates only the pairs that may touch (fewer than listed
    when the list holds pairs beyond reach) and still gets the traversal's bits."""
    from engine import PairCache, triangle_distances

    bank = TreeBank(trees, precision)
    queries = random_queries(trees, 60, seed=11)
    index = {id(t): i for i, t in enumerate(trees)}
    ta = np.array([index[id(q[0])] for q in queries])
    tb = np.array([index[id(q[2])] for q in queries])
    pa, qa = (
        np.array([q[1].position for q in queries]),
        np.array([q[1].orientation for q in queries]),
    )
    pb, qb = (
        np.array([q[3].position for q in queries]),
        np.array([q[3].orientation for q in queries]),
    )
    cache = PairCache(skin=0.5)
    keys = np.arange(len(queries), dtype=np.int64)
    args = (ta, pa, qa, tb, pb, qb)
    bank.find_contacts(*args, cache=cache, keys=keys, threads=1)
    assert len(cache.distances) == len(cache.near) > 0
    tolerance = 1e-9 if precision == "float64" else 1e-4
    for e, (tree_a, pose_a, tree_b, pose_b) in enumerate(queries):
        near = cache.near[cache.offsets[e] : cache.offsets[e + 1]]
        if not len(near):
            continue
        sides = []
        for tree, pose, rows in ((tree_a, pose_a, near[:, 0]), (tree_b, pose_b, near[:, 1])):
            mesh = tree.views.geometry.mesh
            corners = mesh.vertices[mesh.faces[tree.face[rows]]]
            sides.append(pose.apply(corners.reshape(-1, 3)).reshape(-1, 3, 3))
        want = triangle_distances(*sides, kernel="exact").distance
        got = cache.distances[cache.offsets[e] : cache.offsets[e + 1]]
        np.testing.assert_allclose(got, want, rtol=0, atol=tolerance)
        reach = tree_a.leaf_epsilon + tree_b.leaf_epsilon
        assert (got <= 1.5 * reach + tolerance).all()

    again = bank.find_contacts(*args, cache=cache, keys=keys, threads=1)
    fresh = bank.find_contacts(*args, threads=1)
    for name in ("pair_offsets", "pairs", "contact_offsets", "points", "normals", "overlaps"):
        np.testing.assert_array_equal(getattr(again, name), getattr(fresh, name))
    listed = again.counts[:, 6] == 1
    assert listed.all()
    sizes = np.diff(cache.offsets)
    evaluated = again.counts[:, 4]
    found = np.diff(again.pair_offsets)
    assert (found <= evaluated).all() and (evaluated <= sizes).all()
    assert evaluated.sum() < sizes.sum()
