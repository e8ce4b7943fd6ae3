"""Rigid-body kernels: contact forces and the motion update (paper §2, Algorithms 1 and 3).

State arrays (float64, world frame): ``positions (n, 3)`` centres of mass,
``orientations (n, 4)`` unit quaternions (w, x, y, z), ``velocities (n, 3)``,
``angular_velocities (n, 3)``; ``inverse_mass (n,)``, ``inertia`` and
``inverse_inertia (n, 3, 3)`` (body frame, about the centre of mass; inverses 0 for
fixed bodies).

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

from .jit import JIT

PAPER, LINEAR, HERTZ = 0, 1, 2


@njit(**JIT)
def rotation_matrices(orientations, out):
    """``out (n, 3, 3)``: rotation of each unit quaternion ``orientations (n, 4)``."""
    for b in range(orientations.shape[0]):
        _rotation(orientations[b], out[b])


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
    """Picard's convergence test (see ``engine.picard._settled``): every free body's
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


@njit(**JIT)
def advance(start, force, torque, inverse_mass, inertia_body, inverse_inertia, dt, out):
    """One Euler update from the step's start: ``v' = v + dt·F/m``, ``L' = L + dt·τ``,
    ``x' = x + dt·v'``, ``q' = exp(dt·ω̄/2)·q`` with ω̄ = I_w(q)⁻¹L', then ω' = I_w(q')⁻¹L'.

    ``start = (positions, orientations, velocities, angular_velocities)`` at the step's
    start; ``out`` the same four arrays for the result (may not alias ``start``). Angular
    momentum L = I_w ω (I_w = R I R⁻¹ the world inertia) is what the torque changes, so
    it is conserved exactly; the orientation turns by the mean angular velocity. Fixed
    bodies (inverse mass 0) keep their pose and velocities.
    """
    x0, q0, v0, w0 = start
    x1, q1, v1, w1 = out
    rot = np.empty((3, 3))
    inv_world = np.empty((3, 3))
    inertia = np.empty((3, 3))
    momentum = np.empty(3)
    omega = np.empty(3)
    for b in range(x0.shape[0]):
        if inverse_mass[b] == 0.0:
            for c in range(3):
                x1[b, c], v1[b, c], w1[b, c] = x0[b, c], v0[b, c], w0[b, c]
            for c in range(4):
                q1[b, c] = q0[b, c]
            continue
        for c in range(3):
            v1[b, c] = v0[b, c] + dt * force[b, c] * inverse_mass[b]
            x1[b, c] = x0[b, c] + dt * v1[b, c]
        _rotation(q0[b], rot)
        _conjugate(rot, inverse_inertia[b], inv_world)
        _conjugate(rot, inertia_body[b], inertia)
        for i in range(3):
            momentum[i] = dt * torque[b, i]
            for j in range(3):
                momentum[i] += inertia[i, j] * w0[b, j]
        _times(inv_world, momentum, omega)
        _turn(q0[b], omega, dt, q1[b])
        _rotation(q1[b], rot)
        _conjugate(rot, inverse_inertia[b], inv_world)
        _times(inv_world, momentum, omega)
        for c in range(3):
            w1[b, c] = omega[c]


@njit(**JIT)
def _rotation(q, out):
    w, x, y, z = q[0], q[1], q[2], q[3]
    out[0, 0], out[0, 1], out[0, 2] = (
        1 - 2 * (y * y + z * z),
        2 * (x * y - w * z),
        2 * (x * z + w * y),
    )
    out[1, 0], out[1, 1], out[1, 2] = (
        2 * (x * y + w * z),
        1 - 2 * (x * x + z * z),
        2 * (y * z - w * x),
    )
    out[2, 0], out[2, 1], out[2, 2] = (
        2 * (x * z - w * y),
        2 * (y * z + w * x),
        1 - 2 * (x * x + y * y),
    )


@njit(**JIT)
def _conjugate(rot, matrix, out):
    """``out = R · M · Rᵀ`` (a body-frame tensor in the world frame)."""
    for i in range(3):
        for j in range(3):
            total = 0.0
            for k in range(3):
                for m in range(3):
                    total += rot[i, k] * matrix[k, m] * rot[j, m]
            out[i, j] = total


@njit(**JIT)
def _times(m, v, out):
    """``out = m @ v`` for a 3×3 ``m`` and a 3-vector ``v``."""
    for i in range(3):
        out[i] = m[i, 0] * v[0] + m[i, 1] * v[1] + m[i, 2] * v[2]


@njit(**JIT)
def _turn(q, omega, dt, out):
    """``out = exp(dt·ω/2) ⊗ q``, renormalised (ω in the world frame)."""
    angle = np.sqrt(omega[0] ** 2 + omega[1] ** 2 + omega[2] ** 2) * dt
    if angle > 0.0:
        s = np.sin(0.5 * angle) / angle * dt
        rw, rx, ry, rz = np.cos(0.5 * angle), omega[0] * s, omega[1] * s, omega[2] * s
    else:
        rw, rx, ry, rz = 1.0, 0.0, 0.0, 0.0
    w, x, y, z = q[0], q[1], q[2], q[3]
    nw = rw * w - rx * x - ry * y - rz * z
    nx = rw * x + rx * w + ry * z - rz * y
    ny = rw * y - rx * z + ry * w + rz * x
    nz = rw * z + rx * y - ry * x + rz * w
    norm = np.sqrt(nw * nw + nx * nx + ny * ny + nz * nz)
    out[0], out[1], out[2], out[3] = nw / norm, nx / norm, ny / norm, nz / norm
