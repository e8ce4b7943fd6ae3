"""The contact forces linearised about one configuration, and the Newton correction of a
Picard iteration that solves them (``engine.dynamics.picard``).

A backward Euler step of length h from velocities v₀ seeks forces F(x₀ + h·v₁, v₁) that,
applied, give v₁ = v₀ + h·M⁻¹F. About the configuration of the last evaluation the contact
forces change as −(K·Δx + C·Δv): K the springs' stiffness (k_n·nnᵀ per contact, plus k_t·P
for a sticking tangential spring, and for a sliding one, whose force μF_n·ĝ turns with the
spring's g, (μF_n/|g|)·k_t·(P − ĝĝᵀ)), C their velocity slopes (normal damping c_n·nnᵀ, a
tangential spring's damping c_t·P, scaled alike when sliding, and the regularised friction's
Jacobian μF_n/s·(P − t·tᵀ/s²), P = I − nnᵀ, t the sliding velocity, s = √(|t|² + v_slip²)),
each seen by the two bodies through J = [I | −[r]×] (r from the body's lever origin to the
contact point). Friction that is proportional to the normal force (a sliding spring, the
regularised law) also follows its changes: (F_t/F_n)·k_n·nᵀ in K and (F_t/F_n)·c_n·nᵀ in C.
Without these terms the matrix would be symmetric, but Newton's iterates on a pile with
sliding contacts would close the residual by about ten times per iteration instead of
squaring it (measured on the 48-object pile).

The velocity correction z then solves (M + h²K + h·C)·z = h·r, r the residual of the
forces, by BiCGSTAB preconditioned with each body's 6×6 block (the matrix is not
symmetric), and the applied forces become the computed ones less (h·K + C)·z: a sum of
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
    FRICTION_FORCE,
    FRICTION_SCALE,
    NORMAL_MAGNITUDE,
    SLIP,
    SPRING_SLOPE,
    TANGENT,
    TANGENT_SPRING,
)
from engine.kernels.jit import BORROW, JIT


@njit(**BORROW, forceinline=True)
def _slopes(normals, terms, c, w_k, w_c, out):
    """``out (3, 3)`` = w_k·K_c + w_c·C_c for contact ``c`` (module docstring; not
    symmetric where friction follows the normal force)."""
    n0, n1, n2 = normals[c, 0], normals[c, 1], normals[c, 2]
    normal = w_k * terms[c, SPRING_SLOPE] + w_c * terms[c, DAMPING_SLOPE]
    scale = w_k * terms[c, TANGENT_SPRING] + w_c * terms[c, FRICTION_SCALE]
    slip = terms[c, SLIP]
    t0, t1, t2 = terms[c, TANGENT], terms[c, TANGENT + 1], terms[c, TANGENT + 2]
    n = (n0, n1, n2)
    t = (t0, t1, t2)
    inv = 1.0 / (slip * slip) if slip > 0.0 else 0.0
    # friction proportional to the normal force (SLIP > 0: sliding, or the regularised law)
    # changes with it: (F_t/F_n)·nᵀ times the normal slopes
    f_n = terms[c, NORMAL_MAGNITUDE]
    follows = normal / f_n if slip > 0.0 and f_n > 0.0 else 0.0
    f = (terms[c, FRICTION_FORCE], terms[c, FRICTION_FORCE + 1], terms[c, FRICTION_FORCE + 2])
    for i in range(3):
        for j in range(3):
            unit = 1.0 if i == j else 0.0
            out[i, j] = (
                normal * n[i] * n[j]
                + scale * (unit - n[i] * n[j] - t[i] * t[j] * inv)
                + follows * f[i] * n[j]
            )


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
def system_blocks(contacts, origins, mass, inertia, h, free, active, diagonal, coupling):
    """The blocks of M + h²K + h·C (module docstring) over the free bodies: ``diagonal (n,
    6, 6)`` each free body's own (its mass, its world ``inertia (n, 3, 3)`` and Jᵀ·S·J of
    its contacts, J = [I | −[r]×], S a contact's slopes; zero for bodies not ``free``),
    ``coupling (m, 2, 6, 6)`` for each body pair ``active[t]`` (:func:`coupled_pairs`, in
    order) its −J_aᵀ·S·J_b (``[t, 0]``: the rows of A, the columns of B) and −J_bᵀ·S·J_a
    (``[t, 1]``: the rows of B, the columns of A) summed over its contacts. Only the
    coupled pairs have blocks: a scene's candidate pairs are mostly apart, and zeroing
    a block for each (173 kB on the 48-object pile) was most of a correction's time.
    ``contacts = (bodies, offsets, points, normals, terms)``."""
    bodies, offsets, points, normals, terms = contacts
    n = mass.shape[0]
    diagonal[:] = 0.0
    slot = 0  # the next coupled pair's row of ``coupling``
    slopes = np.empty((3, 3))
    turned_a, turned_b = np.empty((3, 3)), np.empty((3, 3))  # S·[r]× of A's and B's lever
    crossed_a, crossed_b = np.empty((3, 3)), np.empty((3, 3))  # [r]×·S
    ra, rb = np.empty(3), np.empty(3)
    for q in range(bodies.shape[0]):
        a, b = bodies[q, 0], bodies[q, 1]
        row = -1
        if slot < active.shape[0] and active[slot] == q:
            row = slot
            slot += 1
            coupling[row] = 0.0
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
            _crossed(ra, slopes, crossed_a)
            _crossed(rb, slopes, crossed_b)
            if free[a]:
                _add_own(diagonal[a], slopes, ra, turned_a, crossed_a)
            if free[b]:
                _add_own(diagonal[b], slopes, rb, turned_b, crossed_b)
            if row >= 0:
                _add_coupling(coupling[row, 0], slopes, ra, turned_b, crossed_a)
                _add_coupling(coupling[row, 1], slopes, rb, turned_a, crossed_b)
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
def _crossed(r, slopes, out):
    """``out (3, 3)`` = [r]×·S: each column r × S's column."""
    for j in range(3):
        s0, s1, s2 = slopes[0, j], slopes[1, j], slopes[2, j]
        out[0, j] = r[1] * s2 - r[2] * s1
        out[1, j] = r[2] * s0 - r[0] * s2
        out[2, j] = r[0] * s1 - r[1] * s0


