"""The vertex–vertex certificate (``triangle_points.vertex_pair``): where it certifies a
triangle pair, the exact kernel's closest points are the same two vertices and its distance
the same (to rounding, 1e-15 of the coordinates); near-degenerate pairs (parallel faces,
crossing edges, a vertex over a face, touching, crossing, ties, margins below τ) are refused;
the vectorised form is the scalar one, and ``certified_points`` takes the certificate where
it holds and ``exact_points`` elsewhere."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from engine.geometry.triangle_set import TriangleSet
from engine.kernels.geometry import triangle_batch as tb
from engine.kernels.geometry import triangle_points as tp

TAU = 2.0**-10


def _rotation(rng: np.random.Generator) -> np.ndarray:
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    return q * np.sign(np.diag(r))


def _sets(a: np.ndarray, b: np.ndarray, precision: str = "float64"):
    return TriangleSet(a, precision=precision), TriangleSet(b, precision=precision)


def _both(sa, sb, t: int):
    one = sa.coords.dtype.type(1)
    got = tp.vertex_point(sa.coords, t, sb.coords, t, one)
    exact = tp.exact_point(sa.coords, sa.frames, t, sb.coords, sb.frames, t, one)
    return got, exact


def _vertex_facing(rng: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Pairs whose closest points are two vertices with a clear margin: A's apex at the
    origin, its other vertices below (z ≤ −0.05·spread), B the same shape mirrored above a
    gap; turned and moved at random."""
    a = np.empty((n, 3, 3))
    b = np.empty((n, 3, 3))
    for t in range(n):
        gap = 10.0 ** rng.uniform(-4, 0)
        base = np.c_[rng.normal(size=(2, 2)), -rng.uniform(0.05, 1.0, size=2)[:, None]]
        a[t] = np.r_[[[0.0, 0.0, 0.0]], base]
        other = np.c_[rng.normal(size=(2, 2)), rng.uniform(0.05, 1.0, size=2)[:, None]]
        b[t] = np.r_[[[0.0, 0.0, gap]], other + [0.0, 0.0, gap]]
        rot, shift = _rotation(rng), rng.normal(size=3) * 10.0 ** rng.uniform(-1, 3)
        a[t] = a[t] @ rot.T + shift
        b[t] = b[t] @ rot.T + shift
    return a, b


def _assert_same_as_exact(got, exact, scale: float, rtol: float) -> None:
    d, p, q = got
    de, pe, qe = exact
    assert abs(d - de) <= rtol * scale, (d, de)
    np.testing.assert_allclose(p, pe, rtol=0, atol=rtol * scale)
    np.testing.assert_allclose(q, qe, rtol=0, atol=rtol * scale)


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**32 - 1))
def test_vertex_facing_pairs_are_certified_and_match_the_exact_kernel(seed):
    a, b = _vertex_facing(np.random.default_rng(seed), 16)
    sa, sb = _sets(a, b)
    for t in range(len(a)):
        got, exact = _both(sa, sb, t)
        assert got[0] >= 0, "a vertex-facing pair with a clear margin was refused"
        # the recorded points are the stored vertices (A's apex, B's apex)
        stored_a = sa.coords[:, t].reshape(3, 3)
        stored_b = sb.coords[:, t].reshape(3, 3)
        assert any((tuple(v) == got[1]) for v in stored_a)
        assert any((tuple(v) == got[2]) for v in stored_b)
        scale = max(np.abs(a[t]).max(), np.abs(b[t]).max())
        _assert_same_as_exact(got, exact, scale, 1e-15)


@pytest.mark.parametrize("seed", range(4))
def test_on_random_pairs_a_certificate_is_the_exact_answer(seed):
    """Random pairs at random distances: every certified pair matches the exact kernel
    (and some are certified, some refused)."""
    rng = np.random.default_rng(seed)
    n = 4000
    a = rng.normal(size=(n, 3, 3))
    b = rng.normal(size=(n, 3, 3)) + rng.normal(size=(n, 1, 3)) * rng.uniform(0, 4, (n, 1, 1))
    sa, sb = _sets(a, b)
    certified = 0
    for t in range(n):
        got, exact = _both(sa, sb, t)
        if got[0] >= 0:
            certified += 1
            scale = max(np.abs(a[t]).max(), np.abs(b[t]).max())
            _assert_same_as_exact(got, exact, scale, 1e-15)
    assert 0 < certified < n


def _refused(a: np.ndarray, b: np.ndarray, precision: str = "float64") -> None:
    sa, sb = _sets(a[None], b[None], precision)
    got, _ = _both(sa, sb, 0)
    assert got[0] == -1, got


