"""Tests of engine.triangle_distances: analytic cases, the naive reference, bad input.

Expected values are analytic (each case says why) or come from
:mod:`engine.geometry.reference`, which is written independently of the kernels.
Properties (hypothesis) and the contact forms are in test_distance_properties.py.
"""

from __future__ import annotations

import numpy as np
import pytest

import engine
from engine import InvalidArgumentError, PairStatus, TriangleSet, triangle_distances
from engine.geometry.reference import (
    point_triangle_distance_naive,
    segment_segment_naive,
    triangle_distance_naive,
    triangle_distances_naive,
)

KERNELS = ("exact", "iterative", "hybrid")
PRECISIONS = ("float64", "float32")
RTOL = 0.01  # engine.geometry.distance.DEFAULT_RTOL, the convergence tolerance of the certificate
REL = {"float64": 1e-12, "float32": 1e-5}  # accuracy expected of a kernel, times the size
NC, CONTACT, NO = PairStatus.NOT_CONVERGED, PairStatus.CONTACT, PairStatus.NO_CONTACT


def rotation(rng: np.random.Generator) -> np.ndarray:
    """A uniformly random proper rotation (3, 3)."""
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q = q * np.sign(np.diag(r))
    return q if np.linalg.det(q) > 0 else -q


def size_of(a: np.ndarray, b: np.ndarray) -> float:
    """Extent of a pair about its own position: the scale of its rounding errors."""
    pts = np.concatenate([a.reshape(-1, 3), b.reshape(-1, 3)])
    return float(np.ptp(pts, axis=0).max())


def on_triangle(p: np.ndarray, tri: np.ndarray) -> float:
    return point_triangle_distance_naive(p, tri)


def decided_contact(r, eps: np.ndarray) -> np.ndarray:
    """Final decision of a kernel: certified contact, or (fallback) exact distance ≤ ε."""
    return (r.status == CONTACT) | ((r.status == NC) & (r.distance <= eps))


# ============================================================================ analytic
# Each case: (a, b, distance, point_a or None, point_b or None). The distance follows
# from a separating slab (A on one side of a plane, B at distance d on the other)
# plus a pair of points at distance d; points are given where the pair is unique.
STD = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
W = 1e-4  # width / length of the needle and the sliver
NEEDLE = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, W, 0.0]])  # short edge v1 v2
SLIVER = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.5, W, 0.0]])  # apex near an edge


def _skew(theta: float, h: float):
    # A ⊂ {z ≤ 0} touching z = 0 only along its edge on the x axis; B ⊂ {z ≥ h} touching
    # z = h only along its edge through (0, 0, h) in direction (cos θ, sin θ, 0). The
    # edges cross in projection at the origin: common perpendicular (0,0,0)-(0,0,h).
    c, s = np.cos(theta), np.sin(theta)
    a = np.array([[-1.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.25, -1.0, -1.0]])
    b = np.array([[-c, -s, h], [c, s, h], [0.25, 1.0, 1.0 + h]])
    return a, b, h, np.zeros(3), np.array([0.0, 0.0, h])


def _vertex_above(tri: np.ndarray, h: float):
    # A vertex of B at height h over the centroid of the flat ``tri``; B ⊂ {z ≥ h}.
    c = tri.mean(axis=0)
    b = np.array([c + [0, 0, h], c + [0.25, 0.5, 1 + h], c + [-0.5, 0.25, 1 + h]])
    return tri, b, h, c, c + [0, 0, h]


SHALLOW = 0.02  # radians


