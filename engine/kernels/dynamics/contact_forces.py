"""Contact force kernels (paper §2): each contact's normal and friction force and torque,
and the Picard convergence test over the bodies' forces.

Contact laws (``law[0]``): ``PAPER`` — F_n = K_s · δ/(ε_a + ε_b) · √m_red, the paper's
spring (1 − |n|/ε with |n| the distance from the contact point to either surface is
δ/(ε_a + ε_b), δ = ε_a + ε_b − d the overlap); ``LINEAR`` — F_n = k·δ; ``HERTZ`` — F_n =
k·δ^{3/2}. Each adds optional normal damping −c·v_n with c = 2ζ√(k_eff·m_red), k_eff =
∂F_n/∂δ (the normal force never pulls, and the dashpot never pushes harder than the spring:
F_n ≤ 2·F_spring, so the force is continuous at contact onset), and a tangential friction
force capped by
Coulomb's law, −μ·F_n·v_t/√(|v_t|² + v_slip²) (a regularised Coulomb law: no history, so a
Picard iteration sees a function of the state only). ``law = (kind, stiffness, damping
ratio ζ, friction μ, slip velocity)``.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from engine.kernels.jit import BORROW, EXACT_BORROW, EXACT_JIT, JIT

PAPER, LINEAR, HERTZ = 0, 1, 2


# columns of a contact's terms (:func:`contact_terms`)
NORMAL_FORCE = 0  # 0:3 the normal force on B (A gets the opposite)
FRICTION_FORCE = 3  # 3:6 the friction force on B
SPRING_SLOPE = 6  # ∂F_n/∂δ
NORMAL_MAGNITUDE = 7  # F_n
FRICTION_SLOPE = 8  # μ·F_n/v_slip, the friction's steepest (sticking) slope
FRICTION_MAGNITUDE = 9  # |F_t|
ENERGY = 10  # the elastic energy of the contact's spring
ACTIVE = 11  # 1.0 where the contact overlaps (δ > 0) and acts, else 0.0
DAMPING_SLOPE = 12  # c_n = −∂F_n/∂v_n where the damping acts (F_n > 0), else 0
FRICTION_SCALE = 13  # μ·F_n/s, s = √(|v_t|² + v_slip²) (0 without friction)
SLIP = 14  # s (a sliding spring: 1; a sticking one: 0)
TANGENT = 15  # 15:18 the sliding velocity v_t of B relative to A (a sliding spring: ĝ)
TANGENT_SPRING = 18  # k_t where the tangential spring sticks, else 0
DISPLACEMENT = 19  # 19:22 the tangential spring's displacement ξ at the end of the step
NORMAL_SPEED = 22  # v_n: B's point moving away from A's along the normal (< 0: closing)
TERMS = 23

# columns of a contact's history (:mod:`engine.dynamics.history`)
HISTORY_DISPLACEMENT = 0  # 0:3 ξ at the start of the step
HISTORY_ALLOWANCE = 3  # the overlap the spring does not push against (a gentle start)
HISTORY_RELEASING = 4  # 1.0 while the contact lets go of an initial overlap, else 0.0
HISTORY = 5


@njit(**JIT)
def contact_terms(bodies, offsets, points, normals, overlaps, state, params, law, first, last,
                  terms):  # fmt: skip
    """Fill ``terms (c, TERMS)`` float64 for the contacts of body pairs ``first:last``: each
    contact's normal and friction force on B, the slopes and magnitudes that
    :func:`apply_terms` sums per body, its elastic energy, and whether it acts.

    ``bodies (k, 2)`` int64: body pair q = (a, b) owns contacts ``offsets[q]:offsets[q + 1]``
    of ``points, normals (c, 3)`` (normals unit, from a to b) and ``overlaps (c,)``.
    ``state = (positions, velocities, angular_velocities, lever_origins)``: velocities give
    the relative sliding velocity. ``params = (mass (n,), epsilon (n,), history (c,
    HISTORY), h)`` with ``inf`` mass for fixed bodies, each contact's history at the start
    of the step (its tangential displacement and its allowance: the spring acts on
    δ − allowance) and the step's length h. Each contact's row is its own: any split of the
    pairs gives the same bits.

    Friction with a tangential spring (``law[5]`` = k_t/k_n > 0, Cundall–Strack): the
    displacement ξ = ξ₀ (turned into the contact's tangent plane, its length kept) +
    h·v_t, the force −k_t·ξ − c_t·v_t (c_t = 2ζ√(k_t·m_red)) capped at μF_n; where
    capped the contact slides and ξ is rescaled to the capped force. Without it
    (``law[5]`` = 0) friction is the regularised Coulomb law."""
    positions, velocities, spins, _ = state
    mass, epsilon, history, h = params
    kind, k_law, zeta, mu, v_slip, kt_ratio = law
    for q in range(first, last):
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
            delta = overlaps[c] - history[c, HISTORY_ALLOWANCE]
            if delta <= 0.0:
                terms[c, :] = 0.0
                continue
            n0, n1, n2 = normals[c, 0], normals[c, 1], normals[c, 2]
            p0, p1, p2 = points[c, 0], points[c, 1], points[c, 2]
            if kind == PAPER:
                k_eff = k_law * np.sqrt(m_red) / reach
                f_n = k_eff * delta
                energy = 0.5 * k_eff * delta * delta
            elif kind == LINEAR:
                k_eff = k_law
                f_n = k_law * delta
                energy = 0.5 * k_law * delta * delta
            else:
                root = np.sqrt(delta)
                k_eff = 1.5 * k_law * root
                f_n = k_law * delta * root
                energy = 0.4 * k_law * delta * delta * root
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
            damping, slope = 0.0, k_eff
            # a contact letting go of an allowance is at least critically damped
            ratio = zeta if history[c, HISTORY_ALLOWANCE] == 0.0 else max(zeta, 1.0)
            if ratio > 0.0:
                damping = 2.0 * ratio * np.sqrt(k_eff * m_red)
                spring = f_n
                f_n = f_n - damping * v_n
                if f_n <= 0.0:  # the dashpot holds the spring off: no force, no slope
                    f_n, damping, slope = 0.0, 0.0, 0.0
                elif f_n > 2.0 * spring:  # the dashpot pushes no harder than the spring
                    f_n, damping, k_eff = 2.0 * spring, 0.0, 2.0 * k_eff
                    slope = k_eff
            t0, t1, t2 = u0 - v_n * n0, u1 - v_n * n1, u2 - v_n * n2
            terms[c, DAMPING_SLOPE] = damping
            terms[c, NORMAL_SPEED] = v_n
            terms[c, TANGENT] = t0
            terms[c, TANGENT + 1] = t1
            terms[c, TANGENT + 2] = t2
            terms[c, NORMAL_FORCE] = f_n * n0
            terms[c, NORMAL_FORCE + 1] = f_n * n1
            terms[c, NORMAL_FORCE + 2] = f_n * n2
            terms[c, SPRING_SLOPE] = slope
            terms[c, NORMAL_MAGNITUDE] = f_n
            terms[c, ENERGY] = energy
            terms[c, ACTIVE] = 1.0
            terms[c, TANGENT_SPRING] = 0.0
            terms[c, DISPLACEMENT : DISPLACEMENT + 3] = 0.0
            if mu > 0.0 and kt_ratio > 0.0:
                _spring_friction(history, c, (n0, n1, n2), (t0, t1, t2), h, f_n, mu,
                                 kt_ratio * k_eff, 2.0 * zeta * np.sqrt(kt_ratio * k_eff * m_red),
                                 terms)  # fmt: skip
            elif mu > 0.0:
                slip = np.sqrt(t0 * t0 + t1 * t1 + t2 * t2 + v_slip * v_slip)
                scale = mu * f_n / slip
                terms[c, FRICTION_FORCE] = -scale * t0
                terms[c, FRICTION_FORCE + 1] = -scale * t1
                terms[c, FRICTION_FORCE + 2] = -scale * t2
                terms[c, FRICTION_SLOPE] = mu * f_n / v_slip
                terms[c, FRICTION_MAGNITUDE] = scale * np.sqrt(t0 * t0 + t1 * t1 + t2 * t2)
                terms[c, FRICTION_SCALE] = scale
                terms[c, SLIP] = slip
            else:
                terms[c, FRICTION_FORCE : FRICTION_FORCE + 3] = 0.0
                terms[c, FRICTION_SLOPE] = 0.0
                terms[c, FRICTION_MAGNITUDE] = 0.0
                terms[c, FRICTION_SCALE] = 0.0
                terms[c, SLIP] = 0.0


@njit(**BORROW, forceinline=True)
def _spring_friction(history, c, normal, tangent, h, f_n, mu, k_t, c_t, terms):
    """Contact ``c``'s friction with a tangential spring of stiffness ``k_t`` and damping
    ``c_t`` (:func:`contact_terms`): its force, slopes, displacement
    into ``terms`` (its energy is not counted in ENERGY, the normal spring's)."""
    n0, n1, n2 = normal
    t0, t1, t2 = tangent
    x0 = history[c, HISTORY_DISPLACEMENT]
    x1 = history[c, HISTORY_DISPLACEMENT + 1]
    x2 = history[c, HISTORY_DISPLACEMENT + 2]
    length = np.sqrt(x0 * x0 + x1 * x1 + x2 * x2)
    along = x0 * n0 + x1 * n1 + x2 * n2
    x0, x1, x2 = x0 - along * n0, x1 - along * n1, x2 - along * n2
    turned = np.sqrt(x0 * x0 + x1 * x1 + x2 * x2)
    if turned > 0.0:
        x0, x1, x2 = x0 * (length / turned), x1 * (length / turned), x2 * (length / turned)
    x0, x1, x2 = x0 + h * t0, x1 + h * t1, x2 + h * t2
    g0, g1, g2 = -k_t * x0 - c_t * t0, -k_t * x1 - c_t * t1, -k_t * x2 - c_t * t2
    size = np.sqrt(g0 * g0 + g1 * g1 + g2 * g2)
    cap = mu * f_n
    if size > cap:  # sliding: the force at Coulomb's cap, the spring stretched to match it
        scale = cap / size
        # the capped force turns with the spring: its slopes are the spring's, scaled by
        # cap/|g|, across its direction ĝ only (stored as TANGENT with SLIP 1)
        terms[c, TANGENT] = g0 / size
        terms[c, TANGENT + 1] = g1 / size
        terms[c, TANGENT + 2] = g2 / size
        terms[c, SLIP] = 1.0
        g0, g1, g2 = g0 * scale, g1 * scale, g2 * scale
        x0, x1, x2 = -g0 / k_t, -g1 / k_t, -g2 / k_t
        size = cap
        terms[c, TANGENT_SPRING] = k_t * scale
        terms[c, FRICTION_SCALE] = c_t * scale
    else:
        terms[c, TANGENT_SPRING] = k_t
        terms[c, FRICTION_SCALE] = c_t
        terms[c, SLIP] = 0.0
    terms[c, FRICTION_FORCE] = g0
    terms[c, FRICTION_FORCE + 1] = g1
    terms[c, FRICTION_FORCE + 2] = g2
    terms[c, FRICTION_SLOPE] = k_t * h + c_t
    terms[c, FRICTION_MAGNITUDE] = size
    terms[c, DISPLACEMENT] = x0
    terms[c, DISPLACEMENT + 1] = x1
    terms[c, DISPLACEMENT + 2] = x2


@njit(**JIT)
def incidence(bodies, starts, entries):
    """Each body's pairs in pair order: ``entries[starts[i]:starts[i + 1]]`` are
    ``2·q + side`` for the pairs q of ``bodies (k, 2)`` int64 that hold body i (side 0 as
    A, 1 as B). ``starts (n + 1,)``, ``entries (2k,)`` int64 are written (a stable counting
    sort)."""
    starts[:] = 0
    for q in range(bodies.shape[0]):
        starts[bodies[q, 0] + 1] += 1
        starts[bodies[q, 1] + 1] += 1
    for i in range(1, starts.shape[0]):
        starts[i] += starts[i - 1]
    fill = starts[:-1].copy()
    for q in range(bodies.shape[0]):
        for side in range(2):
            body = bodies[q, side]
            entries[fill[body]] = 2 * q + side
            fill[body] += 1


@njit(**EXACT_JIT)
def apply_terms(offsets, points, origins, terms, starts, entries, friction, first, last, out):
    """Add to bodies ``first:last`` the forces of their contacts' ``terms``
    (:func:`contact_terms`), each body's in pair order (``starts``, ``entries`` from
    :func:`incidence`), so that every body's sums are the same bits in any split of the
    bodies.

    ``out = (force, torque, friction_force, friction_torque (n, 3), stiffness (n, 3))``:
    normal and friction contributions go to separate arrays, so that a Picard iteration can
    relax them separately; ``stiffness[i]`` receives the sums over i's contacts of ∂F_n/∂δ
    and of the friction's ∂F_t/∂v_t (for the relaxation's first weight) and of the contact
    forces' magnitudes |F_n| + |F_t| (the force scale of Picard's convergence test).
    Torques are taken about ``origins (n, 3)`` (the centres of mass at the start of the
    step: then every contact adds the same moment to both bodies with opposite signs, and
    angular momentum is conserved to rounding). ``friction``: whether μ > 0 (else the
    friction rows are left as they are). Compiled without contraction: the sums do not
    depend on where LLVM places them."""
    force, torque, friction_force, friction_torque, stiffness = out
    for body in range(first, last):
        if starts[body] == starts[body + 1]:
            continue
        # the body's sums in registers, from what ``out`` holds (same order, same bits)
        f = force[body, 0], force[body, 1], force[body, 2]
        m = torque[body, 0], torque[body, 1], torque[body, 2]
        g = friction_force[body, 0], friction_force[body, 1], friction_force[body, 2]
        h = friction_torque[body, 0], friction_torque[body, 1], friction_torque[body, 2]
        s0, s1, s2 = stiffness[body, 0], stiffness[body, 1], stiffness[body, 2]
        o0, o1, o2 = origins[body, 0], origins[body, 1], origins[body, 2]
        for e in range(starts[body], starts[body + 1]):
            q, side = entries[e] >> 1, entries[e] & 1
            sign = 1.0 if side == 1 else -1.0
            for c in range(offsets[q], offsets[q + 1]):
                if terms[c, ACTIVE] == 0.0:
                    continue
                r = points[c, 0] - o0, points[c, 1] - o1, points[c, 2] - o2
                n = NORMAL_FORCE
                f, m = _pushed(f, m, r, sign, terms[c, n], terms[c, n + 1], terms[c, n + 2])
                s0 += terms[c, SPRING_SLOPE]
                s2 += terms[c, NORMAL_MAGNITUDE]
                if friction:
                    t = FRICTION_FORCE
                    g, h = _pushed(g, h, r, sign, terms[c, t], terms[c, t + 1], terms[c, t + 2])
                    s1 += terms[c, FRICTION_SLOPE]
                    s2 += terms[c, FRICTION_MAGNITUDE]
        force[body, 0], force[body, 1], force[body, 2] = f
        torque[body, 0], torque[body, 1], torque[body, 2] = m
        friction_force[body, 0], friction_force[body, 1], friction_force[body, 2] = g
        friction_torque[body, 0], friction_torque[body, 1], friction_torque[body, 2] = h
        stiffness[body, 0], stiffness[body, 1], stiffness[body, 2] = s0, s1, s2


@njit(**EXACT_BORROW, forceinline=True)
def _pushed(force, moment, r, sign, x0, x1, x2):
    """``(force + x, moment + r × x)`` for the force ``x = sign · (x0, x1, x2)`` at lever
    ``r`` (3-tuples; numpy's operations, no contraction)."""
    x0, x1, x2 = sign * x0, sign * x1, sign * x2
    return (
        (force[0] + x0, force[1] + x1, force[2] + x2),
        (
            moment[0] + (r[1] * x2 - r[2] * x1),
            moment[1] + (r[2] * x0 - r[0] * x2),
            moment[2] + (r[0] * x1 - r[1] * x0),
        ),
    )


@njit(**JIT)
def contact_wrench(contacts, state, params, law, incidence, friction, terms, out):
    """:func:`contact_terms` of every pair, then :func:`apply_terms` of every body, in one
    call (a small scene: no split, no hand-off); returns :func:`elastic_energy`.
    ``contacts = (bodies, offsets, points, normals, overlaps)``, ``incidence = (starts,
    entries)`` (:func:`incidence`), the rest as those kernels take them."""
    bodies, offsets, points, normals, overlaps = contacts
    contact_terms(bodies, offsets, points, normals, overlaps, state, params, law, 0,
                  bodies.shape[0], terms)  # fmt: skip
    starts, entries = incidence
    apply_terms(offsets, points, state[3], terms, starts, entries, friction, 0,
                starts.shape[0] - 1, out)  # fmt: skip
    return elastic_energy(terms)


@njit(**EXACT_JIT)
def elastic_energy(terms):
    """The summed elastic energy of the acting contacts of ``terms (c, TERMS)``, in
    contact order."""
    energy = 0.0
    for c in range(terms.shape[0]):
        if terms[c, ACTIVE] != 0.0:
            energy += terms[c, ENERGY]
    return energy


@njit(**JIT)
def largest_overlap(bodies, offsets, overlaps, epsilon):
    """The largest overlap relative to its pair's reach, δ / (ε_a + ε_b), over contacts
    laid out as :func:`contact_terms` takes them (``epsilon (n,)`` float64); −inf for no
    contact."""
    worst = -np.inf
    for q in range(bodies.shape[0]):
        reach = epsilon[bodies[q, 0]] + epsilon[bodies[q, 1]]
        for c in range(offsets[q], offsets[q + 1]):
            worst = max(worst, overlaps[c] / reach)
    return worst


@njit(**JIT)
def same_values(a, b):
    """Whether the flat float64 arrays ``a`` and ``b`` of one length are equal element by
    element (as ``np.array_equal``: NaN differs from everything), stopping at the first
    difference."""
    for i in range(a.shape[0]):  # noqa: SIM110 (a loop that Numba compiles without a generator)
        if a[i] != b[i]:
            return False
    return True


@njit(**EXACT_JIT)
def moved_levers(old, new, normal, body_force, friction, out):
    """Torques of contact forces taken about lever origins ``new`` instead of ``old``
    (``(n, 3)`` float64): τ + (o_old − o_new) × F. ``normal = (force, torque)`` holds the
    normal contact forces plus the constant ``body_force (n, 3)`` (which has no lever
    here), ``friction = (force, torque)`` the friction; ``out = (normal torque, friction
    torque)`` receive the moved torques. numpy's arithmetic, operation for operation (no
    contraction): the same bits as :func:`engine.dynamics.evaluation.cross`."""
    normal_force, normal_torque = normal
    friction_force, friction_torque = friction
    normal_out, friction_out = out
    for b in range(old.shape[0]):
        l0, l1, l2 = old[b, 0] - new[b, 0], old[b, 1] - new[b, 1], old[b, 2] - new[b, 2]
        f0 = normal_force[b, 0] - body_force[b, 0]
        f1 = normal_force[b, 1] - body_force[b, 1]
        f2 = normal_force[b, 2] - body_force[b, 2]
        normal_out[b, 0] = normal_torque[b, 0] + (l1 * f2 - l2 * f1)
        normal_out[b, 1] = normal_torque[b, 1] + (l2 * f0 - l0 * f2)
        normal_out[b, 2] = normal_torque[b, 2] + (l0 * f1 - l1 * f0)
        g0, g1, g2 = friction_force[b, 0], friction_force[b, 1], friction_force[b, 2]
        friction_out[b, 0] = friction_torque[b, 0] + (l1 * g2 - l2 * g1)
        friction_out[b, 1] = friction_torque[b, 1] + (l2 * g0 - l0 * g2)
        friction_out[b, 2] = friction_torque[b, 2] + (l0 * g1 - l1 * g0)


@njit(**JIT)
def settled(computed, mismatch, gross, body_size, radius, fixed, tolerance, atol, weight):
    """Picard's convergence test (see ``engine.dynamics.relaxation.settled``): every free body's
    force mismatch within ``tolerance`` of the forces acting on it, size_f = max(|F|,
    gross + body_size), and its torque mismatch within ``tolerance`` of max(|τ|, R·size_f),
    each plus a floor ``atol · max(max size_f, weight)`` (times R for torques).
    ``computed``, ``mismatch`` = ``(force (n, 3), torque (n, 3))``; ``gross``,
    ``body_size``, ``radius (n,)`` float64; ``fixed (n,)`` bool."""
    sizes = (gross, body_size, radius)
    floor = _floor(computed[0], gross, body_size, fixed, atol, weight)
    for b in range(fixed.shape[0]):
        if not fixed[b] and _fails(computed, mismatch, sizes, b, tolerance, floor):
            return False
    return True


@njit(**JIT)
def unsettled(computed, mismatch, gross, body_size, radius, fixed, tolerance, atol, weight, out):
    """:func:`settled`'s test body by body: ``out (n,)`` bool, True for each body not
    ``fixed`` whose force or torque mismatch is beyond it; returns how many."""
    sizes = (gross, body_size, radius)
    floor = _floor(computed[0], gross, body_size, fixed, atol, weight)
    count = 0
    for b in range(fixed.shape[0]):
        out[b] = not fixed[b] and _fails(computed, mismatch, sizes, b, tolerance, floor)
        count += out[b]
    return count


@njit(**JIT)
def _floor(force, gross, body_size, fixed, atol, weight):
    """The absolute floor of Picard's test: ``atol`` of the largest free body's force scale
    (or of ``weight``)."""
    largest = 0.0
    for b in range(force.shape[0]):
        if not fixed[b]:
            largest = max(largest, _size(force, b, gross[b] + body_size[b]))
    return atol * max(largest, weight)


@njit(**JIT)
def _fails(computed, mismatch, sizes, b, tolerance, floor):
    """Body ``b``'s force or torque mismatch is beyond Picard's test (:func:`settled`)."""
    force, torque = computed
    gross, body_size, radius = sizes
    size_f = _size(force, b, gross[b] + body_size[b])
    size_t = _size(torque, b, radius[b] * size_f)
    if _norm(mismatch[0], b) > tolerance * size_f + floor:
        return True
    return _norm(mismatch[1], b) > tolerance * size_t + floor * radius[b]


@njit(**JIT)
def contact_islands(bodies, offsets, terms, free, labels):
    """``labels (n,)`` int64: each body's island, the smallest body of its connected
    component in the graph of the body pairs ``bodies (k, 2)`` with an acting contact
    (``terms[:, ACTIVE]``; pair q owns contacts ``offsets[q]:offsets[q + 1]``) between two
    ``free (n,)`` bodies (a body that is not free is an island of its own)."""
    n = labels.shape[0]
    for b in range(n):
        labels[b] = b
    for q in range(bodies.shape[0]):
        a, b = bodies[q, 0], bodies[q, 1]
        if not (free[a] and free[b]):
            continue
        acting = False
        for c in range(offsets[q], offsets[q + 1]):
            if terms[c, ACTIVE] != 0.0:
                acting = True
                break
        if acting:
            ra, rb = _root(labels, a), _root(labels, b)
            labels[max(ra, rb)] = min(ra, rb)
    for b in range(n):
        labels[b] = _root(labels, b)


@njit(**JIT)
def _root(labels, b):
    while labels[b] != b:
        labels[b] = labels[labels[b]]  # path halving
        b = labels[b]
    return b


@njit(**JIT)
def _norm(rows, b):
    return np.sqrt(rows[b, 0] * rows[b, 0] + rows[b, 1] * rows[b, 1] + rows[b, 2] * rows[b, 2])


@njit(**JIT)
def _size(rows, b, least):
    return max(_norm(rows, b), least)
