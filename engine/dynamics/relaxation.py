"""Picard relaxation: the fallback of :mod:`engine.dynamics.picard` when Newton corrections
stop contracting, and the tests every iteration's forces go through.

The paper's "weighted average between the currently computed forces and the forces of the
previous step": the applied forces move towards each iteration's computed forces by a weight
β — first 1/(1 + λ) from the contact stiffness (:func:`first_weights`), then Aitken's
safeguarded secant weight (:func:`aitken`). β is one number for all bodies (one for normal,
one for friction forces), so every contact still applies equal and opposite forces:
momentum is conserved exactly at every iteration. Converged when no body's computed force or
torque differs from the applied one by more than ``picard_tolerance`` of the forces acting on
it (:func:`settled`), or on a switch of the contact set (:func:`switch`).
"""

from __future__ import annotations

import numpy as np

from engine.dynamics.bodies import body_terms, smallest_inertia
from engine.dynamics.evaluation import Wrench
from engine.kernels.dynamics import contact_forces as kf
from engine.kernels.dynamics import motion as kd

__all__ = [
    "aitken",
    "cycling",
    "first_weights",
    "flat",
    "settled",
    "settled_cycle",
    "size",
    "switch",
    "unsettled",
]

BETA_MAX = 1.5
BETA_MIN = 0.01
ATOL = 1e-9


def flat(wrench: Wrench, radius: np.ndarray) -> np.ndarray:
    """(6n,) float64: the forces and the torques over the lever ``radius (n,)``, one
    vector (torques made force-like)."""
    return np.concatenate([wrench.force.ravel(), (wrench.torque / radius[:, None]).ravel()])


def size(wrench: Wrench, radius: np.ndarray) -> float:
    """The Euclidean norm of :func:`flat` of ``wrench``, summed in index order by one kernel
    pass (no temporaries, no BLAS)."""
    return float(kd.flat_norm(wrench.force, wrench.torque, radius))


def aitken(beta: float, previous, current) -> float:
    """Aitken's relaxation, safeguarded: the weight that would have cancelled the last
    swing of the residual (it halves when residuals alternate and grows while they keep
    their direction), but at most half the last weight when the residual grew and at most
    twice it otherwise; clamped to [BETA_MIN, BETA_MAX]. The dot products come from one
    kernel pass in a fixed order (:func:`~engine.kernels.dynamics.motion.relaxation_products`),
    not from BLAS, whose threads cost milliseconds per product on a busy machine."""
    if previous is not None:
        products = np.empty(4)
        kd.relaxation_products(previous, current, products)
        along, norm, now, before = (float(x) for x in products)
        proposal = -beta * along / norm if norm > 0 else beta
        grew = now > before
        beta = min(proposal, 0.5 * beta) if grew else min(proposal, 2.0 * beta)
    return min(max(beta, BETA_MIN), BETA_MAX)


def first_weights(scene, stiffness, radius, dt: float) -> list[float]:
    """1/(1 + λ) for the normal and the friction forces, λ the largest per-body gain of a
    Picard sweep: dt²·Σk (spring) and dt·Σc (friction) times (1/m + R²/I_min)."""
    free = ~scene.fixed
    if not free.any() or not stiffness.any():  # no body, or no contact: no gain
        return [1.0, 1.0]
    smallest = smallest_inertia(scene)[free]
    mobility = 1.0 / scene.masses[free] + radius[free] ** 2 / smallest
    gain_n = float((dt * dt * stiffness[free, 0] * mobility).max())
    gain_t = float((dt * stiffness[free, 1] * mobility).max())
    return [1.0 / (1.0 + gain_n), 1.0 / (1.0 + gain_t)]


def unsettled(scene, computed, mismatch, gross, radius) -> np.ndarray:
    """(n,) bool: the free bodies that fail :func:`settled`'s test (at the tolerance)."""
    bodies = body_terms(scene)
    out = np.empty(len(radius), np.bool_)
    kf.unsettled(
        (computed.force, computed.torque),
        (mismatch.force, mismatch.torque),
        gross,
        bodies.size,
        radius,
        scene.fixed,
        scene.picard_tolerance,
        ATOL,
        bodies.weight,
        out,
    )
    return out


def settled(scene, computed, mismatch, gross, radius, tighter: float = 1.0, skip=None) -> bool:
    """Self-consistent: every free body's computed force and torque differ from the applied
    ones (``mismatch``) by at most ``tighter`` × ``scene.picard_tolerance`` of the forces
    acting on it —
    the larger of its net force and the sum of its contact forces' magnitudes ``gross
    (n,)`` plus its weight (a body squeezed between equal and opposite contacts has a
    near-zero net force; relative to it, no iteration would ever settle) — and torques by
    at most that times the lever ``radius``. ``computed``, ``mismatch`` : Wrench.
    ``skip (n,)`` bool: bodies left out as the fixed ones are."""
    bodies = body_terms(scene)
    return kf.settled(
        (computed.force, computed.torque),
        (mismatch.force, mismatch.torque),
        gross,
        bodies.size,
        radius,
        scene.fixed if skip is None else scene.fixed | skip,
        tighter * scene.picard_tolerance,
        ATOL,
        bodies.weight,
    )