def analytic_cases() -> dict:
    cases = {}
    g = 0.5
    # A ⊂ {z = 0}, B ⊂ {z = g}, overlapping in projection (points not unique)
    cases["parallel_stacked"] = (STD, STD + [0.25, 0.25, g], g, None, None)
    cases["parallel_stacked_close"] = (STD, STD + [0.25, 0.25, 1e-3], 1e-3, None, None)
    cases["coplanar_overlapping"] = (STD, STD + [0.25, 0.25, 0.0], 0.0, None, None)
    # A ⊂ {x ≤ 1} meeting x = 1 only at (1,0,0); B ⊂ {x ≥ 1 + g}, edge x = 1 + g, y ∈ [0, 1]
    b = np.array([[1 + g, 0, 0], [1 + g, 1, 0], [2 + g, 0, 0]])
    cases["coplanar_disjoint"] = (STD, b, g, np.array([1.0, 0, 0]), np.array([1 + g, 0, 0]))
    for name, theta in (("perpendicular", np.pi / 2), ("oblique", 0.6), ("shallow", SHALLOW)):
        cases[f"skew_edges_{name}"] = _skew(theta, 0.375)
    cases["vertex_face"] = _vertex_above(STD, 0.375)
    a, b, d, pa, pb = cases["vertex_face"]
    cases["face_vertex"] = (b, a, d, pb, pa)
    # A ⊂ {x ≤ 1}, B ⊂ {x ≥ 1}; A ∩ {x = 1} = {(1, 0, 0)}, a vertex of B
    b = np.array([[1.0, 0, 0], [2, 0, 0], [1, 0, 1]])
    cases["touching_vertex"] = (STD, b, 0.0, np.array([1.0, 0, 0]), np.array([1.0, 0, 0]))
    # A ⊂ {y ≥ 0}, B ⊂ {y ≤ 0}, sharing the edge (0,0,0)-(1,0,0)
    cases["touching_edge"] = (STD, np.array([[0, 0, 0], [1, 0, 0], [0.5, -1, 0.5]]), 0, None, None)
    cases["vertex_on_face"] = _vertex_above(STD, 0.0)
    # B crosses z = 0 along (0.375,0.25,0)-(0.25,0.375,0), inside A
    b = np.array([[0.25, 0.25, -0.5], [0.5, 0.25, 0.5], [0.25, 0.5, 0.5]])
    cases["piercing"] = (STD, b, 0.0, None, None)
    cases["piercing_swapped"] = (b, STD, 0.0, None, None)
    # needle / sliver (aspect 1e-4), each also with its vertices rolled (the kernels
    # treat vertex 0 specially)
    for name, tri in (("needle", NEEDLE), ("sliver", SLIVER)):
        for roll in (0, 1):
            t = np.roll(tri, roll, axis=0)
            key = f"{name}{roll}"
            big = np.array([[-1.0, -1.0, -g], [3.0, -1.0, -g], [-1.0, 3.0, -g]])
            cases[f"{key}_above_face"] = (t, big, g, None, None)
            cases[f"{key}_vertex_above"] = _vertex_above(t, 0.25)
            # a big triangle in the plane x = 0.5 cuts across the needle
            cut = np.array([[0.5, -1.0, -1.0], [0.5, 2.0, -1.0], [0.5, 0.5, 2.0]])
            cases[f"{key}_cut"] = (t, cut, 0.0, None, None)
            # skew: B ⊂ {z ≥ h} with its edge x = 0.5 over the needle's long edge
            b = np.array([[0.5, -1.0, 0.25], [0.5, 1.0, 0.25], [0.5, 0.0, 1.25]])
            cases[f"{key}_skew"] = (t, b, 0.25, None, None)
    return cases


CASES = analytic_cases()
MOTION = np.random.default_rng(20240611)
MOTIONS = {"axis": (np.eye(3), np.zeros(3)), "moved": (rotation(MOTION), MOTION.normal(size=3))}


def _moved(case, motion):
    r, t = MOTIONS[motion]
    a, b, d, pa, pb = case
    mv = lambda x: None if x is None else np.asarray(x, float) @ r.T + t  # noqa: E731
    return mv(a), mv(b), d, mv(pa), mv(pb)


