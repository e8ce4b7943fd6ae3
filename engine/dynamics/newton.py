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

from engine.dynamics.bodies import body_terms
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
        self.fixed_rows = body_terms(scene).fixed

    def predicted(self, evaluation: Evaluation) -> Wrench:
        """The applied forces of the first iteration from the start's ``evaluation``."""
        total = _stacked(evaluation.normal.plus(evaluation.friction))
        drift = self._product(evaluation, self.velocity, 1.0, 0.0)
        target = total - self.h * drift
        return self._corrected(evaluation, target, self.h * target)

    def corrected(self, evaluation: Evaluation, applied: Wrench) -> Wrench:
        """The next applied forces after ``applied`` gave the guess of ``evaluation``."""
        total = _stacked(evaluation.normal.plus(evaluation.friction))
        return self._corrected(evaluation, total, self.h * (total - _stacked(applied)))

    def _corrected(self, evaluation: Evaluation, forces, rhs) -> Wrench:
        found = evaluation.contacts
        contacts = (found.bodies, found.offsets, found.points, found.normals, evaluation.terms)
        if not len(found.points):  # nothing to linearise: the forces are constant
            applied = forces.copy()
            applied[self.fixed_rows] = 0.0
            return Wrench(
                np.ascontiguousarray(applied[:, :3]), np.ascontiguousarray(applied[:, 3:])
            )
        z, change = np.empty_like(rhs), np.empty_like(rhs)
        kl.newton_correction(
            contacts, self.origins, self.mass, self.inertia, self.free, self.h, rhs,
            SOLVE_TOLERANCE, SOLVE_ITERATIONS, z, change,
        )  # fmt: skip
        applied = forces - change
        applied[self.fixed_rows] = 0.0
        return Wrench(np.ascontiguousarray(applied[:, :3]), np.ascontiguousarray(applied[:, 3:]))

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
