"""What a step reports (engine/dynamics/stats.py): a step's summary of its last evaluation and
its counters, and one step's statistics combined from its parts (halves or sub-steps)."""

from __future__ import annotations

import numpy as np
import pytest

from engine import Scene, shapes
from engine.collision.configuration import SEARCH_COUNTERS
from engine.dynamics.stats import StepStats, combined, summary


def _part(**values) -> StepStats:
    base = dict.fromkeys(
        ("picard_iterations", "evaluations", "body_pairs", "contacts", "triangle_pairs",
         *SEARCH_COUNTERS, "halvings"),
        0,
    )  # fmt: skip
    base.update(scheme="implicit", dt=1e-3, converged=True, max_overlap=0.0,
                elastic_energy=0.0, seconds=0.0)  # fmt: skip
    return StepStats(**{**base, **values})


def test_a_combined_step_sums_its_parts_and_ends_in_the_last():
    first = _part(picard_iterations=4, evaluations=2, comparisons=10, listed=3, halvings=1,
                  max_overlap=0.3, travel=1.5, contacts=7, sleeping=2)  # fmt: skip
    second = _part(picard_iterations=5, evaluations=1, comparisons=20, listed=4, converged=False,
                   max_overlap=0.1, travel=0.5, contacts=9, sleeping=3)  # fmt: skip
    step = combined([first, second], 2e-3, 0.25)
    assert (step.picard_iterations, step.evaluations, step.comparisons) == (9, 3, 30)
    assert (step.listed, step.halvings) == (7, 1)
    assert not step.converged  # one part did not
    assert (step.max_overlap, step.travel) == (0.3, 1.5)  # the worst part's
    assert (step.contacts, step.sleeping) == (9, 3)  # the last part's state
    assert (step.dt, step.seconds) == (2e-3, 0.25)


def test_a_summary_counts_every_evaluation_and_describes_the_last():
    scene = Scene()
    scene.add_plane(size=2.0, divisions=2, epsilon=0.002)
    scene.add_body(shapes.box((0.1, 0.1, 0.1)), position=(0.0, 0.0, 0.0515), epsilon=0.002)
    contacts = scene.contacts(scene.positions, scene.orientations)
    assert len(contacts.points) > 0
    earlier = {**dict.fromkeys(contacts.counters, 5), "triangle_pairs": 99}
    told = summary(scene, contacts, [earlier, contacts.counters], 1.5, True, 3)
    for name in contacts.counters:
        if name != "triangle_pairs":
            assert told[name] == 5 + contacts.counters[name]
    assert told["triangle_pairs"] == contacts.counters["triangle_pairs"]  # the last's
    assert (told["contacts"], told["body_pairs"]) == (len(contacts.points), len(contacts.bodies))
    reach = 0.004
    assert told["max_overlap"] == pytest.approx(np.max(contacts.overlaps) / reach, rel=1e-12)
    assert (told["converged"], told["picard_iterations"], told["elastic_energy"]) == (True, 3, 1.5)
