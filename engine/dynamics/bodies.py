"""Per-body terms of a scene that stay the same from one contact search to the next.

:class:`BodyTerms` gathers what the time stepping (:mod:`engine.dynamics.picard`) and the
sleep rule need of every body besides its state: the constant force on it, a force scale,
its bounding radius (a lever), its inverse mass. A scene owns one :class:`BodyCache`
(``Scene.body_cache``) that keeps the terms and the bodies' smallest principal moments
while the arrays they come from are the same; :func:`body_terms` and
:func:`smallest_inertia` read them through it.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass

import numpy as np

__all__ = ["BodyCache", "BodyTerms", "body_terms", "smallest_inertia"]


@dataclass(frozen=True)
class BodyTerms:
    """Per-body terms that stay the same from one search to the next.

    free : (n,) bool; fixed : (k,) int64 rows of the fixed bodies
    force : (n, 3) float64 — weight plus external force (0 on fixed bodies)
    size : (n,) float64 — m·|g| + |external force|
    weight : float — the largest weight of a free body
    radius : (n,) float64 — bounding radius of each body's mesh (a lever that makes
        torques force-like)
    inverse_mass : (n,) float64 — 0 for fixed bodies
    """

    free: np.ndarray
    fixed: np.ndarray
    force: np.ndarray
    size: np.ndarray
    weight: float
    radius: np.ndarray
    inverse_mass: np.ndarray

    @classmethod
    def of(cls, scene) -> BodyTerms:
        """The terms of ``scene``'s bodies now (computed afresh)."""
        free = ~scene.fixed
        force = np.zeros((len(free), 3))
        force[free] = scene.masses[free, None] * scene.gravity + scene.external_forces[free]
        size = np.zeros(len(free))
        size[free] = scene.masses[free] * np.linalg.norm(scene.gravity) + np.linalg.norm(
            scene.external_forces[free], axis=1
        )
        radius = np.array([max(t.bounding_radius, 1e-12) for t in scene.trees])[scene.tree_index]
        weight = float((scene.masses[free] * np.linalg.norm(scene.gravity)).max(initial=0.0))
        inverse_mass = np.where(scene.fixed, 0.0, 1.0 / scene.masses)
        return cls(free, np.flatnonzero(scene.fixed), force, size, weight, radius, inverse_mass)


class BodyCache:
    """A scene's :class:`BodyTerms` and smallest principal moments, each kept while what
    it comes from is unchanged.

    The terms are rebuilt when the bodies, their masses or fixed flags, gravity or the
    external forces change (arrays replaced, or edited in place); the smallest moments
    when ``scene.inertia`` is replaced or ``scene.fixed`` changes (replaced or edited in
    place). The terms of the last ``KEPT`` sets of values are kept: a scene with sleeping
    bodies fixes them around every step (:mod:`engine.dynamics.sleep`), and its terms
    alternate between two fixed masks. While :meth:`held` (a time step, which changes none
    of these), the terms are returned without looking at the arrays: the check costs
    microseconds, and a Picard step asks a hundred times.
    """

    KEPT = 2

    def __init__(self) -> None:
        self._terms: list[tuple[tuple, tuple, BodyTerms]] = []  # arrays, values, terms
        self._held: BodyTerms | None = None
        self._smallest: tuple[np.ndarray, bytes, np.ndarray] | None = None

    def terms(self, scene) -> BodyTerms:
        """The :class:`BodyTerms` of ``scene``'s bodies."""
        if self._held is not None:
            return self._held
        arrays = (scene.masses, scene.tree_index)  # the fixed mask by value: sleep replaces it
        values = tuple(
            a.tobytes() for a in (scene.masses, scene.fixed, scene.gravity, scene.external_forces)
        )
        for kept in self._terms:
            if all(a is b for a, b in zip(kept[0], arrays, strict=True)) and kept[1] == values:
                return kept[2]
        terms = BodyTerms.of(scene)
        self._terms = [(arrays, values, terms), *self._terms[: self.KEPT - 1]]
        return terms

    @contextmanager
    def held(self, scene) -> Iterator[BodyTerms]:
        """Within this block, :meth:`terms` returns ``scene``'s terms of its start without
        checking its arrays: the caller changes none of them (nested blocks keep the
        outermost's)."""
        outer = self._held
        self._held = outer if outer is not None else self.terms(scene)
        try:
            yield self._held
        finally:
            self._held = outer

    def smallest_inertia(self, scene) -> np.ndarray:
        """(n,) float64 smallest principal moment of each free body (NaN for fixed ones),
        kept while ``scene.inertia`` is the same array (adding bodies replaces it) and the
        fixed flags have the same values (replaced or edited in place: a body released
        with ``scene.fixed[i] = False`` gets its moment back)."""
        cached = self._smallest
        values = scene.fixed.tobytes()
        if cached is None or cached[0] is not scene.inertia or cached[1] != values:
            free = ~scene.fixed
            smallest = np.full(len(free), np.nan)
            if free.any():
                smallest[free] = np.linalg.eigvalsh(scene.inertia[free])[:, 0]
            cached = self._smallest = (scene.inertia, values, smallest)
        return cached[2]


def body_terms(scene) -> BodyTerms:
    """The :class:`BodyTerms` of ``scene``'s bodies, from its ``body_cache``."""
    return scene.body_cache.terms(scene)


def smallest_inertia(scene) -> np.ndarray:
    """(n,) float64 smallest principal moment of each free body of ``scene`` (NaN for
    fixed ones), from its ``body_cache``."""
    return scene.body_cache.smallest_inertia(scene)