@njit(**BORROW, forceinline=True)
def _add_own(block, slopes, r, turned, crossed):
    """``block (6, 6)`` += Jᵀ·S·J = [[S, −S[r]×], [[r]×S, −[r]×·S[r]×]] with ``turned`` =
    S·[r]× and ``crossed`` = [r]×·S."""
    for i in range(3):
        for j in range(3):
            block[i, j] += slopes[i, j]
            block[i, 3 + j] -= turned[i, j]
            block[3 + i, j] += crossed[i, j]
    for j in range(3):
        t0, t1, t2 = turned[0, j], turned[1, j], turned[2, j]
        block[3, 3 + j] -= r[1] * t2 - r[2] * t1
        block[4, 3 + j] -= r[2] * t0 - r[0] * t2
        block[5, 3 + j] -= r[0] * t1 - r[1] * t0


@njit(**BORROW, forceinline=True)
def _add_coupling(block, slopes, r_row, turned_column, crossed_row):
    """``block (6, 6)`` += −J_rowᵀ·S·J_column = [[−S, S[r_c]×], [−[r_r]×S, [r_r]×·S[r_c]×]]
    with ``turned_column`` = S·[r_c]× and ``crossed_row`` = [r_r]×·S."""
    for i in range(3):
        for j in range(3):
            block[i, j] -= slopes[i, j]
            block[i, 3 + j] += turned_column[i, j]
            block[3 + i, j] -= crossed_row[i, j]
    for j in range(3):
        t0, t1, t2 = turned_column[0, j], turned_column[1, j], turned_column[2, j]
        block[3, 3 + j] += r_row[1] * t2 - r_row[2] * t1
        block[4, 3 + j] += r_row[2] * t0 - r_row[0] * t2
        block[5, 3 + j] += r_row[0] * t1 - r_row[1] * t0


@njit(**JIT)
def block_factors(diagonal, free, out, pivots):
    """``out (n, 6, 6)``, ``pivots (n, 6)`` int64: each free body's ``diagonal`` block
    (:func:`system_blocks`) as L·U with partial pivoting (:func:`_lu`), the preconditioner
    of :func:`newton_correction`; zero for bodies not ``free (n,)``."""
    for body in range(diagonal.shape[0]):
        out[body] = 0.0
        pivots[body] = 0
        if free[body]:
            out[body] = diagonal[body]
            _lu(out[body], pivots[body])


@njit(**JIT)
def coupled_pairs(bodies, offsets, free):
    """(m,) int64: the body pairs of ``bodies (k, 2)`` with coupling blocks in
    :func:`system_blocks`, in order: both bodies ``free``, a contact between them (pair q
    owns contacts ``offsets[q]:offsets[q + 1]``)."""
    active = np.empty(bodies.shape[0], np.int64)
    coupled = 0
    for q in range(bodies.shape[0]):
        if free[bodies[q, 0]] and free[bodies[q, 1]] and offsets[q + 1] > offsets[q]:
            active[coupled] = q
            coupled += 1
    return active[:coupled].copy()


