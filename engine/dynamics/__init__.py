"""Dynamics: force laws, mass properties, body terms, forces of a configuration, Picard, sleep."""

from engine.dynamics.forces import ContactModel, HertzSpring, LinearSpring, PaperSpring
from engine.dynamics.history import DEFAULT_SEPARATION_SPEED, OverlapReport
from engine.dynamics.picard import StepStats, TunnellingWarning
from engine.dynamics.sleep import Sleep

__all__ = [
    "DEFAULT_SEPARATION_SPEED",
    "ContactModel",
    "HertzSpring",
    "LinearSpring",
    "OverlapReport",
    "PaperSpring",
    "Sleep",
    "StepStats",
    "TunnellingWarning",
]