def check_pair(a, b, d, pa, pb, kernel, precision, *, ptol=0.0):
    """Check one pair against its analytic distance under several contact distances.

    ``ptol`` loosens the comparison of the closest points with ``pa``, ``pb``.
    """
    size = size_of(a, b)
    tol = REL[precision] * size
    epsilons = np.array([0.0, d + 0.1 * size, max(d - 0.1 * size, 0.0), d + 1.0 * size])
    n = len(epsilons)
    r = triangle_distances(
        np.repeat(a[None], n, 0), np.repeat(b[None], n, 0), kernel, precision, epsilons
    )
    dtype = np.dtype(precision)
    assert r.distance.dtype == dtype and r.point_a.shape == (n, 3) and r.status.dtype == np.int8
    assert np.isfinite(r.distance).all() and np.isfinite(r.lower).all()
    for k in range(n):
        assert r.lower[k] - tol <= d <= r.distance[k] + tol, (k, r.lower[k], r.distance[k])
        assert on_triangle(r.point_a[k], a) <= tol and on_triangle(r.point_b[k], b) <= tol
        gap = np.linalg.norm(r.point_a[k].astype(float) - r.point_b[k])
        assert gap == pytest.approx(float(r.distance[k]), abs=tol)
        exact_answer = kernel == "exact" or (kernel == "hybrid" and r.status[k] == NC)
        if exact_answer:
            assert r.distance[k] == pytest.approx(d, abs=tol)
            if pa is not None:
                np.testing.assert_allclose(r.point_a[k], pa, atol=tol + ptol)
                np.testing.assert_allclose(r.point_b[k], pb, atol=tol + ptol)
        if r.status[k] == CONTACT:
            assert r.distance[k] - d <= RTOL * epsilons[k] + tol
        if abs(epsilons[k] - d) > 2 * tol:  # clear-cut classification
            in_contact = d <= epsilons[k]
            if kernel == "exact":
                assert r.status[k] == (CONTACT if in_contact else NO)
            elif r.status[k] != NC:
                assert (r.status[k] == CONTACT) == in_contact
            if kernel != "iterative":
                assert decided_contact(r, epsilons)[k] == in_contact
    if kernel == "exact":
        np.testing.assert_array_equal(r.lower, r.distance)
    if kernel != "exact" and d > 0:
        # Separated pairs: three sweeps find the closest features. (The default, one sweep,
        # only promises a certified bracket lower <= d <= distance, checked above.)
        r3 = triangle_distances(a[None], b[None], kernel, precision, 0.0, iterations=3)
        assert r3.distance[0] == pytest.approx(d, abs=tol)
    return r


@pytest.mark.parametrize("precision", PRECISIONS)
@pytest.mark.parametrize("kernel", KERNELS)
@pytest.mark.parametrize("motion", sorted(MOTIONS))
@pytest.mark.parametrize("name", sorted(CASES))
def test_analytic_cases(name, motion, kernel, precision):
    # In float32 the thin triangles get no face candidates (see the next test), so a
    # closest point on one may be off by up to its width; closest points of edges at
    # a shallow angle θ move by 1/sin θ times any perturbation.
    thin = name.startswith(("needle", "sliver")) and precision == "float32"
    case = _moved(CASES[name], motion)
    ptol = W if thin else 0.0
    if "shallow" in name:
        ptol = REL[precision] * size_of(case[0], case[1]) / np.sin(SHALLOW)
    check_pair(*case, kernel, precision, ptol=ptol)


@pytest.mark.parametrize("precision", PRECISIONS)
@pytest.mark.parametrize("kernel", KERNELS)
@pytest.mark.parametrize("rolled", [0, 1, 2])
@pytest.mark.parametrize("shape", ["needle", "sliver"])
def test_vertex_touching_the_interior_of_a_needle_or_sliver(shape, rolled, kernel, precision):
    # B's vertex lies on the centroid of the thin triangle, B ⊂ {z ≥ 0}: distance 0.
    # TriangleSet puts each triangle's largest angle at vertex 0, so a needle is exact
    # whatever its vertex order. A cap sliver (largest angle near 180°, sin² below 64 ulp)
    # has no reliable plane in float32: it gets no face candidates and its distance is
    # that of its edges, documented to be within the sliver's width (docs/kernels.md).
    tri = np.roll(NEEDLE if shape == "needle" else SLIVER, rolled, axis=0)
    if shape == "sliver" and precision == "float32":
        a, b = _vertex_above(tri, 0.0)[:2]
        r = triangle_distances(a[None], b[None], kernel, precision, 0.0)
        width = W * size_of(a, b)
        assert 0.0 <= float(r.distance[0]) <= width
        assert float(r.lower[0]) <= float(r.distance[0])
        return
    check_pair(*_vertex_above(tri, 0.0), kernel, precision)


# Two edges at angle θ with a common perpendicular of length h (the _skew case). The
# exact kernel's segment-segment step solves for the closest points of the lines with
# a·e − b² as denominator; for nearly parallel edges that difference is rounding
# noise, the clamped line parameter is arbitrary and the distance comes out too large.
NEARLY_PARALLEL = {"float32": (1e-4, 1e-4), "float64": (1e-8, 1e-11)}  # θ, h
ACCURACY = {"float32": 1e-5, "float64": 1e-9}  # times the size


@pytest.mark.parametrize("precision", PRECISIONS)
def test_nearly_parallel_skew_edges_exact_distance(precision):
    a, b, h, pa, pb = _skew(*NEARLY_PARALLEL[precision])
    assert triangle_distance_naive(a, b)[0] == pytest.approx(h, abs=1e-15)
    tol = ACCURACY[precision] * size_of(a, b)
    r = triangle_distances(a[None], b[None], "exact", precision)
    assert float(r.distance[0]) == pytest.approx(h, abs=tol)


