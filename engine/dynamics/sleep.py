"""Bodies at rest sleep: no narrow phase, no integration, until something moving touches them.

A free body that stays within ``speed`` × ``steps`` × dt of where it came to rest for
``steps`` consecutive steps (no point of it farther, |Δx| + θ·R: its mean surface speed
over them below ``speed``) falls asleep: during a step it is treated as fixed (zero
velocity, no integration; pairs of two sleeping or sleeping and fixed bodies are never
tested, as fixed–fixed pairs are not), while its contacts with awake bodies are evaluated
as usual, so an awake body still rests on it. The test is on where the body is, not on its
velocity at the step's end: under the implicit midpoint rule a stiff contact mode can ring
at the step's frequency (the velocity +v, −v, +v … while the body stays where it is), and
a body on a switch of its contact set can cycle through a few micrometres; both are at rest.
A body that leaves that distance is moving: after each step every body in contact with a
moving one (a pair with a contact in the step's accepted evaluation,
``scene.touching``; the broad phase's candidate pairs where there is none) is kept awake
(a sleeping one wakes, its velocity starting from zero, and starts counting again), and
wakes the bodies it touches in turn when it moves. A body merely near a moving one (a
lemon rolling past a loaf) does not wake it: it would touch it first. Anything that
changes the scene from outside (``set_state``, external forces, new bodies) wakes every
body.

Sleeping is an approximation (a sleeping body feels no gravity and no contact forces: in
the step in which a moving body first touches it, it stands as a fixed one), off by
default: ``Scene(sleep=True)`` or ``Scene(sleep=Sleep(speed=…, steps=…))``.

A :class:`Sleep` does not step the scene: ``Scene.step`` runs the time step
(:func:`engine.dynamics.picard.step`) inside :meth:`Sleep.frozen` and then calls
:meth:`Sleep.update` with the bodies' bounding radii
(:attr:`engine.dynamics.bodies.BodyTerms.radius`).
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

import numpy as np

from engine.errors import InvalidArgumentError
from engine.kernels.dynamics import motion as kd

__all__ = ["Sleep"]


class Sleep:
    """The sleep rule and each body's sleep state.

    Parameters
    ----------
    speed : float — mean surface speed below which a body counts as at rest (> 0)
    steps : int — consecutive steps at rest before it sleeps (>= 1)

    Attributes
    ----------
    asleep : (n,) bool — the bodies asleep
    rest : (n,) int64 — consecutive steps each body has been at rest
    anchor : ((n, 3), (n, 4)) float64 — positions and orientations where each resting
        body's count began
    """

    def __init__(self, speed: float = 1e-3, steps: int = 50) -> None:
        if not (np.isfinite(speed) and speed > 0):
            raise InvalidArgumentError(f"sleep speed must be finite and > 0, got {speed!r}")
        if int(steps) < 1:
            raise InvalidArgumentError(f"sleep steps must be >= 1, got {steps!r}")
        self.speed, self.steps = float(speed), int(steps)
        self.wake_all(0)

    def wake_all(self, n: int) -> None:
        """Every one of ``n`` bodies awake, none at rest."""
        self.asleep = np.zeros(n, bool)
        self.rest = np.zeros(n, np.int64)
        self.anchor = (np.zeros((n, 3)), np.zeros((n, 4)))  # set as each count begins

    @property
    def sleeping(self) -> int:
        """How many bodies are asleep."""
        return int(self.asleep.sum())

    @contextmanager
    def frozen(self, scene) -> Iterator[None]:
        """Within the block, ``scene``'s sleeping free bodies are fixed (``scene.fixed``
        replaced by one with them set) and at rest (their velocities and angular
        velocities zeroed); on leaving it, even by an exception, ``scene.fixed`` is the
        array it was. A scene of a different body count wakes every body first."""
        if len(self.asleep) != len(scene):
            self.wake_all(len(scene))
        frozen = self.asleep & ~scene.fixed
        if not frozen.any():
            yield
            return
        fixed = scene.fixed
        scene.fixed = fixed | frozen
        scene.velocities[frozen] = 0.0
        scene.angular_velocities[frozen] = 0.0
        try:
            yield
        finally:
            scene.fixed = fixed

    def update(self, scene, radius: np.ndarray, start: tuple, dt: float, touching=None) -> None:
        """After a step of ``dt`` from ``start`` (positions (n, 3), orientations (n, 4)
        float64) of ``scene`` (bodies thawed): count the steps each awake free body has
        been at rest — no point of it :attr:`speed` × :attr:`steps` × ``dt`` or more from
        where it was when its count began (|Δx| + θ·R, R the bounding ``radius (n,)``
        float64 of its tree) — and put to sleep those at rest for :attr:`steps` steps;
        the bodies of ``touching (k, 2)`` int64 pairs (in contact in the step; None: the
        broad phase's candidate pairs) with a moving one wake or start counting again. A
        body that falls asleep is at rest: its velocity and angular velocity become
        zero."""
        if len(self.asleep) != len(radius):
            self.wake_all(len(radius))
        moving = np.empty(len(radius), np.bool_)
        reach = self.speed * self.steps * float(dt)
        end = (scene.positions, scene.orientations)
        any_moving, others = kd.rest_counts(
            start, end, self.anchor, radius, scene.fixed, self.asleep, reach, self.rest, moving
        )
        if any_moving and others:
            # bodies touching a moving one: sleepers wake, resting ones count from zero
            if touching is None:
                _, touching = scene.configuration(scene.positions, scene.orientations)
            kd.wake_near(touching, moving, self.asleep, self.rest)
        # asleep is at rest (frozen() zeroes them anyway)
        kd.fall_asleep(scene.fixed, self.asleep, self.rest, self.steps, scene.velocities,
                       scene.angular_velocities)  # fmt: skip
