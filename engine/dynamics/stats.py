"""What a time step did (:class:`StepStats`), and the warning of a step that may miss
contacts (:class:`TunnellingWarning`); :mod:`engine.dynamics.picard` fills them."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

from engine.collision.configuration import SEARCH_COUNTERS
from engine.kernels.dynamics import contact_forces as kf

__all__ = ["StepStats", "TunnellingWarning", "combined", "summary"]


@dataclass(frozen=True)
class StepStats:
    """What one time step did.

    scheme : str; dt : float — the step (its halves, if it was retried, are included)
    converged : bool — Picard converged (always True for ``explicit``)
    picard_iterations : int — Picard iterations (1 for ``explicit``)
    evaluations : int — contact searches run: the first iteration of a step that follows
        a converged step reuses that step's last evaluation (same configuration), and
        iterations on a frozen contact set search nothing
    body_pairs : int — body pairs of the narrow phase, last evaluation
    contacts : int — merged contact points, last evaluation
    triangle_pairs : int — finest-level triangle pairs in contact, last evaluation
    comparisons, iterative, fallbacks, sphere_pruned, unfoldings : int — search counters
        summed over all evaluations
    folds : int — multiscale: sibling groups folded back into their parent
    listed : int — body-pair searches served by the pair cache's lists (no traversal)
    max_overlap : float — largest overlap / (ε_a + ε_b) at the end of the step
    elastic_energy : float — energy stored in the contact springs, last evaluation
    halvings : int — how many times the step was split because Picard did not converge
    seconds : float — wall time
    travel : float — the step's largest surface travel of a body relative to its ε,
        (|v| + |ω|·R)·dt / ε at the step's start: above 1 a contact may be missed
        (tunnelling)
    substeps : int — sub-steps the step was split into because of ``travel`` (1: none)
    sleeping : int — bodies asleep after the step (:mod:`engine.dynamics.sleep`)
    """

    scheme: str
    dt: float
    converged: bool
    picard_iterations: int
    evaluations: int
    body_pairs: int
    contacts: int
    triangle_pairs: int
    comparisons: int
    iterative: int
    fallbacks: int
    sphere_pruned: int
    unfoldings: int
    folds: int
    listed: int
    max_overlap: float
    elastic_energy: float
    halvings: int
    seconds: float
    travel: float = 0.0
    substeps: int = 1
    sleeping: int = 0


class TunnellingWarning(UserWarning):
    """A step moves some body's surface by more than its ε: contacts may be missed."""


def summary(scene, contacts, counters, energy, converged: bool, iterations: int) -> dict:
    totals = {k: sum(c[k] for c in counters) for k in counters[0] if k != "triangle_pairs"}
    eps = scene.epsilon
    worst = 0.0
    if len(contacts.points):  # each overlap relative to its pair's reach ε_a + ε_b
        found = (contacts.bodies, contacts.offsets, contacts.overlaps)
        worst = float(kf.largest_overlap(*found, eps))
    return {
        "converged": bool(converged),
        "picard_iterations": iterations,
        "body_pairs": len(contacts.bodies),
        "contacts": len(contacts.points),
        "triangle_pairs": counters[-1]["triangle_pairs"],
        "max_overlap": worst,
        "elastic_energy": float(energy),
        **totals,
    }


def combined(parts: list[StepStats], dt: float, seconds: float) -> StepStats:
    """One step's statistics from consecutive parts of it (halves or sub-steps): counters
    summed, the state of the last part, the worst overlap."""
    summed = ("picard_iterations", "evaluations", *SEARCH_COUNTERS, "halvings")
    last = parts[-1]
    return dataclasses.replace(
        last,
        dt=dt,
        converged=all(p.converged for p in parts),
        max_overlap=max(p.max_overlap for p in parts),
        seconds=seconds,
        travel=max(p.travel for p in parts),
        **{k: sum(getattr(p, k) for p in parts) for k in summed},
    )
