"""The fast paths of engine.geometry.distance from raw arrays (kernels in
engine/kernels/geometry/triangle_paired.py): TriangleSet preparation in one kernel pass, and
the paired form preparing blocks inside its kernel with vectorised closest points.

Each is compared bit for bit with the path it replaced, rebuilt here from its parts: the
numpy largest-angle-first rotation, ``frames_kernel`` on float64 coordinates, and
``triangle_batch.paired_kernel`` (scalar ``exact_point`` closest points), which stays the
kernel of ``mesh_distance``. The one exception: when a triangle's two longest edges are equal
up to rounding, numpy's sum and the kernel's (fused multiply-adds) may pick different ones as
"longest"; either rotation is valid, and results then agree within float rounding.
Distances are checked against the naive oracle of engine.geometry.reference, degenerate
triangles and float32 included.
"""

from __future__ import annotations

import numpy as np
import pytest
from paired_rounding import assert_same_field

from engine import (
    InvalidArgumentError,
    PairStatus,
    TriangleSet,
    triangle_contacts,
    triangle_distances,
)
from engine.arguments import check_kernel, kernel_constants
from engine.geometry.reference import triangle_distances_naive
from engine.kernels.geometry import triangle_batch as tb

KERNELS = ("exact", "iterative", "hybrid")
PRECISIONS = ("float64", "float32")
FIELDS = ("distance", "lower", "point_a", "point_b", "status")


def _old_set(tri: np.ndarray, precision: str) -> TriangleSet:
    """The preparation before the kernel: numpy rotation, frames_kernel in float64."""
    tri = np.asarray(tri, np.float64)
    opposite = np.stack(
        [
            np.einsum("ij,ij->i", tri[:, 2] - tri[:, 1], tri[:, 2] - tri[:, 1]),
            np.einsum("ij,ij->i", tri[:, 0] - tri[:, 2], tri[:, 0] - tri[:, 2]),
            np.einsum("ij,ij->i", tri[:, 1] - tri[:, 0], tri[:, 1] - tri[:, 0]),
        ],
        axis=1,
    )
    order = (np.argmax(opposite, axis=1)[:, None] + np.arange(3)[None, :]) % 3
    rotated = np.take_along_axis(tri, order[:, :, None], axis=1)
    coords = np.ascontiguousarray(rotated.reshape(-1, 9).T)
    frames = np.empty((14, len(tri)))
    dtype = np.dtype(precision).type
    tb.frames_kernel(coords, frames, 1.0, float(kernel_constants(dtype)[1]))
    return TriangleSet.prepared(coords.astype(dtype), frames.astype(dtype))


def _ambiguous(tri: np.ndarray) -> np.ndarray:
    """``(n,)`` bool: the two longest edges are equal within 1e-9 (relative), so which one
    is "longest" depends on rounding."""
    tri = np.asarray(tri, np.float64)
    sq = np.sort(((tri - np.roll(tri, 1, axis=1)) ** 2).sum(axis=2), axis=1)
    return sq[:, 2] - sq[:, 1] <= 1e-9 * sq[:, 2]


def _old_paired(a, b, kernel, precision, eps):
    """triangle_distances as it was: two old sets and triangle_batch.paired_kernel."""
    sa, sb = _old_set(a, precision), _old_set(b, precision)
    dtype = np.dtype(precision).type
    n = len(sa)
    one, band = kernel_constants(dtype)
    params = (check_kernel(kernel), np.int64(1), dtype(0.01), one, band)
    out = [np.empty(n, dtype), np.empty(n, dtype), np.empty((3, n), dtype)]
    out += [np.empty((3, n), dtype), np.empty(n, np.int8)]
    stats = np.zeros(tb.N_STATS, np.int64)
    e = np.full(n, eps, dtype)
    tb.paired_kernel(sa.coords, sa.frames, sb.coords, sb.frames, e, 0, n, params, *out, stats)
    return out[0], out[1], out[2].T, out[3].T, out[4], stats


def _degenerate(rng: np.random.Generator, n: int) -> np.ndarray:
    """Zero-area triangles (repeated vertices, collinear), needles, slivers, isosceles and
    equilateral ones (ties between the longest edges), at random poses and scales."""
    kinds = []
    p, q = rng.normal(size=(n, 3)), rng.normal(size=(n, 3))
    kinds.append(np.stack([p, p, p], 1))  # a point
    kinds.append(np.stack([p, q, q], 1))  # a segment, repeated vertex
    kinds.append(np.stack([p, q, 0.3 * p + 0.7 * q], 1))  # collinear
    kinds.append(np.stack([p, q, q + 1e-4 * rng.normal(size=(n, 3))], 1))  # needle
    kinds.append(np.stack([p, q, 0.5 * (p + q) + 1e-4 * rng.normal(size=(n, 3))], 1))  # sliver
    iso = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]])  # two equal short edges
    equi = np.array([[0.0, 0, 0], [1, 0, 0], [0.5, np.sqrt(3) / 2, 0]])
    for base in (iso, equi):
        shift = rng.normal(size=(n, 1, 3))
        kinds.append(np.roll(base, rng.integers(3), axis=0)[None] * 2.0 + shift)
    tri = np.concatenate(kinds)
    return tri * 10 ** rng.uniform(-2, 2, size=(len(tri), 1, 1))


