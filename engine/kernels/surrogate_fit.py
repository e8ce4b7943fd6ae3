"""Appendix-A surrogate functional and its minimiser (host side: :mod:`engine.surrogates`).

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

from .jit import JIT

N_PARAMS = 6


@njit(**JIT)
def _dot(a, b):
    total = 0.0
    for i in range(a.size):
        total += a[i] * b[i]
    return total


@njit(**JIT)
def _cross(a, b):
    return np.array(
        [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
    )


@njit(**JIT)
def _on_segment(p, a, b):
    """(t, squared distance) of the point ``a + t (b − a)``, t in [0, 1], closest to p."""
    ab = np.empty(3)
    ap = np.empty(3)
    for c in range(3):
        ab[c], ap[c] = b[c] - a[c], p[c] - a[c]
    length2 = _dot(ab, ab)
    t = min(1.0, max(0.0, _dot(ap, ab) / length2)) if length2 > 0.0 else 0.0
    dist2 = 0.0
    for c in range(3):
        dist2 += (ap[c] - t * ab[c]) ** 2
    return t, dist2


@njit(**JIT)
def closest_weights(p, a, b, c):
    """Barycentric weights of the point of triangle ``abc`` closest to ``p`` (all (3,)).

    Ericson, Real-Time Collision Detection §5.1.5; a degenerate triangle (a repeated
    corner, collinear corners: sine of its angle at ``a`` below 1e-12) is the nearest
    point of its three edges.
    """
    abx, aby, abz = b[0] - a[0], b[1] - a[1], b[2] - a[2]
    acx, acy, acz = c[0] - a[0], c[1] - a[1], c[2] - a[2]
    nx, ny, nz = aby * acz - abz * acy, abz * acx - abx * acz, abx * acy - aby * acx
    ab2, ac2 = abx * abx + aby * aby + abz * abz, acx * acx + acy * acy + acz * acz
    if not nx * nx + ny * ny + nz * nz > 1e-24 * ab2 * ac2:
        t0, e0 = _on_segment(p, a, b)
        t1, e1 = _on_segment(p, b, c)
        t2, e2 = _on_segment(p, c, a)
        if e0 <= e1 and e0 <= e2:
            return 1.0 - t0, t0, 0.0
        return (0.0, 1.0 - t1, t1) if e1 <= e2 else (t2, 0.0, 1.0 - t2)
    apx, apy, apz = p[0] - a[0], p[1] - a[1], p[2] - a[2]
    d1 = abx * apx + aby * apy + abz * apz
    d2 = acx * apx + acy * apy + acz * apz
    if d1 <= 0.0 and d2 <= 0.0:
        return 1.0, 0.0, 0.0
    bpx, bpy, bpz = p[0] - b[0], p[1] - b[1], p[2] - b[2]
    d3 = abx * bpx + aby * bpy + abz * bpz
    d4 = acx * bpx + acy * bpy + acz * bpz
    if d3 >= 0.0 and d4 <= d3:
        return 0.0, 1.0, 0.0
    vc = d1 * d4 - d3 * d2
    if vc <= 0.0 and d1 >= 0.0 and d3 <= 0.0:  # d1 − d3 = |ab|² > 0
        v = d1 / (d1 - d3)
        return 1.0 - v, v, 0.0
    cpx, cpy, cpz = p[0] - c[0], p[1] - c[1], p[2] - c[2]
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
def _soft_max(r, beta, coef):
    """``S = (mean r^β)^(1/β)`` of ``r (n,)`` ≥ 0; writes ``n · ∂S/∂r_i`` to ``coef (n,)``."""
    n = r.size
    top = 0.0
    for i in range(n):
        top = max(top, r[i])
    if not top > 0.0:
        coef[:] = 0.0
        return 0.0
    mean = 0.0
    for i in range(n):
        mean += (r[i] / top) ** beta
    s = top * (mean / n) ** (1.0 / beta)
    for i in range(n):
        coef[i] = (r[i] / s) ** (beta - 1.0)
    return s


@njit(**JIT)
def objective(x, points, tris, params, grad):
    """Value of the functional at ``x (3, 3)``; its gradient is written to ``grad (3, 3)``.

    ``points (m, 3)`` covered vertices, ``tris (t, 3, 3)`` covered triangles,
    ``params (6,)`` as in the module docstring; all float64, normalised frame.
    """
    beta, alpha_area, alpha_inside, beta_normal, w_eps, w_paper = params
    grad[:] = 0.0
    value = 0.0
    m, t = points.shape[0], tris.shape[0]
    n = m if w_eps > 0.0 else 0
    n_paper = 3 * t if w_paper > 0.0 else 0
    lam = np.empty((max(n, n_paper), 3))
    diff = np.empty((max(n, n_paper), 3))
    r = np.empty(max(n, n_paper))
    coef = np.empty(max(n, n_paper))
    if n > 0:  # covered vertices → surrogate: d_i = |p_i − Σ λ_k x_k|
        for i in range(n):
            lam[i, 0], lam[i, 1], lam[i, 2] = closest_weights(points[i], x[0], x[1], x[2])
            for c in range(3):
                near = lam[i, 0] * x[0, c] + lam[i, 1] * x[1, c] + lam[i, 2] * x[2, c]
                diff[i, c] = points[i, c] - near
            r[i] = np.sqrt(_dot(diff[i], diff[i]))
        value += w_eps * _soft_max(r[:n], beta, coef[:n])
        for i in range(n):
            if r[i] > 0.0:
                g = w_eps * coef[i] / (n * r[i])
                for k in range(3):
                    for c in range(3):
                        grad[k, c] -= g * lam[i, k] * diff[i, c]
    if n_paper > 0:  # surrogate vertices → covered triangles: d_kj = |x_k − c_kj|
        for k in range(3):
            for j in range(t):
                q = k * t + j
                a, b, c = tris[j, 0], tris[j, 1], tris[j, 2]
                lam[q, 0], lam[q, 1], lam[q, 2] = closest_weights(x[k], a, b, c)
                for c in range(3):
                    near = lam[q, 0] * tris[j, 0, c] + lam[q, 1] * tris[j, 1, c]
                    diff[q, c] = x[k, c] - near - lam[q, 2] * tris[j, 2, c]
                r[q] = np.sqrt(_dot(diff[q], diff[q]))
        value += w_paper * _soft_max(r[:n_paper], beta, coef[:n_paper])
        for q in range(n_paper):
            if r[q] > 0.0:
                g = w_paper * coef[q] / (n_paper * r[q])
                for c in range(3):
                    grad[q // t, c] += g * diff[q, c]
    e = np.empty((3, 3))  # e[k] = x[k+2] − x[k+1], the edge opposite x[k]
    for k in range(3):
        for c in range(3):
            e[k, c] = x[(k + 2) % 3, c] - x[(k + 1) % 3, c]
    normal = _cross(e[1], e[2])  # (x2 − x1) × (x3 − x1)
    size = np.sqrt(_dot(normal, normal))
    if not size > 0.0:
        return np.inf
    for c in range(3):
        normal[c] /= size
    g_cross = np.zeros(3)  # ∂value/∂cross
    if alpha_area > 0.0:
        value += 0.5 * alpha_area / size**2
        for c in range(3):
            g_cross[c] -= alpha_area / size**3 * normal[c]
    if alpha_inside > 0.0:
        g_normal = np.zeros(3)
        for k in range(3):
            for i in range(m):
                h = 0.0
                for c in range(3):
                    h += (x[k, c] - points[i, c]) * normal[c]
                if h > 0.0:
                    value += alpha_inside / (beta_normal * m) * h**beta_normal
                    g = alpha_inside / m * h ** (beta_normal - 1.0)
                    for c in range(3):
                        grad[k, c] += g * normal[c]
                        g_normal[c] += g * (x[k, c] - points[i, c])
        along = _dot(g_normal, normal)
        for c in range(3):
            g_cross[c] += (g_normal[c] - along * normal[c]) / size
    for k in range(3):  # cross = x1×x2 + x2×x3 + x3×x1, so ∂/∂x[k] = −e[k] × g_cross
        part = _cross(e[k], g_cross)
        for c in range(3):
            grad[k, c] -= part[c]
    return value


@njit(**JIT)
def minimise(x, points, tris, params, iterations, history, tolerance):
    """L-BFGS with Armijo backtracking from ``x (3, 3)``, in place; returns the evaluations.

    Stops after ``iterations`` steps, when a step lowers the value by less than
    ``tolerance · (|value| + tolerance)``, or when no step along the direction helps.
    """
    n = 9
    xs = np.empty(n)
    for i in range(n):
        xs[i] = x[i // 3, i % 3]
    grad = np.empty((3, 3))
    gs = np.empty(n)
    f = objective(x, points, tris, params, grad)
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
            alpha[q] = rho[q] * _dot(s_hist[q], d)
            for i in range(n):
                d[i] -= alpha[q] * y_hist[q, i]
        if count > 0:
            q = (stored - 1) % history
            gamma = _dot(s_hist[q], y_hist[q]) / _dot(y_hist[q], y_hist[q])
            for i in range(n):
                d[i] *= gamma
        for j in range(stored - count, stored):
            q = j % history
            b = alpha[q] - rho[q] * _dot(y_hist[q], d)
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
            f_new = objective(x, points, tris, params, grad)
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
