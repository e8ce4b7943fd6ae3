"""Time stepping of a :class:`~engine.scene.Scene` (paper §2 Algorithms 1 and 3, §5).

* ``explicit`` — Algorithm 1 in the Euler–Cromer order the paper mentions: forces of the
  current configuration, then ``v' = v + dt·F/m``, ``L' = L + dt·τ``, and the pose moves
  with the new velocities. Unlike the forward order (pose first) it does not pump energy
  into an undamped contact spring, and it conserves linear and angular momentum to
  rounding (torques are taken about the step's starting centres of mass).
* ``implicit`` — Algorithm 3: Picard iterations on the end-of-step velocities; each
  iteration finds the contacts of the guessed configuration with the flat search, and
  moves every body from the step's start with the (relaxed) forces.
* ``implicit-surrogate`` — the same with the multiresolution search in every iteration.
* ``implicit-midpoint`` — the implicit midpoint rule, second order (not in the paper):
  an ``implicit-surrogate`` step of dt/2 to the midpoint, then the state extrapolated
  linearly through it to the end of the step (positions, velocities and angular momenta
  2·mid − start; the orientation turned on by the same rotation). Backward Euler is
  first order and dissipative (a collision's restitution 0.62 at dt = 1e-3); the
  midpoint rule is neither (BENCHMARKS.md). Its :class:`StepStats` (contacts, overlap,
  elastic energy) describe the midpoint, the configuration it evaluated last. It adds no
  numerical damping: with an undamped contact law a resting body keeps a small
  oscillation (mm/s) and never sleeps; the law's damping brings it to rest.

Newton corrections first (:mod:`engine.dynamics.newton`): each iteration's next applied
forces solve the contact forces linearised about the configuration it evaluated. A
correction that does not shrink the residual is halved (damped Newton, from the iterate it
started at) up to ``BACKTRACKS`` times per contact set (each frozen set, and the searched
iterations after the last one) — friction springs that switch
between sticking and sliding, contacts that start or stop acting and the clamped dashpot
make the forces only piecewise smooth, and a full correction can overshoot a kink — then the
step falls back to the relaxation below.

Frozen contact sets (not in the paper): between searches, iterations evaluate the contacts
of the last search carried rigidly with the bodies
(:class:`~engine.dynamics.evaluation.MovedContacts`) — no search, and forces that change
smoothly, so the iteration does not flip between contact sets. Once it settles on a
frozen set, a search of that same configuration decides: if its forces pass Picard's test
the step is accepted (the accepted forces are always a search's), else the iteration goes
on from them on a new frozen set; after ``MAX_FREEZES`` sets, or as soon as the searches
go from one contact set to another and back (:func:`~engine.dynamics.relaxation.cycling`: a
configuration on a switch of the contact set, where the frozen sets would alternate until
they ran out), every iteration searches. A
frozen set is solved to ``FROZEN_TOLERANCE`` of the tolerance (cheap: no search), so the
accepted step sits near the set's own fixed point rather than anywhere within 1 % of the
forces on a body (a sliding box's net force is far less than that); once its residual is
within the tolerance itself, the search follows one more Newton correction without a frozen
evaluation to confirm it (the correction squares a small residual: on the settled
48-object pile 0.3 of the tolerance became 0.001, and a settled step took 3 iterations
instead of 4). The
implicit midpoint rule's first frozen set is the last step's midpoint contacts
(:func:`_carried_contacts`), so a step whose contacts do not change costs one search.

Islands (:mod:`engine.dynamics.islands`): when a search's forces fail Picard's test on some
bodies only, the bodies outside their islands (connected by acting contacts) keep the
applied forces they passed with — Newton's corrections and the relaxation leave their rows —
so their configuration stays the same bit for bit, and the next search searches only the
body pairs with a moved body (multiresolution search; the others' contacts are the same).
Every search's forces are still tested on every body, held or not.

Picard relaxation (:mod:`engine.dynamics.relaxation`: the paper's "weighted average
between the currently computed forces and the forces of the previous step", with Aitken's
weights) conserves momentum at every iteration too. Converged when no body's computed force
or torque differs from the applied one by more than ``picard_tolerance`` (1 %) of the
forces acting on it. A step that does not converge within ``max_picard_iterations`` says so
in its :class:`StepStats`; with ``max_halvings > 0`` it is redone as two half steps.

Warm start across steps: a converged step ends in the configuration it evaluated last,
so the next step's first iteration reuses that evaluation, kept in the scene's declared
``warm_start`` (:class:`~engine.dynamics.evaluation.WarmStart`; ``StepStats.evaluations``
counts the searches actually run). (A linear extrapolation of the first applied forces
from the last two steps was tried and dropped: more evaluations on the grid, 39 against 32
over ten steps, and a resting sphere crept at 3e-3 m/s — the accepted solution, anywhere
within the tolerance, was biased the same way every step.)

Where things live: :func:`step` takes the scene as an argument (this module never imports
:mod:`engine.scene`, which composes it); the forces of one configuration come from
:func:`~engine.dynamics.evaluation.evaluate` as an
:class:`~engine.dynamics.evaluation.Evaluation` — normal and friction forces and torques as
:class:`~engine.dynamics.evaluation.Wrench` records — and the per-body terms (constant
forces, levers, inverse masses) from :func:`~engine.dynamics.bodies.body_terms`. Sleeping
bodies are frozen around a step by the scene (:mod:`engine.dynamics.sleep`), not here.
"""

