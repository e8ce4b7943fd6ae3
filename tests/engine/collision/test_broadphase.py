"""Broad phase: candidate pairs against an O(n²) oracle (hypothesis and fixed scenes)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import engine.collision.broadphase as bp
from engine import InvalidArgumentError
from engine.collision.broadphase import candidate_pairs
from engine.kernels.collision import broadphase as kb

PROPS = settings(max_examples=150, deadline=None)


def oracle(centres, radii, fixed=None) -> np.ndarray:
    """All pairs i < j with dx² + dy² + dz² ≤ (r_i + r_j)² (same float64 expression, same
    order of operations), not both fixed; lexicographic order."""
    c, r = np.asarray(centres, np.float64), np.asarray(radii, np.float64)
    n = len(r)
    f = np.zeros(n, bool) if fixed is None else np.asarray(fixed, bool)
    d = c[:, None, :] - c[None, :, :]
    d2 = d[..., 0] * d[..., 0] + d[..., 1] * d[..., 1] + d[..., 2] * d[..., 2]
    s = r[:, None] + r[None, :]
    hit = (d2 <= s * s) & ~(f[:, None] & f[None, :])
    i, j = np.nonzero(np.triu(hit, 1))
    return np.stack([i, j], axis=1).astype(np.int64)


def check(centres, radii, fixed=None) -> np.ndarray:
    got = candidate_pairs(centres, radii, fixed)
    assert got.dtype == np.int64 and got.ndim == 2 and got.shape[1] == 2
    np.testing.assert_array_equal(got, oracle(centres, radii, fixed))
    return got


# Scenes on a half-integer lattice with half-integer radii: exact arithmetic, so touching
# spheres (|c_i − c_j| = r_i + r_j exactly) and coincident centres occur often.
lattice = st.integers(0, 40).flatmap(
    lambda n: st.tuples(
        st.lists(st.tuples(*[st.integers(-6, 6)] * 3), min_size=n, max_size=n),
        st.lists(st.sampled_from([0, 1, 2, 3, 4, 5, 8, 40, 1000]), min_size=n, max_size=n),
        st.lists(st.booleans(), min_size=n, max_size=n),
    )
)


@PROPS
@given(scene=lattice, scale=st.sampled_from([1.0, 0.5, 2.0**-20, 2.0**30]))
def test_lattice_scenes_match_oracle(scene, scale):
    points, halves, fixed = scene
    centres = np.array(points, np.float64).reshape(-1, 3) * scale / 2
    radii = np.array(halves, np.float64) * scale / 2
    check(centres, radii, np.array(fixed, bool))


@PROPS
@given(
    n=st.integers(0, 60),
    seed=st.integers(0, 2**32 - 1),
    spread=st.floats(1e-3, 1e3),
    decades=st.floats(0, 8),
    offset=st.sampled_from([0.0, 1e6, -3e9]),
)
def test_random_scenes_match_oracle(n, seed, spread, decades, offset):
    """Float centres and radii spanning up to 8 decades, some zero, far from the origin."""
    rng = np.random.default_rng(seed)
    centres = rng.normal(size=(n, 3)) * spread + offset
    radii = spread * 10.0 ** rng.uniform(-decades, 0.3, n)
    radii[rng.random(n) < 0.1] = 0.0
    check(centres, radii, rng.random(n) < 0.3)


@PROPS
@given(seed=st.integers(0, 2**32 - 1), scale=st.floats(1e-6, 1e6))
def test_nearly_touching_pairs_match_oracle(seed, scale):
    """Pairs placed at r_i + r_j (rounded either way) in random directions."""
    rng = np.random.default_rng(seed)
    n = 16
    a = rng.normal(size=(n, 3)) * scale * 10
    u = rng.normal(size=(n, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    ra, rb = scale * rng.uniform(0.01, 1, n), scale * rng.uniform(0.01, 1, n)
    b = a + u * ((ra + rb) * (1 + rng.integers(-2, 3, n) * 2e-16))[:, None]
    check(np.concatenate([a, b]), np.concatenate([ra, rb]))


@pytest.mark.parametrize(
    ("name", "value"),
    [("BUCKET_LOAD", 10**12), ("CELL_FACTOR", 0.3), ("CELL_FACTOR", 7.0), ("LEVEL_BITS", 1)],
)
def test_tuning_never_changes_the_result(monkeypatch, name, value):
    """One hash bucket for everything (every cell collides), cells a third of a diameter
    (4 per axis), huge cells, one level per binade: same pairs."""
    rng = np.random.default_rng(7)
    n = 400
    centres = rng.uniform(0, 12, (n, 3))
    centres[:40] = np.round(centres[:40])  # coincident and lattice-aligned bodies
    radii = 10.0 ** rng.uniform(-2, 0.5, n)
    radii[:40] = 0.5
    fixed = rng.random(n) < 0.2
    want = candidate_pairs(centres, radii, fixed)
    np.testing.assert_array_equal(want, oracle(centres, radii, fixed))
    monkeypatch.setattr(bp, name, value)
    np.testing.assert_array_equal(candidate_pairs(centres, radii, fixed), want)


@pytest.mark.parametrize("small", [0, 10**6])
@pytest.mark.parametrize("n", [2, 7, 64, 65, 300])
def test_brute_force_and_grid_paths_agree(monkeypatch, small, n):
    """Every scene through the brute force (small scenes) and through the grid alike:
    touching lattice spheres (exact arithmetic), coincident centres, fixed bodies."""
    rng = np.random.default_rng(n)
    centres = rng.integers(0, 6, (n, 3)) / 2.0
    radii = rng.integers(0, 3, n) / 2.0
    fixed = rng.random(n) < 0.3
    monkeypatch.setattr(bp, "SMALL_SCENE", small)
    check(centres, radii, fixed)


def test_packed_grid_finds_exactly_the_face_neighbours():
    """8 × 8 × 8 unit-diameter spheres at spacing 0.995: each overlaps its face
    neighbours only (diagonals are 1.407 apart)."""
    g = np.stack(np.meshgrid(*[np.arange(8)] * 3, indexing="ij"), axis=-1).reshape(-1, 3)
    pairs = check(g * 0.995, np.full(len(g), 0.5))
    assert len(pairs) == 3 * 8 * 8 * 7
    assert (np.abs(g[pairs[:, 0]] - g[pairs[:, 1]]).sum(axis=1) == 1).all()


def test_scale_differences_and_a_fixed_plane_body():
    """An 80-triangle-sized sphere against spheres scaled 2, 4, 8, on a huge fixed body that
    everything touches; a second fixed body overlapping the first is never paired with it."""
    centres = np.array([[0, 0, 1], [2.8, 0, 2], [0, 3.9, 4], [10, 0, 8], [0, 0, -1e4]], float)
    radii = np.array([1, 2, 4, 8, 1e4 + 0.01])
    fixed = np.array([False, False, False, False, True])
    pairs = check(centres, radii, fixed)
    want = [[0, 1], [0, 2], [0, 4], [1, 2], [1, 3], [1, 4], [2, 3], [2, 4], [3, 4]]
    assert pairs.tolist() == want
    centres = np.vstack([centres, [5, 5, -1e4]])
    radii, fixed = np.append(radii, 1e4 + 0.1), np.append(fixed, True)
    more = check(centres, radii, fixed)
    assert (4, 5) not in {tuple(p) for p in more}
    assert {(0, 5), (1, 5), (2, 5), (3, 5)} <= {tuple(p) for p in more}


def test_many_small_bodies_on_a_fixed_floor():
    rng = np.random.default_rng(3)
    """The floor is body 0: its partners form one long, unordered run to sort."""
    n = 1200
    centres = np.vstack([[15, 15, -1e5], rng.uniform(0, 30, (n, 3)) * [1, 1, 0.1]])
    radii = np.append(1e5 + 0.5, rng.uniform(0.2, 0.6, n))
    fixed = np.append(True, np.zeros(n, bool))
    pairs = check(centres, radii, fixed)
    assert 100 < (pairs[:, 0] == 0).sum() < n


@pytest.mark.parametrize("n", [0, 1])
def test_empty_and_single_body(n):
    pairs = candidate_pairs(np.zeros((n, 3)), np.ones(n))
    assert pairs.shape == (0, 2) and pairs.dtype == np.int64


def test_coincident_points_and_all_fixed():
    centres = np.zeros((4, 3))
    np.testing.assert_array_equal(
        candidate_pairs(centres, np.zeros(4)), [[0, 1], [0, 2], [0, 3], [1, 2], [1, 3], [2, 3]]
    )
    assert candidate_pairs(centres, np.ones(4), np.ones(4, bool)).shape == (0, 2)
    np.testing.assert_array_equal(
        candidate_pairs(centres, np.ones(4), [True, False, True, True]), [[0, 1], [1, 2], [1, 3]]
    )


def test_deterministic_and_permutation_invariant():
    rng = np.random.default_rng(11)
    n = 500
    centres, radii = rng.uniform(0, 10, (n, 3)), 10.0 ** rng.uniform(-1.5, 0.3, n)
    fixed = rng.random(n) < 0.5
    first = candidate_pairs(centres, radii, fixed)
    np.testing.assert_array_equal(candidate_pairs(centres, radii, fixed), first)
    perm = rng.permutation(n)
    moved = candidate_pairs(centres[perm], radii[perm], fixed[perm])
    mapped = np.sort(perm[moved], axis=1)
    mapped = mapped[np.lexsort((mapped[:, 1], mapped[:, 0]))]
    np.testing.assert_array_equal(mapped, first)


def test_each_pair_is_reported_by_one_cell(monkeypatch):
    """The owner rule, not the final pass, keeps pairs unique (across cells and levels)."""
    sort_pairs = kb.sort_pairs
    reported = []

    def spy(pairs, offsets, found, n, out):
        reported.append(int(found.sum()))
        return sort_pairs(pairs, offsets, found, n, out)

    monkeypatch.setattr(kb, "sort_pairs", spy)
    rng = np.random.default_rng(5)
    n = 600
    centres, radii = rng.uniform(0, 8, (n, 3)), 10.0 ** rng.uniform(-1.5, 0.7, n)
    pairs = check(centres, radii)
    assert reported == [len(pairs)] and len(pairs) > n


def test_sort_pairs_drops_repeats():
    """Repeats only arise on a 64-bit cell-hash collision; the final pass removes them."""
    pairs = np.array([[3, 4], [0, 2], [9, 9], [0, 2], [0, 1], [3, 4], [0, 1]], np.int64)
    offsets, found = np.array([0, 3, 7]), np.array([2, 4])  # row 2 is a gap
    out = np.empty((6, 2), np.int64)
    k = kb.sort_pairs(pairs, offsets, found, 5, out)
    np.testing.assert_array_equal(out[:k], [[0, 1], [0, 2], [3, 4]])
    # one body with many partners (a floor) and a few with one: long and short runs
    partners = np.random.default_rng(1).permutation(np.arange(2, 60))
    pairs = np.concatenate([np.stack([np.ones(58, int), partners], 1), [[0, 5], [3, 4]]])
    out = np.empty((60, 2), np.int64)
    k = kb.sort_pairs(pairs, np.array([0, 60]), np.array([60]), 60, out)
    np.testing.assert_array_equal(out[:k], [[0, 5], *[[1, j] for j in range(2, 60)], [3, 4]])


def test_huge_coordinates_within_the_limit():
    centres = np.array([[1e149, 0, 0], [1e149 + 2e148, 0, 0], [-1e149, 0, 0]])
    check(centres, np.array([1e148, 1e148, 1e148]))


@pytest.mark.parametrize(
    ("centres", "radii", "fixed", "match"),
    [
        (np.zeros((3, 2)), np.ones(3), None, r"shape \(n, 3\)"),
        (np.zeros(3), np.ones(1), None, r"shape \(n, 3\)"),
        (np.zeros((3, 3)), np.ones(2), None, r"radii must have shape \(3,\)"),
        (np.zeros((3, 3)), np.ones((3, 1)), None, r"radii must have shape \(3,\)"),
        ([[0, 0, np.nan]], [1.0], None, "centres must be finite.*body 0"),
        ([[0, 0, 0], [np.inf, 0, 0]], [1.0, 1.0], None, "centres must be finite.*body 1"),
        ([[0, 0, 1e200]], [1.0], None, "centres must be finite and within"),
        (np.zeros((2, 3)), [1.0, np.nan], None, "radii must be finite.*body 1"),
        (np.zeros((2, 3)), [1.0, -0.5], None, "non-negative; body 1"),
        (np.zeros((2, 3)), [1.0, 1j], None, "radii must be real"),
        ([["a", "b", "c"]], [1.0], None, "centres must be a numeric"),
        (np.zeros((2, 3)), np.ones(2), [0, 1], "boolean mask of shape"),
        (np.zeros((2, 3)), np.ones(2), [True], "boolean mask of shape"),
    ],
)
def test_validation(centres, radii, fixed, match):
    with pytest.raises(InvalidArgumentError, match=match):
        candidate_pairs(centres, radii, fixed)


# ---------------------------------------------------------------- the kept list (Verlet)
def walk(list_, centres, radii, fixed, moves) -> None:
    """Each configuration of ``centres`` moved by ``moves`` in turn: the kept list's pairs
    are the oracle's, row for row."""
    c = centres.copy()
    for move in moves:
        c = c + move
        got = list_.pairs(np.ascontiguousarray(c), radii, fixed)
        assert got.dtype == np.int64 and got.shape[1] == 2
        np.testing.assert_array_equal(got, oracle(c, radii, fixed))


