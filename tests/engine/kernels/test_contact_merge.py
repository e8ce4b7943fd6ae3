"""``contact_kernel``'s shortcuts change no result beyond rounding: rows equal to the row
before are counted, not repeated (``_merge`` weighs each distinct row by its copies);
``_merge`` skips the sort of overlaps already in non-increasing order and gives a point
equal to the one before the same cluster. Checked
against a plain Python transcription of the documented algorithm on rows with many repeats
(the pole fans of the "aligned" sphere grid give hundreds of equal rows a body pair)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from engine.kernels.collision.contact_merge import (
    _deepest_first,
    _merge,
    _radix_order,
    contact_kernel,
    key_order,
)


def _reference_merge(points, normals, overlaps, radius):
    order = np.argsort(-overlaps, kind="mergesort")
    first, label = [], np.empty(len(points), np.int64)
    for s in order:
        best, best_d2 = -1, radius * radius
        for c, f in enumerate(first):
            d2 = float(((f - points[s]) ** 2).sum())
            if d2 < best_d2:
                best, best_d2 = c, d2
        if best < 0:
            first.append(points[s].copy())
            best = len(first) - 1
        label[s] = best
    k = len(first)
    out_p, out_n, out_o = np.zeros((k, 3)), np.zeros((k, 3)), np.zeros(k)
    count = np.zeros(k)
    for s in order:
        c = label[s]
        if count[c] == 0:
            out_n[c] = normals[s]
        count[c] += 1
        out_o[c] += overlaps[s]
        out_p[c] += points[s]
    return out_p / count[:, None], out_n, out_o / count


def _repeated_rows(rng, m, distinct):
    """``m`` rows drawn from ``distinct`` values, in runs (as a fan's rows come)."""
    values = rng.normal(size=(distinct, 3))
    runs = np.sort(rng.integers(0, distinct, size=m))
    return values[runs], runs


@pytest.mark.parametrize("seed", range(6))
def test_deepest_first_is_the_stable_argsort(seed):
    rng = np.random.default_rng(seed)
    for overlaps in (
        np.sort(rng.integers(0, 4, 50).astype(float))[::-1].copy(),  # sorted, with ties
        rng.integers(0, 4, 50).astype(float),
        np.r_[1.0, 1.0, np.nan, 0.5],
        np.r_[np.nan, 1.0],
        np.zeros(0),
        np.r_[0.0, -0.0, 0.0],
    ):
        got = _deepest_first(overlaps)
        np.testing.assert_array_equal(got, np.argsort(-overlaps, kind="mergesort"))


@pytest.mark.parametrize("radius", [0.0, 0.3, 1.5])
@pytest.mark.parametrize("seed", range(4))
def test_merge_of_repeated_points_is_the_greedy_merge(seed, radius):
    rng = np.random.default_rng(seed)
    m = 300
    points, runs = _repeated_rows(rng, m, 7)
    normals = rng.normal(size=(m, 3))
    overlaps = rng.integers(0, 3, 7).astype(float)[runs]
    if seed % 2:
        overlaps = np.sort(overlaps)[::-1].copy()  # the sort-free path
    k_out = np.empty((m, 3)), np.empty((m, 3)), np.empty(m)
    k = _merge(points, normals, overlaps, np.ones(m), radius, *k_out)
    want = _reference_merge(points, normals, overlaps, radius)
    assert k == len(want[0])
    for got, ref in zip(k_out, want, strict=True):
        np.testing.assert_allclose(got[:k], ref, rtol=1e-14, atol=1e-15)


@pytest.mark.parametrize("seed", range(4))
def test_contact_kernel_on_repeated_rows(seed):
    """Rows in runs of equal values (some with coincident points, which take A's face
    normal, so a run of those must not reuse a row of another face) give the documented
    points, normals and overlaps."""
    rng = np.random.default_rng(seed)
    m, n_faces = 200, 50
    pa, runs = _repeated_rows(rng, m, 9)
    gap = rng.normal(scale=0.01, size=(9, 3))
    gap[::3] = 0.0  # coincident points
    pb = pa + gap[runs]
    distance = np.linalg.norm(pb - pa, axis=1)
    node_i = np.arange(m) % n_faces  # node t is face t; keys distinct and sorted
    node_j = np.arange(m) // n_faces
    node_i, node_j = np.sort(node_j), node_i  # (face_a, face_b) in order
    status = np.ones(m, np.int8)
    found = (node_i, node_j, distance, pa.T.copy(), pb.T.copy(), status)
    face = np.arange(n_faces, dtype=np.int32)
    normals_a = rng.normal(size=(n_faces, 3))
    normals_a /= np.linalg.norm(normals_a, axis=1)[:, None]
    ea, eb, tiny, radius = 0.02, 0.01, 1e-9, 0.01
    setup = (ea, eb, tiny, radius, np.eye(3), np.zeros(3))
    out = (np.empty((m, 2), np.int64), np.empty((m, 3)), np.empty((m, 3)), np.empty(m))
    mm, k = contact_kernel(found, m, face, face, n_faces, True, normals_a, setup, out)
    assert mm == m
    np.testing.assert_array_equal(out[0], np.c_[node_i, node_j])
    g = pb - pa
    length = np.linalg.norm(g, axis=1)
    points = pa + ea / (ea + eb) * g
    normals = np.where((length > tiny)[:, None], g / np.where(length > 0, length, 1)[:, None], 0)
    normals[length <= tiny] = normals_a[node_i[length <= tiny]]
    overlaps = np.clip(ea + eb - distance, 0, ea + eb)
    want = _reference_merge(points, normals, overlaps, radius)
    assert k == len(want[0])
    for got, ref in zip(out[1:], want, strict=True):
        np.testing.assert_allclose(got[:k], ref, rtol=1e-13, atol=1e-15)


@pytest.mark.parametrize("radius", [1e-9, 0.3, 1.5])
@pytest.mark.parametrize("seed", range(4))
def test_a_weighted_row_merges_as_its_copies(seed, radius):
    """A row standing for w equal rows merges as those w rows would (rounding apart), for
    any merge radius above 0 (``contact_kernel`` counts copies only then)."""
    rng = np.random.default_rng(seed)
    m = 40
    points, runs = _repeated_rows(rng, m, 11)
    normals = rng.normal(size=(m, 3))
    overlaps = rng.integers(0, 3, 11).astype(float)[runs]
    copies = rng.integers(1, 6, m).astype(float)
    k_out = np.empty((m, 3)), np.empty((m, 3)), np.empty(m)
    k = _merge(points, normals, overlaps, copies, radius, *k_out)
    expanded = np.repeat(np.arange(m), copies.astype(int))
    want = _reference_merge(points[expanded], normals[expanded], overlaps[expanded], radius)
    assert k == len(want[0])
    for got, ref in zip(k_out, want, strict=True):
        np.testing.assert_allclose(got[:k], ref, rtol=1e-14, atol=1e-15)


@settings(max_examples=60, deadline=None)
@given(
    size=st.integers(1, 700),
    bits=st.integers(1, 62),
    runs=st.integers(1, 40),
    seed=st.integers(0, 2**32 - 1),
)
def test_key_order_is_argsorts_permutation_on_runs(size, bits, runs, seed):
    """Distinct non-negative keys of up to 62 bits in ``runs`` sorted runs (the traversal
    reports its leaf pairs so): ``key_order`` (its radix sort from ``RADIX_FROM`` keys,
    its merge of two runs, or ``np.argsort``) and ``_radix_order`` itself give
    ``np.argsort``'s permutation."""
    rng = np.random.default_rng(seed)
    keys = np.unique(rng.integers(0, 2**bits, size=size, dtype=np.int64))
    rng.shuffle(keys)
    cuts = np.sort(rng.choice(np.arange(1, max(len(keys), 2)), size=runs - 1))
    keys = np.concatenate([np.sort(part) for part in np.split(keys, cuts)])
    np.testing.assert_array_equal(key_order(keys), np.argsort(keys))
    np.testing.assert_array_equal(_radix_order(keys), np.argsort(keys))