from __future__ import annotations

import dataclasses
import math
import time
import warnings

import numpy as np

from engine.dynamics import islands
from engine.dynamics import relaxation as rx
from engine.dynamics.bodies import body_terms
from engine.dynamics.evaluation import (
    MovedContacts,
    WarmStart,
    Wrench,
    evaluate,
    evaluation_key,
    reused,
    unsearched,
)
from engine.dynamics.history import ContactHistory, allowances, carried, govern
from engine.dynamics.newton import Linearization
from engine.dynamics.stats import StepStats, TunnellingWarning, combined, summary
from engine.kernels.dynamics import contact_forces as kf
from engine.kernels.dynamics import motion as kd
from engine.workers import in_parts

__all__ = ["StepStats", "TunnellingWarning", "step", "travel"]

SWITCH_AFTER = 4
"""Picard iterations after which a step may settle on a contact-set switch
(:func:`~engine.dynamics.relaxation.switch`, which needs four searched iterations anyway).
It was 8: a loaf resting on a switch (seed 7 of the 48-object pile) took 13 iterations and
9 searches every other step, 8 and 4 with 4."""
NORMAL, FRICTION = 0, 1
"""The two parts of the contact forces a Picard iteration relaxes, each with its weight."""
_BODIES_PER_PART = 2048  # bodies a worker thread advances at least (~0.3 ms)
NEWTON_CONTRACTION = 1.0
"""A Newton correction must shrink the residual by this factor (1: at all) …"""
BACKTRACKS = 8
"""… else it is halved, at most this many times per contact set (each frozen set, and the
searched iterations after the last one); after that the step relaxes from the last
iterate."""
MAX_FREEZES = 10
"""Frozen contact sets a step solves on before it iterates on searched forces only."""
FROZEN_TOLERANCE = 0.1
"""A frozen set's iteration settles at this fraction of ``picard_tolerance`` … (the
search that checks it then has the rest of the tolerance for what the frozen set missed:
0.3 and 0.5 took 8 % fewer iterations on the settled 48-object pile, but on one seed of 8
the pile cycled through frozen sets, 21 and 153 steps unconverged against 10)"""
FROZEN_CHECK_WITHIN = 1.0
"""… but once its residual is within this fraction of ``picard_tolerance``, one more Newton
correction and the search follow (no frozen evaluation confirms the correction: it squares
a small residual, 0.3 of the tolerance became 0.001 on the settled 48-object pile; 0 turns
this off; 100 took 9 % less time over sixteen pile seeds, but one seed's largest overlap
reached 0.266 of the reach) …"""
FROZEN_TIGHT_ITERATIONS = 4
"""… within its first this many iterations, and after them at the tolerance itself (a set
whose springs flip between sticking and sliding need not be solved so far)."""


