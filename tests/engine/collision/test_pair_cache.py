"""The pair cache's parts: a search with the last search's pairs and chunks reads and renews
each chunk's own part; any other search works on one flat part. Either way the contacts
are a fresh traversal's and the lists one thread's, bit for bit."""

from __future__ import annotations

import numpy as np
import pytest
from posed_pairs import batch_trees, query_arrays, random_queries

import engine.collision.batch as batch
import engine.collision.pair_cache as pair_cache
from engine import PairCache, TreeBank

CONTACTS = ("pair_offsets", "pairs", "contact_offsets", "points", "normals", "overlaps")
LISTS = ("keys", "rotations", "shifts", "offsets", "near", "distances")


@pytest.fixture(scope="module")
def trees():
    return batch_trees()


@pytest.fixture
def many_chunks(monkeypatch):
    """Chunks of 4 pairs (at most 4 a thread), and every join on the worker threads."""
    monkeypatch.setattr(batch, "_PAIRS_PER_TASK", 4)
    monkeypatch.setattr(batch, "_CHUNKS_PER_THREAD", 4)
    monkeypatch.setattr(pair_cache, "PARALLEL_JOIN", 0)


def walk(trees, seed: int, steps: int, count: int = 48, jump: int = -1):
    """A random walk of ``count`` body pairs through contact: yields the query arrays of
    each step (B drifts by a few mm a step; after step ``jump`` every B moves by 0.05,
    past every list's skin)."""
    rng = np.random.default_rng(seed)
    ta, pa, qa, tb, pb, qb = query_arrays(trees, random_queries(trees, count, seed=seed))
    for step in range(steps):
        yield ta, pa, qa, tb, pb, qb
        pb = pb + rng.normal(scale=0.004, size=pb.shape) + (0.05 if step == jump else 0.0)


def equal(a, b, names) -> None:
    for name in names:
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)


def test_each_chunk_reads_and_renews_its_own_part(trees, many_chunks, monkeypatch):
    bank = TreeBank(trees, "float64")
    renewals = []
    renew = PairCache._renew

    def counted(self, c, kept, result):
        if self is split:
            renewals.append((int(kept.sum()), len(kept)))
        return renew(self, c, kept, result)

    monkeypatch.setattr(PairCache, "_renew", counted)
    split, single = PairCache(), PairCache()
    keys = np.arange(48, dtype=np.int64) * 7 + 3  # in order: the first search makes parts
    for args in walk(trees, seed=5, steps=30, jump=15):
        got = bank.find_contacts(*args, cache=split, keys=keys, threads=2)
        want = bank.find_contacts(*args, threads=1)
        equal(got, want, CONTACTS)
        equal(bank.find_contacts(*args, cache=single, keys=keys, threads=1), want, CONTACTS)
    assert len(split._parts) == 8  # 48 pairs, 4 chunks a thread: never joined
    kept = np.array(renewals)
    assert len(kept) == 29 * 8  # every search after the first went by part
    assert ((kept[:, 0] > 0) & (kept[:, 0] < kept[:, 1])).any()  # kept and new lists joined
    assert (kept[:, 0] == 0).any()  # every list of a part new
    equal(split, single, LISTS)  # read: the parts joined once
    assert len(split._parts) == 1


@pytest.mark.parametrize("change", ["keys", "threads", "order"])
def test_other_searches_work_on_one_flat_part(trees, many_chunks, change):
    """Pairs dropped and added, another thread count, keys out of order: the general path,
    with the same contacts and, after it, the same lists as one thread's."""
    bank = TreeBank(trees, "float64")
    split, single = PairCache(), PairCache()
    keys = np.arange(48, dtype=np.int64) * 7 + 3
    rng = np.random.default_rng(3)
    for step, args in enumerate(walk(trees, seed=9, steps=12)):
        threads, mine = 2, np.arange(48)
        if change == "keys" and step % 3 == 2:
            mine = np.sort(rng.choice(48, 40, replace=False))
        if change == "threads" and step % 2:
            threads = 3
        if change == "order" and step % 4 == 1:
            mine = rng.permutation(48)
        sub = tuple(a[mine] for a in args)
        got = bank.find_contacts(*sub, cache=split, keys=keys[mine], threads=threads)
        equal(got, bank.find_contacts(*sub, threads=1), CONTACTS)
        bank.find_contacts(*sub, cache=single, keys=keys[mine], threads=1)
        equal(split, single, LISTS)


