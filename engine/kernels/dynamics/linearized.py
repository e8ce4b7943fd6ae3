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
def system_blocks(contacts, origins, mass, inertia, h, free, diagonal, coupling):
    """The blocks of M + h²K + h·C (module docstring) over the free bodies: ``diagonal (n,
    6, 6)`` each free body's own (its mass, its world ``inertia (n, 3, 3)`` and Jᵀ·S·J of
    its contacts, J = [I | −[r]×], S a contact's slopes; zero for bodies not ``free``),
    ``coupling (k, 6, 6)`` each body pair's −J_aᵀ·S·J_b summed over its contacts (the
    rows of A, the columns of B; B's rows of A's columns are its transpose; zero unless
    both are free). ``contacts = (bodies, offsets, points, normals, terms)``."""
    bodies, offsets, points, normals, terms = contacts
    n = mass.shape[0]
    diagonal[:] = 0.0
    coupling[:] = 0.0
    slopes = np.empty((3, 3))
    turned_a, turned_b = np.empty((3, 3)), np.empty((3, 3))  # S·[r]× of A's and B's lever
    ra, rb = np.empty(3), np.empty(3)
    for q in range(bodies.shape[0]):
        a, b = bodies[q, 0], bodies[q, 1]
        if not (free[a] or free[b]):
            continue
        for c in range(offsets[q], offsets[q + 1]):
            if terms[c, ACTIVE] == 0.0:
                continue
            _slopes(normals, terms, c, h * h, h, slopes)
            for i in range(3):
                ra[i] = points[c, i] - origins[a, i]
                rb[i] = points[c, i] - origins[b, i]
            _turned(slopes, ra, turned_a)
            _turned(slopes, rb, turned_b)
            if free[a]:
                _add_own(diagonal[a], slopes, ra, turned_a)
            if free[b]:
                _add_own(diagonal[b], slopes, rb, turned_b)
            if free[a] and free[b]:
                # −J_aᵀ·S·J_b = [[−S, S[r_b]×], [(S[r_a]×)ᵀ, [r_a]×·S[r_b]×]]
                block = coupling[q]
                for i in range(3):
                    for j in range(3):
                        block[i, j] -= slopes[i, j]
                        block[i, 3 + j] += turned_b[i, j]
                        block[3 + i, j] += turned_a[j, i]
                for j in range(3):
                    t0, t1, t2 = turned_b[0, j], turned_b[1, j], turned_b[2, j]
                    block[3, 3 + j] += ra[1] * t2 - ra[2] * t1
                    block[4, 3 + j] += ra[2] * t0 - ra[0] * t2
                    block[5, 3 + j] += ra[0] * t1 - ra[1] * t0
    for body in range(n):
        if not free[body]:
            continue
        for i in range(3):
            diagonal[body, i, i] += mass[body]
            for j in range(3):
                diagonal[body, 3 + i, 3 + j] += inertia[body, i, j]


@njit(**BORROW, forceinline=True)
def _turned(slopes, r, out):
    """``out (3, 3)`` = S·[r]×, [r]× = [[0, −r₂, r₁], [r₂, 0, −r₀], [−r₁, r₀, 0]]."""
    for i in range(3):
        out[i, 0] = slopes[i, 1] * r[2] - slopes[i, 2] * r[1]
        out[i, 1] = slopes[i, 2] * r[0] - slopes[i, 0] * r[2]
        out[i, 2] = slopes[i, 0] * r[1] - slopes[i, 1] * r[0]


@njit(**BORROW, forceinline=True)
def _add_own(block, slopes, r, turned):
    """``block (6, 6)`` += Jᵀ·S·J = [[S, −S[r]×], [[r]×S, −[r]×·S[r]×]] ([r]×S = −(S[r]×)ᵀ
    for a symmetric S) with ``turned`` = S·[r]×."""
    for i in range(3):
        for j in range(3):
            block[i, j] += slopes[i, j]
            block[i, 3 + j] -= turned[i, j]
            block[3 + j, i] -= turned[i, j]
    for j in range(3):
        t0, t1, t2 = turned[0, j], turned[1, j], turned[2, j]
        block[3, 3 + j] -= r[1] * t2 - r[2] * t1
        block[4, 3 + j] -= r[2] * t0 - r[0] * t2
        block[5, 3 + j] -= r[0] * t1 - r[1] * t0