def travel(scene, dt: float) -> tuple[float, int]:
    """``(ratio, body)``: the largest (|v| + |ω|·R)·dt / ε over the free bodies (R: the
    bounding radius of the body's tree, ε: its leaf ε) and that body (-1 for none)."""
    ratio, body = kd.largest_travel(
        scene.velocities,
        scene.angular_velocities,
        body_terms(scene).radius,
        scene.epsilon,
        scene.fixed,
        float(dt),
    )
    return (0.0, -1) if body < 0 else (float(ratio), int(body))


def step(scene, dt: float, scheme: str, halvings_left: int | None = None) -> StepStats:
    """Advance ``scene`` by ``dt`` with ``scheme`` (see the module docstring).

    No contact is missed while every body's surface moves by less than its ε per step
    (:func:`travel` ≤ 1: the step cannot jump from outside the contact halo to beyond
    it). Above that, ``scene.substeps`` splits the step into ⌈travel⌉ equal sub-steps;
    otherwise a :class:`TunnellingWarning` says so."""
    with scene.body_cache.held(scene):  # a step changes no mass, mask or force
        return _step(scene, dt, scheme, halvings_left)


def _step(scene, dt: float, scheme: str, halvings_left: int | None) -> StepStats:
    start = time.perf_counter()
    ratio, body = travel(scene, dt)
    if ratio > 1.0 and halvings_left is None:
        k = math.ceil(ratio)
        if scene.substeps:
            parts = [step(scene, dt / k, scheme, scene.max_halvings) for _ in range(k)]
            merged = combined(parts, dt, time.perf_counter() - start)
            return dataclasses.replace(merged, travel=ratio, substeps=k)
        warnings.warn(
            TunnellingWarning(
                f"body {body} moves {ratio:.3g} times its ε in this step of {dt:g}: contacts"
                f" may be missed. Use dt <= {dt / ratio:.3g} or Scene(substeps=True)"
            ),
            stacklevel=3,
        )
    left = scene.max_halvings if halvings_left is None else halvings_left
    state = _state(scene)
    history, gentle = scene.contact_history, scene.gentle_start
    if scheme == "explicit":
        stats = _explicit(scene, dt)
        scene.warm_start = None
    elif scheme == "multiscale":
        search = scene.multiscale
        search.begin_step()
        stats = _picard(scene, dt, search)
    elif scheme == "implicit-midpoint":
        stats = _picard(scene, dt / 2, _Search(scene, hierarchy=True), full_dt=dt)
        if stats["converged"] or left == 0:
            _extrapolate(scene, state, dt)
    else:
        stats = _picard(scene, dt, _Search(scene, hierarchy=scheme == "implicit-surrogate"))
    if not stats["converged"] and left > 0:
        _restore(scene, state)
        scene.contact_history, scene.gentle_start = history, gentle
        first = step(scene, dt / 2, scheme, left - 1)
        second = step(scene, dt / 2, scheme, left - 1)
        merged = combined([first, second], dt, time.perf_counter() - start)
        return dataclasses.replace(merged, halvings=merged.halvings + 1, travel=ratio)
    scene.time += dt
    scene.gentle_start = False
    govern(scene, body_terms(scene).radius)
    return StepStats(
        scheme=scheme,
        dt=dt,
        halvings=0,
        seconds=time.perf_counter() - start,
        travel=ratio,
        **stats,
    )


