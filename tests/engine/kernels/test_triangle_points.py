"""The vectorised exact closest points (``triangle_points.exact_points``) are the scalar
``exact_point``'s, bit for bit, on near, crossing, parallel and sliver pairs."""

from __future__ import annotations

import numpy as np
import pytest
from numba import njit

from engine.geometry.distance import TriangleSet
from engine.kernels.geometry import triangle_batch as tb
from engine.kernels.geometry import triangle_points as tp


@njit
def _scalar(a, fa, b, fb, m, one, out):
    for t in range(m):
        d, p, q = tp.exact_point(a, fa, t, b, fb, t, one)
        out[0, t] = d
        out[1, t], out[2, t], out[3, t] = p
        out[4, t], out[5, t], out[6, t] = q


def _pairs(seed: int, n: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    a = rng.normal(size=(n, 3, 3))
    b = a + rng.normal(scale=0.05, size=(n, 3, 3)) + rng.normal(scale=0.1, size=(n, 1, 3))
    q = n // 4
    b[:q] = a[:q] + rng.normal(scale=0.3, size=(q, 1, 3))  # translated copies: parallel faces
    a[q : 2 * q, 2] = a[q : 2 * q, 0] + 1e-7 * rng.normal(size=(q, 3))  # slivers
    b[2 * q : 3 * q] = a[2 * q : 3 * q, ::-1]  # the same triangle, reversed
    return a, b


@pytest.mark.parametrize("precision", ["float64", "float32"])
def test_vectorised_points_are_the_scalar_points(precision):
    a, b = _pairs(3, 3 * tb.BLOCK // 2)
    sa, sb = TriangleSet(a, precision=precision), TriangleSet(b, precision=precision)
    dtype = np.dtype(precision).type
    one = dtype(1)
    rows = tp.point_rows(sa.coords)
    for t0 in range(0, len(a), tb.BLOCK):
        m = min(tb.BLOCK, len(a) - t0)
        block = [
            np.ascontiguousarray(x[:, t0 : t0 + tb.BLOCK])
            for x in (sa.coords, sa.frames, sb.coords, sb.frames)
        ]
        block = [np.concatenate([x, np.zeros((x.shape[0], tb.BLOCK - m), dtype)], 1) for x in block]
        tp.exact_points(*block, m, one, *rows)
        want = np.empty((7, m), dtype)
        _scalar(*block, m, one, want)
        got = np.array([r[:m] for r in rows])
        np.testing.assert_array_equal(got, want)
        assert (want[0] == 0).any() and (want[0] > 0).any()


@pytest.mark.parametrize("precision", ["float64", "float32"])
def test_short_blocks_are_the_scalar_values(precision):
    """Blocks of 1 to 17 pairs, exactly as wide as the block (``tail_masked`` kernels run
    them as masked vector lanes, with no scalar remainder, and read nothing past ``m``):
    ``exact_paired``'s distances and ``exact_points``' values are the scalar
    ``exact_point``'s, bit for bit."""
    a, b = _pairs(5, 4 * 17)
    sa, sb = TriangleSet(a, precision=precision), TriangleSet(b, precision=precision)
    one = np.dtype(precision).type(1)
    rows = tp.point_rows(sa.coords)
    for m in range(1, 18):
        t0 = (3 * m) % (len(a) - m)
        block = [
            np.ascontiguousarray(x[:, t0 : t0 + m])
            for x in (sa.coords, sa.frames, sb.coords, sb.frames)
        ]
        want = np.empty((7, m), sa.coords.dtype)
        _scalar(*block, m, one, want)
        dist = np.empty(m, sa.coords.dtype)
        tp.exact_paired(*block, m, one, dist)
        np.testing.assert_array_equal(dist, want[0])
        tp.exact_points(*block, m, one, *rows)
        np.testing.assert_array_equal(np.array([r[:m] for r in rows]), want)
