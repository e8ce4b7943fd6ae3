"""Contacts of a scene configuration: the record the contact searches hand the force kernel.

:meth:`engine.scene.Scene.contacts` (a fresh flat or multiresolution search) and
:class:`~engine.collision.multiscale.MultiscaleSearch` (fronts kept between calls) both
return a :class:`Contacts`; :mod:`engine.dynamics.picard` evaluates forces from it and sums
its :data:`SEARCH_COUNTERS` into the step's statistics.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["SEARCH_COUNTERS", "Contacts"]

SEARCH_COUNTERS = (
    "comparisons",
    "iterative",
    "fallbacks",
    "sphere_pruned",
    "unfoldings",
    "folds",
    "listed",
)
"""The search counters summed over a configuration's body pairs (:class:`Contacts`)."""


@dataclass(frozen=True)
class Contacts:
    """Contacts of one configuration, as the force kernel takes them.

    bodies : (k, 2) int64 body pairs (a < b) tested in the narrow phase
    offsets : (k + 1,) int64 — pair q owns rows ``offsets[q]:offsets[q + 1]``
    points, normals : (c, 3) float64; overlaps : (c,) float64
    counters : dict of summed search counters (:data:`SEARCH_COUNTERS` and
        ``triangle_pairs``)
    """

    bodies: np.ndarray
    offsets: np.ndarray
    points: np.ndarray
    normals: np.ndarray
    overlaps: np.ndarray
    counters: dict