class _Search:
    """A fresh search of every configuration (flat or multiresolution); with ``partial``
    (multiresolution only), of the body pairs with a body moved since its last search
    (:func:`~engine.dynamics.islands.search`)."""

    def __init__(self, scene, hierarchy: bool) -> None:
        self.scene, self.hierarchy = scene, hierarchy
        self.partial = False
        self.last: islands.Searched | None = None

    def __call__(self, positions, orientations):
        if not self.hierarchy:
            return self.scene.contacts(positions, orientations, False), None, False
        last = self.last if self.partial else None
        self.last = islands.search(self.scene, positions, orientations, last)
        return self.last.contacts, None, False


def _explicit(scene, dt: float) -> dict:
    x, q, v, w = _state(scene)
    search = _Search(scene, hierarchy=True)
    history = scene.contact_history
    evaluation = evaluate(scene, (x, q, v, w), x, search, dt, history)
    if scene.gentle_start:
        history, evaluation = _gentle_start(scene, evaluation, (x, q, v, w), dt, history)
    _commit_history(scene, evaluation, (x, q), dt, False, history)
    scene.touching = touching(evaluation.contacts)
    out = tuple(np.empty_like(a) for a in (x, q, v, w))
    total = evaluation.normal.plus(evaluation.friction)
    _advance(scene, (x, q, v, w), total.force, total.torque, dt, out)
    _restore(scene, out)
    contacts = evaluation.contacts
    told = summary(scene, contacts, [contacts.counters], evaluation.energy, True, 1)
    return {**told, "evaluations": 1}


