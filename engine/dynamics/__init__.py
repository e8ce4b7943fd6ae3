"""Dynamics: contact force laws, mass properties, Picard time stepping and sleeping bodies."""

from engine.dynamics.forces import ContactModel, HertzSpring, LinearSpring, PaperSpring
from engine.dynamics.picard import StepStats, TunnellingWarning
from engine.dynamics.sleep import Sleep

__all__ = [
    "ContactModel",
    "HertzSpring",
    "LinearSpring",
    "PaperSpring",
    "Sleep",
    "StepStats",
    "TunnellingWarning",
]