@njit(**JIT)
def _block_product(diagonal, coupling, bodies, active, z, out):
    """``out (n, 6)`` = (M + h²K + h·C)·z from :func:`system_blocks`' blocks, over the
    body pairs ``active`` (those with coupling blocks, row t of ``coupling`` for
    ``active[t]``)."""
    for b in range(z.shape[0]):
        for i in range(6):
            total = 0.0
            for j in range(6):
                total += diagonal[b, i, j] * z[b, j]
            out[b, i] = total
    for t in range(active.shape[0]):
        q = active[t]
        a, b = bodies[q, 0], bodies[q, 1]
        to_a_block, to_b_block = coupling[t, 0], coupling[t, 1]
        for i in range(6):
            to_a, to_b = 0.0, 0.0
            for j in range(6):
                to_a += to_a_block[i, j] * z[b, j]
                to_b += to_b_block[i, j] * z[a, j]
            out[a, i] += to_a
            out[b, i] += to_b


@njit(**BORROW)
def _lu(a, pivots):
    """``a (6, 6)`` overwritten by its L·U factors with partial pivoting (L unit lower
    below the diagonal, U on and above it); ``pivots (6,)`` the row swapped into each."""
    for k in range(6):
        best, row = abs(a[k, k]), k
        for i in range(k + 1, 6):
            if abs(a[i, k]) > best:
                best, row = abs(a[i, k]), i
        pivots[k] = row
        if row != k:
            for j in range(6):
                a[k, j], a[row, j] = a[row, j], a[k, j]
        for i in range(k + 1, 6):
            a[i, k] /= a[k, k]
            for j in range(k + 1, 6):
                a[i, j] -= a[i, k] * a[k, j]


@njit(**JIT)
def _preconditioned(factors, pivots, free, r, out):
    """``out (n, 6)``: each free body's block solved for its row of ``r`` by its L·U
    ``factors (n, 6, 6)`` and ``pivots (n, 6)`` (:func:`block_factors`); 0 elsewhere."""
    for b in range(r.shape[0]):
        if not free[b]:
            out[b, :] = 0.0
            continue
        lu, swap = factors[b], pivots[b]
        for i in range(6):
            out[b, i] = r[b, i]
        for i in range(6):
            k = swap[i]
            if k != i:
                out[b, i], out[b, k] = out[b, k], out[b, i]
        for i in range(6):
            total = out[b, i]
            for k in range(i):
                total -= lu[i, k] * out[b, k]
            out[b, i] = total
        for i in range(5, -1, -1):
            total = out[b, i]
            for k in range(i + 1, 6):
                total -= lu[i, k] * out[b, k]
            out[b, i] = total / lu[i, i]


@njit(**JIT)
def _dot(x, y, free):
    total = 0.0
    for b in range(x.shape[0]):
        if free[b]:
            for i in range(6):
                total += x[b, i] * y[b, i]
    return total


@njit(**JIT)
def newton_correction(contacts, origins, mass, inertia, free, h, rhs, tolerance, most, z,
                      change):  # fmt: skip
    """Solve (M + h²K + h·C)·z = ``rhs (n, 6)`` for the free bodies by BiCGSTAB (van der
    Vorst), preconditioned with each body's 6×6 block, to a relative residual
    ``tolerance`` or ``most`` iterations; writes ``z (n, 6)`` (0 on bodies not ``free``)
    and ``change (n, 6)`` = (h·K + C)·z on the free bodies (0 elsewhere: the contact
    forces' change under the correction, from the same blocks), and returns the
    iterations taken. ``contacts = (bodies, offsets, points, normals, terms)`` of one
    evaluation; ``mass (n,)``, world ``inertia (n, 3, 3)``. The matrix is not symmetric
    where friction follows the normal force (module docstring)."""
    bodies, offsets = contacts[0], contacts[1]
    n = mass.shape[0]
    active = coupled_pairs(bodies, offsets, free)
    diagonal, coupling = np.empty((n, 6, 6)), np.empty((active.shape[0], 2, 6, 6))
    system_blocks(contacts, origins, mass, inertia, h, free, active, diagonal, coupling)
    factors, pivots = np.empty((n, 6, 6)), np.empty((n, 6), np.int64)
    block_factors(diagonal, free, factors, pivots)
    z[:] = 0.0
    change[:] = 0.0
    r = rhs.copy()
    for b in range(n):
        if not free[b]:
            r[b, :] = 0.0
    start = np.sqrt(_dot(r, r, free))
    if start == 0.0:
        return 0
    taken = _bicgstab(diagonal, coupling, bodies, active, factors, pivots, free, r, start,
                      tolerance, most, z)  # fmt: skip
    # (h·K + C)·z = ((M + h²K + h·C)·z − M·z)/h on the free bodies
    _block_product(diagonal, coupling, bodies, active, z, change)
    for b in range(n):
        if not free[b]:
            change[b, :] = 0.0
            continue
        for i in range(3):
            own = mass[b] * z[b, i]
            spin = inertia[b, i, 0] * z[b, 3] + inertia[b, i, 1] * z[b, 4]
            spin += inertia[b, i, 2] * z[b, 5]
            change[b, i] = (change[b, i] - own) / h
            change[b, 3 + i] = (change[b, 3 + i] - spin) / h
    return taken


