"""Properties of the triangle-distance kernels (hypothesis) and the contact forms.

The oracle is :mod:`engine.geometry.reference` (independent of the kernels) or the exact
kernel itself once test_distance.py has checked it against the reference.
"""

from __future__ import annotations

import functools

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from paired_rounding import assert_same_field

import engine
from engine import PairStatus, TriangleSet, triangle_contacts, triangle_distances
from engine.geometry.reference import (
    point_triangle_distance_naive,
    segment_segment_naive,
    triangle_distance_naive,
    triangles_intersect_naive,
)

KERNELS = ("exact", "iterative", "hybrid")
PRECISIONS = ("float64", "float32")
RTOL = 0.01  # engine.geometry.distance.DEFAULT_RTOL
NC, CONTACT, NO = PairStatus.NOT_CONVERGED, PairStatus.CONTACT, PairStatus.NO_CONTACT
EDGES = ((0, 1), (1, 2), (2, 0))
PROPS = settings(max_examples=150, deadline=None)


def size_of(a: np.ndarray, b: np.ndarray) -> float:
    pts = np.concatenate([a.reshape(-1, 3), b.reshape(-1, 3)])
    return float(np.ptp(pts, axis=0).max())


def one(a, b, kernel="exact", precision="float64", eps=0.0, **kw):
    """Single-pair result as Python floats: (distance, lower, point_a, point_b, status)."""
    r = triangle_distances(a[None], b[None], kernel, precision, eps, threads=1, **kw)
    return (
        float(r.distance[0]),
        float(r.lower[0]),
        r.point_a[0].astype(float),
        r.point_b[0].astype(float),
        int(r.status[0]),
    )


# --------------------------------------------------------------------------- strategies
def _well_shaped(t: np.ndarray) -> bool:
    """No thin or tiny triangles: every angle has sin ≥ 0.01, every edge ≥ 0.05.

    Thin triangles and nearly parallel edges have their own tests in test_distance.py
    (where the float32 kernel is known to lose accuracy).
    """
    e = [t[j] - t[i] for i, j in EDGES]
    longest = max(float(x @ x) for x in e)
    n = np.cross(e[0], -e[2])
    return min(float(x @ x) for x in e) >= 0.05**2 and float(np.linalg.norm(n)) >= 0.01 * longest


# Coordinates below 1e-6 in magnitude are snapped to 0: heights whose products
# underflow fake edge crossings in the exact kernel, a bug pinned down by
# test_distance.py::test_tiny_heights_do_not_fake_a_crossing.
coordinate = st.floats(-2.0, 2.0, allow_nan=False, allow_infinity=False).map(
    lambda x: 0.0 if abs(x) < 1e-6 else x
)
triangle = arrays(np.float64, (3, 3), elements=coordinate).filter(_well_shaped)
offset = arrays(
    np.float64, (3,), elements=st.floats(-4.0, 4.0).map(lambda x: 0.0 if abs(x) < 1e-6 else x)
)


@st.composite
def triangle_pairs(draw):
    """Two well-shaped triangles: apart, near, intersecting, or touching (B's vertex on A)."""
    a = draw(triangle)
    b = draw(triangle) + draw(offset) * draw(st.sampled_from([0.0, 0.1, 0.5, 1.0]))
    if draw(st.booleans()):  # touching: move B so that its vertex 0 lies on A
        w = np.array(draw(st.tuples(*[st.floats(0.0, 1.0)] * 3))) + 1e-3
        b = b - b[0] + (w / w.sum()) @ a
    return a, b


@st.composite
def rotations(draw):
    q = np.array(draw(st.tuples(*[st.floats(-1.0, 1.0)] * 4)))
    assume(np.linalg.norm(q) > 0.1)
    w, x, y, z = q / np.linalg.norm(q)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


# --------------------------------------------------------------------------- properties
@PROPS
@given(triangle_pairs(), st.sampled_from(PRECISIONS))
def test_symmetry(pair, precision):
    a, b = pair
    tol = {"float64": 1e-12, "float32": 1e-5}[precision] * size_of(a, b)
    d_ab, _, pa, pb, _ = one(a, b, precision=precision)
    d_ba, _, qb, qa, _ = one(b, a, precision=precision)
    assert d_ab == pytest.approx(d_ba, abs=tol)
    for kernel in ("iterative", "hybrid"):  # certified bounds hold either way round
        for x, y in ((a, b), (b, a)):
            d, low, _, _, _ = one(x, y, kernel, precision)
            assert low - tol <= d_ab <= d + tol


