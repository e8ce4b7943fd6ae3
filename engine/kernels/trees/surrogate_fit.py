"""Appendix-A surrogate functional and its minimiser (host side: :mod:`engine.trees.surrogates`).

Everything is in the normalised frame of one group (covered vertices centred and
scaled to unit radius), so the parameters are dimensionless. ``params`` holds

    [beta, alpha_area, alpha_inside, beta_normal, weight_epsilon, weight_paper]

and the functional of the surrogate vertices ``x (3, 3)`` is

    weight_epsilon · S_β(dist(points_i, X))          covered vertices → surrogate
  + weight_paper   · S_β(dist(x_k, tris_j))          surrogate vertices → covered
  + alpha_area / 2 · |(x2 − x1) × (x3 − x1)|^(−2)
  + alpha_inside / beta_normal · Σ_k mean_i max(0, (x_k − points_i)·N)^beta_normal

with ``S_β(r) = (mean r^β)^(1/β)`` (a soft maximum, evaluated as ``max r ·
(mean (r / max r)^β)^(1/β)`` so it cannot overflow) and N the unit normal of X.
Gradients are analytic: for the distance d from p to X with closest point
``c = Σ λ_k x_k``, ``∂d/∂x_k = −λ_k (p − c)/d``.
"""

import numpy as np
from numba import njit

from engine.kernels.jit import JIT

N_PARAMS = 6


@njit(**JIT)
def _dot(a, b):
    total = 0.0
    for i in range(a.size):
        total += a[i] * b[i]
    return total


@njit(**JIT)
def _dot_row(a, row, b):
    """``a[row] · b`` without a view of the row."""
    total = 0.0
    for i in range(b.size):
        total += a[row, i] * b[i]
    return total


@njit(**JIT)
def _on_segment(px, py, pz, ax, ay, az, bx, by, bz):
    """(t, squared distance) of the point ``a + t (b − a)``, t in [0, 1], closest to p."""
    abx, aby, abz = bx - ax, by - ay, bz - az
    apx, apy, apz = px - ax, py - ay, pz - az
    length2 = abx * abx + aby * aby + abz * abz
    t = 0.0
    if length2 > 0.0:
        t = min(1.0, max(0.0, (apx * abx + apy * aby + apz * abz) / length2))
    return t, (apx - t * abx) ** 2 + (apy - t * aby) ** 2 + (apz - t * abz) ** 2


@njit(**JIT)
def closest_weights(p, a, b, c):
    """Barycentric weights of the point of triangle ``abc`` closest to ``p`` (all (3,)).

    Ericson, Real-Time Collision Detection §5.1.5; a degenerate triangle (a repeated
    corner, collinear corners: sine of its angle at ``a`` below 1e-12) is the nearest
    point of its three edges. :func:`closest_weights_xyz` takes the coordinates.
    """
    return closest_weights_xyz(
        p[0], p[1], p[2], a[0], a[1], a[2], b[0], b[1], b[2], c[0], c[1], c[2]
    )