@PROPS
@given(
    n=st.integers(65, 160),
    seed=st.integers(0, 2**32 - 1),
    step=st.sampled_from([0.0, 1e-9, 1e-4, 1e-3, 0.01, 0.05, 0.3]),
    skin=st.sampled_from([0.0, 0.01, 0.05, 0.5]),
)
def test_kept_list_matches_the_oracle_as_bodies_move(n, seed, step, skin):
    rng = np.random.default_rng(seed)
    centres = rng.uniform(-3, 3, (n, 3))
    radii = rng.uniform(0.2, 0.8, n)
    radii[rng.integers(0, n)] = 0.0  # a point body
    fixed = rng.random(n) < 0.2
    moves = rng.normal(0, step, (12, n, 3)) * ~fixed[:, None]
    if fixed.any():  # a fixed body may be moved by its owner too
        moves[5, rng.choice(np.flatnonzero(fixed))] += 1e-12
    walk(bp.CandidateList(skin), centres, radii, fixed, moves)


def test_kept_list_is_reused_while_bodies_stay_near_and_made_again_otherwise():
    rng = np.random.default_rng(7)
    side = 6
    grid = np.stack(np.meshgrid(*[np.arange(side)] * 3, indexing="ij"), -1).reshape(-1, 3)
    centres, radii = grid * 1.0, np.full(len(grid), 0.5)  # face neighbours touch exactly
    fixed = np.zeros(len(grid), bool)
    kept = bp.CandidateList(0.05)
    small = rng.normal(0, 1e-3, (6, len(grid), 3))
    walk(kept, centres, radii, fixed, [np.zeros_like(centres), *small])
    assert (kept.made, kept.reused) == (1, 6)
    # one body moves beyond its growth (0.025): the list is made again
    jump = np.zeros_like(centres)
    jump[17, 0] = 0.03
    walk(kept, centres + small.sum(0), radii, fixed, [jump])
    assert kept.made == 2
    # a change of radius or of the fixed mask makes it again, whatever the positions
    kept.pairs(np.ascontiguousarray(centres), radii * 1.0001, fixed)
    kept.pairs(np.ascontiguousarray(centres), radii * 1.0001, fixed | (grid[:, 0] == 0))
    assert kept.made == 4
    # a fixed body that moves at all makes it again
    fixed = grid[:, 2] == 0
    kept.pairs(np.ascontiguousarray(centres), radii, fixed)
    nudge = np.zeros_like(centres)
    nudge[0, 2] = -1e-9
    walk(kept, centres, radii, fixed, [nudge])
    assert kept.made == 6


def test_kept_list_skin_must_be_finite_and_non_negative():
    for skin in (-0.1, np.nan, np.inf):
        with pytest.raises(InvalidArgumentError, match="skin"):
            bp.CandidateList(skin)