def switch(scene, recent, applied, gross, radius, groups=None) -> bool:
    """Settled on a switch of the contact set: the last computed totals ``recent``
    (:class:`~engine.dynamics.evaluation.Wrench` or (force, torque) pairs, up to six) take
    two values A and B in turn — each at least twice, within the Picard tolerance, and the
    sequence goes from one to the other and back (a single change from A to B is a
    transition, not a cycle) — and the applied totals ``applied`` lie within the tolerance
    of the segment from A to B (one weight for the whole scene).

    The merged contact forces jump where a contact point joins or leaves a cluster (the
    merge radius is a threshold), and a step that ends at such a configuration has no
    fixed point: its iterates flip between the two contact sets forever (measured: a box
    resting on a plane, 68,000 steps in, ±0.5 N on a 9.81 N weight). The forces of a
    configuration on the switch are taken as the combination of the two one-sided limits
    that the iteration converges to, as for any discontinuous right-hand side (Filippov).

    ``groups (n,)`` int64, if given, labels bodies tested together (Picard passes each
    body its own label): each group with a body whose applied forces are not its last
    computed ones is tested on its own bodies, with its own two values and its own weight,
    and the step settles when every such group does. Two bodies resting apart that each
    sit on a switch are two switches, four combinations of contact sets, which the whole
    scene's two-value test never accepts (measured: a 48-object pile whose two loaves
    each flipped a floor contact ran the 50 iterations and 44–47 searches of an unconverged
    step, 20 times in 200 steps; 9 times body by body). The test decides when to stop
    only: the applied forces are the iteration's, equal and opposite contact forces
    whatever the grouping."""
    if len(recent) < 4:
        return False
    recent, applied = [Wrench(*r) for r in recent], Wrench(*applied)
    if groups is None:
        return _switch(scene, recent, applied, gross, radius, None)
    last = recent[-1]
    apart = unsettled(scene, last, applied.minus(last), gross, radius)
    if not apart.any():  # nothing to settle on a switch: the plain test decides
        return False
    free = ~scene.fixed
    for label in np.unique(groups[apart]):
        others = ~(free & (groups == label))  # every body but the group's, left out
        if not _switch(scene, recent, applied, gross, radius, others):
            return False
    return True


def _switch(scene, recent, applied, gross, radius, skip) -> bool:
    """:func:`switch`'s test of the bodies not in ``skip (n,)`` bool (None: every body)."""
    last = recent[-1]
    same = [settled(scene, last, r.minus(last), gross, radius, skip=skip) for r in recent]
    side_a = [r for r, s in zip(recent, same, strict=True) if s]
    side_b = [r for r, s in zip(recent, same, strict=True) if not s]
    changes = sum(x != y for x, y in zip(same[:-1], same[1:], strict=True))
    if len(side_a) < 2 or len(side_b) < 2 or changes < 2:
        return False
    first_b = side_b[0]
    if not all(settled(scene, first_b, r.minus(first_b), gross, radius, skip=skip) for r in side_b):
        return False
    return _on_segment(scene, mean(side_a), mean(side_b), applied, gross, radius, skip)


def settled_cycle(scene, recent, applied, gross, radius) -> bool:
    """Settled on a switch that frozen contact sets found: the last three computed totals
    ``recent`` go from A to B and back to A (:func:`cycling`: three searches, each of the
    configuration a frozen set settled at, the middle one on the other side), and the
    applied totals lie within the tolerance of the segment from A (the mean of the two) to
    B. The same acceptance as :func:`switch`, whose cycle of searched iterations needs each
    side twice: frozen sets that settle on either side of the switch and find the other
    are that evidence already."""
    if not cycling(scene, recent, gross, radius):
        return False
    a, b, again = (Wrench(*r) for r in recent[-3:])
    applied = Wrench(*applied)
    return _on_segment(scene, mean([a, again]), b, applied, gross, radius)


def _on_segment(scene, a: Wrench, b: Wrench, applied: Wrench, gross, radius, skip=None) -> bool:
    """``applied`` within the Picard tolerance (:func:`settled`) of the nearest point of the
    segment from ``a`` to ``b`` (one weight for the bodies not in ``skip (n,)`` bool, the
    whole scene by default)."""
    step_ab = b.minus(a)
    span, offset = flat(step_ab, radius), flat(applied.minus(a), radius)
    if skip is not None:  # the weight of the bodies tested only
        rows = np.tile(np.repeat(~skip, 3), 2)
        span, offset = span[rows], offset[rows]
    t = float(np.clip(offset @ span / (span @ span), 0.0, 1.0)) if span @ span > 0 else 0.0
    point = Wrench(a.force + t * step_ab.force, a.torque + t * step_ab.torque)
    return settled(scene, applied, applied.minus(point), gross, radius, skip=skip)


def cycling(scene, recent, gross, radius) -> bool:
    """The last three computed totals ``recent`` (as :func:`switch` takes them) go from A
    to B and back to A: within the Picard tolerance of each other, the first and the last,
    not the middle one. Frozen contact sets then cycle too: on A's set the iteration
    settles where a search finds B, on B's where it finds A — a configuration on a switch
    of the contact set, which the frozen sets cannot resolve and :func:`switch` can."""
    if len(recent) < 3:
        return False
    a, b, again = (Wrench(*r) for r in recent[-3:])
    return settled(scene, again, again.minus(a), gross, radius) and not settled(
        scene, again, again.minus(b), gross, radius
    )


def mean(wrenches: list[Wrench]) -> Wrench:
    """The mean force and the mean torque of ``wrenches``."""
    return Wrench(
        np.mean([w.force for w in wrenches], axis=0),
        np.mean([w.torque for w in wrenches], axis=0),
    )
