"""Contact force kernels (paper §2): each contact's normal and friction force and torque,
and the Picard convergence test over the bodies' forces.

Contact laws (``law[0]``): ``PAPER`` — F_n = K_s · δ/(ε_a + ε_b) · √m_red, the paper's
spring (1 − |n|/ε with |n| the distance from the contact point to either surface is
δ/(ε_a + ε_b), δ = ε_a + ε_b − d the overlap); ``LINEAR`` — F_n = k·δ; ``HERTZ`` — F_n =
k·δ^{3/2}. Each adds optional normal damping −c·v_n with c = 2ζ√(k_eff·m_red), k_eff =
∂F_n/∂δ (the normal force never pulls), and a tangential friction force capped by
Coulomb's law, −μ·F_n·v_t/√(|v_t|² + v_slip²) (a regularised Coulomb law: no history, so a
Picard iteration sees a function of the state only). ``law = (kind, stiffness, damping
ratio ζ, friction μ, slip velocity)``.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from engine.kernels.jit import JIT

PAPER, LINEAR, HERTZ = 0, 1, 2


@njit(**JIT)
def contact_forces(bodies, offsets, points, normals, overlaps, state, params, law, out):
    """Add contact forces and torques to ``out``; returns the elastic energy.

    ``out = (force, torque, friction_force, friction_torque (n, 3), stiffness (n, 2))``:
    normal (spring and damping) and friction contributions go to separate arrays, so that
    a Picard iteration can relax them separately; ``stiffness (n, 3)[b]`` receives the sums
    over b's contacts of ∂F_n/∂δ and of the friction's ∂F_t/∂v_t (for the relaxation's
    first weight) and of the contact forces' magnitudes |F_n| + |F_t| (the force scale of
    Picard's convergence test).

    ``bodies (k, 2)`` int64: body pair q = (a, b) owns contacts ``offsets[q]:offsets[q + 1]``
    of ``points, normals (c, 3)`` (normals unit, from a to b) and ``overlaps (c,)``.
    ``state = (positions, velocities, angular_velocities, lever_origins)``: velocities give
    the relative sliding velocity; torques are taken about ``lever_origins (n, 3)`` (the
    centres of mass at the start of the step: then every contact adds the same moment to
    both bodies with opposite signs, and angular momentum is conserved to rounding).
    ``params = (mass (n,), epsilon (n,))`` with ``inf`` mass for fixed bodies.
    """
    positions, velocities, spins, origins = state
    mass, epsilon = params
    force, torque, friction_force, friction_torque, stiffness = out
    kind, k_law, zeta, mu, v_slip = law
    energy = 0.0
    for q in range(bodies.shape[0]):
        a, b = bodies[q, 0], bodies[q, 1]
        ma, mb = mass[a], mass[b]
        if np.isinf(ma):
            m_red = mb
        elif np.isinf(mb):
            m_red = ma
        else:
            m_red = ma * mb / (ma + mb)
        reach = epsilon[a] + epsilon[b]
        for c in range(offsets[q], offsets[q + 1]):
            delta = overlaps[c]
            if delta <= 0.0:
                continue
            n0, n1, n2 = normals[c, 0], normals[c, 1], normals[c, 2]
            p0, p1, p2 = points[c, 0], points[c, 1], points[c, 2]
            if kind == PAPER:
                k_eff = k_law * np.sqrt(m_red) / reach
                f_n = k_eff * delta
                energy += 0.5 * k_eff * delta * delta
            elif kind == LINEAR:
                k_eff = k_law
                f_n = k_law * delta
                energy += 0.5 * k_law * delta * delta
            else:
                root = np.sqrt(delta)
                k_eff = 1.5 * k_law * root
                f_n = k_law * delta * root
                energy += 0.4 * k_law * delta * delta * root
            # velocity of B's material point relative to A's, at the contact point
            ra0, ra1, ra2 = p0 - positions[a, 0], p1 - positions[a, 1], p2 - positions[a, 2]
            rb0, rb1, rb2 = p0 - positions[b, 0], p1 - positions[b, 1], p2 - positions[b, 2]
            wa, wb = spins[a], spins[b]
            u0 = velocities[b, 0] + wb[1] * rb2 - wb[2] * rb1
            u1 = velocities[b, 1] + wb[2] * rb0 - wb[0] * rb2
            u2 = velocities[b, 2] + wb[0] * rb1 - wb[1] * rb0
            u0 -= velocities[a, 0] + wa[1] * ra2 - wa[2] * ra1
            u1 -= velocities[a, 1] + wa[2] * ra0 - wa[0] * ra2
            u2 -= velocities[a, 2] + wa[0] * ra1 - wa[1] * ra0
            v_n = u0 * n0 + u1 * n1 + u2 * n2
            if zeta > 0.0:
                f_n = max(f_n - 2.0 * zeta * np.sqrt(k_eff * m_red) * v_n, 0.0)
            t0, t1, t2 = u0 - v_n * n0, u1 - v_n * n1, u2 - v_n * n2
            # forces on B (A gets the opposite)
            _apply(force, torque, origins, b, p0, p1, p2, f_n * n0, f_n * n1, f_n * n2)
            _apply(force, torque, origins, a, p0, p1, p2, -f_n * n0, -f_n * n1, -f_n * n2)
            stiffness[a, 0] += k_eff
            stiffness[b, 0] += k_eff
            stiffness[a, 2] += f_n
            stiffness[b, 2] += f_n
            if mu > 0.0:
                slip = np.sqrt(t0 * t0 + t1 * t1 + t2 * t2 + v_slip * v_slip)
                scale = mu * f_n / slip
                g0, g1, g2 = -scale * t0, -scale * t1, -scale * t2
                _apply(friction_force, friction_torque, origins, b, p0, p1, p2, g0, g1, g2)
                _apply(friction_force, friction_torque, origins, a, p0, p1, p2, -g0, -g1, -g2)
                stiffness[a, 1] += mu * f_n / v_slip  # the steepest (sticking) slope
                stiffness[b, 1] += mu * f_n / v_slip
                gross = scale * np.sqrt(t0 * t0 + t1 * t1 + t2 * t2)
                stiffness[a, 2] += gross
                stiffness[b, 2] += gross
    return energy


@njit(**JIT)
def settled(computed, mismatch, gross, body_size, radius, fixed, tolerance, atol, weight):
    """Picard's convergence test (see ``engine.dynamics.picard._settled``): every free body's
    force mismatch within ``tolerance`` of the forces acting on it, size_f = max(|F|,
    gross + body_size), and its torque mismatch within ``tolerance`` of max(|τ|, R·size_f),
    each plus a floor ``atol · max(max size_f, weight)`` (times R for torques).
    ``computed``, ``mismatch`` = ``(force (n, 3), torque (n, 3))``; ``gross``,
    ``body_size``, ``radius (n,)`` float64; ``fixed (n,)`` bool."""
    force, torque = computed
    mismatch_f, mismatch_t = mismatch
    n = force.shape[0]
    largest = 0.0
    for b in range(n):
        if not fixed[b]:
            largest = max(largest, _size(force, b, gross[b] + body_size[b]))
    floor = atol * max(largest, weight)
    for b in range(n):
        if fixed[b]:
            continue
        size_f = _size(force, b, gross[b] + body_size[b])
        size_t = _size(torque, b, radius[b] * size_f)
        if _norm(mismatch_f, b) > tolerance * size_f + floor:
            return False
        if _norm(mismatch_t, b) > tolerance * size_t + floor * radius[b]:
            return False
    return True


@njit(**JIT)
def _norm(rows, b):
    return np.sqrt(rows[b, 0] * rows[b, 0] + rows[b, 1] * rows[b, 1] + rows[b, 2] * rows[b, 2])


@njit(**JIT)
def _size(rows, b, least):
    return max(_norm(rows, b), least)


@njit(**JIT)
def _apply(force, torque, origins, body, p0, p1, p2, g0, g1, g2):
    """Add force ``g`` at point ``p`` to ``body`` (moment about ``origins[body]``)."""
    r0, r1, r2 = p0 - origins[body, 0], p1 - origins[body, 1], p2 - origins[body, 2]
    force[body, 0] += g0
    force[body, 1] += g1
    force[body, 2] += g2
    torque[body, 0] += r1 * g2 - r2 * g1
    torque[body, 1] += r2 * g0 - r0 * g2
    torque[body, 2] += r0 * g1 - r1 * g0
