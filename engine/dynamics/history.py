"""Contact history across time steps: the tangential springs of static friction and the
allowances of a gentle start (:mod:`engine.kernels.dynamics.history`).

* **Tangential springs** (Cundall–Strack; ``ContactModel.tangential_stiffness`` > 0): each
  contact carries the displacement ξ of its spring from one step to the next. A step's
  contact takes the history of the last step's contact of the same body pair whose point,
  in body A's frame, is nearest within the pair's reach ε_a + ε_b (merged points move as
  clusters change: identity is by place on A's surface). A new contact starts at ξ = 0; a
  contact that stops acting loses its spring.
* **Allowances** (a gentle start): after the state is set from outside (bodies added,
  ``Scene.set_state`` with positions or orientations), each contact of the next step's
  start that is not closing gets its overlap as an allowance: its spring acts on
  δ − allowance only, so it starts relaxed. (A closing contact, a collision under way when
  the state was set, keeps its spring: an allowance would let the bodies pass into each
  other, and the speed cap below would brake a body on its way in.) Each step then lets
  go of v·dt/2 of every allowance (v the scene's
  ``separation_speed``), so the spring's rest point moves apart at v/2, and while it has an
  allowance the contact is at least critically damped (ζ ≥ 1), so the bodies follow it
  without overshooting it where the step resolves the spring. Where it does not (a small
  body, a stiff spring: ω·dt ≫ 1) the integration overshoots all the same, so after each
  step a body that still has a contact with an allowance is slowed to a surface speed of
  at most v (:func:`govern`, as physics engines cap their depenetration velocity):
  bodies separate no faster than v. A body that rested at its
  equilibrium overlap when the state was set sinks by that overlap (micrometres) and
  rises again within a few steps.

A :class:`ContactHistory` is the record of one accepted configuration; ``Scene`` keeps the
last one (``Scene.contact_history``) and drops it when the state is set from outside.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from engine.errors import InvalidArgumentError
from engine.kernels.dynamics import contact_forces as kf
from engine.kernels.dynamics import history as kh

__all__ = [
    "DEFAULT_SEPARATION_SPEED",
    "ContactHistory",
    "OverlapReport",
    "allowances",
    "carried",
    "check_speed",
    "govern",
    "overlap_report",
]

DEFAULT_SEPARATION_SPEED = 0.5
"""m/s: the fastest that overlaps found after the state is set are let go (``inf``: no
gentle start, each spring pushes its overlap apart at once)."""


@dataclass(frozen=True)
class OverlapReport:
    """Body pairs whose surfaces cross (overlap beyond the reach ε_a + ε_b: the closest
    points coincide), found when the state was set.

    pairs : (k, 2) int64 — the body pairs (a < b)
    largest : float — the largest overlap of any contact relative to its pair's reach
        (0 without contacts; at most 1)
    """

    pairs: np.ndarray
    largest: float


def overlap_report(contacts, epsilon: np.ndarray) -> OverlapReport:
    """The :class:`OverlapReport` of ``contacts`` of a configuration (``epsilon (n,)``
    float64 each body's ε)."""
    found = np.zeros(len(contacts.bodies), bool)
    largest = 0.0
    if len(contacts.points):
        bodies, offsets = contacts.bodies, contacts.offsets
        reach = epsilon[bodies[:, 0]] + epsilon[bodies[:, 1]]
        pair = np.repeat(np.arange(len(bodies)), np.diff(offsets))
        fraction = contacts.overlaps / reach[pair]
        largest = float(fraction.max())
        found[pair[fraction >= 1.0 - 1e-9]] = True
    return OverlapReport(np.asarray(contacts.bodies[found], np.int64).reshape(-1, 2), largest)


def check_speed(speed) -> float:
    """``speed`` as a float if it is a number > 0 (``inf`` allowed), else an error."""
    if isinstance(speed, bool) or not isinstance(speed, int | float) or not speed > 0:
        raise InvalidArgumentError(f"separation_speed must be a number > 0, got {speed!r}")
    return float(speed)


@dataclass(frozen=True)
class ContactHistory:
    """Each contact's history after an accepted step.

    keys : (m,) int64 — body pairs a·count + b, ascending
    offsets : (m + 1,) int64 — pair i owns contacts ``offsets[i]:offsets[i + 1]``
    local : (c, 3) float64 — contact points in body A's frame
    values : (c, HISTORY) float64 — tangential displacement (world frame) and allowance
    count : int — bodies of the scene it was made in
    governed : (g,) int64 — bodies that had a releasing contact at the start or the end of
        the step that made it (:func:`govern`)
    """

    keys: np.ndarray
    offsets: np.ndarray
    local: np.ndarray
    values: np.ndarray
    count: int
    governed: np.ndarray

    @classmethod
    def of(cls, contacts, positions, orientations, values, start=None) -> ContactHistory:
        """The history of ``contacts`` found at ``positions (n, 3)``, ``orientations
        (n, 4)``, with ``values (c, HISTORY)`` float64; ``start (c, HISTORY)``: their
        history at the start of the step, if any (for :attr:`governed`)."""
        releasing = values[:, kf.HISTORY_RELEASING] != 0.0
        if start is not None:
            releasing = releasing | (start[:, kf.HISTORY_RELEASING] != 0.0)
        governed = np.zeros(0, np.int64)
        if releasing.any():  # rarely: only after the state was set from outside
            pair = np.repeat(np.arange(len(contacts.bodies)), np.diff(contacts.offsets))
            governed = np.unique(contacts.bodies[pair[releasing]]).astype(np.int64)
        count = len(positions)
        local = np.empty((len(contacts.points), 3))
        kh.local_points(contacts.bodies, contacts.offsets, contacts.points, positions,
                        orientations, local)  # fmt: skip
        keys = contacts.bodies[:, 0] * count + contacts.bodies[:, 1]
        offsets = np.asarray(contacts.offsets, np.int64)
        if len(keys) > 1 and not (np.diff(keys) > 0).all():
            order = np.argsort(keys, kind="stable")
            sizes = np.diff(offsets)[order]
            rows = np.concatenate([np.arange(offsets[i], offsets[i + 1]) for i in order])
            keys, local, values = keys[order], local[rows], values[rows]
            offsets = np.concatenate([[0], np.cumsum(sizes)])
        return cls(keys.astype(np.int64), offsets, local, values, count, governed)

    @property
    def releasing(self) -> bool:
        """Some contact still lets go of an initial overlap."""
        return bool((self.values[:, kf.HISTORY_RELEASING] != 0.0).any())

    def matched(self, contacts, positions, orientations, epsilon) -> np.ndarray:
        """(c, HISTORY) float64: each of ``contacts``' history (zeros for a new contact)
        at ``positions``, ``orientations`` of a scene of the same bodies."""
        out = np.zeros((len(contacts.points), kf.HISTORY))
        if not len(out) or not len(self.keys) or len(positions) != self.count:
            return out
        local = np.empty((len(out), 3))
        kh.local_points(contacts.bodies, contacts.offsets, contacts.points, positions,
                        orientations, local)  # fmt: skip
        kh.matched(contacts.bodies, contacts.offsets, local, epsilon, self.count, self.keys,
                   self.offsets, self.local, self.values, out)  # fmt: skip
        return out


def govern(scene, radius: np.ndarray) -> None:
    """Scale down the velocities of ``scene``'s free bodies that have a releasing contact
    (it had an allowance, or it still overlaps by more than a step's release since) so
    that their surface speed |v| + |ω|·R (``radius (n,)``) is at most the
    scene's ``separation_speed`` (the depenetration cap of physics engines: a contact's
    spring is far stiffer than a time step resolves when bodies are small, and no
    integration keeps a stiff spring dragged apart from overshooting)."""
    history = scene.contact_history
    if history is None or not np.isfinite(scene.separation_speed) or not len(history.governed):
        return
    bodies = history.governed[~scene.fixed[history.governed]]
    v, w = scene.velocities[bodies], scene.angular_velocities[bodies]
    speed = np.linalg.norm(v, axis=1) + np.linalg.norm(w, axis=1) * radius[bodies]
    scale = np.minimum(1.0, scene.separation_speed / np.maximum(speed, 1e-300))
    scene.velocities[bodies] = v * scale[:, None]
    scene.angular_velocities[bodies] = w * scale[:, None]


def carried(evaluation, release: float, midpoint: bool) -> np.ndarray:
    """(c, HISTORY) float64: what the contacts of an accepted ``evaluation`` leave to the
    next step (:func:`~engine.kernels.dynamics.history.carried`)."""
    out = np.empty((len(evaluation.terms), kf.HISTORY))
    overlaps = evaluation.contacts.overlaps
    kh.carried(evaluation.terms, evaluation.history, overlaps, float(release), bool(midpoint), out)
    return out


def allowances(evaluation) -> np.ndarray:
    """(c, HISTORY) float64: ``evaluation.history`` with each contact's allowance for a
    gentle start: its whole overlap, unless it is closing (module docstring)."""
    out = evaluation.history.copy()
    kh.initial_allowance(evaluation.contacts.overlaps, evaluation.terms, out)
    return out