@njit(**JIT)
def closest_weights_xyz(px, py, pz, ax, ay, az, bx, by, bz, cx, cy, cz):
    """:func:`closest_weights` on scalar coordinates (no array views in hot loops)."""
    abx, aby, abz = bx - ax, by - ay, bz - az
    acx, acy, acz = cx - ax, cy - ay, cz - az
    nx, ny, nz = aby * acz - abz * acy, abz * acx - abx * acz, abx * acy - aby * acx
    ab2, ac2 = abx * abx + aby * aby + abz * abz, acx * acx + acy * acy + acz * acz
    if not nx * nx + ny * ny + nz * nz > 1e-24 * ab2 * ac2:
        t0, e0 = _on_segment(px, py, pz, ax, ay, az, bx, by, bz)
        t1, e1 = _on_segment(px, py, pz, bx, by, bz, cx, cy, cz)
        t2, e2 = _on_segment(px, py, pz, cx, cy, cz, ax, ay, az)
        if e0 <= e1 and e0 <= e2:
            return 1.0 - t0, t0, 0.0
        return (0.0, 1.0 - t1, t1) if e1 <= e2 else (t2, 0.0, 1.0 - t2)
    apx, apy, apz = px - ax, py - ay, pz - az
    d1 = abx * apx + aby * apy + abz * apz
    d2 = acx * apx + acy * apy + acz * apz
    if d1 <= 0.0 and d2 <= 0.0:
        return 1.0, 0.0, 0.0
    bpx, bpy, bpz = px - bx, py - by, pz - bz
    d3 = abx * bpx + aby * bpy + abz * bpz
    d4 = acx * bpx + acy * bpy + acz * bpz
    if d3 >= 0.0 and d4 <= d3:
        return 0.0, 1.0, 0.0
    vc = d1 * d4 - d3 * d2
    if vc <= 0.0 and d1 >= 0.0 and d3 <= 0.0:  # d1 − d3 = |ab|² > 0
        v = d1 / (d1 - d3)
        return 1.0 - v, v, 0.0
    cpx, cpy, cpz = px - cx, py - cy, pz - cz
    d5 = abx * cpx + aby * cpy + abz * cpz
    d6 = acx * cpx + acy * cpy + acz * cpz
    if d6 >= 0.0 and d5 <= d6:
        return 0.0, 0.0, 1.0
    vb = d5 * d2 - d1 * d6
    if vb <= 0.0 and d2 >= 0.0 and d6 <= 0.0:  # d2 − d6 = |ac|² > 0
        w = d2 / (d2 - d6)
        return 1.0 - w, 0.0, w
    va = d3 * d6 - d5 * d4
    if va <= 0.0 and d4 - d3 >= 0.0 and d5 - d6 >= 0.0:  # their sum is |bc|² > 0
        w = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        return 0.0, 1.0 - w, w
    den = va + vb + vc  # = |ab × ac|² > 0
    v, w = vb / den, vc / den
    return 1.0 - v - w, v, w


@njit(**JIT)
def _power(x, exponent):
    """``x ** exponent`` for x ≥ 0: repeated squaring when the exponent is a whole number up
    to 1024 (β = 64 costs six multiplications instead of a ``pow`` call), else ``pow``."""
    if exponent == np.floor(exponent) and 0.0 <= exponent <= 1024.0:
        e = int(exponent)
        result, base = 1.0, x
        while e > 0:
            if e & 1:
                result *= base
            base *= base
            e >>= 1
        return result
    return x**exponent


@njit(**JIT)
def _soft_max(work, n, weight, beta, count):
    """``S = (Σ w_i r_i^β / count)^(1/β)`` of ``r_i = work[i, 6] ≥ 0`` (i < n) with weights
    ``weight (n,)`` (``count`` = Σ w: a weighted sample of a larger set stands for all of
    it); writes ``count · ∂S/∂r_i`` to ``work[i, 7]``."""
    top = 0.0
    for i in range(n):
        top = max(top, work[i, 6])
    if not top > 0.0:
        for i in range(n):
            work[i, 7] = 0.0
        return 0.0
    total = 0.0
    for i in range(n):
        total += weight[i] * _power(work[i, 6] / top, beta)
    s = top * (total / count) ** (1.0 / beta)
    for i in range(n):
        work[i, 7] = weight[i] * _power(work[i, 6] / s, beta - 1.0)
    return s


@njit(**JIT)
def full_pairs(n_tris):
    """The pairs (surrogate vertex k, covered triangle j) of the functional's second term
    over all ``n_tris`` triangles: ``vertex (3 n_tris,)``, ``tri (3 n_tris,)`` int64."""
    vertex = np.empty(3 * n_tris, np.int64)
    tri = np.empty(3 * n_tris, np.int64)
    for k in range(3):
        for j in range(n_tris):
            vertex[k * n_tris + j] = k
            tri[k * n_tris + j] = j
    return vertex, tri