@pytest.mark.parametrize("precision", ["float64", "float32"])
@pytest.mark.parametrize("seed", range(8))
def test_near_degenerate_pairs_are_refused(seed, precision):
    rng = np.random.default_rng(seed)
    rot, shift = _rotation(rng), rng.normal(size=3)

    def turned(x):
        return x @ rot.T + shift

    tri = np.array([[0.0, 0.0, 0.0], [1.0, 0.1, 0.0], [0.2, 0.9, 0.0]])
    up = np.array([0.0, 0.0, 0.01 + rng.uniform(0, 0.5)])
    # parallel faces: a translated copy above (and one slightly tilted, within τ)
    _refused(turned(tri), turned(tri + up), precision)
    tilt = tri.copy()
    tilt[1, 2] = 1e-4
    _refused(turned(tri), turned(tilt + up), precision)
    # a vertex of B over the interior of A
    over = np.array([[0.3, 0.3, 0.0], [0.5, 2.0, 1.0], [2.0, 0.5, 1.0]]) + up
    _refused(turned(tri), turned(over), precision)
    # crossing edges (edge–edge closest points inside both edges)
    a = np.array([[-1.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
    b = np.array([[0.0, -1.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]) + up
    _refused(turned(a), turned(b), precision)
    # an edge of B over a vertex of A: the vertex is closest to the edge's interior
    b = np.array([[-1.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]) + up
    _refused(turned(np.array([[0.0, 0.0, 0.0], [0.5, 1.0, -1.0], [-0.5, 1.0, -1.0]])), turned(b))
    # touching at a vertex (distance 0), and crossing triangles
    apex_a = np.array([[0.0, 0.0, 0.0], [1.0, 0.3, -1.0], [-0.4, 1.0, -1.0]])
    apex_b = np.array([[0.0, 0.0, 0.0], [1.0, -0.2, 1.0], [-0.3, -1.0, 1.0]])
    _refused(turned(apex_a), turned(apex_b), precision)
    _refused(turned(apex_a), turned(apex_b - [0.0, 0.0, 0.1]), precision)
    # a tie: B's apex equidistant from two vertices of A
    tie = np.array([[-0.5, 0.0, 0.0], [0.5, 0.0, 0.0], [0.0, 1.0, -1.0]])
    _refused(turned(tie), turned(np.array([[0.0, 0.0, 1.0], [1.0, 1.0, 2.0], [-1.0, 0.5, 2.0]])))
    # a degenerate triangle (one point): certified as the point (a vertex equal to the
    # chosen one passes), and the exact kernel agrees
    sa, sb = _sets(turned(np.zeros((1, 3, 3))), turned(apex_b + up)[None], precision)
    got, exact = _both(sa, sb, 0)
    assert got[0] >= 0
    _assert_same_as_exact(got, exact, 2.0, 1e-15 if precision == "float64" else 1e-6)


@pytest.mark.parametrize("precision", ["float64", "float32"])
def test_the_margin_is_tau(precision):
    """A's other vertices at an angle ``s`` below the plane normal to g through the apex:
    certified for s a little above τ, refused a little below."""

    def pair(s):
        a = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, -s], [0.0, 1.0, -s]])
        b = np.array([[0.0, 0.0, 0.5], [1.0, 0.0, 1.5], [0.0, 1.0, 1.5]])
        return _sets(a[None], b[None], precision)

    for s, certified in ((1.5 * TAU, True), (0.5 * TAU, False), (-TAU, False)):
        got, exact = _both(*pair(s), 0)
        assert (got[0] >= 0) == certified, s
        if certified:
            _assert_same_as_exact(got, exact, 1.5, 1e-15 if precision == "float64" else 1e-6)


@pytest.mark.parametrize("precision", ["float64", "float32"])
def test_vectorised_and_certified_points(precision):
    """``vertex_points`` is ``vertex_point`` bit for bit; ``certified_points`` gives the
    certificate where it holds and ``exact_points``' values (the scalar ``exact_point``'s)
    elsewhere, in place."""
    rng = np.random.default_rng(11)
    m = tb.BLOCK
    a1, b1 = _vertex_facing(rng, m // 2)
    a2 = rng.normal(size=(m - m // 2, 3, 3))
    b2 = a2 + rng.normal(scale=0.3, size=(m - m // 2, 1, 3))  # parallel faces: refused
    order = rng.permutation(m)
    sa, sb = _sets(np.r_[a1, a2][order], np.r_[b1, b2][order], precision)
    one = sa.coords.dtype.type(1)
    rows, final = tp.point_rows(sa.coords), tp.point_rows(sa.coords)
    block = [x.copy() for x in (sa.coords, sa.frames, sb.coords, sb.frames)]
    tp.vertex_points(block[0], block[2], m, one, *final)
    got = np.array([r[:m] for r in final])
    for t in range(m):
        d, p, q = tp.vertex_point(sa.coords, t, sb.coords, t, one)
        assert got[0, t] == d
        if d >= 0:
            np.testing.assert_array_equal(got[1:, t], [*p, *q])
    certified = got[0] >= 0
    assert 0 < certified.sum() < m
    tp.certified_points(*block, m, one, final, rows)
    result = np.array([r[:m] for r in final])
    np.testing.assert_array_equal(result[:, certified], got[:, certified])
    for t in np.flatnonzero(~certified):
        d, p, q = tp.exact_point(sa.coords, sa.frames, t, sb.coords, sb.frames, t, one)
        np.testing.assert_array_equal(result[:, t], [d, *p, *q])
