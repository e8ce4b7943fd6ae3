"""The forces of one configuration of a scene, and their reuse by the next time step.

:func:`evaluate` searches the contacts of a configuration and turns them into forces and
torques (:class:`Wrench`, normal and friction apart) with the scene's contact law: an
:class:`Evaluation`. A converged Picard step (:mod:`engine.dynamics.picard`) ends in the
configuration it evaluated last; it leaves that evaluation in ``Scene.warm_start`` (a
:class:`WarmStart`), and the next step's first iteration takes it from there
(:func:`reused`) instead of searching the same configuration again. Anything that
changes the scene from outside clears ``Scene.warm_start``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from engine.collision.configuration import Contacts
from engine.dynamics.bodies import body_terms
from engine.kernels.dynamics import contact_forces as kf
from engine.kernels.dynamics import motion as kd
from engine.workers import in_parts

__all__ = [
    "Evaluation",
    "MovedContacts",
    "WarmStart",
    "Wrench",
    "contact_forces",
    "evaluate",
    "evaluation_key",
    "reused",
    "unsearched",
]

_PAIRS_PER_PART = 8192  # a part of contact_forces' pairs: ~0.1 ms of terms
_BODIES_PER_PART = 2048  # a part of its bodies: ~0.06 ms of sums


class Wrench(NamedTuple):
    """Forces and torques on every body: ``force``, ``torque`` (n, 3) float64 (world
    frame; torques about the lever origins of the evaluation)."""

    force: np.ndarray
    torque: np.ndarray

    def plus(self, other: Wrench) -> Wrench:
        """Row-wise ``self + other``, force and torque."""
        return Wrench(self.force + other.force, self.torque + other.torque)

    def minus(self, other: Wrench) -> Wrench:
        """Row-wise ``self − other``, force and torque."""
        return Wrench(self.force - other.force, self.torque - other.torque)


class Evaluation(NamedTuple):
    """The forces of one configuration.

    normal : Wrench — normal contact forces plus gravity and the external forces
    friction : Wrench — friction forces
    stiffness : (n, 3) float64 — per body, sums over its contacts: ∂F_n/∂δ, the
        friction's ∂F_t/∂v_t, and |F_n| + |F_t| (the force scale of Picard's test)
    contacts : Contacts — the leaf contacts found
    energy : float — elastic energy stored in the contact springs
    terms : (c, TERMS) float64 — each leaf contact's terms
        (:func:`~engine.kernels.dynamics.contact_forces.contact_terms`): the slopes of the
        linearised forces (:mod:`engine.kernels.dynamics.linearized`)
    history : (c, HISTORY) float64 — each leaf contact's history at the step's start
        (:mod:`engine.dynamics.history`)
    changed : bool — the search's fronts changed (multiscale), so the contact set of
        the configuration is not final
    """

    normal: Wrench
    friction: Wrench
    stiffness: np.ndarray
    contacts: Contacts
    energy: float
    terms: np.ndarray
    history: np.ndarray
    changed: bool


@dataclass(frozen=True)
class WarmStart:
    """The last converged step's final evaluation, kept for the next step.

    key : tuple — what besides the state the forces depend on (:func:`evaluation_key`)
    state : tuple of (n, 3), (n, 4), (n, 3), (n, 3) float64 — positions, orientations,
        velocities and angular velocities it was made of
    origins : (n, 3) float64 — the lever origins of its torques
    evaluation : Evaluation
    """

    key: tuple
    state: tuple
    origins: np.ndarray
    evaluation: Evaluation


class MovedContacts:
    """A search that finds nothing new: the ``contacts`` found at ``positions (n, 3)``,
    ``orientations (n, 4)`` carried rigidly to any other configuration of the same bodies
    (:func:`~engine.kernels.dynamics.motion.moved_contacts`: points move with both bodies,
    normals turn with A, overlaps shrink by the relative motion along the normal). A
    Picard iteration solves on such a frozen contact set, and a real search of its answer
    decides whether it stands (:mod:`engine.dynamics.picard`)."""

    def __init__(self, scene, contacts: Contacts, positions, orientations) -> None:
        self.contacts = contacts
        self.before = (positions.copy(), orientations.copy())
        epsilon, bodies = scene.epsilon, contacts.bodies
        self.reach = np.ascontiguousarray(epsilon[bodies[:, 0]] + epsilon[bodies[:, 1]])
        self.counters = unsearched(contacts.counters)
        self.incidence = _incidence(bodies, len(positions))
        self._matched: tuple | None = None  # (history, its contacts' rows)

    def matched(self, history, moved: Contacts, positions, orientations, epsilon):
        """(c, HISTORY) float64: the contacts' history (``history.matched`` of ``moved``,
        this set at ``positions``, ``orientations``), matched at the set's first
        evaluation and kept: a frozen set keeps its contacts, and so their identities."""
        kept = self._matched
        if kept is None or kept[0] is not history:
            kept = (history, history.matched(moved, positions, orientations, epsilon))
            self._matched = kept
        return kept[1]

    def __call__(self, positions, orientations):
        found = self.contacts
        out = (
            np.empty_like(found.points),
            np.empty_like(found.normals),
            np.empty_like(found.overlaps),
        )
        if len(found.points):
            before = (found.points, found.normals, found.overlaps)
            kd.moved_contacts(found.bodies, found.offsets, before, self.reach, self.before,
                              (positions, orientations), out)  # fmt: skip
        moved = Contacts(found.bodies, found.offsets, *out, self.counters)
        return moved, None, False


def unsearched(counters: dict) -> dict:
    """The search counters of an evaluation that did not search: all zero but the
    contacts it evaluated (``triangle_pairs``)."""
    return {k: (v if k == "triangle_pairs" else 0) for k, v in counters.items()}


def evaluate(
    scene, configuration, origins: np.ndarray, search, h: float = 0.0, history=None
) -> Evaluation:
    """The :class:`Evaluation` of ``configuration`` (positions, orientations, velocities,
    angular velocities) with torques about ``origins (n, 3)``: ``search(positions,
    orientations)`` returns ``(contacts, surrogate contacts or None, changed)``.
    Surrogate contacts (multiscale) add normal forces only. ``history``: the contacts'
    :class:`~engine.dynamics.history.ContactHistory` at the start of a step of length
    ``h`` (None: no tangential spring is stretched, no allowance)."""
    x, q, v, w = configuration
    contacts, surrogate, changed = search(x, q)
    frozen = isinstance(search, MovedContacts)
    if history is None:
        matched = np.zeros((len(contacts.points), kf.HISTORY))
    elif frozen:
        matched = search.matched(history, contacts, x, q, scene.epsilon)
    else:
        matched = history.matched(contacts, x, q, scene.epsilon)
    bodies = body_terms(scene)
    block = np.zeros((5, len(x), 3))  # one allocation: force, torque, the friction's, stiffness
    block[0] = bodies.force
    force, torque, friction_force, friction_torque, stiffness = out = tuple(block)
    law = scene.contact_model.parameters()
    energy = 0.0
    terms = np.zeros((len(contacts.points), kf.TERMS))
    frictionless = (*law[:3], 0.0, *law[4:])
    for found, parameters, kept, past in (
        (contacts, law, terms, matched),
        (surrogate, frictionless, None, None),
    ):
        if found is not None and len(found.points):
            state = (x, v, w, origins)
            if past is None:
                past = np.zeros((len(found.points), kf.HISTORY))
            params = (scene.masses, scene.epsilon, past, float(h))
            incidence = search.incidence if frozen and found is contacts else None
            energy += contact_forces(
                found, state, params, parameters, out, scene.threads, kept, incidence
            )
    if len(bodies.fixed):
        block[:4, bodies.fixed] = 0.0
    return Evaluation(
        normal=Wrench(force, torque),
        friction=Wrench(friction_force, friction_torque),
        stiffness=stiffness,
        contacts=contacts,
        energy=energy,
        terms=terms,
        history=matched,
        changed=changed,
    )


def contact_forces(
    found: Contacts, state, params, law, out, threads: int | None, terms=None, incidence=None
) -> float:
    """Add the forces of the contacts ``found`` to ``out`` with the contact ``law`` (the
    kernel tuple of a :class:`~engine.dynamics.forces.ContactModel`); returns their elastic
    energy. ``state = (positions, velocities, angular_velocities, lever_origins)``, each
    ``(n, 3)`` float64; ``params = (masses, epsilon, history, h)``: ``(n,)`` float64 (``inf``
    mass for a fixed body), the contacts' ``(c, HISTORY)`` history and the step length
    (:func:`~engine.kernels.dynamics.contact_forces.contact_terms`); ``out`` as
    :func:`~engine.kernels.dynamics.contact_forces.apply_terms` takes it; ``terms``, if
    given, a ``(c, TERMS)`` float64 array that receives the contacts' terms; ``incidence``,
    if given, each body's pairs (:func:`_incidence` of ``found.bodies``).

    Each contact's terms are computed in parts of the pairs, then each body sums its own
    contacts in pair order, in parts of the bodies, on the worker threads (``threads``;
    None: all cores): the same bits at any thread count. On the paper's 24,576-sphere
    grid (71,168 contacts) this was 2.2 ms of serial host work an evaluation."""
    bodies, offsets = found.bodies, found.offsets
    if terms is None:
        terms = np.empty((len(found.points), kf.TERMS))
    friction = law[3] > 0.0
    if len(bodies) < 2 * _PAIRS_PER_PART and len(state[0]) < 2 * _BODIES_PER_PART:
        # one part of each: one call (the parts' bits, no hand-off)
        contacts = (bodies, offsets, found.points, found.normals, found.overlaps)
        incidence = incidence or _incidence(bodies, len(state[0]))
        return kf.contact_wrench(contacts, state, params, law, incidence, friction, terms, out)

    def terms_part(first: int, last: int) -> None:
        kf.contact_terms(
            bodies, offsets, found.points, found.normals, found.overlaps, state, params, law,
            first, last, terms,
        )  # fmt: skip

    in_parts(threads, len(bodies), terms_part, least=_PAIRS_PER_PART)
    starts, entries = incidence or _incidence(bodies, len(state[0]))

    def bodies_part(first: int, last: int) -> None:
        kf.apply_terms(
            offsets, found.points, state[3], terms, starts, entries, friction, first, last, out
        )

    in_parts(threads, len(starts) - 1, bodies_part, least=_BODIES_PER_PART)
    return kf.elastic_energy(terms)


def _incidence(bodies: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """``(starts (n + 1,), entries (2k,))`` int64: each of ``n`` bodies' pairs among
    ``bodies (k, 2)`` (:func:`~engine.kernels.dynamics.contact_forces.incidence`)."""
    starts, entries = np.empty(n + 1, np.int64), np.empty(2 * len(bodies), np.int64)
    kf.incidence(bodies, starts, entries)
    return starts, entries


def evaluation_key(scene, search) -> tuple:
    """What, besides the state, an evaluation's forces depend on."""
    return (
        type(search).__name__,
        getattr(search, "hierarchy", None),
        len(scene),
        scene.kernel,
        scene.precision,
        scene.contact_model.parameters(),
        scene.gravity.tobytes(),
        scene.external_forces.tobytes(),
        scene.fixed.tobytes(),
        scene.masses.tobytes(),
    )