def _pairs(seed: int, n: int = 700) -> tuple[np.ndarray, np.ndarray]:
    """Random pairs: separated, near, intersecting, and degenerate against anything; more
    than one block (256) and a tail."""
    rng = np.random.default_rng(seed)
    a = rng.normal(size=(n, 3, 3))
    b = (
        rng.normal(size=(n, 3, 3))
        + rng.normal(size=(n, 1, 3)) * rng.choice([0.0, 0.5, 3.0], n)[:, None, None]
    )
    deg = _degenerate(rng, 40)
    other = deg[rng.permutation(len(deg))] + rng.normal(scale=0.2, size=(len(deg), 1, 3))
    return np.concatenate([a, deg, other]), np.concatenate([b, other, deg])


@pytest.mark.parametrize("precision", PRECISIONS)
@pytest.mark.parametrize("input_dtype", ["float64", "float32"])
def test_triangle_set_equals_the_numpy_preparation(precision, input_dtype):
    a, b = _pairs(1)
    tri = np.concatenate([a, b]).astype(input_dtype)
    new, old = TriangleSet(tri, precision), _old_set(tri, precision)
    assert new.dtype == np.dtype(precision) and len(new) == len(tri)
    tie = _ambiguous(tri)
    assert 0 < tie.sum() < len(tri) // 4  # equilateral triangles, points, ...
    for name in ("coords", "frames"):
        np.testing.assert_array_equal(
            getattr(new, name)[:, ~tie], getattr(old, name)[:, ~tie], err_msg=name
        )
    np.testing.assert_array_equal(new.coords_rm, new.coords.T)
    np.testing.assert_array_equal(new.frames_rm, new.frames.T)
    assert new.coords_rm.flags.c_contiguous and new.coords_rm.shape == (len(tri), 9)
    # at a tie: the same triangle, its vertices rotated (orientation kept)
    got = new.coords[:, tie].T.reshape(-1, 3, 3)
    want = tri[tie].astype(precision)
    rotations = np.stack([np.roll(want, -k, axis=1) for k in range(3)])
    assert (rotations == got[None]).all(axis=(2, 3)).any(axis=0).all()


@pytest.mark.parametrize("precision", PRECISIONS)
@pytest.mark.parametrize("kernel", KERNELS)
def test_paired_from_arrays_equals_the_previous_path(kernel, precision):
    a, b = _pairs(2)
    old = _old_paired(a, b, kernel, precision, 0.05)
    tie = _ambiguous(a) | _ambiguous(b)
    x, y = a, b
    scale = np.abs(np.concatenate([a, b], axis=1)).max(axis=(1, 2))
    if precision == "float32" and kernel != "exact":
        # float32 one sweep on raw arrays prepares in float32 (paired_fused.native_block,
        # checked in test_triangle_paired_fused.py); prepared sets take the block path
        x, y = TriangleSet(a, precision), TriangleSet(b, precision)
    for threads in (1, 2):
        new = triangle_distances(x, y, kernel, precision, 0.05, threads=threads)
        for name, want in zip(FIELDS, old, strict=False):
            got = getattr(new, name)
            assert got.dtype == want.dtype and got.shape == want.shape, name
            assert_same_field(
                name, got[~tie], want[~tie], scale[~tie], f"{name}, {threads} threads"
            )
        if kernel == "exact":  # at ties: the same distance within rounding
            size = np.ptp(np.concatenate([a, b], axis=1), axis=1).max(axis=1)[tie]
            rel = 1e-12 if precision == "float64" else 1e-5
            np.testing.assert_array_less(np.abs(new.distance[tie] - old[0][tie]), rel * size)
        assert new.point_a.flags.c_contiguous and new.point_b.flags.c_contiguous
        stats = old[5]
        assert (new.stats.pairs, new.stats.iterative, new.stats.fallbacks) == (
            stats[tb.STAT_PAIRS],
            stats[tb.STAT_ITERATIVE],
            stats[tb.STAT_FALLBACKS],
        )
    if kernel == "hybrid":
        assert new.stats.fallbacks > 256  # the fallback queue was resolved more than once