@pytest.mark.parametrize("kernel", KERNELS)
@pytest.mark.parametrize("precision", PRECISIONS)
def test_nearly_parallel_skew_edges_contact_decision(precision, kernel):
    # ε exceeds the true distance h by twice the accuracy expected of the precision,
    # so the pair is in contact; the module docs also promise that the hybrid kernel
    # decides exactly as the exact kernel does.
    a, b, h, pa, pb = _skew(*NEARLY_PARALLEL[precision])
    eps = np.array([h + 2 * ACCURACY[precision] * size_of(a, b)])
    r = triangle_distances(a[None], b[None], kernel, precision, eps)
    if kernel == "iterative":
        assert r.status[0] != NO
    else:
        assert decided_contact(r, eps)[0]


@pytest.mark.parametrize("precision", PRECISIONS)
@pytest.mark.parametrize("kernel", KERNELS)
def test_tiny_heights_do_not_fake_a_crossing(kernel, precision):
    # B lies (up to heights h, 2h above z = 0) in A's plane, in the half-plane
    # x + y ≥ 1.25 while A ⊂ {x + y ≤ 1}: distance 0.25/√2 between (0.25, 1, h) and
    # (0.125, 0.875, 0). With h this small the product of two heights underflows to 0,
    # which the exact kernel's edge-crossing test (heights of opposite sign: product
    # ≤ 0) takes for a crossing; the crossing parameter 2h / (2h − h) = 2 is not
    # clamped to the edge, and the extrapolated point (0.25, 0.5) lies inside A, so
    # the kernel reports distance 0 (a false contact).
    h = {"float64": 1e-170, "float32": 1e-23}[precision]
    b = np.array([[0.25, 1.5, 2 * h], [0.25, 1.0, h], [1.0, 1.5, h]])
    d = 0.25 / np.sqrt(2.0)
    pa, pb = np.array([0.125, 0.875, 0.0]), np.array([0.25, 1.0, h])
    assert triangle_distance_naive(STD, b)[0] == pytest.approx(d, rel=1e-15)
    check_pair(STD, b, d, pa, pb, kernel, precision)


# ---------------------------------------------------------------- far from the origin
FAR = {"float64": (1e4, 1e6), "float32": (1e3,)}


@pytest.mark.parametrize("kernel", KERNELS)
@pytest.mark.parametrize(
    ("precision", "offset"), [(p, o) for p in PRECISIONS for o in FAR[p]], ids=str
)
@pytest.mark.parametrize(
    "name", ["vertex_face", "skew_edges_oblique", "coplanar_disjoint", "piercing", "sliver0_skew"]
)
def test_far_from_the_origin(name, precision, offset, kernel):
    a, b, d, pa, pb = _moved(CASES[name], "moved")
    shift = offset * np.array([1.0, -0.75, 0.5])
    dtype = np.dtype(precision)
    # what the kernel sees: the shifted pair rounded to its precision
    fa, fb = ((x + shift).astype(dtype).astype(float) for x in (a, b))
    size = size_of(a, b)
    tol = REL[precision] * size
    near = triangle_distances(a[None], b[None], kernel, precision)
    far = triangle_distances(fa[None], fb[None], kernel, precision)
    near_d, far_d, far_lower = float(near.distance[0]), float(far.distance[0]), float(far.lower[0])
    # input rounding moves each vertex by at most ~ulp(offset): so does the distance
    moved = 4 * float(np.finfo(dtype).eps) * offset
    ref = triangle_distance_naive(fa, fb)[0]
    assert ref == pytest.approx(d, abs=2 * moved + 1e-12 * size)
    if kernel == "exact" or (kernel == "hybrid" and far.status[0] == NC):
        # the pair-local frame loses nothing beyond the rounding of the input
        assert far_d == pytest.approx(ref, abs=tol)
        assert far_d == pytest.approx(near_d, abs=tol + 2 * moved)
    assert far_lower - tol <= ref <= far_d + tol
    for p, q, tri in ((far.point_a[0], near.point_a[0], fa), (far.point_b[0], near.point_b[0], fb)):
        assert on_triangle(p.astype(float), tri) <= tol + moved
        if pa is not None and kernel == "exact":
            np.testing.assert_allclose(p.astype(float) - shift, q, atol=tol + 2 * moved)