@njit(**JIT)
def corrected_forces(contacts, origins, mass, inertia, free, h, computed, applied, tolerance,
                     most, out):  # fmt: skip
    """The next applied forces of a Newton correction, in one call: with F the ``computed``
    and A the ``applied`` forces (each ``(force, torque)``, ``(n, 3)`` float64), z solves
    (M + h²K + h·C)·z = h·(F − A) (:func:`newton_correction`) and ``out = (force, torque)``
    receives F − (h·K + C)·z, 0 on bodies not ``free``. ``applied`` may be ``computed``'s
    zeros (a prediction: the right-hand side is h·F). Returns the solve's iterations."""
    n = mass.shape[0]
    forces, rhs = np.empty((n, 6)), np.empty((n, 6))
    for b in range(n):
        for i in range(3):
            forces[b, i], forces[b, 3 + i] = computed[0][b, i], computed[1][b, i]
            rhs[b, i] = h * (forces[b, i] - applied[0][b, i])
            rhs[b, 3 + i] = h * (forces[b, 3 + i] - applied[1][b, i])
    z, change = np.empty((n, 6)), np.zeros((n, 6))
    taken = 0
    if contacts[2].shape[0] > 0:  # else nothing to linearise: the forces are constant
        taken = newton_correction(contacts, origins, mass, inertia, free, h, rhs, tolerance,
                                  most, z, change)  # fmt: skip
    force, torque = out
    for b in range(n):
        for i in range(3):
            force[b, i] = forces[b, i] - change[b, i] if free[b] else 0.0
            torque[b, i] = forces[b, 3 + i] - change[b, 3 + i] if free[b] else 0.0
    return taken


@njit(**JIT)
def _bicgstab(diagonal, coupling, bodies, active, factors, pivots, free, r, start, tolerance,
              most, z):  # fmt: skip
    """BiCGSTAB on the blocks from ``r`` (the right-hand side, norm ``start`` > 0) and
    ``z`` = 0 (:func:`newton_correction`); returns the iterations taken."""
    n = r.shape[0]
    shadow = r.copy()
    p, v = np.zeros((n, 6)), np.zeros((n, 6))
    y, s, w, t = np.empty((n, 6)), np.empty((n, 6)), np.empty((n, 6)), np.empty((n, 6))
    rho, alpha, omega = 1.0, 1.0, 1.0
    for iteration in range(most):
        rho_new = _dot(shadow, r, free)
        if rho_new == 0.0:  # breakdown: z is the best this Krylov space gives
            return iteration
        beta = (rho_new / rho) * (alpha / omega)
        rho = rho_new
        for b in range(n):
            for i in range(6):
                p[b, i] = r[b, i] + beta * (p[b, i] - omega * v[b, i])
        _preconditioned(factors, pivots, free, p, y)
        _block_product(diagonal, coupling, bodies, active, y, v)
        along = _dot(shadow, v, free)
        if along == 0.0:
            return iteration
        alpha = rho / along
        for b in range(n):
            for i in range(6):
                s[b, i] = r[b, i] - alpha * v[b, i]
        if np.sqrt(_dot(s, s, free)) <= tolerance * start:
            for b in range(n):
                for i in range(6):
                    z[b, i] += alpha * y[b, i]
            return iteration + 1
        _preconditioned(factors, pivots, free, s, w)
        _block_product(diagonal, coupling, bodies, active, w, t)
        tt = _dot(t, t, free)
        omega = _dot(t, s, free) / tt if tt > 0.0 else 0.0
        for b in range(n):
            for i in range(6):
                z[b, i] += alpha * y[b, i] + omega * w[b, i]
                r[b, i] = s[b, i] - omega * t[b, i]
        if np.sqrt(_dot(r, r, free)) <= tolerance * start or omega == 0.0:
            return iteration + 1
    return most