def _picard(scene, dt: float, search, full_dt: float | None = None) -> dict:
    """Picard iterations of a backward Euler step of ``dt`` (the half step of the implicit
    midpoint rule when ``full_dt`` is given: the whole step's length)."""
    start = _state(scene)
    guess = tuple(a.copy() for a in start)
    radius = body_terms(scene).radius
    history = scene.contact_history
    applied: Wrench | None = None  # the applied total (normal and friction forces)
    relaxed: list[Wrench] | None = None  # per part (NORMAL, FRICTION) once relaxing
    residual, beta = [None, None], [1.0, 1.0]
    counters, converged, iterations, evaluations = [], False, 0, 0
    key = evaluation_key(scene, search)
    forceless = True  # no evaluation of this step has had a contact force so far
    recent: list[Wrench] = []  # the last computed totals
    newton: Linearization | None = Linearization(scene, start, dt)
    last_size = math.inf
    anchor: Wrench | None = None  # the applied forces the last Newton correction started from
    backtracks = 0  # Newton corrections halved on this contact set
    # frozen contact sets (module docstring): the contacts of the last search, moved rigidly
    freezes = 0 if isinstance(search, _Search) else MAX_FREEZES
    frozen: MovedContacts | None = None
    frozen_at = 0  # the iteration that first evaluated the current frozen set
    searched = True
    # islands (engine.dynamics.islands): the bodies that passed a search's test keep the
    # applied forces they passed with while Newton corrects the others
    hold: np.ndarray | None = None  # (n,) bool
    held: Wrench | None = None
    by_island = isinstance(search, _Search) and search.hierarchy
    bodies = np.arange(len(start[0]))  # switches are tested body by body (rx.switch)
    while iterations < scene.max_picard_iterations:
        iterations += 1
        warm = reused(scene, key, start) if iterations == 1 else None
        if iterations == 1 and warm is None and freezes < MAX_FREEZES:
            frozen = _carried_contacts(scene, key)  # the last step's, moved to its end
            freezes += frozen is not None
            frozen_at = iterations
        if frozen is not None:
            evaluation = evaluate(scene, guess, start[0], frozen, dt, history)
        elif warm is None:
            evaluation = evaluate(scene, guess, start[0], search, dt, history)
            evaluations += 1
        elif history is not None:  # the same contacts; their springs start from this step
            evaluation = evaluate(scene, guess, start[0], _Found(warm.contacts), dt, history)
        else:
            evaluation = warm
        if iterations == 1 and scene.gentle_start:
            history, evaluation = _gentle_start(scene, evaluation, guess, dt, history)
        stiffness, changed = evaluation.stiffness, evaluation.changed
        forceless = forceless and not stiffness.any()
        computed = (evaluation.normal, evaluation.friction)  # indexed by NORMAL, FRICTION
        found = evaluation.contacts.counters
        # a frozen set's counters are unsearched already
        counters.append(found if warm is None else unsearched(found))
        total = evaluation.normal.plus(evaluation.friction)
        was_frozen = not searched  # the last iteration evaluated a frozen set
        searched = frozen is None  # the forces of this configuration, not of a frozen set
        if applied is None:  # the step's start: predict its end (linearly implicit Euler)
            applied = newton.predicted(evaluation)
        else:
            change = None  # per part (NORMAL, FRICTION), once relaxing
            if relaxed is None:  # Newton corrections: the total against the applied total
                mismatch = total.minus(applied)
            else:
                change = [c.minus(a) for c, a in zip(computed, relaxed, strict=True)]
                mismatch = change[NORMAL].plus(change[FRICTION])
            # body forces alone, every time: the applied forces are the computed ones exactly
            # a frozen set is solved tighter (its iterations search nothing): the search
            # then checks an answer within FROZEN_TOLERANCE of the set's own fixed point
            on_set = iterations - frozen_at  # iterations on this frozen set so far
            tighter = 1.0 if searched or on_set > FROZEN_TIGHT_ITERATIONS else FROZEN_TOLERANCE
            settled = forceless or rx.settled(
                scene, total, mismatch, stiffness[:, 2], radius, tighter,
                None if searched else hold,
            )  # fmt: skip
            # within the tolerance itself on a frozen set: one more correction, then the search
            loose = (
                not (settled or searched)
                and newton is not None
                and tighter < FROZEN_CHECK_WITHIN
                and rx.settled(
                    scene, total, mismatch, stiffness[:, 2], radius, FROZEN_CHECK_WITHIN, hold
                )
            )
            if searched:
                recent = [] if changed else [*recent[-5:], total]
                if not settled and iterations > SWITCH_AFTER:
                    settled = rx.switch(scene, recent, applied, stiffness[:, 2], radius, bodies)
                cycle = not settled and freezes < MAX_FREEZES
                if cycle and rx.cycling(scene, recent, stiffness[:, 2], radius):
                    # on a switch: settled where the frozen sets' answer lies between its
                    # two sides, else the searched iterations resolve it
                    freezes = MAX_FREEZES
                    settled = rx.settled_cycle(scene, recent, applied, stiffness[:, 2], radius)
                if not settled and by_island and not changed:
                    failing = rx.unsettled(scene, total, mismatch, stiffness[:, 2], radius)
                    hold = ~scene.fixed & ~islands.moving(scene, evaluation, failing)
                    hold, held = (hold, applied) if hold.any() else (None, None)
                    search.partial = hold is not None
            elif settled:  # solved on the frozen set: a search of this guess decides
                frozen = None
                continue
            converged = settled and not changed  # multiscale: nothing unfolded either
            if converged:
                break
            size = rx.size(mismatch, radius)
            if searched and (freezes < MAX_FREEZES or was_frozen):
                # a new contact set (a new frozen set, or the searched iterations after the
                # last one): the residual starts over
                last_size, backtracks = math.inf, 0
            growing = size > NEWTON_CONTRACTION * last_size
            if newton is not None and not changed and growing and backtracks < BACKTRACKS:
                # damped Newton: half of the last correction, from the iterate it started at
                backtracks += 1
                applied = _held(
                    Wrench(
                        0.5 * (anchor.force + applied.force),
                        0.5 * (anchor.torque + applied.torque),
                    ),
                    held,
                    hold,
                )
                _advance(scene, start, applied.force, applied.torque, dt, guess)
                continue
            if newton is not None and (changed or growing):
                # not contracting (a contact-set switch) or the fronts moved: relax instead
                newton, relaxed = None, [applied, _zero(applied)]
                change = [computed[NORMAL].minus(applied), computed[FRICTION]]
                beta = rx.first_weights(scene, stiffness, radius, dt)
            last_size = size
            if newton is not None:
                anchor = applied  # the iterate the correction starts from
                applied = _held(newton.corrected(evaluation, applied, total), held, hold)
                if loose:
                    frozen = None
            else:
                if changed:  # a front moved: the secant history no longer describes the map
                    residual = [None, None]
                    beta = rx.first_weights(scene, stiffness, radius, dt)
                for part in (NORMAL, FRICTION):  # each with its own weight
                    new = rx.flat(change[part], radius)
                    beta[part] = rx.aitken(beta[part], residual[part], new)
                    residual[part] = new
                    relaxed[part] = Wrench(
                        relaxed[part].force + beta[part] * change[part].force,
                        relaxed[part].torque + beta[part] * change[part].torque,
                    )
                if hold is not None:  # held: the forces they passed with, as the normal part
                    relaxed = [_held(relaxed[NORMAL], held, hold), _held(relaxed[FRICTION],
                               _zero(held), hold)]  # fmt: skip
                applied = relaxed[NORMAL].plus(relaxed[FRICTION])
        if searched and freezes < MAX_FREEZES and newton is not None:
            frozen, freezes = (
                MovedContacts(scene, evaluation.contacts, guess[0], guess[1]),
                freezes + 1,
            )
            frozen_at = iterations + 1  # its first evaluation is the next iteration's
        _advance(scene, start, applied.force, applied.torque, dt, guess)
    _restore(scene, guess)
    # the forces of the accepted configuration are the next step's first evaluation
    scene.warm_start = WarmStart(key, guess, start[0], evaluation) if converged else None
    _commit_history(scene, evaluation, guess, full_dt or dt, full_dt is not None, history)
    scene.touching = touching(evaluation.contacts)
    contacts, energy = evaluation.contacts, evaluation.energy
    told = summary(scene, contacts, counters, energy, converged, iterations)
    return {**told, "evaluations": evaluations}