@PROPS
@given(triangle_pairs(), rotations(), offset)
def test_rigid_motion_invariance(pair, r, t):
    a, b = pair
    t = 2.5 * t
    ma, mb = a @ r.T + t, b @ r.T + t
    tol = 1e-11 * (size_of(a, b) + np.abs(t).max())
    d, _, pa, pb, _ = one(a, b)
    dm, _, qa, qb, _ = one(ma, mb)
    assert dm == pytest.approx(d, abs=tol)
    assert point_triangle_distance_naive(qa, ma) <= tol
    assert point_triangle_distance_naive(qb, mb) <= tol
    # the moved pair's points, moved back, are also a closest pair of the original
    back_a, back_b = (qa - t) @ r, (qb - t) @ r
    assert point_triangle_distance_naive(back_a, a) <= tol
    assert point_triangle_distance_naive(back_b, b) <= tol
    assert np.linalg.norm(back_a - back_b) == pytest.approx(d, abs=tol)
    # float32: same within its accuracy
    d32 = one(ma, mb, precision="float32")[0]
    assert d32 == pytest.approx(d, abs=1e-5 * (size_of(a, b) + np.abs(t).max()))


@PROPS
@given(triangle_pairs(), st.sampled_from(PRECISIONS))
def test_distance_is_at_most_every_vertex_and_edge_distance(pair, precision):
    a, b = pair
    tol = {"float64": 1e-12, "float32": 1e-5}[precision] * size_of(a, b)
    bounds = [point_triangle_distance_naive(v, b) for v in a]
    bounds += [point_triangle_distance_naive(v, a) for v in b]
    bounds += [segment_segment_naive(a[i], a[j], b[k], b[m])[0] for i, j in EDGES for k, m in EDGES]
    d, _, pa, pb, _ = one(a, b, precision=precision)
    assert d <= min(bounds) + tol
    assert np.linalg.norm(pa - pb) == pytest.approx(d, abs=tol)
    assert point_triangle_distance_naive(pa, a) <= tol
    assert point_triangle_distance_naive(pb, b) <= tol
    low = one(a, b, "iterative", precision)[1]
    assert low <= min(bounds) + tol


@PROPS
@given(triangle_pairs(), st.sampled_from(KERNELS))
def test_distance_is_zero_exactly_when_the_triangles_meet(pair, kernel):
    a, b = pair
    size = size_of(a, b)
    tol = 1e-12 * size
    ref = triangle_distance_naive(a, b)[0]
    meet = triangles_intersect_naive(a, b)
    d, low, pa, pb, status = one(a, b, kernel, eps=0.0)
    if meet:
        assert low <= tol
        if kernel != "iterative":
            assert d <= tol
            assert np.linalg.norm(pa - pb) <= tol
    elif ref > 1e-9 * size:  # clearly apart (tiny gaps are within rounding)
        assert d > 0.0 and status != CONTACT
        if kernel == "exact":
            assert status == NO and low == d


@PROPS
@given(triangle_pairs())
def test_float32_agrees_with_float64(pair):
    a, b = pair
    tol = 1e-5 * size_of(a, b)
    d64 = one(a, b, precision="float64")[0]
    d32, _, pa, pb, _ = one(a, b, precision="float32")
    assert d32 == pytest.approx(d64, abs=tol)
    assert point_triangle_distance_naive(pa, a) <= tol
    assert point_triangle_distance_naive(pb, b) <= tol


@PROPS
@given(triangle_pairs(), st.sampled_from(PRECISIONS), st.integers(1, 8))
def test_certificate_brackets_the_exact_distance(pair, precision, iterations):
    a, b = pair
    dtype = np.dtype(precision)
    # float64 truth of what the kernel sees (the input rounded to its precision)
    ra, rb = a.astype(dtype).astype(float), b.astype(dtype).astype(float)
    d = triangle_distance_naive(ra, rb)[0]
    tol = 64 * float(np.finfo(dtype).eps) * (size_of(a, b) + d)
    upper, lower, pa, pb, _ = one(a, b, "iterative", precision, iterations=iterations)
    assert lower - tol <= d <= upper + tol
    assert np.linalg.norm(pa - pb) == pytest.approx(upper, abs=tol)


