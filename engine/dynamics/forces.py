"""Contact force laws (paper §2): pluggable, each a set of parameters for one kernel.

A law maps one merged contact (overlap δ = ε_a + ε_b − d, unit normal from A to B,
point) and the bodies' masses and velocities to a force on B (and its opposite on A).
Every law has optional normal damping (ratio ζ of the critical damping of the contact
spring, the normal force never pulls) and a tangential friction force capped by
Coulomb's law: by default a tangential spring with history per persistent contact
(Cundall–Strack: it sticks below the cap, so a body rests on a slope below the friction
angle; :mod:`engine.dynamics.history` keeps the springs across steps), or with
``tangential_stiffness=0`` the regularised law that fades in below ``slip_velocity``
(no history, and a body on a slope creeps at F_t·v_slip/(μF_n)).

A new law is a subclass with a ``kind`` known to
:func:`engine.kernels.dynamics.contact_forces.contact_terms` (one more branch there).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from engine.errors import InvalidArgumentError
from engine.kernels.dynamics import contact_forces as kd

__all__ = ["ContactModel", "HertzSpring", "LinearSpring", "PaperSpring"]


@dataclass(frozen=True)
class ContactModel:
    """Base of the contact laws.

    stiffness : float — the law's spring constant (see the subclass)
    damping : float — normal damping as a fraction ζ ≥ 0 of critical damping
    friction : float — Coulomb coefficient μ ≥ 0
    slip_velocity : float — without a tangential spring, below this sliding speed friction
        fades in linearly (> 0)
    tangential_stiffness : float — the tangential spring's stiffness as a fraction of the
        normal spring's slope k_n (default 2/7, elastic spheres of Poisson ratio ≈ 0.3);
        its damping is the normal damping ratio ζ. 0: the regularised law, no history
    """

    stiffness: float = 1000.0
    damping: float = 0.0
    friction: float = 0.5
    slip_velocity: float = 1e-2
    tangential_stiffness: float = 2.0 / 7.0
    kind = kd.PAPER

    def __post_init__(self) -> None:
        for name in (
            "stiffness", "damping", "friction", "slip_velocity", "tangential_stiffness"
        ):  # fmt: skip
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int | float):
                raise InvalidArgumentError(f"{name} must be a number, got {value!r}")
            if not (math.isfinite(value) and value >= 0):
                raise InvalidArgumentError(f"{name} must be finite and >= 0, got {value!r}")
        if self.stiffness <= 0 or self.slip_velocity <= 0:
            raise InvalidArgumentError("stiffness and slip_velocity must be > 0")

    def parameters(self) -> tuple[int, float, float, float, float, float]:
        """``(kind, stiffness, damping, friction, slip_velocity, tangential_stiffness)``
        for the force kernel."""
        return (
            int(self.kind),
            float(self.stiffness),
            float(self.damping),
            float(self.friction),
            float(self.slip_velocity),
            float(self.tangential_stiffness),
        )

    @property
    def sticks(self) -> bool:
        """Friction with a tangential spring: its contacts carry history across steps."""
        return self.friction > 0 and self.tangential_stiffness > 0


@dataclass(frozen=True)
class PaperSpring(ContactModel):
    """The paper's law: F_n = K_s · (1 − |n|/ε) · √(m_a m_b / (m_a + m_b)), K_s =
    ``stiffness`` (1,000), where 1 − |n|/ε = δ/(ε_a + ε_b) (|n|: distance from the
    contact point to either closest point); a fixed body's mass is infinite."""

    kind = kd.PAPER


@dataclass(frozen=True)
class LinearSpring(ContactModel):
    """Linear spring–dashpot: F_n = k·δ − c·v_n, k = ``stiffness`` (force / length)."""

    kind = kd.LINEAR


@dataclass(frozen=True)
class HertzSpring(ContactModel):
    """Hertzian spring: F_n = k·δ^{3/2} − c·v_n, k = ``stiffness`` (4/3 E* √R* for two
    elastic spheres)."""

    kind = kd.HERTZ
