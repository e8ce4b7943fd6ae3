"""Surrogate fitting (Appendix A): gradient, closest points, never worse, conservative,
deterministic."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from engine import InvalidArgumentError, shapes
from engine.geometry.reference import point_triangle_distance_naive
from engine.kernels.trees.surrogate_fit import closest_weights
from engine.trees.build import build_tree
from engine.trees.surrogates import (
    FITS,
    FitParameters,
    enclosing_triangle,
    fit_triangle,
    functional,
    largest_distance,
    region_volume,
)

ALL_TERMS = FitParameters(
    beta=8.0,
    alpha_area=0.05,
    alpha_inside=2.0,
    beta_normal=3.0,
    weight_epsilon=1.0,
    weight_paper=0.5,
)


def _group(seed: int = 0, faces: int = 30):
    """A curved, bumpy patch of triangles, its vertices and its initial triangle."""
    mesh = shapes.noisy_sphere(subdivisions=2, eta_r=1.3, seed=seed)
    tris = mesh.triangles[np.argsort(mesh.triangles.mean(axis=1)[:, 2])[-faces:]]
    points = np.unique(tris.reshape(-1, 3), axis=0)
    return tris, points, enclosing_triangle(points, tris)


@pytest.mark.parametrize("params", [FITS["epsilon"], FITS["paper"], ALL_TERMS])
def test_gradient_matches_finite_differences(params):
    tris, points, initial = _group()
    rng = np.random.default_rng(1)
    size = np.ptp(points, axis=0).max()
    for _ in range(3):  # shrunk and jittered: vertices inside, outside and on edges
        x = 0.6 * initial + 0.4 * points.mean(axis=0) + rng.normal(scale=0.05 * size, size=(3, 3))
        _, grad = functional(x, points, tris, params)
        h = 1e-6 * size
        numeric = np.zeros((3, 3))
        for k in range(3):
            for c in range(3):
                step = np.zeros((3, 3))
                step[k, c] = h
                up, _ = functional(x + step, points, tris, params)
                down, _ = functional(x - step, points, tris, params)
                numeric[k, c] = (up - down) / (2 * h)
        np.testing.assert_allclose(grad, numeric, rtol=1e-5, atol=1e-7 * np.abs(grad).max())


def _edge_distance(p, tri):
    """Distance from ``p`` to the union of the edges of ``tri`` (clamped projections)."""
    best = np.inf
    for a, b in ((tri[0], tri[1]), (tri[1], tri[2]), (tri[2], tri[0])):
        ab = b - a
        t = np.clip((p - a) @ ab / (ab @ ab), 0, 1) if ab @ ab > 0 else 0.0
        best = min(best, np.linalg.norm(p - a - t * ab))
    return best


def test_closest_weights_give_the_distance():
    rng = np.random.default_rng(2)
    tri = rng.normal(size=(3, 3))
    line = np.array([tri[1], 2 * tri[1] - tri[0], tri[0]])  # collinear, up to rounding
    cases = [
        (tri, point_triangle_distance_naive),
        (np.array([tri[0], tri[0], tri[1]]), point_triangle_distance_naive),  # repeated corner
        (np.array([tri[2]] * 3), point_triangle_distance_naive),  # a point
        (line, _edge_distance),
        (line[[1, 2, 0]], _edge_distance),
    ]
    for t, expected in cases:
        for p in rng.normal(scale=2.0, size=(300, 3)):
            lam = np.array(closest_weights(p, t[0], t[1], t[2]))
            assert (lam >= 0).all() and lam.sum() == pytest.approx(1.0)
            got = np.linalg.norm(p - lam @ t)
            assert got == pytest.approx(expected(p, t), rel=1e-9, abs=1e-12)


def test_fit_lowers_the_functional_and_is_deterministic():
    tris, points, initial = _group(seed=3)
    params = FITS["epsilon"]
    before = (points.copy(), tris.copy(), initial.copy())
    a = fit_triangle(points, tris, initial, params)
    b = fit_triangle(points, tris, initial, params)
    np.testing.assert_array_equal(a, b)
    for arr, orig in zip((points, tris, initial), before, strict=True):
        np.testing.assert_array_equal(arr, orig)  # inputs untouched
    assert functional(a, points, tris, params)[0] < functional(initial, points, tris, params)[0]


@pytest.mark.parametrize("fit", ["epsilon", "paper"])
def test_fit_never_enlarges_an_epsilon_region(fit):
    """Node by node, the fitted tree's ε-regions are at most the initial tree's, and
    fitting shrinks some (same seed: same groups)."""
    mesh = shapes.stretched_sphere(subdivisions=2, eta=1.4)
    initial = build_tree(mesh, 0.0, seed=4, fit="initial")
    fitted = build_tree(mesh, 0.0, seed=4, fit=fit)
    np.testing.assert_array_equal(fitted.face, initial.face)
    shrunk = 0
    for node in np.flatnonzero(initial.face < 0):
        v0 = region_volume(initial.triangles[node], initial.epsilon[node])
        v1 = region_volume(fitted.triangles[node], fitted.epsilon[node])
        assert v1 <= v0, node
        shrunk += v1 < v0
    assert shrunk > 0
    assert fitted.stats.volume_ratio < initial.stats.volume_ratio


def test_a_worse_fit_is_rejected():
    """The literal functional shrinks a flat patch's surrogate to a small triangle with a
    large ε; the guard keeps the initial triangle (ε = 0 for a flat patch)."""
    mesh = shapes.plane(size=(2.0, 2.0), divisions=2)  # 8 coplanar triangles
    tris = mesh.triangles
    points = np.unique(tris.reshape(-1, 3), axis=0)
    initial = enclosing_triangle(points, tris)
    raw = fit_triangle(points, tris, initial, FITS["paper"])
    assert largest_distance(points, raw) > 0.1  # the fit alone is worse
    tree = build_tree(mesh, 0.0, branching=8, fit="paper")
    assert tree.epsilon[0] <= 1e-12 * mesh.diameter  # 0 up to the distance's rounding
    np.testing.assert_allclose(tree.triangles[0], initial, atol=1e-12 * mesh.diameter)


@pytest.mark.parametrize("fit", ["epsilon", "paper", ALL_TERMS])
def test_fitted_trees_are_conservative(fit):
    """Random points of the covered triangles lie within ε_node − ε_leaf of the surrogate,
    and a covered vertex attains it."""
    mesh = shapes.noisy_sphere(subdivisions=2, eta_r=1.4, seed=5)
    tree = build_tree(mesh, 0.01, seed=1, fit=fit)
    rng = np.random.default_rng(0)
    for node in np.flatnonzero(tree.face < 0)[::3]:
        tris = mesh.triangles[tree.covered_faces(node)]
        w = rng.dirichlet(np.ones(3), size=(len(tris), 3))
        inner = np.einsum("tkv,tvd->tkd", w, tris).reshape(-1, 3)
        surrogate = tree.triangles[node]
        bound = tree.epsilon[node] - tree.leaf_epsilon
        worst = max(point_triangle_distance_naive(p, surrogate) for p in inner)
        assert worst <= bound + 1e-9 * mesh.diameter, node
        corner = max(point_triangle_distance_naive(p, surrogate) for p in tris.reshape(-1, 3))
        assert corner == pytest.approx(bound, abs=1e-9 * mesh.diameter)


def test_fitted_tree_is_deterministic():
    mesh = shapes.stretched_sphere(subdivisions=2, eta=1.8)
    a, b = build_tree(mesh, 0.01, seed=2), build_tree(mesh, 0.01, seed=2)
    np.testing.assert_array_equal(a.triangles, b.triangles)
    np.testing.assert_array_equal(a.epsilon, b.epsilon)


@pytest.mark.parametrize("fit", ["nope", 3, None])
def test_unknown_fit_is_rejected(fit):
    with pytest.raises(InvalidArgumentError, match="fit"):
        build_tree(shapes.box(), 0.01, fit=fit)


@pytest.mark.parametrize(
    "change",
    [
        {"beta": 1.0},
        {"alpha_area": -1.0},
        {"beta_normal": 0.5},
        {"weight_epsilon": 0.0, "weight_paper": 0.0},
        {"history": 0},
        {"beta": float("nan")},
    ],
)
def test_bad_fit_parameters_are_rejected(change):
    with pytest.raises(InvalidArgumentError, match="fit parameters"):
        dataclasses.replace(FITS["epsilon"], **change)