def touching(contacts) -> np.ndarray:
    """(k, 2) int64: the body pairs of ``contacts`` with at least one contact (the sleep
    rule wakes a body through them, :mod:`engine.dynamics.sleep`)."""
    return np.ascontiguousarray(contacts.bodies[contacts.offsets[1:] > contacts.offsets[:-1]])


def _carried_contacts(scene, key: tuple) -> MovedContacts | None:
    """The contacts of the last step's last search (``scene.warm_start``, made with the
    same ``key``) moved rigidly to any configuration, or None. The implicit midpoint rule
    ends a step beyond the configuration it searched last (the midpoint): its contacts,
    carried on, stand in for a search of the next step's start."""
    warm = scene.warm_start
    if warm is None or warm.key != key:
        return None
    return MovedContacts(scene, warm.evaluation.contacts, warm.state[0], warm.state[1])


def _held(applied: Wrench, held: Wrench | None, hold: np.ndarray | None) -> Wrench:
    """``applied`` with the rows ``hold (n,)`` bool of ``held`` (bodies whose islands
    passed a search's test keep the forces they passed with)."""
    if hold is None:
        return applied
    force, torque = applied.force.copy(), applied.torque.copy()
    force[hold], torque[hold] = held.force[hold], held.torque[hold]
    return Wrench(force, torque)


def _zero(wrench: Wrench) -> Wrench:
    return Wrench(np.zeros_like(wrench.force), np.zeros_like(wrench.torque))


class _Found:
    """A search that returns contacts found before (an evaluation without searching)."""

    def __init__(self, contacts) -> None:
        self.contacts = contacts

    def __call__(self, positions, orientations):
        return self.contacts, None, False


