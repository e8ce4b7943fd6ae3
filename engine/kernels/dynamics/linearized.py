"""The contact forces linearised about one configuration, and the Newton correction of a
Picard iteration that solves them (``engine.dynamics.picard``).

A backward Euler step of length h from velocities v₀ seeks forces F(x₀ + h·v₁, v₁) that,
applied, give v₁ = v₀ + h·M⁻¹F. About the configuration of the last evaluation the contact
forces change as −(K·Δx + C·Δv): K the springs' stiffness (k_n·nnᵀ per contact, plus k_t·P
for a sticking tangential spring, and for a sliding one, whose force μF_n·ĝ turns with the
spring's g, (μF_n/|g|)·k_t·(P − ĝĝᵀ)), C their velocity slopes (normal damping c_n·nnᵀ, a
tangential spring's damping c_t·P, scaled alike when sliding, and the regularised friction's
Jacobian
μF_n/s·(P − t·tᵀ/s²), P = I − nnᵀ, t the sliding velocity, s = √(|t|² + v_slip²)), each
seen by the two bodies through J = [I | −[r]×] (r from the body's lever origin to the contact
point). The velocity correction z then solves (M + h²K + h·C)·z = h·r, r the residual of
the forces, and the applied forces become the computed ones less (h·K + C)·z: a sum of
equal and opposite contact forces for any z, so momentum is conserved whatever the solve's
accuracy. Body vectors are ``(n, 6)`` float64: force (or linear velocity) then torque (or
angular velocity), world frame.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from engine.kernels.dynamics.contact_forces import (
    ACTIVE,
    DAMPING_SLOPE,
    FRICTION_SCALE,
    SLIP,
    SPRING_SLOPE,
    TANGENT,
    TANGENT_SPRING,
)
from engine.kernels.jit import BORROW, JIT


@njit(**BORROW, forceinline=True)
def _slopes(normals, terms, c, w_k, w_c, out):
    """``out (3, 3)`` = w_k·K_c + w_c·C_c for contact ``c`` (module docstring)."""
    n0, n1, n2 = normals[c, 0], normals[c, 1], normals[c, 2]
    normal = w_k * terms[c, SPRING_SLOPE] + w_c * terms[c, DAMPING_SLOPE]
    scale = w_k * terms[c, TANGENT_SPRING] + w_c * terms[c, FRICTION_SCALE]
    slip = terms[c, SLIP]
    t0, t1, t2 = terms[c, TANGENT], terms[c, TANGENT + 1], terms[c, TANGENT + 2]
    n = (n0, n1, n2)
    t = (t0, t1, t2)
    inv = 1.0 / (slip * slip) if slip > 0.0 else 0.0
    for i in range(3):
        for j in range(3):
            unit = 1.0 if i == j else 0.0
            out[i, j] = normal * n[i] * n[j] + scale * (unit - n[i] * n[j] - t[i] * t[j] * inv)


@njit(**BORROW, forceinline=True)
def _relative(z, a, b, ra, rb, out):
    """``out (3,)``: velocity of B's point at ``rb`` relative to A's at ``ra`` under the
    body velocities ``z (n, 6)`` (linear, angular)."""
    for i in range(3):
        j, k = (i + 1) % 3, (i + 2) % 3
        out[i] = (z[b, i] + z[b, 3 + j] * rb[k] - z[b, 3 + k] * rb[j]) - (
            z[a, i] + z[a, 3 + j] * ra[k] - z[a, 3 + k] * ra[j]
        )


@njit(**JIT)
def contact_product(bodies, offsets, points, normals, terms, origins, z, w_k, w_c, out):
    """``out (n, 6)`` += (w_k·K + w_c·C)·z over the acting contacts (module docstring).

    ``bodies (k, 2)`` int64 and ``offsets (k + 1,)`` as in
    :func:`~engine.kernels.dynamics.contact_forces.contact_terms`; ``points, normals
    (c, 3)``, ``terms (c, TERMS)`` float64 of one evaluation; ``origins (n, 3)`` the lever
    origins; ``z (n, 6)`` body velocities. Rows of fixed bodies receive terms too (the
    caller ignores them)."""
    slopes = np.empty((3, 3))
    u = np.empty(3)
    ra, rb = np.empty(3), np.empty(3)
    for q in range(bodies.shape[0]):
        a, b = bodies[q, 0], bodies[q, 1]
        for c in range(offsets[q], offsets[q + 1]):
            if terms[c, ACTIVE] == 0.0:
                continue
            for i in range(3):
                ra[i] = points[c, i] - origins[a, i]
                rb[i] = points[c, i] - origins[b, i]
            _slopes(normals, terms, c, w_k, w_c, slopes)
            _relative(z, a, b, ra, rb, u)
            for i in range(3):
                g = slopes[i, 0] * u[0] + slopes[i, 1] * u[1] + slopes[i, 2] * u[2]
                j, k = (i + 1) % 3, (i + 2) % 3
                out[b, i] += g
                out[a, i] -= g
                # torque r × g: component j gets r_k·g_i, component k gets −r_j·g_i
                out[b, 3 + j] += rb[k] * g
                out[b, 3 + k] -= rb[j] * g
                out[a, 3 + j] -= ra[k] * g
                out[a, 3 + k] += ra[j] * g


@njit(**JIT)
def block_inverses(bodies, offsets, points, normals, terms, origins, mass, inertia, h, free, out):
    """``out (n, 6, 6)``: the inverse of each free body's diagonal block of
    M + h²K + h·C (its mass, its world ``inertia (n, 3, 3)``, and its own contacts' terms),
    the preconditioner of :func:`newton_correction`; zero for bodies not ``free (n,)``."""
    n = mass.shape[0]
    block = np.zeros((n, 6, 6))
    slopes = np.empty((3, 3))
    jac = np.empty((3, 6))
    r = np.empty(3)
    for q in range(bodies.shape[0]):
        for side in range(2):
            body = bodies[q, side]
            if not free[body]:
                continue
            for c in range(offsets[q], offsets[q + 1]):
                if terms[c, ACTIVE] == 0.0:
                    continue
                _slopes(normals, terms, c, h * h, h, slopes)
                for i in range(3):
                    r[i] = points[c, i] - origins[body, i]
                # J = [I | −[r]×]: u_i = z_i + (ω × r)_i
                for i in range(3):
                    j, k = (i + 1) % 3, (i + 2) % 3
                    for col in range(6):
                        jac[i, col] = 0.0
                    jac[i, i] = 1.0
                    jac[i, 3 + j] = r[k]
                    jac[i, 3 + k] = -r[j]
                for x in range(6):
                    for y in range(6):
                        total = 0.0
                        for i in range(3):
                            for m in range(3):
                                total += jac[i, x] * slopes[i, m] * jac[m, y]
                        block[body, x, y] += total
    for body in range(n):
        if not free[body]:
            out[body] = 0.0
            continue
        for i in range(3):
            block[body, i, i] += mass[body]
            for j in range(3):
                block[body, 3 + i, 3 + j] += inertia[body, i, j]
        out[body] = np.linalg.inv(block[body])


@njit(**JIT)
def _mass_product(mass, inertia, free, z, out):
    """``out (n, 6)`` = M·z for the free bodies, 0 elsewhere."""
    for b in range(z.shape[0]):
        if not free[b]:
            out[b, :] = 0.0
            continue
        for i in range(3):
            out[b, i] = mass[b] * z[b, i]
            out[b, 3 + i] = (
                inertia[b, i, 0] * z[b, 3] + inertia[b, i, 1] * z[b, 4] + inertia[b, i, 2] * z[b, 5]
            )


@njit(**JIT)
def _preconditioned(inverses, free, r, out):
    for b in range(r.shape[0]):
        for i in range(6):
            total = 0.0
            if free[b]:
                for j in range(6):
                    total += inverses[b, i, j] * r[b, j]
            out[b, i] = total


@njit(**JIT)
def _dot(x, y, free):
    total = 0.0
    for b in range(x.shape[0]):
        if free[b]:
            for i in range(6):
                total += x[b, i] * y[b, i]
    return total


@njit(**JIT)
def newton_correction(contacts, origins, mass, inertia, free, h, rhs, tolerance, most, z):
    """Solve (M + h²K + h·C)·z = ``rhs (n, 6)`` for the free bodies by conjugate gradients,
    preconditioned with each body's 6×6 block, to a relative residual ``tolerance`` or
    ``most`` iterations; writes ``z (n, 6)`` (0 on bodies not ``free``) and returns the
    iterations taken. ``contacts = (bodies, offsets, points, normals, terms)`` of one
    evaluation; ``mass (n,)``, world ``inertia (n, 3, 3)``. The matrix is symmetric
    positive definite: every contact's slopes are (k_n, c_n ≥ 0, the friction's Jacobian
    is positive semi-definite)."""
    bodies, offsets, points, normals, terms = contacts
    n = mass.shape[0]
    inverses = np.empty((n, 6, 6))
    block_inverses(bodies, offsets, points, normals, terms, origins, mass, inertia, h, free,
                   inverses)  # fmt: skip
    z[:] = 0.0
    r = rhs.copy()
    for b in range(n):
        if not free[b]:
            r[b, :] = 0.0
    p, s, product = np.empty((n, 6)), np.empty((n, 6)), np.empty((n, 6))
    _preconditioned(inverses, free, r, s)
    p[:] = s
    rs = _dot(r, s, free)
    start = np.sqrt(_dot(r, r, free))
    if start == 0.0:
        return 0
    for iteration in range(most):
        _mass_product(mass, inertia, free, p, product)
        contact_product(bodies, offsets, points, normals, terms, origins, p, h * h, h, product)
        curvature = _dot(p, product, free)
        if curvature <= 0.0:
            return iteration
        alpha = rs / curvature
        for b in range(n):
            for i in range(6):
                z[b, i] += alpha * p[b, i]
                r[b, i] -= alpha * product[b, i]
        if not free.all():
            for b in range(n):
                if not free[b]:
                    r[b, :] = 0.0
        if np.sqrt(_dot(r, r, free)) <= tolerance * start:
            return iteration + 1
        _preconditioned(inverses, free, r, s)
        rs_new = _dot(r, s, free)
        beta = rs_new / rs
        rs = rs_new
        for b in range(n):
            for i in range(6):
                p[b, i] = s[b, i] + beta * p[b, i]
    return most