eps_offsets = st.one_of(
    st.just(0.0),
    st.floats(-1e-6, 1e-6),
    st.floats(-1e-3, 1e-3),
    st.floats(-0.5, 0.5),
)


@PROPS
@given(triangle_pairs(), st.sampled_from(PRECISIONS), eps_offsets, st.integers(1, 8))
def test_certified_classification_matches_the_exact_kernel(pair, precision, rel, iterations):
    a, b = pair
    size = size_of(a, b)
    d = one(a, b, "exact", precision)[0]
    eps = max(d + rel * size, 0.0)
    # the exact kernel's own decision, made in its precision
    ex = one(a, b, "exact", precision, eps)
    eps_k = float(np.asarray(eps, dtype=precision))  # what the kernels compare with
    exact_contact = ex[0] <= eps_k
    assert (ex[4] == CONTACT) == exact_contact
    it = one(a, b, "iterative", precision, eps, iterations=iterations)
    if it[4] != NC:
        assert (it[4] == CONTACT) == exact_contact
    hy = one(a, b, "hybrid", precision, eps, iterations=iterations)
    assert hy[4] == it[4]  # the hybrid status is the iterative kernel's, before fallback
    hybrid_contact = hy[4] == CONTACT or (hy[4] == NC and hy[0] <= eps_k)
    assert hybrid_contact == exact_contact
    if hy[4] == NC:
        assert hy[0] == ex[0]


# ============================================================================ contacts
MESH = engine.geometry.shapes.icosphere(2).triangles  # 320 triangles of the unit sphere
N = len(MESH)
GAPS = (-0.1, -0.02, 0.0, 0.3)  # between the circumscribed spheres


def _rotation(rng: np.random.Generator) -> np.ndarray:
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q = q * np.sign(np.diag(r))
    return q if np.linalg.det(q) > 0 else -q


@functools.cache
def scene(gap: float):
    """A rotated copy of MESH, its centre 2 + gap away, and per-triangle halos."""
    rng = np.random.default_rng(int(1000 * gap) + 1000)
    u = rng.normal(size=3)
    u /= np.linalg.norm(u)
    b = MESH @ _rotation(rng).T + (2.0 + gap) * u
    return b, rng.uniform(0.0, 0.03, N), rng.uniform(0.0, 0.03, N)


@functools.cache
def brute_force(gap: float, precision: str):
    """Exact distance of every pair (i, j) of MESH × copy, and its contact distance."""
    b, eps_a, eps_b = scene(gap)
    dtype = np.dtype(precision)
    i, j = np.repeat(np.arange(N), N), np.tile(np.arange(N), N)
    eps = eps_a.astype(dtype)[i] + eps_b.astype(dtype)[j]  # summed as the kernel sums
    r = triangle_distances(MESH[i], b[j], "exact", precision, eps.astype(float), threads=1)
    assert r.stats.pairs == N * N
    return r.distance.reshape(N, N), eps.reshape(N, N), (r.status == CONTACT).reshape(N, N)


def check_contacts(res, gap, precision, kernel, tested):
    """``res`` against brute force over the pairs ``tested`` (k, 2)."""
    b, _, _ = scene(gap)
    dist, eps, contact = brute_force(gap, precision)
    size = 2 * float(np.ptp(MESH[0], axis=0).max())
    tol = {"float64": 1e-12, "float32": 1e-5}[precision] * size
    got = res.pairs
    assert got.dtype == np.int64 and got.shape == (len(res), 2)
    assert res.distance.dtype == np.dtype(precision) and res.point_a.shape == (len(res), 3)
    found = {tuple(p) for p in got.tolist()}
    expected = {tuple(p) for p in tested.tolist() if contact[p[0], p[1]]}
    st_ = res.status
    if kernel == "iterative":
        assert set(np.unique(st_)) <= {CONTACT, NC}
        certain = {tuple(p) for p in got[st_ == CONTACT].tolist()}
        assert certain <= expected, sorted(certain - expected)[:5]
        assert expected <= found, sorted(expected - found)[:5]
    else:
        assert (st_ == CONTACT).all()
        assert found == expected, (sorted(found - expected)[:5], sorted(expected - found)[:5])
    d = dist[got[:, 0], got[:, 1]]
    e = eps[got[:, 0], got[:, 1]]
    if kernel == "exact":
        np.testing.assert_allclose(res.distance, d, rtol=0, atol=tol)
    else:
        assert (res.distance >= d - tol).all()  # an upper bound
        c = st_ == CONTACT
        assert (res.distance[c] - d[c] <= RTOL * e[c] + tol).all()
    gap_ = np.linalg.norm(res.point_a.astype(float) - res.point_b, axis=1)
    np.testing.assert_allclose(gap_, res.distance, rtol=0, atol=tol)
    for k in np.random.default_rng(0).choice(len(res), min(len(res), 40), replace=False):
        i, j = got[k]
        assert point_triangle_distance_naive(res.point_a[k].astype(float), MESH[i]) <= tol
        assert point_triangle_distance_naive(res.point_b[k].astype(float), b[j]) <= tol