def _gentle_start(scene, evaluation, configuration, h: float, history):
    """After the state was set from outside: ``(history, evaluation)`` with every contact
    of the step's start given its allowance (:mod:`engine.dynamics.history`), the start's
    forces evaluated again with it (same contacts, no search)."""
    if not math.isfinite(scene.separation_speed):  # overlaps pushed apart at once
        return history, evaluation
    values = allowances(evaluation)
    if not (values[:, kf.HISTORY_ALLOWANCE] > 0.0).any():
        return history, evaluation
    x, q = configuration[0], configuration[1]
    history = ContactHistory.of(evaluation.contacts, x, q, values)
    found = _Found(evaluation.contacts)
    return history, evaluate(scene, configuration, x, found, h, history)


def _commit_history(scene, evaluation, configuration, dt: float, midpoint: bool, history):
    """Leave the contacts' history of the accepted ``evaluation`` (at ``configuration``)
    to the next step of ``scene``: kept while friction sticks or an allowance is left."""
    if not scene.contact_model.sticks and history is None:
        scene.contact_history = None
        return
    values = carried(evaluation, 0.5 * scene.separation_speed * dt, midpoint)
    start = evaluation.history
    releasing = (values[:, kf.HISTORY_RELEASING] != 0.0) | (start[:, kf.HISTORY_RELEASING] != 0.0)
    if not scene.contact_model.sticks and not releasing.any():
        scene.contact_history = None
        return
    x, q = configuration[0], configuration[1]
    scene.contact_history = ContactHistory.of(evaluation.contacts, x, q, values, start)


def _extrapolate(scene, start, dt: float) -> None:
    """From the midpoint the scene is at, on through it to the end of the step: free bodies'
    positions, velocities and world angular momenta become 2·mid − start, orientations turn
    on by the rotation from start to mid. The half step took contact torques about the
    start's centres; over the whole step they act about the midpoint's, so the spin gains
    dt·(x_start − x_mid) × F_contact — with it linear and angular momentum are conserved
    exactly, as the midpoint rule conserves every quadratic invariant. The last evaluation
    (of the midpoint) is no longer the configuration's: ``scene.warm_start`` keeps it with
    the midpoint's state, which the next step does not reuse as its start's forces (the
    states differ) but carries on as a frozen contact set (:func:`_carried_contacts`)."""
    mid = (scene.positions, scene.orientations, scene.velocities, scene.angular_velocities)
    out = tuple(np.empty_like(a) for a in mid)
    kd.extrapolated(start, mid, scene.inertia, scene.inverse_inertia, scene.masses,
                    body_terms(scene).force, ~scene.fixed, float(dt), out)  # fmt: skip
    scene.positions, scene.orientations, scene.velocities, scene.angular_velocities = out


def _advance(scene, start, force, torque, dt: float, out) -> None:
    """:func:`~engine.kernels.dynamics.motion.advance` of every body, in parts on the
    scene's worker threads when there are many (each body's update is its own: the same
    bits in any split; on the paper's 24,576-sphere grid one pass took 3.5 ms, three a
    step)."""
    inverse_mass = body_terms(scene).inverse_mass
    inertia, inverse_inertia = scene.inertia, scene.inverse_inertia
    if len(inverse_mass) < 2 * _BODIES_PER_PART:  # one part: no views, no hand-off
        kd.advance(start, force, torque, inverse_mass, inertia, inverse_inertia, dt, out)
        return

    def part(a: int, b: int) -> None:
        kd.advance(
            tuple(x[a:b] for x in start),
            force[a:b],
            torque[a:b],
            inverse_mass[a:b],
            inertia[a:b],
            inverse_inertia[a:b],
            dt,
            tuple(x[a:b] for x in out),
        )

    in_parts(scene.threads, len(inverse_mass), part, least=_BODIES_PER_PART)


def _state(scene) -> tuple[np.ndarray, ...]:
    return (
        scene.positions.copy(),
        scene.orientations.copy(),
        scene.velocities.copy(),
        scene.angular_velocities.copy(),
    )


def _restore(scene, state) -> None:
    scene.positions, scene.orientations, scene.velocities, scene.angular_velocities = (
        a.copy() for a in state
    )