@njit(**JIT)
def objective(x, points, tris, params, grad):
    """Value of the functional at ``x (3, 3)``; its gradient is written to ``grad (3, 3)``.

    ``points (m, 3)`` covered vertices, ``tris (t, 3, 3)`` covered triangles,
    ``params (6,)`` as in the module docstring; all float64, normalised frame.
    """
    pair_vertex, pair_tri = full_pairs(tris.shape[0])
    w_points, w_pairs = np.ones(points.shape[0]), np.ones(pair_vertex.size)
    work = np.empty((max(points.shape[0], pair_vertex.size), 8))
    return objective_sampled(
        x, points, w_points, tris, pair_vertex, pair_tri, w_pairs, params, grad, work
    )


@njit(**JIT)
def objective_sampled(
    x, points, w_points, tris, pair_vertex, pair_tri, w_pairs, params, grad, work
):
    """:func:`objective` over a weighted sample of its terms: covered vertices ``points
    (m, 3)`` with weights ``w_points (m,)``, and pairs (surrogate vertex ``pair_vertex[q]``,
    covered triangle ``tris[pair_tri[q]]``) of the second term with weights ``w_pairs``;
    each soft maximum is the weighted mean (a sample stands for a larger group). Writes
    the gradient to ``grad (3, 3)``; ``work (≥ max(m, pairs), 8)`` float64 is scratch.
    """
    n_points, n_pairs = w_points.sum(), w_pairs.sum()
    beta, alpha_area, alpha_inside, beta_normal, w_eps, w_paper = params
    grad[:] = 0.0
    value = 0.0
    m = points.shape[0]
    n = m if w_eps > 0.0 else 0
    n_paper = pair_vertex.size if w_paper > 0.0 else 0
    # work[i]: closest-point weights (0:3), difference vector (3:6), distance (6), ∂S/∂r (7)
    if n > 0:  # covered vertices → surrogate: d_i = |p_i − Σ λ_k x_k|
        x0, x1, x2 = x[0, 0], x[0, 1], x[0, 2]
        y0, y1, y2 = x[1, 0], x[1, 1], x[1, 2]
        z0, z1, z2 = x[2, 0], x[2, 1], x[2, 2]
        for i in range(n):
            l0, l1, l2 = closest_weights_xyz(
                points[i, 0], points[i, 1], points[i, 2], x0, x1, x2, y0, y1, y2, z0, z1, z2
            )
            work[i, 0], work[i, 1], work[i, 2] = l0, l1, l2
            d0 = points[i, 0] - (l0 * x0 + l1 * y0 + l2 * z0)
            d1 = points[i, 1] - (l0 * x1 + l1 * y1 + l2 * z1)
            d2 = points[i, 2] - (l0 * x2 + l1 * y2 + l2 * z2)
            work[i, 3], work[i, 4], work[i, 5] = d0, d1, d2
            work[i, 6] = np.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
        value += w_eps * _soft_max(work, n, w_points, beta, n_points)
        g00 = g01 = g02 = g10 = g11 = g12 = g20 = g21 = g22 = 0.0
        for i in range(n):
            if work[i, 6] > 0.0:
                g = w_eps * work[i, 7] / (n_points * work[i, 6])
                h0, h1, h2 = g * work[i, 3], g * work[i, 4], g * work[i, 5]
                l0, l1, l2 = work[i, 0], work[i, 1], work[i, 2]
                g00 += l0 * h0
                g01 += l0 * h1
                g02 += l0 * h2
                g10 += l1 * h0
                g11 += l1 * h1
                g12 += l1 * h2
                g20 += l2 * h0
                g21 += l2 * h1
                g22 += l2 * h2
        grad[0, 0] -= g00
        grad[0, 1] -= g01
        grad[0, 2] -= g02
        grad[1, 0] -= g10
        grad[1, 1] -= g11
        grad[1, 2] -= g12
        grad[2, 0] -= g20
        grad[2, 1] -= g21
        grad[2, 2] -= g22
    if n_paper > 0:  # surrogate vertices → covered triangles: d_kj = |x_k − c_kj|
        for q in range(n_paper):
            k, j = pair_vertex[q], pair_tri[q]
            l0, l1, l2 = closest_weights_xyz(
                x[k, 0], x[k, 1], x[k, 2],
                tris[j, 0, 0], tris[j, 0, 1], tris[j, 0, 2],
                tris[j, 1, 0], tris[j, 1, 1], tris[j, 1, 2],
                tris[j, 2, 0], tris[j, 2, 1], tris[j, 2, 2],
            )  # fmt: skip
            d0 = x[k, 0] - (l0 * tris[j, 0, 0] + l1 * tris[j, 1, 0] + l2 * tris[j, 2, 0])
            d1 = x[k, 1] - (l0 * tris[j, 0, 1] + l1 * tris[j, 1, 1] + l2 * tris[j, 2, 1])
            d2 = x[k, 2] - (l0 * tris[j, 0, 2] + l1 * tris[j, 1, 2] + l2 * tris[j, 2, 2])
            work[q, 3], work[q, 4], work[q, 5] = d0, d1, d2
            work[q, 6] = np.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
        value += w_paper * _soft_max(work, n_paper, w_pairs, beta, n_pairs)
        for q in range(n_paper):
            if work[q, 6] > 0.0:
                g = w_paper * work[q, 7] / (n_pairs * work[q, 6])
                k = pair_vertex[q]
                grad[k, 0] += g * work[q, 3]
                grad[k, 1] += g * work[q, 4]
                grad[k, 2] += g * work[q, 5]
    # e_k = x[k+2] − x[k+1], the edge opposite x[k]; cross = (x2 − x1) × (x3 − x1) = e_1 × e_2
    e10, e11, e12 = x[0, 0] - x[2, 0], x[0, 1] - x[2, 1], x[0, 2] - x[2, 2]
    e20, e21, e22 = x[1, 0] - x[0, 0], x[1, 1] - x[0, 1], x[1, 2] - x[0, 2]
    n0, n1, n2 = e11 * e22 - e12 * e21, e12 * e20 - e10 * e22, e10 * e21 - e11 * e20
    size = np.sqrt(n0 * n0 + n1 * n1 + n2 * n2)
    if not size > 0.0:
        return np.inf
    n0, n1, n2 = n0 / size, n1 / size, n2 / size
    c0 = c1 = c2 = 0.0  # ∂value/∂cross
    if alpha_area > 0.0:
        value += 0.5 * alpha_area / size**2
        f = alpha_area / size**3
        c0, c1, c2 = -f * n0, -f * n1, -f * n2
    if alpha_inside > 0.0:
        gn0 = gn1 = gn2 = 0.0
        for k in range(3):
            for i in range(m):
                h0, h1, h2 = x[k, 0] - points[i, 0], x[k, 1] - points[i, 1], x[k, 2] - points[i, 2]
                h = h0 * n0 + h1 * n1 + h2 * n2
                if h > 0.0:  # a weighted mean over the group, like the soft maxima
                    value += alpha_inside * w_points[i] / (beta_normal * n_points) * h**beta_normal
                    g = alpha_inside * w_points[i] / n_points * h ** (beta_normal - 1.0)
                    grad[k, 0] += g * n0
                    grad[k, 1] += g * n1
                    grad[k, 2] += g * n2
                    gn0, gn1, gn2 = gn0 + g * h0, gn1 + g * h1, gn2 + g * h2
        along = gn0 * n0 + gn1 * n1 + gn2 * n2
        c0 += (gn0 - along * n0) / size
        c1 += (gn1 - along * n1) / size
        c2 += (gn2 - along * n2) / size
    for k in range(3):  # cross = x1×x2 + x2×x3 + x3×x1, so ∂/∂x[k] = −e[k] × g_cross
        a, b = (k + 2) % 3, (k + 1) % 3
        f0, f1, f2 = x[a, 0] - x[b, 0], x[a, 1] - x[b, 1], x[a, 2] - x[b, 2]
        grad[k, 0] -= f1 * c2 - f2 * c1
        grad[k, 1] -= f2 * c0 - f0 * c2
        grad[k, 2] -= f0 * c1 - f1 * c0
    return value