def test_parallel_joins_equal_one_threads_lists(trees, many_chunks):
    """Every step read (so every search works on one flat part, renewed by the parallel
    join): after each step the cache holds the very lists one thread leaves."""
    bank = TreeBank(trees, "float64")
    split, single = PairCache(), PairCache()
    keys = np.random.default_rng(11).permutation(np.arange(48) * 5 + 2)
    renewed = 0
    for args in walk(trees, seed=5, steps=30):
        got = bank.find_contacts(*args, cache=split, keys=keys, threads=2)
        one = bank.find_contacts(*args, cache=single, keys=keys, threads=1)
        equal(got, bank.find_contacts(*args, threads=1), CONTACTS)
        equal(one, got, CONTACTS)
        equal(split, single, LISTS)
        served = got.counts[:, 6]
        renewed += int(0 < served.sum() < len(served))  # kept and new lists joined
    assert renewed > 0


def test_clear_and_sizes(trees):
    bank = TreeBank(trees, "float64")
    cache = PairCache()
    args = next(walk(trees, seed=1, steps=1))
    bank.find_contacts(*args, cache=cache, keys=np.arange(48), threads=1)
    assert len(cache) == 48 and cache.nbytes > cache.keys.nbytes
    cache.clear()
    assert len(cache) == 0 and len(cache.near) == 0 and cache.offsets.tolist() == [0]


@pytest.mark.parametrize("keys_order", ["sorted", "shuffled"])
def test_a_small_search_split_in_two_halves_is_one_threads(trees, monkeypatch, keys_order):
    """Fewer pairs than the worker chunks take, split in two halves (every search: no
    least work): the contacts are a fresh traversal's and the lists one thread's, bit for
    bit, through renewals and the walk's jump past every skin."""
    monkeypatch.setattr(batch, "SPLIT_ENTRIES", 0)
    monkeypatch.setattr(batch, "SPLIT_COMPARISONS", 0)
    bank = TreeBank(trees, "float64")
    split, single = PairCache(), PairCache()
    keys = np.arange(48, dtype=np.int64) * 3 + 1
    if keys_order == "shuffled":
        keys = np.random.default_rng(2).permutation(keys)
    for args in walk(trees, seed=7, steps=24, jump=12):
        assert len(batch._halves(split, keys, 48)) == 3  # two halves
        got = bank.find_contacts(*args, cache=split, keys=keys, threads=2)
        equal(got, bank.find_contacts(*args, threads=1), CONTACTS)
        equal(bank.find_contacts(*args, cache=single, keys=keys, threads=1), got, CONTACTS)
        equal(split, single, LISTS)


def test_halves_balance_the_listed_work(trees, monkeypatch):
    """Split when the lists hold at least ``SPLIT_ENTRIES`` leaf pairs and the last renewal
    made at least ``SPLIT_COMPARISONS`` comparisons, not otherwise; the cut halves the
    estimated work (listed leaf pairs plus a query's own)."""
    bank = TreeBank(trees, "float64")
    cache = PairCache()
    keys = np.arange(48, dtype=np.int64)
    args = list(walk(trees, seed=3, steps=2))
    found = bank.find_contacts(*args[0], cache=cache, keys=keys, threads=1)
    assert cache.comparisons == found.comparisons > 0
    sizes = cache.sizes(keys)
    np.testing.assert_array_equal(sizes, np.diff(cache.offsets))
    assert cache.sizes(np.array([1000], np.int64)).tolist() == [-1]
    listed = int(sizes.sum())
    assert listed > 0
    monkeypatch.setattr(batch, "SPLIT_COMPARISONS", found.comparisons)
    monkeypatch.setattr(batch, "SPLIT_ENTRIES", listed + 1)
    assert batch._halves(cache, keys, 48).tolist() == [0, 48]
    monkeypatch.setattr(batch, "SPLIT_ENTRIES", listed)
    bounds = batch._halves(cache, keys, 48)
    assert bounds[0] == 0 and bounds[2] == 48
    work = sizes + batch._QUERY_ENTRIES
    first, second = work[: bounds[1]].sum(), work[bounds[1] :].sum()
    assert first >= second >= first - work[bounds[1] - 1]
    monkeypatch.setattr(batch, "SPLIT_COMPARISONS", found.comparisons + 1)
    assert batch._halves(cache, keys, 48).tolist() == [0, 48]
    assert batch._halves(None, keys, 48).tolist() == [0, 48]
    # a read-only search leaves the count of the last renewal
    bank.run(query_arrays_of(args[1]), "hybrid", 1, cache, keys, read_only=True)
    assert cache.comparisons == found.comparisons
    cache.clear()
    assert cache.comparisons == 0


def query_arrays_of(args):
    """``TreeBank.run``'s six query arrays of ``find_contacts``' arguments."""
    ta, pa, qa, tb, pb, qb = args
    return np.asarray(ta, np.int64), np.asarray(tb, np.int64), pa, qa, pb, qb
