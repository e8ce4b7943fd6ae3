"""service/search.py: a batch cut into runs of consecutive pairs, each searched apart and
merged in order, answers exactly what the whole batch answers (the cluster's chunked
contacts requests rest on it), for the multiresolution and the flat search; runs cut by
their places' measured speeds come to end together; pieces taken back from slow or
stalled places answer every piece once and end a request in bounded time."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from engine import build_tree, shapes
from service.banks import BankCache
from service.search import RunSpeeds, SentPieces, find, merge, split
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


@settings(max_examples=40, deadline=None)
@given(
    speeds=st.lists(st.floats(0.5, 2.0), min_size=1, max_size=5),
    handoffs=st.lists(st.floats(0.0, 0.1), min_size=5, max_size=5),
    pairs=st.integers(2_000, 20_000),
)
def test_runs_cut_by_measured_speeds_end_together(speeds, handoffs, pairs):
    """Places searching at ``speeds`` times this process's rate, each answer arriving a
    hand-off after its search (at most a quarter of the best cut's time), where the best
    cut's shares are within :class:`RunSpeeds`' bounds: after 25 requests cut by it
    (starting from equal shares), every run ends within 1 % of the earliest time any cut
    allows — where shares equal to the threads (the old cut) end up to 2x later."""
    rate = 10_000.0  # this process's pairs per second
    places = [f"node-{k}" for k in range(len(speeds))]
    late = {p: h * pairs / rate for p, h in zip(places, handoffs, strict=False)}
    # the earliest common end: pairs = rate * (T + sum(v * (T - late)))
    best = (pairs / rate + sum(v * late[p] for p, v in zip(places, speeds, strict=True))) / (
        1 + sum(speeds)
    )
    # where each place's share is then within RunSpeeds' bounds (4x either way) and its
    # hand-off at most a quarter of its run (measured: 20-30 ms of 300-400)
    assume(all(0.25 < v * (best - late[p]) / best < 4 for p, v in zip(places, speeds, strict=True)))
    assume(all(late[p] <= best / 4 for p in places))
    column = (np.arange(pairs),)
    estimates = RunSpeeds()

    def ends(weights):
        mine, *runs = (len(r[0]) for r in split(column, weights))
        return (
            mine / rate,
            [
                n / (rate * v) + late[p] if n else 0.0
                for p, v, n in zip(places, speeds, runs, strict=True)
            ],
            mine,
            runs,
        )

    for _ in range(25):
        here, there, mine, runs = ends([1.0, *estimates.weights(places, 1.0)])
        estimates.update(
            (mine, here), {p: (n, t) for p, n, t in zip(places, runs, there, strict=True)}, 1.0
        )
    here, there, _, _ = ends([1.0, *estimates.weights(places, 1.0)])
    finish = [here, *there]
    assert max(finish) <= best * 1.01 + 2 / rate  # a pair's rounding
    assert min(finish) >= best * 0.99 - 2 / rate


@given(
    updates=st.lists(
        st.tuples(
            st.integers(0, 10**6),
            st.floats(0.0, 100.0),
            st.integers(0, 10**6),
            st.floats(0.0, 100.0),
        ),
        max_size=30,
    ),
    prior=st.floats(0.1, 10.0),
)
def test_measured_speeds_stay_within_their_bounds(updates, prior):
    """Whatever runs report — empty, instant, a cold worker's minutes — a place's speed
    stays within [prior / 4, prior * 4] (no place is ever left without pairs), an
    unmeasured place has the prior, and a place forgotten starts again from it."""
    estimates = RunSpeeds()
    for mine, here, n, elapsed in updates:
        estimates.update((mine, here), {"a": (n, elapsed)}, prior)
    a, b = estimates.weights(["a", "b"], prior)
    assert prior / 4 * (1 - 1e-12) <= a <= prior * 4 * (1 + 1e-12)
    assert b == prior
    estimates.keep(["b"])
    assert estimates.weights(["a"], prior) == [prior]


def test_a_place_that_answered_nothing_falls_to_its_lower_bound():
    """A place whose run was all taken back (it answered none of it) counts as slow: its
    speed moves toward prior / 4, not left where it was."""
    estimates = RunSpeeds()
    estimates.update((1000, 1.0), {"a": (0, 1.0)}, 1.0)
    assert estimates.weights(["a"], 1.0) == [pytest.approx(1.0 + 0.3 * (0.25 - 1.0))]


def _simulate(speeds, handoffs, sizes, mine: int, per_pair: float):
    """A request on :class:`SentPieces` in simulated time: place p searches its pieces
    front to back at ``speeds[p]`` times this process's rate (0: stalled, never answers),
    each answer here ``handoffs[p]`` seconds after its end; this process searches its own
    ``mine`` pairs, then takes pieces back (each at ``per_pair`` seconds a pair) or waits
    for the next answer. ``(the board, when every piece had its answer, pieces taken)``."""
    board = SentPieces(sizes, 0.0)
    events = []  # (time here, place, piece)
    for p, (v, late) in enumerate(zip(speeds, handoffs, strict=True)):
        if v > 0:
            ends = np.cumsum(sizes[p]) * per_pair / v
            events += [(end + late, p, k) for k, end in enumerate(ends)]
    events.sort()
    step = min(min(s) for s in sizes) * per_pair / 50  # the clock while waiting
    horizon = 10 * (mine + sum(map(sum, sizes))) * per_pair + 1.0

    def deliver(until: float) -> None:
        while events and events[0][0] <= until:
            at, p, k = events.pop(0)
            board.handed(p, k, ("there", p, k), at)

    now, taken = mine * per_pair, 0
    while True:
        deliver(now)
        picked = board.take(now, per_pair)
        if picked is None:
            if board.done():
                return board, max(board.completed), taken
            now = min(events[0][0], now + step) if events else now + step
            assert now < horizon, "no piece left to take and none arriving: a stalled request"
            continue
        p, k = picked
        now += sizes[p][k] * per_pair
        deliver(now)
        board.give(p, k, ("here", p, k), now)
        taken += 1


@settings(max_examples=60, deadline=None)
@given(
    speeds=st.lists(st.sampled_from([0.0, 0.03, 0.3, 0.7, 1.0, 1.5]), min_size=1, max_size=4),
    late=st.floats(0.0, 0.02),
    pieces=st.integers(1, 8),
    share=st.integers(50, 400),
    mine=st.integers(0, 800),
)
def test_pieces_taken_back_answer_each_piece_once_in_bounded_time(
    speeds, late, pieces, share, mine
):
    """Whatever the places' speeds — stalled, 30x slower, faster — every piece has one
    answer, its own, and the request ends no later than this process alone would have
    taken for the pairs, plus, for each place, one piece it was on (this process waits
    ``patience`` times its own time for it before taking it back) and the hand-off."""
    per_pair = 1e-4
    sizes = [[share] * pieces for _ in speeds]
    board, end, _ = _simulate(speeds, [late] * len(speeds), sizes, mine, per_pair)
    for p, run in enumerate(board.answers):
        assert [a[1:] for a in run] == [(p, k) for k in range(pieces)]
    alone = (mine + sum(map(sum, sizes))) * per_pair
    stalls = len(speeds) * ((1 + board.patience) * share * per_pair + late)
    assert end <= alone + stalls + 1e-9
    assert all(error is None for error in board.errors)


@settings(max_examples=40, deadline=None)
@given(pieces=st.integers(1, 8), share=st.integers(50, 400), places=st.integers(1, 4))
def test_places_as_fast_as_their_share_lose_no_piece(pieces, share, places):
    """Runs cut to the places' speeds (here: all as fast as this process, each given what
    this process searches itself) end together, and nothing is taken back: no work twice."""
    sizes = [[share] * pieces for _ in range(places)]
    board, end, taken = _simulate([1.0] * places, [0.0] * places, sizes, share * pieces, 1e-4)
    assert taken == 0
    assert all(a[0] == "there" for run in board.answers for a in run)
    assert end == pytest.approx(share * pieces * 1e-4)


def test_the_pieces_left_of_a_place_that_failed_are_taken_back():
    """A place that fails after two of its four pieces: the two it answered are kept, the
    other two are this process's at once (no wait for a piece it was on); a failure once
    every piece has its answer (a task cancelled then) changes nothing."""
    board = SentPieces([[10] * 4], 0.0)
    board.handed(0, 0, "a0", 0.1)
    board.handed(0, 1, "a1", 0.2)
    assert board.take(0.21, 1.0) == (0, 3)  # not begun: taken back
    assert board.take(0.21, 1.0) is None  # the place is on piece 2: wait for it
    assert board.failed(0, RuntimeError("node died"))
    assert board.take(0.22, 1.0) == (0, 2)
    board.give(0, 2, "h2", 0.3)
    board.give(0, 3, "h3", 0.4)
    assert board.done() and board.answers == [["a0", "a1", "h2", "h3"]]
    assert board.handed_pairs == [20] and board.completed == [0.4]
    assert not board.failed(0, RuntimeError("cancelled"))