@njit(**JIT)
def minimise(x, points, tris, params, iterations, history, tolerance):
    """L-BFGS with Armijo backtracking from ``x (3, 3)``, in place; returns the evaluations.

    Stops after ``iterations`` steps, when a step lowers the value by less than
    ``tolerance · (|value| + tolerance)``, or when no step along the direction helps.
    """
    pair_vertex, pair_tri = full_pairs(tris.shape[0])
    w_points, w_pairs = np.ones(points.shape[0]), np.ones(pair_vertex.size)
    return minimise_sampled(
        x, points, w_points, tris, pair_vertex, pair_tri, w_pairs,
        params, iterations, history, tolerance,
    )  # fmt: skip


@njit(**JIT)
def minimise_sampled(
    x, points, w_points, tris, pair_vertex, pair_tri, w_pairs, params, iterations, history, tol
):
    """:func:`minimise` of :func:`objective_sampled` (same terms and means)."""
    tolerance = tol
    work = np.empty((max(points.shape[0], pair_vertex.size), 8))
    n = 9
    xs = np.empty(n)
    for i in range(n):
        xs[i] = x[i // 3, i % 3]
    grad = np.empty((3, 3))
    gs = np.empty(n)
    f = objective_sampled(
        x, points, w_points, tris, pair_vertex, pair_tri, w_pairs, params, grad, work
    )
    for i in range(n):
        gs[i] = grad[i // 3, i % 3]
    evals = 1
    if not np.isfinite(f):
        return evals
    g = np.empty(n)
    for i in range(n):
        g[i] = gs[i]
    s_hist = np.zeros((history, n))
    y_hist = np.zeros((history, n))
    rho = np.zeros(history)
    alpha = np.zeros(history)
    d, x_old, sv, yv = np.empty(n), np.empty(n), np.empty(n), np.empty(n)
    stored = 0
    for _ in range(iterations):
        for i in range(n):
            d[i] = -g[i]
        count = min(stored, history)
        for j in range(count):  # two-loop recursion, newest first
            q = (stored - 1 - j) % history
            alpha[q] = rho[q] * _dot_row(s_hist, q, d)
            for i in range(n):
                d[i] -= alpha[q] * y_hist[q, i]
        if count > 0:
            q = (stored - 1) % history
            gamma = _dot_row(s_hist, q, y_hist[q]) / _dot_row(y_hist, q, y_hist[q])
            for i in range(n):
                d[i] *= gamma
        for j in range(stored - count, stored):
            q = j % history
            b = alpha[q] - rho[q] * _dot_row(y_hist, q, d)
            for i in range(n):
                d[i] += b * s_hist[q, i]
        slope = _dot(g, d)
        if not slope < 0.0:  # not a descent direction: restart along −g
            for i in range(n):
                d[i] = -g[i]
            slope = _dot(g, d)
            stored = count = 0
        if not slope < 0.0:
            break
        step = 1.0 if count > 0 else min(1.0, 0.1 / np.sqrt(-slope))
        for i in range(n):
            x_old[i] = xs[i]
        accepted = False
        for _ in range(40):
            for i in range(n):
                xs[i] = x_old[i] + step * d[i]
                x[i // 3, i % 3] = xs[i]
            f_new = objective_sampled(
                x, points, w_points, tris, pair_vertex, pair_tri, w_pairs, params, grad, work
            )
            evals += 1
            if f_new <= f + 1e-4 * step * slope:
                accepted = True
                break
            step *= 0.5
        if not accepted:
            for i in range(n):
                x[i // 3, i % 3] = x_old[i]
            break
        for i in range(n):
            gs[i] = grad[i // 3, i % 3]
        for i in range(n):
            sv[i] = xs[i] - x_old[i]
            yv[i] = gs[i] - g[i]
        sy = _dot(sv, yv)
        if sy > 1e-12 * np.sqrt(_dot(sv, sv) * _dot(yv, yv)):  # curvature pair kept
            q = stored % history
            rho[q] = 1.0 / sy
            for i in range(n):
                s_hist[q, i], y_hist[q, i] = sv[i], yv[i]
            stored += 1
        done = f - f_new <= tolerance * (abs(f) + tolerance)
        f = f_new
        for i in range(n):
            g[i] = gs[i]
        if done:
            break
    return evals
