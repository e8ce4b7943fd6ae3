"""Rigid-body motion kernels (paper §2, Algorithms 1 and 3): the update of the state from
forces and torques, and rotation matrices of the orientations.

State arrays (float64, world frame): ``positions (n, 3)`` centres of mass,
``orientations (n, 4)`` unit quaternions (w, x, y, z), ``velocities (n, 3)``,
``angular_velocities (n, 3)``; ``inverse_mass (n,)``, ``inertia`` and
``inverse_inertia (n, 3, 3)`` (body frame, about the centre of mass; inverses 0 for
fixed bodies).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from engine.kernels.geometry.rotation import quaternion_rotation
from engine.kernels.jit import BORROW, JIT


@njit(**JIT)
def rotation_matrices(orientations, out):
    """``out (n, 3, 3)`` float64: rotation of each unit quaternion ``orientations (n, 4)``
    float64 (:func:`~engine.kernels.geometry.rotation.quaternion_rotation`)."""
    for b in range(orientations.shape[0]):
        quaternion_rotation(orientations[b], out[b])


@njit(**JIT)
def world_inertias(orientations, inertia_body, free, out):
    """``out (n, 3, 3)`` float64: R·I·Rᵀ of each body (``orientations (n, 4)`` unit
    quaternions, ``inertia_body (n, 3, 3)``), zero where not ``free (n,)`` bool."""
    rot = np.empty((3, 3))
    for b in range(orientations.shape[0]):
        if not free[b]:
            out[b] = 0.0
            continue
        quaternion_rotation(orientations[b], rot)
        _conjugate(rot, inertia_body[b], out[b])


@njit(**JIT)
def placed_bodies(positions, orientations, centers, spheres, limit, out):
    """Place the bodies: ``out = (origins, centres)``, each ``(n, 3)`` float64,
    receives each body's mesh-frame origin x − R·c and the world centre origin + R·s of its
    root bounding sphere, for ``positions (n, 3)``, unit ``orientations (n, 4)`` (R: their
    rotations), ``centers (n, 3)`` (centres of mass, mesh frame) and ``spheres (n, ≥3)``
    (root sphere centres, mesh frame). Returns the first body with a centre coordinate
    that is not finite within ±``limit``, else −1."""
    origins, centres = out
    rot = np.empty((3, 3))
    bad = -1
    for b in range(positions.shape[0]):
        quaternion_rotation(orientations[b], rot)
        for i in range(3):
            turned = rot[i, 0] * centers[b, 0] + rot[i, 1] * centers[b, 1]
            origins[b, i] = positions[b, i] - (turned + rot[i, 2] * centers[b, 2])
        for i in range(3):
            turned = rot[i, 0] * spheres[b, 0] + rot[i, 1] * spheres[b, 1]
            centres[b, i] = origins[b, i] + (turned + rot[i, 2] * spheres[b, 2])
            if bad < 0 and not abs(centres[b, i]) <= limit:  # NaN fails too
                bad = b
    return bad


@njit(**JIT)
def rest_counts(start, end, anchor, radius, fixed, asleep, reach, rest, moving):
    """The sleep rule's count after a step (:mod:`engine.dynamics.sleep`). ``start``,
    ``end``, ``anchor``: ``(positions (n, 3), orientations (n, 4))`` float64 — the bodies
    at the step's start, at its end, and where each one's count began. An awake free
    body (not ``fixed``, not ``asleep (n,)`` bool) whose count ``rest (n,)`` int64 is 0
    begins one at the step's start (its ``anchor`` rows become ``start``'s); it has
    rested one step more while no point of it is ``reach`` or more from where it was at
    its anchor (|Δx| + θ·R, θ the angle of the rotation between the two orientations, R
    its bounding ``radius (n,)`` float64), else its count is 0 and ``moving (n,)`` bool
    receives it. Every other body's count is 0. Returns ``(any moving, any asleep or
    resting)``."""
    positions, orientations = end
    anchor_positions, anchor_orientations = anchor
    any_moving, others = False, False
    for b in range(positions.shape[0]):
        awake = not fixed[b] and not asleep[b]
        if awake and rest[b] == 0:
            for i in range(3):
                anchor_positions[b, i] = start[0][b, i]
            for i in range(4):
                anchor_orientations[b, i] = start[1][b, i]
        resting = awake and _displacement(end, anchor, radius, b) < reach
        moving[b] = awake and not resting
        rest[b] = rest[b] + 1 if resting else 0
        any_moving = any_moving or moving[b]
        others = others or asleep[b] or resting
    return any_moving, others


@njit(**BORROW, forceinline=True)
def _displacement(end, anchor, radius, b):
    """|Δx| + θ·R of body ``b`` between ``anchor`` and ``end`` (as :func:`rest_counts`):
    no point of it moved farther. θ = 2·atan2(|u|, |w|) for the rotation (w, u) = q ⊗ q̄ₐ
    (accurate at small angles, where an arccos of the dot product is not)."""
    x, q = end[0], end[1]
    xa, qa = anchor[0], anchor[1]
    d0, d1, d2 = x[b, 0] - xa[b, 0], x[b, 1] - xa[b, 1], x[b, 2] - xa[b, 2]
    w, u0, u1, u2 = q[b, 0], q[b, 1], q[b, 2], q[b, 3]
    wa, a0, a1, a2 = qa[b, 0], qa[b, 1], qa[b, 2], qa[b, 3]
    real = w * wa + u0 * a0 + u1 * a1 + u2 * a2
    r0 = wa * u0 - w * a0 - (u1 * a2 - u2 * a1)
    r1 = wa * u1 - w * a1 - (u2 * a0 - u0 * a2)
    r2 = wa * u2 - w * a2 - (u0 * a1 - u1 * a0)
    angle = 2.0 * np.arctan2(np.sqrt(r0 * r0 + r1 * r1 + r2 * r2), abs(real))
    return np.sqrt(d0 * d0 + d1 * d1 + d2 * d2) + radius[b] * angle


@njit(**JIT)
def wake_near(pairs, moving, asleep, rest):
    """Each body of a pair ``pairs (k, 2)`` int64 whose other body is ``moving
    (n,)`` bool wakes (``asleep (n,)`` bool cleared) and starts its ``rest (n,)`` int64
    count again."""
    for t in range(pairs.shape[0]):
        a, b = pairs[t, 0], pairs[t, 1]
        if moving[b]:
            asleep[a] = False
            rest[a] = 0
        if moving[a]:
            asleep[b] = False
            rest[b] = 0


@njit(**JIT)
def fall_asleep(fixed, asleep, rest, steps, velocities, angular_velocities):
    """The awake free bodies that have rested ``steps`` steps (``rest (n,)`` int64) fall
    asleep (``asleep (n,)`` bool set), at rest: their rows of ``velocities`` and
    ``angular_velocities (n, 3)`` float64 become 0."""
    for b in range(fixed.shape[0]):
        if not fixed[b] and not asleep[b] and rest[b] >= steps:
            asleep[b] = True
            for c in range(3):
                velocities[b, c] = 0.0
                angular_velocities[b, c] = 0.0


@njit(**JIT)
def largest_travel(velocities, angular_velocities, radius, epsilon, fixed, dt):
    """``(ratio, body)``: the largest (|v| + |ω|·R)·|dt| / ε over the bodies that are not
    ``fixed (n,)`` bool, and the first body that has it (−1 for none); ``velocities``,
    ``angular_velocities (n, 3)``, bounding ``radius (n,)``, ``epsilon (n,)`` float64."""
    largest, body = 0.0, -1
    for b in range(velocities.shape[0]):
        if fixed[b]:
            continue
        ratio = _surface_speed(velocities, angular_velocities, radius, b) * abs(dt) / epsilon[b]
        if body < 0 or ratio > largest:
            largest, body = ratio, b
    return largest, body


@njit(**BORROW, forceinline=True)
def _surface_speed(velocities, angular_velocities, radius, b):
    """|v| + |ω|·R of body ``b`` (arrays as :func:`largest_travel`)."""
    v0, v1, v2 = velocities[b, 0], velocities[b, 1], velocities[b, 2]
    w0, w1, w2 = angular_velocities[b, 0], angular_velocities[b, 1], angular_velocities[b, 2]
    linear = np.sqrt(v0 * v0 + v1 * v1 + v2 * v2)
    return linear + radius[b] * np.sqrt(w0 * w0 + w1 * w1 + w2 * w2)


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
        quaternion_rotation(q0[b], rot)
        _conjugate(rot, inverse_inertia[b], inv_world)
        _conjugate(rot, inertia_body[b], inertia)
        for i in range(3):
            momentum[i] = dt * torque[b, i]
            for j in range(3):
                momentum[i] += inertia[i, j] * w0[b, j]
        _times(inv_world, momentum, omega)
        _turn(q0[b], omega, dt, q1[b])
        quaternion_rotation(q1[b], rot)
        _conjugate(rot, inverse_inertia[b], inv_world)
        _times(inv_world, momentum, omega)
        for c in range(3):
            w1[b, c] = omega[c]


@njit(**JIT)
def extrapolated(start, mid, inertia_body, inverse_inertia, mass, force, free, dt, out):
    """The implicit midpoint rule's end of step (``engine.dynamics.picard._extrapolate``):
    from ``start`` through ``mid`` (each ``(positions, orientations, velocities,
    angular_velocities)``) on to ``out`` (the same four arrays; may not alias either).
    A ``free (n,)`` body's position and velocity become 2·mid − start, its orientation
    turns on by the rotation from start to mid (q₂ = q₁ ⊗ q̄₀ ⊗ q₁, renormalised), and its
    world angular momentum becomes 2·L₁ − L₀ + dt·(x₀ − x₁) × F_c, F_c = m·(v₁ − v₀)·2/dt −
    ``force (n, 3)`` the contact force of the half step (``force``: gravity and external
    forces), whence ω₂ = R₂ I⁻¹ R₂ᵀ L₂. Other bodies keep ``mid``. ``mass (n,)``,
    ``inertia_body``, ``inverse_inertia (n, 3, 3)`` (body frame)."""
    x0, q0, v0, w0 = start
    x1, q1, v1, w1 = mid
    x2, q2, v2, w2 = out
    rot = np.empty((3, 3))
    world = np.empty((3, 3))
    before, now, spin = np.empty(3), np.empty(3), np.empty(3)
    contact, lever = np.empty(3), np.empty(3)
    for b in range(x0.shape[0]):
        if not free[b]:
            for c in range(3):
                x2[b, c], v2[b, c], w2[b, c] = x1[b, c], v1[b, c], w1[b, c]
            for c in range(4):
                q2[b, c] = q1[b, c]
            continue
        quaternion_rotation(q0[b], rot)
        _conjugate(rot, inertia_body[b], world)
        _times(world, w0[b], before)
        quaternion_rotation(q1[b], rot)
        _conjugate(rot, inertia_body[b], world)
        _times(world, w1[b], now)
        # q₁ ⊗ q̄₀, then ⊗ q₁
        a0, a1, a2, a3 = q1[b, 0], q1[b, 1], q1[b, 2], q1[b, 3]
        h0, h1, h2, h3 = _product(a0, a1, a2, a3, q0[b, 0], -q0[b, 1], -q0[b, 2], -q0[b, 3])
        _normalised(_product(h0, h1, h2, h3, a0, a1, a2, a3), q2[b])
        for c in range(3):
            contact[c] = mass[b] * (v1[b, c] - v0[b, c]) * (2.0 / dt) - force[b, c]
            lever[c] = x0[b, c] - x1[b, c]
            x2[b, c] = 2.0 * x1[b, c] - x0[b, c]
            v2[b, c] = 2.0 * v1[b, c] - v0[b, c]
        for c in range(3):
            j, k = (c + 1) % 3, (c + 2) % 3
            moment = lever[j] * contact[k] - lever[k] * contact[j]
            spin[c] = 2.0 * now[c] - before[c] + dt * moment
        quaternion_rotation(q2[b], rot)
        _conjugate(rot, inverse_inertia[b], world)
        _times(world, spin, now)
        for c in range(3):
            w2[b, c] = now[c]


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
    _normalised(_product(rw, rx, ry, rz, q[0], q[1], q[2], q[3]), out)


@njit(**BORROW, forceinline=True)
def _product(a0, a1, a2, a3, b0, b1, b2, b3):
    """The Hamilton product a ⊗ b of two quaternions (w, x, y, z), by components."""
    return (
        a0 * b0 - a1 * b1 - a2 * b2 - a3 * b3,
        a0 * b1 + a1 * b0 + a2 * b3 - a3 * b2,
        a0 * b2 - a1 * b3 + a2 * b0 + a3 * b1,
        a0 * b3 + a1 * b2 - a2 * b1 + a3 * b0,
    )


@njit(**BORROW, forceinline=True)
def _normalised(q, out):
    """``out (4,)`` = the quaternion ``q`` (a 4-tuple) over its norm."""
    norm = np.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    out[0], out[1], out[2], out[3] = q[0] / norm, q[1] / norm, q[2] / norm, q[3] / norm


@njit(**JIT)
def relaxation_products(previous, current, out):
    """``out (4,)`` float64: the dot products of Aitken's relaxation over the residuals
    ``previous``, ``current (m,)`` float64 and their swing ``s = current − previous``:
    ``(previous·s, s·s, current·current, previous·previous)``, each summed in index order
    (one pass, no BLAS: a multithreaded ``ddot`` of a scene's residual costs milliseconds
    on a loaded machine and sums in an order that depends on its thread count)."""
    ps, ss, cc, pp = 0.0, 0.0, 0.0, 0.0
    for t in range(previous.shape[0]):
        p, c = previous[t], current[t]
        s = c - p
        ps += p * s
        ss += s * s
        cc += c * c
        pp += p * p
    out[0], out[1], out[2], out[3] = ps, ss, cc, pp


@njit(**JIT)
def flat_norm(force, torque, radius):
    """√(Σ|F_i|² + Σ|τ_i/R_i|²) of ``force``, ``torque (n, 3)`` and levers ``radius (n,)``
    float64: the norm of the forces and the torques made force-like, in index order."""
    total = 0.0
    for b in range(force.shape[0]):
        for i in range(3):
            total += force[b, i] * force[b, i]
    for b in range(torque.shape[0]):
        for i in range(3):
            t = torque[b, i] / radius[b]
            total += t * t
    return np.sqrt(total)


@njit(**JIT)
def moved_contacts(bodies, offsets, found, reach, before, after, out):
    """Contacts found at the configuration ``before`` carried rigidly to ``after``: each
    contact's point moves with body A and with body B (``p_a = R_a R_a⁰ᵀ (p − x_a⁰) + x_a``,
    likewise p_b), its normal turns with A, and its overlap shrinks by how far B's point
    moved from A's along it: δ' = δ − n'·(p_b − p_a), at most ``reach (k,)`` (the pair's
    ε_a + ε_b, as a search clips it). The new point is the middle of p_a and p_b.

    ``bodies (k, 2)``, ``offsets (k + 1,)`` int64 as in a search's contacts; ``found =
    (points, normals, overlaps)`` of ``c`` contacts (``(c, 3)``, ``(c, 3)``, ``(c,)``
    float64); ``before``, ``after``: ``(positions (n, 3), orientations (n, 4))`` float64
    of the bodies (centres of mass, unit quaternions); ``out`` as ``found``."""
    points, normals, overlaps = found
    out_points, out_normals, out_overlaps = out
    x0, q0 = before
    x1, q1 = after
    r0, r1 = np.empty((3, 3)), np.empty((3, 3))
    turns = np.empty((q0.shape[0], 3, 3))  # R R⁰ᵀ of each body in a pair with contacts
    done = np.zeros(q0.shape[0], np.bool_)
    pa, pb = np.empty(3), np.empty(3)
    for pair in range(bodies.shape[0]):
        if offsets[pair + 1] == offsets[pair]:
            continue
        for body in (bodies[pair, 0], bodies[pair, 1]):
            if done[body]:
                continue
            quaternion_rotation(q0[body], r0)
            quaternion_rotation(q1[body], r1)
            for i in range(3):
                for j in range(3):
                    turns[body, i, j] = (
                        r1[i, 0] * r0[j, 0] + r1[i, 1] * r0[j, 1] + r1[i, 2] * r0[j, 2]
                    )
            done[body] = True
    for pair in range(bodies.shape[0]):
        a, b = bodies[pair, 0], bodies[pair, 1]
        turn_a, turn_b = turns[a], turns[b]
        for c in range(offsets[pair], offsets[pair + 1]):
            for i in range(3):
                pa[i] = x1[a, i]
                pb[i] = x1[b, i]
                for j in range(3):
                    pa[i] += turn_a[i, j] * (points[c, j] - x0[a, j])
                    pb[i] += turn_b[i, j] * (points[c, j] - x0[b, j])
            along = 0.0
            for i in range(3):
                n = turn_a[i, 0] * normals[c, 0] + turn_a[i, 1] * normals[c, 1]
                n += turn_a[i, 2] * normals[c, 2]
                out_normals[c, i] = n
                along += n * (pb[i] - pa[i])
                out_points[c, i] = 0.5 * (pa[i] + pb[i])
            out_overlaps[c] = min(overlaps[c] - along, reach[pair])
