"""Islands of a Picard step (engine/dynamics/islands.py): a search of the pairs with a moved
body gives the whole configuration's contacts bit for bit; islands are the connected parts
of the acting contacts; the per-body test agrees with Picard's."""

from __future__ import annotations

import numpy as np
import pytest

from engine import PaperSpring, Scene, shapes
from engine.dynamics import islands
from engine.dynamics import relaxation as rx
from engine.dynamics.evaluation import Wrench, evaluate
from engine.kernels.dynamics import contact_forces as kf


def _row(seed: int = 0) -> Scene:
    """A plane and six boxes on it in a row, neighbours touching, turned a little."""
    rng = np.random.default_rng(seed)
    scene = Scene(contact_model=PaperSpring(damping=0.3, friction=0.5))
    scene.add_plane(size=2.0, divisions=4, epsilon=0.002)
    for k in range(6):
        q = np.array([1.0, *rng.normal(scale=0.01, size=3)])
        scene.add_body(shapes.box((0.1, 0.1, 0.1)), position=(0.1015 * k, 0.0, 0.0515),
                       orientation=q / np.linalg.norm(q), epsilon=0.002)  # fmt: skip
    return scene


def _same(a, b) -> None:
    for name in ("bodies", "offsets", "points", "normals", "overlaps"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)


@pytest.mark.parametrize("moved", [(2,), (1, 2), (6,), ()])
def test_a_search_of_the_moved_pairs_is_the_whole_configurations(moved):
    scene, fresh = _row(), _row()
    x0, q0 = scene.positions.copy(), scene.orientations.copy()
    first = islands.search(scene, x0, q0)
    assert len(first.contacts.points) > 0 and first.triangles.sum() > 0
    x1, q1 = x0.copy(), q0.copy()
    for b in moved:
        x1[b] += (3e-4, -2e-4, -1e-4)
        turn = np.array([1.0, 0.0, 0.0, 2e-3])
        w, v = turn[0], turn[1:]
        q = q1[b]
        q1[b] = [w * q[0] - v @ q[1:], *(w * q[1:] + q[0] * v + np.cross(v, q[1:]))]
        q1[b] /= np.linalg.norm(q1[b])
    partial = islands.search(scene, x1, q1, first)
    whole = islands.search(fresh, x1, q1)  # a scene that never searched before
    _same(partial.contacts, whole.contacts)
    np.testing.assert_array_equal(partial.triangles, whole.triangles)
    assert partial.contacts.counters["triangle_pairs"] == whole.contacts.counters["triangle_pairs"]
    # only the pairs with a moved body were searched
    pairs = whole.contacts.bodies
    asked = np.isin(pairs, list(moved)).any(axis=1).sum()
    assert partial.contacts.counters["listed"] <= asked
    if not moved:
        assert partial.contacts.counters["comparisons"] == 0
    # the pair cache was left as it was: a later whole search is the same as well
    again = islands.search(scene, x1, q1)
    _same(again.contacts, whole.contacts)


def test_islands_are_the_connected_parts_of_the_acting_contacts():
    rng = np.random.default_rng(4)
    n = 12
    for _ in range(50):
        k = 15
        bodies = np.sort(rng.choice(n, size=(k, 2), replace=True), axis=1)
        bodies = bodies[bodies[:, 0] < bodies[:, 1]]
        counts = rng.integers(0, 3, size=len(bodies))
        offsets = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
        terms = np.zeros((int(offsets[-1]), kf.TERMS))
        terms[:, kf.ACTIVE] = rng.random(len(terms)) < 0.6
        free = rng.random(n) < 0.8
        labels = np.empty(n, np.int64)
        kf.contact_islands(bodies, offsets, terms, free, labels)
        expected = list(range(n))  # union-find written out
        for q, (a, b) in enumerate(bodies):
            acting = terms[offsets[q] : offsets[q + 1], kf.ACTIVE].any()
            if acting and free[a] and free[b]:
                ra, rb = expected[a], expected[b]
                low, high = min(ra, rb), max(ra, rb)
                expected = [low if e == high else e for e in expected]
        np.testing.assert_array_equal(labels, expected)


def test_the_per_body_test_is_picards():
    scene = _row()
    state = (scene.positions, scene.orientations, scene.velocities, scene.angular_velocities)
    found = islands.search(scene, scene.positions, scene.orientations).contacts

    def search(x, q):
        return found, None, False

    evaluation = evaluate(scene, state, scene.positions, search)
    total = evaluation.normal.plus(evaluation.friction)
    gross, radius = evaluation.stiffness[:, 2], np.full(len(scene), 0.1)
    rng = np.random.default_rng(2)
    for scale in (0.0, 1e-4, 1e-2, 1.0):
        off = Wrench(rng.normal(size=(len(scene), 3)) * scale, np.zeros((len(scene), 3)))
        off.force[rng.random(len(scene)) < 0.5] = 0.0
        failing = rx.unsettled(scene, total, off, gross, radius)
        assert not failing[scene.fixed].any()
        assert failing.any() == (not rx.settled(scene, total, off, gross, radius))
        for b in np.flatnonzero(~scene.fixed):  # each body alone: the same verdict
            alone = Wrench(np.zeros_like(off.force), np.zeros_like(off.torque))
            alone.force[b] = off.force[b]
            assert failing[b] == (not rx.settled(scene, total, alone, gross, radius))
    # the islands of a failing middle box: the boxes it touches, through free boxes
    failing = np.zeros(len(scene), np.bool_)
    failing[3] = True
    moving = islands.moving(scene, evaluation, failing)
    reached, frontier = {3}, [3]  # through acting contacts between free bodies
    while frontier:
        b = frontier.pop()
        for q, pair in enumerate(found.bodies):
            acting = evaluation.terms[found.offsets[q] : found.offsets[q + 1], kf.ACTIVE].any()
            if acting and b in pair and not scene.fixed[pair].any():
                other = int(pair[0] if pair[1] == b else pair[1])
                if other not in reached:
                    reached.add(other)
                    frontier.append(other)
    assert len(reached) > 1  # the middle box touches its neighbours
    np.testing.assert_array_equal(np.flatnonzero(moving), sorted(reached))


def test_a_last_search_that_lacks_an_unmoved_pair_is_searched_again_whole():
    """Unmoved pairs take their contacts from the last search only where it has them: a
    record without one of them (an empty one, too) gives way to a search of every pair."""
    scene, fresh = _row(), _row()
    x, q = scene.positions.copy(), scene.orientations.copy()
    whole = islands.search(fresh, x, q)
    found = whole.contacts
    for drop in (slice(1, None), slice(0, 0)):  # the first pair missing; no pair at all
        kept = np.arange(len(found.bodies))[drop]
        counts = np.diff(found.offsets)[kept]
        rows = np.concatenate([np.arange(found.offsets[i], found.offsets[i + 1]) for i in kept]
                              + [np.zeros(0, np.int64)]).astype(np.int64)  # fmt: skip
        partial = type(found)(found.bodies[kept], np.concatenate([[0], np.cumsum(counts)]),
                              found.points[rows], found.normals[rows], found.overlaps[rows],
                              found.counters)  # fmt: skip
        last = islands.Searched(x.copy(), q.copy(), partial, whole.triangles[kept])
        again = islands.search(scene, x, q, last)
        _same(again.contacts, found)
        np.testing.assert_array_equal(again.triangles, whole.triangles)
