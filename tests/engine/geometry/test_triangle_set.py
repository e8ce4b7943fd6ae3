"""TriangleSet (engine/geometry/triangle_set.py): the preparation's invariants, the
row-major copies, subsets, reuse by :meth:`TriangleSet.of`, threads, and bad input.

The preparation's bits against the old numpy path are checked in test_distance_paired.py;
here each invariant is checked against the input triangles themselves."""

from __future__ import annotations

import numpy as np
import pytest

from engine import InvalidArgumentError, TriangleSet
from engine.geometry import triangle_set as ts

PRECISIONS = ("float64", "float32")


def _triangles(seed: int, n: int) -> np.ndarray:
    """(n, 3, 3) float64: random triangles of mixed sizes and shapes."""
    rng = np.random.default_rng(seed)
    tri = rng.normal(size=(n, 3, 3))
    return tri * 10 ** rng.uniform(-1, 1, size=(n, 1, 1))


@pytest.mark.parametrize("precision", PRECISIONS)
def test_each_triangle_is_rotated_to_its_largest_angle_with_orientation_kept(precision):
    tri = _triangles(1, 500)
    s = TriangleSet(tri, precision)
    assert s.dtype == np.dtype(precision) and len(s) == len(tri)
    got = s.coords.T.reshape(-1, 3, 3).astype(np.float64)
    want = tri.astype(precision).astype(np.float64)
    rotations = np.stack([np.roll(want, -k, axis=1) for k in range(3)])  # cyclic: same normal
    assert (rotations == got[None]).all(axis=(2, 3)).any(axis=0).all()
    # vertex 0 is opposite the longest edge (ties within rounding excepted)
    lengths = np.stack(
        [np.linalg.norm(got[:, (k + 2) % 3] - got[:, (k + 1) % 3], axis=1) for k in range(3)],
        axis=1,
    )
    slack = 1e-12 if precision == "float64" else 1e-5
    assert (lengths[:, 0] >= lengths.max(axis=1) * (1 - slack)).all()


@pytest.mark.parametrize("precision", PRECISIONS)
def test_frames_hold_the_unit_normal_of_each_triangle(precision):
    tri = _triangles(2, 300)
    s = TriangleSet(tri, precision)
    v = s.coords.T.reshape(-1, 3, 3).astype(np.float64)
    normal = s.frames[0:3].T.astype(np.float64)
    cross = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
    want = cross / np.linalg.norm(cross, axis=1, keepdims=True)
    tol = 1e-9 if precision == "float64" else 1e-4
    np.testing.assert_allclose(normal, want, atol=tol)


@pytest.mark.parametrize("precision", PRECISIONS)
def test_row_major_copies_subsets_and_prepared_sets(precision):
    s = TriangleSet(_triangles(3, 200), precision)
    np.testing.assert_array_equal(s.coords_rm, s.coords.T)
    np.testing.assert_array_equal(s.frames_rm, s.frames.T)
    assert s.coords_rm.flags.c_contiguous and s.frames_rm.shape == (200, 14)
    index = np.array([5, 0, 199, 5])
    sub = s.subset(index, "float32")
    assert sub.dtype == np.float32 and len(sub) == 4
    np.testing.assert_array_equal(sub.coords, s.coords[:, index].astype(np.float32))
    np.testing.assert_array_equal(sub.frames, s.frames[:, index].astype(np.float32))
    again = TriangleSet.prepared(s.coords, s.frames)
    assert again.dtype == s.dtype and len(again) == len(s)
    np.testing.assert_array_equal(again.frames, s.frames)


def test_of_reuses_a_set_of_the_same_precision_and_rejects_another():
    tri = _triangles(4, 10)
    s = TriangleSet(tri, "float32")
    assert TriangleSet.of(s, "float32") is s
    made = TriangleSet.of(tri, "float64")
    assert isinstance(made, TriangleSet) and made.dtype == np.float64
    with pytest.raises(InvalidArgumentError, match=r"x is a float32 TriangleSet"):
        TriangleSet.of(s, "float64", "x")


@pytest.mark.parametrize("precision", PRECISIONS)
def test_threads_do_not_change_the_preparation(precision):
    tri = _triangles(5, ts._SERIAL_PAIRS + 1000)  # above the serial cut: split over a pool
    one, two = TriangleSet(tri, precision, threads=1), TriangleSet(tri, precision, threads=2)
    np.testing.assert_array_equal(one.coords, two.coords)
    np.testing.assert_array_equal(one.frames, two.frames)
    np.testing.assert_array_equal(one.coords_rm, two.coords_rm)


@pytest.mark.parametrize(
    ("triangles", "threads", "match"),
    [
        (np.zeros((2, 3, 2)), None, r"triangles"),
        (np.full((2, 3, 3), np.nan), None, r"non-finite coordinate in triangle 0"),
        (np.full((1, 3, 3), 1e300), None, r"triangle 0"),
        (np.zeros((2, 3, 3)), 0, r"threads must be a positive integer"),
        (np.zeros((2, 3, 3)), True, r"threads must be a positive integer"),
    ],
)
def test_bad_input_says_what_was_wrong(triangles, threads, match):
    with pytest.raises(InvalidArgumentError, match=match):
        TriangleSet(triangles, threads=threads)