def reused(scene, key: tuple, start) -> Evaluation | None:
    """``scene.warm_start``'s evaluation if it was made of exactly this state ``start``
    (same positions, orientations, velocities, spins) and ``key`` (everything else the
    forces depend on), with its torques moved to this step's lever origins; else None.

    A converged Picard step ends in the configuration whose forces it evaluated last, so
    the next step's first iteration — the forces of its start — is that evaluation: it
    is reused instead of searched again. Only the lever origins of the torques differ
    (the start of the step): τ' = τ + (o_old − o_new) × F for each body's contact force F.
    """
    warm = scene.warm_start
    if warm is None:
        return None
    if warm.key != key or not all(_same(a, b) for a, b in zip(warm.state, start, strict=True)):
        return None
    evaluation = warm.evaluation
    normal, friction = evaluation.normal, evaluation.friction
    if evaluation.stiffness.any():  # else no contact force: the torques have no lever to move
        normal, friction = _moved_levers(scene, normal, friction, warm.origins, start[0])
    return evaluation._replace(normal=normal, friction=friction, changed=False)


def _same(a: np.ndarray, b: np.ndarray) -> bool:
    """``np.array_equal`` of two float64 state arrays, in one pass without temporaries."""
    if a.shape != b.shape:
        return False
    return bool(kf.same_values(np.ravel(a), np.ravel(b)))


def _moved_levers(scene, normal: Wrench, friction: Wrench, old, new):
    """``(normal, friction)`` wrenches with the torques of the contact forces taken about
    ``new (n, 3)`` instead of ``old`` lever origins."""
    bodies = body_terms(scene)
    normal_torque, friction_torque = np.empty_like(normal.torque), np.empty_like(friction.torque)
    kf.moved_levers(
        old, new, normal, bodies.force, friction, (normal_torque, friction_torque)
    )  # one pass: 0.09 ms on the paper's 24,576-sphere grid, numpy's 20 took 1.1 ms
    normal_torque[bodies.fixed] = 0.0
    friction_torque[bodies.fixed] = 0.0
    return Wrench(normal.force, normal_torque), Wrench(friction.force, friction_torque)