@pytest.mark.parametrize("precision", PRECISIONS)
def test_paired_exact_matches_the_oracle_on_degenerate_triangles(precision):
    rng = np.random.default_rng(3)
    deg = _degenerate(rng, 30)
    a = deg
    b = deg[rng.permutation(len(deg))] + rng.normal(scale=0.3, size=(len(deg), 1, 3))
    r = triangle_distances(a.astype(precision), b.astype(precision), "exact", precision)
    x, y = a.astype(precision).astype(float), b.astype(precision).astype(float)
    d, _, _ = triangle_distances_naive(x, y)
    size = np.ptp(np.concatenate([x, y], axis=1), axis=1).max(axis=1)
    tol = (1e-9 if precision == "float64" else 2e-5) * size
    np.testing.assert_array_less(np.abs(r.distance - d), tol + 1e-300)
    gap = np.linalg.norm(r.point_a.astype(float) - r.point_b, axis=1)
    np.testing.assert_array_less(np.abs(gap - r.distance), tol + 1e-300)


def test_mixed_sets_and_arrays_and_awkward_inputs_agree():
    a, b = _pairs(4, 300)
    sa, sb = TriangleSet(a, "float32"), TriangleSet(b, "float32")
    want = triangle_distances(sa, sb, "hybrid", "float32", 0.05)
    # raw arrays: float32 preparation (paired_fused.native_block), the same for any layout
    want_raw = triangle_distances(a, b, "hybrid", "float32", 0.05)
    np.testing.assert_array_equal(want_raw.status, want.status)
    variants = {
        "sets": (sa, sb),
        "set, array": (sa, b),
        "array, set": (a, sb),
        "lists": (a.tolist(), b.tolist()),
        "fortran": (np.asfortranarray(a), b),
        "read-only": (a.copy(), b.copy()),
    }
    for arr in variants["read-only"]:
        arr.flags.writeable = False
    scale = np.abs(np.concatenate([a, b], axis=1)).max(axis=(1, 2))
    for name, (x, y) in variants.items():
        got = triangle_distances(x, y, "hybrid", "float32", 0.05)
        ref = want if isinstance(x, TriangleSet) or isinstance(y, TriangleSet) else want_raw
        for field in FIELDS:  # float32 points: their last bits vary between calls (AVX-512)
            assert_same_field(field, getattr(got, field), getattr(ref, field), scale, name)


@pytest.mark.parametrize("precision", PRECISIONS)
@pytest.mark.parametrize("kernel", KERNELS)
def test_contacts_from_arrays_equal_contacts_from_sets(kernel, precision):
    a, b = _pairs(5, 200)
    a, b = a[~_ambiguous(a)], b[~_ambiguous(b)]  # (ties: see the module's docstring)
    a = a[: len(b)]
    b = b[: len(a)]
    pairs = np.stack([np.arange(len(a)), np.arange(len(a))[::-1]], 1)
    for listed in (None, pairs):
        got = triangle_contacts(a, b, 0.1, 0.1, pairs=listed, kernel=kernel, precision=precision)
        sa, sb = _old_set(a, precision), _old_set(b, precision)
        want = triangle_contacts(sa, sb, 0.1, 0.1, pairs=listed, kernel=kernel, precision=precision)
        assert len(got) == len(want) > 0
        for field in ("pairs", "distance", "point_a", "point_b", "status"):
            np.testing.assert_array_equal(getattr(got, field), getattr(want, field), field)


@pytest.mark.parametrize(
    ("bad", "precision", "match"),
    [
        (np.nan, "float64", "a has a non-finite coordinate in triangle 300"),
        (np.inf, "float32", "a has a non-finite coordinate in triangle 300"),
        (1e30, "float32", r"a has a coordinate beyond .* in triangle 300"),
    ],
)
def test_invalid_coordinates_found_by_the_kernels_are_reported(bad, precision, match):
    a, b = _pairs(6, 400)
    a[300, 1, 2] = bad
    with pytest.raises(InvalidArgumentError, match=match):
        triangle_distances(a, b, "hybrid", precision)
    with pytest.raises(InvalidArgumentError, match=match):
        TriangleSet(a, precision, "a")
    with pytest.raises(InvalidArgumentError, match=match.replace("a has", "b has")):
        triangle_distances(b, a, "exact", precision, threads=2)


def test_statuses_of_the_paired_exact_form():
    a, b = _pairs(7, 300)
    r = triangle_distances(a, b, "exact", "float64", 0.3)
    np.testing.assert_array_equal(r.status == PairStatus.CONTACT, r.distance <= 0.3)
    np.testing.assert_array_equal(r.lower, r.distance)