# ============================================================== against the reference
def _random_pairs(seed: int, per_kind: int = 500) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Seeded random pairs of several kinds, each (n, 3, 3) float64 twice."""
    rng = np.random.default_rng(seed)
    n = per_kind

    def tris(m):
        return rng.normal(size=(m, 3, 3))

    def direction(m):
        v = rng.normal(size=(m, 3))
        return v / np.linalg.norm(v, axis=1, keepdims=True)

    kinds = {}
    a = tris(n)
    kinds["separated"] = (a, tris(n) + (3 + 2 * rng.random((n, 1, 1))) * direction(n)[:, None])
    a = tris(n)
    kinds["near"] = (a, tris(n) + (1 + rng.random((n, 1, 1))) * direction(n)[:, None])
    a = tris(n)
    kinds["intersecting"] = (a, 0.5 * tris(n) + a.mean(axis=1, keepdims=True))
    # touching: a vertex of B on A (random barycentrics), B's other vertices on one side
    a = tris(n)
    w = rng.dirichlet(np.ones(3), n)
    on_a = np.einsum("nk,nkj->nj", w, a)
    nrm = np.cross(a[:, 1] - a[:, 0], a[:, 2] - a[:, 0])
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    legs = rng.normal(size=(n, 2, 3))
    legs += (np.abs(np.einsum("nkj,nj->nk", legs, nrm)) + 0.1)[..., None] * nrm[:, None]
    kinds["touching"] = (a, np.concatenate([on_a[:, None], on_a[:, None] + legs], axis=1))
    # nearly parallel faces: B = A turned by 1e-6..1e-1 rad about its centroid, lifted
    # along A's normal by 0..0.3 (either side) and slid in A's plane
    a = tris(n)
    b = np.empty_like(a)
    for t in range(n):
        axis = rng.normal(size=3)
        axis /= np.linalg.norm(axis)
        ang = 10 ** rng.uniform(-6, -1)
        k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
        r = np.eye(3) + np.sin(ang) * k + (1 - np.cos(ang)) * k @ k
        c = a[t].mean(axis=0)
        m = np.cross(a[t, 1] - a[t, 0], a[t, 2] - a[t, 0])
        m /= np.linalg.norm(m)
        slide = rng.normal(size=3)
        slide -= (slide @ m) * m
        lift = rng.choice([0.0, 1e-4, 1e-2, 0.3]) * rng.uniform(-1, 1)
        b[t] = (a[t] - c) @ r.T + c + lift * m + 0.5 * slide
    kinds["parallel_faces"] = (a, b)
    # nearly parallel skew edges (angles 1e-6..1e-1) at gaps 1e-6..1, moved rigidly
    a = np.empty((n, 3, 3))
    b = np.empty((n, 3, 3))
    for t in range(n):
        x, y, _, _, _ = _skew(10 ** rng.uniform(-6, -1), 10 ** rng.uniform(-6, 0))
        r, s = rotation(rng), rng.normal(size=3)
        a[t], b[t] = x @ r.T + s, y @ r.T + s
    kinds["parallel_edges"] = (a, b)
    # every kind at scales 1e-2..1e2
    for key, (a, b) in kinds.items():
        s = 10 ** rng.uniform(-2, 2, size=(n, 1, 1))
        kinds[key] = (a * s, b * s)
    return kinds


@pytest.fixture(scope="module")
def random_pairs():
    kinds = _random_pairs(7)
    a = np.concatenate([kinds[k][0] for k in kinds])
    b = np.concatenate([kinds[k][1] for k in kinds])
    kind = np.concatenate([[k] * len(kinds[k][0]) for k in kinds])
    d, pa, pb = triangle_distances_naive(a, b)
    size = np.array([size_of(x, y) for x, y in zip(a, b, strict=True)])
    return {"a": a, "b": b, "kind": kind, "d": d, "pa": pa, "pb": pb, "size": size}


def test_random_pairs_cover_every_regime(random_pairs):
    rel = random_pairs["d"] / random_pairs["size"]
    assert (rel == 0).sum() > 300  # touching and intersecting
    assert ((rel > 0) & (rel < 1e-3)).sum() > 100  # near contact
    assert (rel > 0.3).sum() > 300  # well separated


def _assert_points(a, b, pa, pb, dist, tol):
    gap = np.linalg.norm(pa.astype(float) - pb, axis=1)
    np.testing.assert_array_less(np.abs(gap - dist), tol)
    for t in range(len(a)):
        assert on_triangle(pa[t].astype(float), a[t]) <= tol[t], t
        assert on_triangle(pb[t].astype(float), b[t]) <= tol[t], t


def test_exact_float64_matches_the_reference(random_pairs):
    a, b, d, size = (random_pairs[k] for k in ("a", "b", "d", "size"))
    r = triangle_distances(a, b, "exact", "float64")
    tol = 1e-9 * size
    bad = np.flatnonzero(np.abs(r.distance - d) > tol)
    assert not len(bad), [(random_pairs["kind"][t], d[t], r.distance[t]) for t in bad[:5]]
    _assert_points(a, b, r.point_a, r.point_b, r.distance, tol + 1e-300)
    # the reference's own points are consistent too
    _assert_points(a, b, random_pairs["pa"], random_pairs["pb"], d, tol + 1e-300)


def test_exact_float32_matches_the_reference(random_pairs):
    # Nearly parallel skew edges are excluded: see test_nearly_parallel_skew_edges_exact_kernel.
    keep = random_pairs["kind"] != "parallel_edges"
    a, b, size = random_pairs["a"][keep], random_pairs["b"][keep], random_pairs["size"][keep]
    r = triangle_distances(a, b, "exact", "float32")
    d = triangle_distances_naive(a.astype(np.float32), b.astype(np.float32))[0]
    tol = 1e-5 * size
    bad = np.flatnonzero(np.abs(r.distance - d) > tol)
    assert not len(bad), [(d[t], r.distance[t], size[t]) for t in bad[:5]]
    _assert_points(a, b, r.point_a, r.point_b, r.distance, 2 * tol)


@pytest.mark.parametrize("kernel", ["iterative", "hybrid"])
def test_iterative_and_hybrid_float64_against_exact(random_pairs, kernel):
    a, b, size = random_pairs["a"], random_pairs["b"], random_pairs["size"]
    n = len(a)
    exact = triangle_distances(a, b, "exact", "float64").distance
    rng = np.random.default_rng(3)
    tol = 1e-12 * size
    for eps in (
        np.zeros(n),
        exact * rng.uniform(0.5, 1.5, n) + 1e-3 * size * rng.random(n),
        exact + 1e-6 * size * rng.uniform(-1, 1, n),
        exact + size,
    ):
        eps = np.maximum(eps, 0.0)
        r = triangle_distances(a, b, kernel, "float64", eps)
        st = r.status
        assert set(np.unique(st)) <= {NO, CONTACT, NC}
        assert r.stats.pairs == n and r.stats.iterative == n and r.stats.culled == 0
        assert r.stats.fallbacks == (int((st == NC).sum()) if kernel == "hybrid" else 0)
        # certificate: lower ≤ exact (≤ the returned distance, an upper bound)
        np.testing.assert_array_less(r.lower - tol, exact + 1e-300)
        np.testing.assert_array_less(exact - tol, r.distance + 1e-300)
        # certified classifications are right
        assert (exact[st == CONTACT] <= eps[st == CONTACT]).all()
        assert (exact[st == NO] > eps[st == NO]).all()
        c = st == CONTACT
        np.testing.assert_array_less(r.distance[c] - exact[c], RTOL * eps[c] + tol[c] + 1e-300)
        if kernel == "hybrid":
            # not converged: the exact kernel's answer
            nc = st == NC
            np.testing.assert_array_less(np.abs(r.distance[nc] - exact[nc]), tol[nc] + 1e-300)
            np.testing.assert_array_equal(decided_contact(r, eps), exact <= eps)
        _assert_points(a, b, r.point_a, r.point_b, r.distance, tol + 1e-300)


# ============================================================================ bad input
def _tri(n=2):
    return np.tile(STD, (n, 1, 1))


def _nan():
    t = _tri()
    t[1, 2, 0] = np.nan
    return t


def _inf():
    t = _tri()
    t[0, 1, 2] = np.inf
    return t


BAD_DISTANCES = [
    ({"a": _tri()[:, :, :2]}, r"shape \(n, 3, 3\), got \(2, 3, 2\)"),
    ({"a": STD}, r"shape \(n, 3, 3\)"),
    ({"a": np.zeros((2, 4, 3))}, r"shape \(n, 3, 3\)"),
    ({"a": [["x"] * 3] * 3}, r"numeric"),
    ({"a": _nan()}, r"non-finite coordinate in triangle 1"),
    ({"b": _inf()}, r"non-finite coordinate in triangle 0"),
    ({"b": _tri(3)}, r"pair up: 2 and 3"),
    ({"epsilon": -1.0}, r"epsilon must be finite and non-negative"),
    ({"epsilon": np.array([0.1, -1e-9])}, r"epsilon must be finite and non-negative"),
    ({"epsilon": np.nan}, r"epsilon must be finite"),
    ({"epsilon": np.zeros(3)}, r"epsilon must be a scalar or shape \(2,\)"),
    ({"kernel": "fast"}, r"kernel must be one of \['exact', 'hybrid', 'iterative'\]"),
    ({"kernel": None}, r"kernel must be one of"),
    ({"precision": "float16"}, r"precision must be one of \['float32', 'float64'\]"),
    ({"precision": np.float64}, r"precision must be one of"),
    ({"iterations": 0}, r"iterations must be an integer in \[1, 64\], got 0"),
    ({"iterations": 65}, r"iterations must be an integer in \[1, 64\]"),
    ({"iterations": 2.0}, r"iterations must be an integer"),
    ({"iterations": True}, r"iterations must be an integer"),  # as threads=True is refused
    ({"rtol": -0.1}, r"rtol must be finite and non-negative"),
    ({"rtol": None}, r"rtol must be finite"),
    ({"epsilon": "a"}, r"epsilon must be"),
    ({"rtol": np.inf}, r"rtol must be finite"),
    ({"threads": 0}, r"threads must be a positive integer"),
    ({"threads": 1.5}, r"threads must be a positive integer"),
    ({"threads": True}, r"threads must be a positive integer"),
]


@pytest.mark.parametrize(("change", "match"), BAD_DISTANCES, ids=lambda x: str(x)[:40])
def test_triangle_distances_rejects_bad_input(change, match):
    args = {"a": _tri(), "b": _tri() + [0, 0, 1], "epsilon": 0.0}
    args.update(change)
    with pytest.raises(InvalidArgumentError, match=match):
        triangle_distances(**args)


def test_triangle_set_precision_mismatch_is_rejected():
    s32 = TriangleSet(_tri(), "float32")
    with pytest.raises(
        InvalidArgumentError, match=r"a is a float32 TriangleSet but precision='float64'"
    ):
        triangle_distances(s32, _tri(), precision="float64")
    with pytest.raises(InvalidArgumentError, match=r"b is a float32 TriangleSet"):
        engine.triangle_contacts(_tri(), s32, precision="float64")
    with pytest.raises(InvalidArgumentError, match=r"precision must be one of"):
        TriangleSet(_tri(), "float128")
    with pytest.raises(InvalidArgumentError, match=r"non-finite coordinate in triangle 1"):
        TriangleSet(_nan())


BAD_CONTACTS = [
    ({"pairs": [[0, 2]]}, r"pairs index out of range.*a has 2 and b has 2 triangles"),
    ({"pairs": [[2, 0]]}, r"pairs index out of range"),
    ({"pairs": [[0, -1]]}, r"pairs index out of range"),
    ({"pairs": [[0.0, 1.0]]}, r"pairs must be an integer \(k, 2\) array"),
    ({"pairs": [0, 1]}, r"pairs must be an integer \(k, 2\) array"),
    ({"pairs": [[0, 1, 1]]}, r"pairs must be an integer \(k, 2\) array"),
    ({"pairs": [[True, False]]}, r"pairs must be an integer"),
    ({"epsilon_a": -1.0}, r"epsilon_a must be finite and non-negative"),
    ({"epsilon_b": [0.0, -0.5]}, r"epsilon_b must be finite and non-negative"),
    ({"epsilon_b": [0.0, 0.1, 0.2]}, r"epsilon_b must be a scalar or shape \(2,\)"),
    ({"a": _nan()}, r"non-finite coordinate in triangle 1"),
    ({"b": np.zeros((2, 3))}, r"shape \(n, 3, 3\)"),
    ({"kernel": "Exact"}, r"kernel must be one of"),
    ({"precision": "double"}, r"precision must be one of"),
    ({"iterations": 0}, r"iterations must be an integer in \[1, 64\]"),
]


@pytest.mark.parametrize(("change", "match"), BAD_CONTACTS, ids=lambda x: str(x)[:40])
def test_triangle_contacts_rejects_bad_input(change, match):
    args = {"a": _tri(), "b": _tri() + [0, 0, 1]}
    args.update(change)
    with pytest.raises(InvalidArgumentError, match=match):
        engine.triangle_contacts(**args)


# ==================================================================== degenerate input
DEGENERATE = {
    "repeated_v0_v1": [[0.25, 0.25, 0.0], [0.25, 0.25, 0.0], [0.5, 0.125, 0.0]],
    "repeated_v1_v2": [[0.25, 0.25, 0.0], [0.5, 0.125, 0.0], [0.5, 0.125, 0.0]],
    "point": [[0.25, 0.25, 0.0]] * 3,
    "collinear": [[0.25, 0.25, 0.0], [0.5, 0.125, 0.0], [0.75, 0.0, 0.0]],
}


@pytest.mark.parametrize("precision", PRECISIONS)
@pytest.mark.parametrize("kernel", KERNELS)
@pytest.mark.parametrize("order", ["degenerate_first", "degenerate_second"])
@pytest.mark.parametrize("shape", sorted(DEGENERATE))
def test_zero_area_triangles_are_measured_or_rejected(shape, order, kernel, precision):
    # A zero-area triangle (a segment or a point) 1 below the unit triangle in z = 1,
    # and touching it at (0.25, 0.25, 1) when lifted: the API accepts it, so it must
    # either raise InvalidArgumentError or give the distance (never NaN).
    deg = np.array(DEGENERATE[shape])
    tri = STD + [0.0, 0.0, 1.0]
    for lift, d in ((0.0, 1.0), (1.0, 0.0)):
        x = deg + [0.0, 0.0, lift]
        a, b = (x, tri) if order == "degenerate_first" else (tri, x)
        assert triangle_distance_naive(a, b)[0] == pytest.approx(d, abs=1e-15)
        try:
            r = triangle_distances(a[None], b[None], kernel, precision, 0.5)
        except InvalidArgumentError:
            continue
        assert np.isfinite(r.distance).all() and np.isfinite(r.lower).all()
        assert r.lower[0] - 1e-6 <= d <= r.distance[0] + 1e-6
        if kernel == "exact" or (kernel == "hybrid" and r.status[0] == NC):
            assert r.distance[0] == pytest.approx(d, abs=1e-6)
        if kernel != "iterative":
            assert decided_contact(r, np.array([0.5]))[0] == (d <= 0.5)
        elif r.status[0] != NC:
            assert (r.status[0] == CONTACT) == (d <= 0.5)


def test_reference_segment_segment_textbook_cases():
    # the reference itself, on cases with known answers
    o, x, y = np.zeros(3), np.array([1.0, 0, 0]), np.array([0, 1.0, 0])
    d, p, q = segment_segment_naive(o, x, y + [0.5, 0, 1], -y + [0.5, 0, 1])
    assert d == 1.0 and np.allclose(p, [0.5, 0, 0]) and np.allclose(q, [0.5, 0, 1])
    d, p, q = segment_segment_naive(o, x, x * 2, x * 3)  # collinear, apart
    assert d == 1.0 and np.allclose(p, x) and np.allclose(q, 2 * x)
    d, p, q = segment_segment_naive(o, o, y, y)  # two points
    assert d == 1.0
    d, p, q = segment_segment_naive(o, x, x + y, 2 * x + y)  # parallel, end to end
    assert d == pytest.approx(1.0) and np.allclose(p, x) and np.allclose(q, x + y)
    d, _, _ = segment_segment_naive(o, 2 * x, 0.5 * x + y, 1.5 * x + y)  # parallel overlap
    assert d == pytest.approx(1.0)


def test_reference_point_triangle_on_near_collinear_triangles():
    # in floating point, Ericson's region tests cancel for slivers; the reference then
    # solves exactly. Oracle: the triangle is within its height h of its longest edge.
    rng = np.random.default_rng(11)
    for k in range(600):  # half collinear up to rounding only, half slightly bent
        a, u = rng.normal(size=3), rng.normal(size=3)
        off = rng.normal(size=3) * 10 ** rng.uniform(-12, -5) * (k % 2)
        tri = np.array([a, a + u, a + rng.uniform(-1, 2) * u + off])
        p = rng.normal(size=3) * 2
        edges = [(tri[i], tri[j]) for i, j in ((0, 1), (1, 2), (2, 0))]
        to_edges = min(segment_segment_naive(p, p, q0, q1)[0] for q0, q1 in edges)
        height = np.linalg.norm(np.cross(tri[1] - tri[0], tri[2] - tri[0])) / max(
            np.linalg.norm(q1 - q0) for q0, q1 in edges
        )
        d = point_triangle_distance_naive(p, tri)
        assert to_edges - height - 1e-12 <= d <= to_edges + 1e-12