def check_stats(stats, kernel, tested: int):
    assert stats.pairs == tested
    if kernel == "exact":
        assert stats.culled == stats.iterative == stats.fallbacks == 0
    else:
        assert stats.culled + stats.iterative == tested
        assert 0 <= stats.fallbacks <= stats.iterative
        if kernel == "iterative":
            assert stats.fallbacks == 0


@pytest.mark.parametrize("threads", [1, 2])
@pytest.mark.parametrize("precision", PRECISIONS)
@pytest.mark.parametrize("kernel", KERNELS)
@pytest.mark.parametrize("gap", GAPS)
def test_all_pairs_match_brute_force(gap, kernel, precision, threads):
    b, eps_a, eps_b = scene(gap)
    res = triangle_contacts(
        MESH, b, eps_a, eps_b, kernel=kernel, precision=precision, threads=threads
    )
    every = np.stack(np.meshgrid(np.arange(N), np.arange(N), indexing="ij"), -1).reshape(-1, 2)
    check_contacts(res, gap, precision, kernel, every)
    check_stats(res.stats, kernel, N * N)
    order = np.lexsort((res.pairs[:, 1], res.pairs[:, 0]))
    np.testing.assert_array_equal(order, np.arange(len(res)))  # ordered by (i, j)
    if gap <= 0.0:
        assert len(res) > 0
    if threads == 2:  # same answer as one thread
        one_thread = triangle_contacts(
            MESH, b, eps_a, eps_b, kernel=kernel, precision=precision, threads=1
        )
        np.testing.assert_array_equal(res.pairs, one_thread.pairs)
        np.testing.assert_array_equal(res.distance, one_thread.distance)
        assert res.stats == one_thread.stats