@njit(**JIT)
def block_factors(diagonal, free, out):
    """``out (n, 6, 6)``: the lower Cholesky factor L (L·Lᵀ) of each free body's
    ``diagonal`` block (:func:`system_blocks`), the preconditioner of
    :func:`newton_correction`; zero for bodies not ``free (n,)``. The blocks are symmetric
    positive definite (a positive mass and inertia plus positive semi-definite slopes)."""
    for body in range(diagonal.shape[0]):
        out[body] = 0.0
        if free[body]:
            _cholesky(diagonal[body], out[body])


@njit(**JIT)
def _block_product(diagonal, coupling, bodies, active, z, out):
    """``out (n, 6)`` = (M + h²K + h·C)·z from :func:`system_blocks`' blocks, over the
    body pairs ``active`` (those with a coupling block)."""
    for b in range(z.shape[0]):
        for i in range(6):
            total = 0.0
            for j in range(6):
                total += diagonal[b, i, j] * z[b, j]
            out[b, i] = total
    for t in range(active.shape[0]):
        q = active[t]
        a, b = bodies[q, 0], bodies[q, 1]
        block = coupling[q]
        for i in range(6):
            to_a, to_b = 0.0, 0.0
            for j in range(6):
                to_a += block[i, j] * z[b, j]
                to_b += block[j, i] * z[a, j]
            out[a, i] += to_a
            out[b, i] += to_b


@njit(**BORROW)
def _cholesky(a, out):
    """``out (6, 6)``: the lower Cholesky factor of the symmetric positive definite ``a``
    (its lower triangle is read); the upper triangle of ``out`` is left as it was."""
    for j in range(6):
        diagonal = a[j, j]
        for k in range(j):
            diagonal -= out[j, k] * out[j, k]
        out[j, j] = np.sqrt(diagonal)
        for i in range(j + 1, 6):
            total = a[i, j]
            for k in range(j):
                total -= out[i, k] * out[j, k]
            out[i, j] = total / out[j, j]


@njit(**JIT)
def _preconditioned(factors, free, r, out):
    """``out (n, 6)``: each free body's block solved for its row of ``r`` by the Cholesky
    ``factors (n, 6, 6)`` (L·y = r, then Lᵀ·x = y); 0 elsewhere."""
    for b in range(r.shape[0]):
        if not free[b]:
            out[b, :] = 0.0
            continue
        low = factors[b]
        for i in range(6):
            total = r[b, i]
            for k in range(i):
                total -= low[i, k] * out[b, k]
            out[b, i] = total / low[i, i]
        for i in range(5, -1, -1):
            total = out[b, i]
            for k in range(i + 1, 6):
                total -= low[k, i] * out[b, k]
            out[b, i] = total / low[i, i]


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
    bodies, offsets = contacts[0], contacts[1]
    n = mass.shape[0]
    diagonal, coupling = np.empty((n, 6, 6)), np.empty((bodies.shape[0], 6, 6))
    system_blocks(contacts, origins, mass, inertia, h, free, diagonal, coupling)
    factors = np.empty((n, 6, 6))
    block_factors(diagonal, free, factors)
    coupled = 0  # the body pairs with a coupling block: both free, a contact acting
    active = np.empty(bodies.shape[0], np.int64)
    for q in range(bodies.shape[0]):
        if free[bodies[q, 0]] and free[bodies[q, 1]] and offsets[q + 1] > offsets[q]:
            active[coupled] = q
            coupled += 1
    active = active[:coupled]
    z[:] = 0.0
    r = rhs.copy()
    for b in range(n):
        if not free[b]:
            r[b, :] = 0.0
    p, s, product = np.empty((n, 6)), np.empty((n, 6)), np.empty((n, 6))
    _preconditioned(factors, free, r, s)
    p[:] = s
    rs = _dot(r, s, free)
    start = np.sqrt(_dot(r, r, free))
    if start == 0.0:
        return 0
    for iteration in range(most):
        _block_product(diagonal, coupling, bodies, active, p, product)
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
        _preconditioned(factors, free, r, s)
        rs_new = _dot(r, s, free)
        beta = rs_new / rs
        rs = rs_new
        for b in range(n):
            for i in range(6):
                p[b, i] = s[b, i] + beta * p[b, i]
    return most
