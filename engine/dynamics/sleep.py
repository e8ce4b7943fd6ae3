"""Bodies at rest sleep: no narrow phase, no integration, until something moving comes near.

A free body whose surface speed |v| + |ω|·R stays below ``speed`` for ``steps`` consecutive
steps falls asleep: during a step it is treated as fixed (zero velocity, no integration;
pairs of two sleeping or sleeping and fixed bodies are never tested, as fixed–fixed pairs
are not), while its contacts with awake bodies are evaluated as usual, so an awake body
still rests on it. After each step every body that is a broad-phase candidate of an awake
body moving at ``speed`` or faster is kept awake (a sleeping one wakes, its velocity starting
from zero), and wakes its neighbours in turn when it moves. Anything that changes the scene
from outside (``set_state``, external forces, new bodies) wakes every body.

Sleeping is an approximation (a sleeping body feels no gravity and no contact forces), off
by default: ``Scene(sleep=True)`` or ``Scene(sleep=Sleep(speed=…, steps=…))``.

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
    speed : float — surface speed below which a body counts as at rest (> 0)
    steps : int — consecutive steps at rest before it sleeps (>= 1)

    Attributes
    ----------
    asleep : (n,) bool — the bodies asleep
    rest : (n,) int64 — consecutive steps each body has been at rest
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

    def update(self, scene, radius: np.ndarray) -> None:
        """After a step of ``scene`` (bodies thawed): count the steps each awake free body
        has been at rest — surface speed |v| + |ω|·R below :attr:`speed`, R the bounding
        ``radius (n,) float64`` of its tree — and put to sleep those at rest for
        :attr:`steps` steps; bodies near a moving one (broad-phase candidates) wake or
        start counting again. A body that falls asleep is at rest: its velocity and angular
        velocity become zero."""
        moving = np.empty(len(radius), np.bool_)
        any_moving, others = kd.rest_counts(
            scene.velocities, scene.angular_velocities, radius, scene.fixed, self.asleep,
            self.speed, self.rest, moving,
        )  # fmt: skip
        if any_moving and others:
            # bodies near a moving one: sleepers wake, resting ones keep counting from zero
            _, pairs = scene.configuration(scene.positions, scene.orientations)
            kd.wake_near(pairs, moving, self.asleep, self.rest)
        # asleep is at rest (frozen() zeroes them anyway)
        kd.fall_asleep(scene.fixed, self.asleep, self.rest, self.steps, scene.velocities,
                       scene.angular_velocities)  # fmt: skip