@pytest.mark.parametrize("threads", [1, 2])
@pytest.mark.parametrize("precision", PRECISIONS)
@pytest.mark.parametrize("kernel", KERNELS)
@pytest.mark.parametrize("gap", GAPS)
def test_listed_pairs_match_brute_force(gap, kernel, precision, threads):
    b, eps_a, eps_b = scene(gap)
    rng = np.random.default_rng(5)
    flat = np.sort(rng.choice(N * N, 80_000, replace=False))  # > 65,536: threaded
    tested = np.stack([flat // N, flat % N], axis=1)
    res = triangle_contacts(
        MESH, b, eps_a, eps_b, pairs=tested, kernel=kernel, precision=precision, threads=threads
    )
    check_contacts(res, gap, precision, kernel, tested)
    check_stats(res.stats, kernel, len(tested))
    order = np.lexsort((res.pairs[:, 1], res.pairs[:, 0]))
    np.testing.assert_array_equal(order, np.arange(len(res)))
    # prepared sets give the same answer as arrays
    sa, sb = TriangleSet(MESH, precision), TriangleSet(b, precision)
    again = triangle_contacts(
        sa, sb, eps_a, eps_b, pairs=tested, kernel=kernel, precision=precision, threads=threads
    )
    np.testing.assert_array_equal(again.pairs, res.pairs)
    np.testing.assert_array_equal(again.distance, res.distance)


@pytest.mark.parametrize("kernel", KERNELS)
def test_listed_pairs_in_any_order_with_repeats(kernel):
    b, eps_a, eps_b = scene(0.0)
    _, _, contact = brute_force(0.0, "float64")
    hits = np.argwhere(contact)
    rng = np.random.default_rng(9)
    tested = np.concatenate([hits, hits[:5], rng.integers(0, N, (500, 2))])
    tested = tested[rng.permutation(len(tested))]
    res = triangle_contacts(MESH, b, eps_a, eps_b, pairs=tested, kernel=kernel, threads=1)
    check_contacts(res, 0.0, "float64", kernel, tested)
    check_stats(res.stats, kernel, len(tested))
    expected = [tuple(p) for p in tested.tolist() if contact[p[0], p[1]]]
    got = [tuple(p) for p in res.pairs.tolist()]
    if kernel != "iterative":
        assert sorted(got) == sorted(expected)  # repeats reported as often as listed


@pytest.mark.parametrize("precision", PRECISIONS)
@pytest.mark.parametrize("kernel", KERNELS)
@pytest.mark.parametrize(("subdivisions", "threads"), [(1, 1), (2, 2)])
def test_more_contacts_than_the_first_buffer_holds(
    subdivisions, threads, kernel, precision, monkeypatch
):
    # Coincident spheres with halos summing to 3 > their diameter: every pair is in
    # contact, far more than the first output buffer (1024 + 8 per row) of each chunk.
    capacities = []
    buffers = engine.geometry.distance._contact_buffers

    def spy(capacity, like):
        capacities.append(capacity)
        return buffers(capacity, like)

    monkeypatch.setattr(engine.geometry.distance, "_contact_buffers", spy)
    t = engine.geometry.shapes.icosphere(subdivisions).triangles
    n = len(t)
    res = triangle_contacts(t, t, 1.5, 1.5, kernel=kernel, precision=precision, threads=threads)
    assert len(capacities) > (1 if threads == 1 else 2)  # the re-run path was taken
    assert len(res) == n * n
    every = np.stack(np.meshgrid(np.arange(n), np.arange(n), indexing="ij"), -1).reshape(-1, 2)
    np.testing.assert_array_equal(res.pairs, every)
    check_stats(res.stats, kernel, n * n)
    if kernel != "iterative":
        assert (res.status == CONTACT).all()
    assert np.isfinite(res.distance).all() and (res.distance <= 2.0 + 1e-5).all()
    same = np.flatnonzero(res.pairs[:, 0] == res.pairs[:, 1])  # a triangle with itself
    if kernel == "exact":
        assert (res.distance[same] == 0).all()
    listed = triangle_contacts(
        t, t, 1.5, 1.5, pairs=every, kernel=kernel, precision=precision, threads=threads
    )
    assert len(listed) == n * n
    check_stats(listed.stats, kernel, n * n)


@pytest.mark.parametrize("threads", [1, 2])
@pytest.mark.parametrize("kernel", KERNELS)
def test_empty_inputs(kernel, threads):
    b, eps_a, eps_b = scene(0.0)
    for pairs in (np.empty((0, 2), np.int64), np.empty((0, 2))):
        res = triangle_contacts(MESH, b, eps_a, eps_b, pairs=pairs, kernel=kernel, threads=threads)
        assert len(res) == 0 and res.pairs.shape == (0, 2) and res.point_a.shape == (0, 3)
        assert res.stats.pairs == 0
    none = np.empty((0, 3, 3))
    for x, y in ((none, b), (MESH, none), (none, none)):
        res = triangle_contacts(x, y, kernel=kernel, threads=threads)
        assert len(res) == 0 and res.pairs.shape == (0, 2) and res.stats.pairs == 0
    r = triangle_distances(none, none, kernel, threads=threads)
    assert r.distance.shape == (0,) and r.point_a.shape == (0, 3) and r.stats.pairs == 0


@pytest.mark.parametrize("precision", PRECISIONS)
@pytest.mark.parametrize("kernel", KERNELS)
def test_paired_distances_threaded_equal_serial(kernel, precision):
    b, _, _ = scene(0.02)
    rng = np.random.default_rng(11)
    i, j = rng.integers(0, N, 70_000), rng.integers(0, N, 70_000)  # > 65,536 pairs
    eps = rng.uniform(0, 0.05, len(i))
    r1 = triangle_distances(MESH[i], b[j], kernel, precision, eps, threads=1)
    r2 = triangle_distances(MESH[i], b[j], kernel, precision, eps, threads=2)
    scale = np.abs(np.concatenate([MESH[i], b[j]], axis=1)).max(axis=(1, 2))
    for field in ("distance", "lower", "point_a", "point_b", "status"):  # see paired_rounding
        assert_same_field(field, getattr(r1, field), getattr(r2, field), scale, field)
    assert r1.stats == r2.stats and r1.stats.pairs == len(i)
    if kernel == "hybrid":
        assert r1.stats.fallbacks == int((r1.status == NC).sum())
