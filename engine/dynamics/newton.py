"""Newton corrections of the Picard iteration: the contact forces linearised about the last
evaluated configuration, solved for the velocity correction
(:mod:`engine.kernels.dynamics.linearized`).

A Picard iteration of a backward Euler step of length h applies forces A, moves the bodies
with them from the step's start, and computes the forces F of that guess. The paper relaxes
A towards F by a weight; here the next A is the fixed point of the forces linearised about
the guess: z solves (M + h²K + h·C)·z = h·(F − A) and A ← F − (h·K + C)·z. The first
iteration predicts from the start's forces F₀ and velocities v₀ (linearly implicit Euler):
(M + h²K + h·C)·z = h·(F₀ − h·K·v₀), A = F₀ − h·K·v₀ − (h·K + C)·z. Every correction is a sum
of equal and opposite contact forces, so momentum is conserved at every iteration, and the
step is still accepted only where the computed forces of its configuration match the applied
ones (Picard's test): the linearisation chooses the iterates, never the answer.
"""

from __future__ import annotations

import numpy as np

from engine.dynamics.evaluation import Evaluation, Wrench
from engine.kernels.dynamics import linearized as kl
from engine.kernels.dynamics import motion as kd

__all__ = ["Linearization"]

SOLVE_TOLERANCE = 1e-3
"""Relative residual at which the iterations of a correction's solve stop: an inexact
Newton step (its error is a thousandth of the residual it corrects, which the frozen sets
settle to a thousandth of the forces). 1e-6 took twice the solver's iterations and no
fewer Picard iterations on the 48-object pile."""
SOLVE_ITERATIONS = 100
"""The most iterations of one correction's solve."""


class Linearization:
    """The linearised contact forces of one backward Euler step of length ``h`` from the
    state ``start`` (positions, orientations, velocities, angular velocities) of
    ``scene``: masses and world inertias at the start, torques about the start's centres
    of mass."""

    def __init__(self, scene, start, h: float) -> None:
        x, q = start[0], start[1]
        self.h = float(h)
        self.origins = x
        self.free = ~scene.fixed
        self.mass = np.where(self.free, scene.masses, 0.0)
        self.inertia = np.empty((len(x), 3, 3))
        kd.world_inertias(q, scene.inertia, self.free, self.inertia)
        self.velocity = np.concatenate([start[2], start[3]], axis=1)

    def predicted(self, evaluation: Evaluation) -> Wrench:
        """The applied forces of the first iteration from the start's ``evaluation``."""
        total = _stacked(evaluation.normal.plus(evaluation.friction))
        drift = self._product(evaluation, self.velocity, 1.0, 0.0)
        target = total - self.h * drift
        zero = np.zeros((len(target), 3))
        computed = Wrench(np.ascontiguousarray(target[:, :3]), np.ascontiguousarray(target[:, 3:]))
        return self._corrected(evaluation, computed, Wrench(zero, zero))

    def corrected(self, evaluation: Evaluation, applied: Wrench, total: Wrench | None = None
                  ) -> Wrench:  # fmt: skip
        """The next applied forces after ``applied`` gave the guess of ``evaluation``
        (``total``: its normal plus friction forces, if the caller has them)."""
        if total is None:
            total = evaluation.normal.plus(evaluation.friction)
        return self._corrected(evaluation, total, applied)

    def _corrected(self, evaluation: Evaluation, computed: Wrench, applied: Wrench) -> Wrench:
        """F − (h·K + C)·z with z from (M + h²K + h·C)·z = h·(F − A), F ``computed``, A
        ``applied`` (:func:`~engine.kernels.dynamics.linearized.corrected_forces`)."""
        found = evaluation.contacts
        contacts = (found.bodies, found.offsets, found.points, found.normals, evaluation.terms)
        out = Wrench(np.empty_like(computed.force), np.empty_like(computed.torque))
        kl.corrected_forces(
            contacts, self.origins, self.mass, self.inertia, self.free, self.h,
            (computed.force, computed.torque), (applied.force, applied.torque),
            SOLVE_TOLERANCE, SOLVE_ITERATIONS, (out.force, out.torque),
        )  # fmt: skip
        return out

    def _product(self, evaluation: Evaluation, z, w_k: float, w_c: float) -> np.ndarray:
        """(w_k·K + w_c·C)·z, ``(n, 6)`` float64."""
        out = np.zeros((len(z), 6))
        found = evaluation.contacts
        if len(found.points):
            kl.contact_product(
                found.bodies, found.offsets, found.points, found.normals, evaluation.terms,
                self.origins, np.ascontiguousarray(z), w_k, w_c, out,
            )  # fmt: skip
        return out


def _stacked(wrench: Wrench) -> np.ndarray:
    """(n, 6) float64: force then torque."""
    return np.concatenate([wrench.force, wrench.torque], axis=1)
