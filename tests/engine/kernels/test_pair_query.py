"""The flat-argument query kernel: the same contacts as the nested-argument traversal
(``query_kernel``, which the batch runs), and its room protocol (nothing written when the
leaf pairs found do not fit; the host then runs it again with room)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from engine import Pose, build_tree, shapes
from engine.collision import contacts
from engine.collision.contacts import ContactSet, ContactStats, find_contacts
from engine.collision.query import TINY, ULP, query_parameters
from engine.kernels.collision.batch import query_margin, relative_pose
from engine.kernels.collision.pair_query import pair_query
from engine.kernels.collision.traversal import query_kernel
from engine.kernels.geometry import triangle_batch as tb

LEVELS = 64
NO_BOXES = np.empty((0, 15)), np.empty((0, 21))  # no node boxes, no bounds table


@pytest.fixture(scope="module")
def trees():
    return build_tree(shapes.noisy_sphere(2, seed=4), 0.02, seed=1), build_tree(
        shapes.torus(), 0.02, seed=1
    )


def _poses(seed: int, count: int):
    rng = np.random.default_rng(seed)
    for _ in range(count):
        q, direction = rng.normal(size=4), rng.normal(size=3)
        qa = rng.normal(size=4)
        pa = Pose(rng.normal(size=3), qa / np.linalg.norm(qa))
        reach = rng.uniform(0.6, 2.6)
        pb = Pose(
            pa.position + reach * direction / np.linalg.norm(direction), q / np.linalg.norm(q)
        )
        yield pa, pb


def _run(ta, pa, tb_, pb, precision, capacity, boxes=True, bounds_margin=None):
    """``pair_query`` on the trees' cached sides; ``boxes=False`` passes no node boxes and
    no bounds table (spheres only, as ``query_kernel`` prunes); ``bounds_margin``: the
    bounds-only search's margin (default the early-out's slack, as ``find_contacts``
    passes it)."""
    if bounds_margin is None:
        bounds_margin = contacts._far_slack(ta, pa, tb_, pb)[1]
    side_a, side_b = ta.views.query_side_a(precision), tb_.views.query_side_b
    if not boxes:
        side_a, side_b = (*side_a[:-2], *NO_BOXES), (*side_b[:-2], *NO_BOXES)
    parameters = contacts._parameters("hybrid", precision, 1)
    counters = np.zeros(tb.N_STATS + LEVELS, np.int64)
    out = (
        np.empty((capacity, 2), np.int64),
        np.empty((capacity, 3)),
        np.empty((capacity, 3)),
        np.empty(capacity),
    )
    tiny = TINY * max(ta.bounding_radius, tb_.bounding_radius)
    merge = min(ta.leaf_epsilon, tb_.leaf_epsilon)
    found, m, k, depth, unfoldings = pair_query(
        *side_a,
        *side_b,
        pa.position,
        pa.orientation,
        pb.position,
        pb.orientation,
        bounds_margin,
        *parameters,
        tiny,
        merge,
        counters,
        *out,
    )
    return found, m, k, depth, unfoldings, counters, out


def _nested(ta, pa, tb_, pb, precision, boxes=False):
    """The same query through ``query_kernel`` (nested arguments, as the batch calls it);
    ``boxes``: with the trees' node boxes, as the batch passes them, else spheres only."""
    dtype = np.dtype(precision).type
    rot_a, rotation, shift = relative_pose(pa.position, pa.orientation, pb.position, pb.orientation)
    sa, master = ta.views.geometry.node_set(precision, False), tb_.views.geometry.master
    boxes_a, boxes_b = (ta.views.boxes, tb_.views.boxes) if boxes else NO_BOXES[:1] * 2
    body_a = (sa.coords_rm, sa.frames_rm, *ta.views.structure, ta.views.spheres, boxes_a)
    body_b = (
        master.coords_rm,
        master.frames_rm,
        *tb_.views.structure,
        tb_.views.spheres,
        boxes_b,
    )
    coarse, leaf = query_parameters("hybrid", dtype, 1)
    contact = contacts._contact_setup(ta, tb_, rot_a, pa.position.copy(), "hybrid")
    margin = query_margin(ta.views.geometry.extent, tb_.views.geometry.extent, shift, ULP[dtype])
    stats, levels = np.zeros(tb.N_STATS, np.int64), np.zeros(LEVELS, np.int64)
    depth, unfoldings, result, _, _ = query_kernel(
        body_a, body_b, (rotation, shift), margin, 0.0, coarse, leaf, contact, stats, levels
    )
    return depth, unfoldings, result, stats, levels


@pytest.mark.parametrize("precision", ["float64", "float32"])
def test_flat_entry_equals_nested_traversal(trees, precision):
    """The flat entry is the nested traversal (as the batch runs it) bit for bit, counters
    included, without node boxes and with them; with them (as ``find_contacts`` and the
    batch run it) the contacts are those of spheres only and the boxes prune node pairs
    the spheres keep."""
    ta, tb_ = trees
    touching = 0
    compared = {True: 0, False: 0}
    for pa, pb in _poses(3, 40):
        boxed = _run(ta, pa, tb_, pb, precision, 4096, bounds_margin=-1.0)  # traversal only
        found, m, k, depth, unfoldings, counters, out = _run(
            ta, pa, tb_, pb, precision, 4096, boxes=False
        )
        assert boxed[1:3] == (m, k)
        for got, want, rows in zip(boxed[-1], out, (m, k, k, k), strict=True):
            np.testing.assert_array_equal(got[:rows], want[:rows])
        assert boxed[5][tb.N_STATS :].sum() <= counters[tb.N_STATS :].sum()
        for with_boxes, run in ((True, boxed[5]), (False, counters)):
            compared[with_boxes] += run[tb.N_STATS :].sum()
        assert m >= 0 and found >= m
        # the nested traversal, spheres only and with boxes, against each flat run
        for flat, with_boxes in (
            ((depth, unfoldings, counters, out), False),
            (boxed[3:5] + boxed[5:], True),
        ):
            depth2, unfoldings2, result, stats, levels = _nested(
                ta, pa, tb_, pb, precision, boxes=with_boxes
            )
            assert tuple(flat[:2]) == (depth2, unfoldings2)
            np.testing.assert_array_equal(flat[2][: tb.N_STATS], stats)
            np.testing.assert_array_equal(flat[2][tb.N_STATS :], levels)
            got = (flat[3][0][:m], *(x[:k] for x in flat[3][1:]))
            for g, want in zip(got, result, strict=True):
                np.testing.assert_array_equal(g, want)
        touching += m > 0
    assert 0 < touching < 40
    assert compared[True] < compared[False]


def test_without_room_nothing_is_written(trees):
    ta, tb_ = trees
    for pa, pb in _poses(5, 40):
        flat = find_contacts(ta, pa, tb_, pb, kernel="exact", hierarchy=False)
        if len(flat.pairs) >= 8:
            break
    else:
        pytest.fail("no pose with 8 contact pairs")
    found, m, k, *_ = _run(ta, pa, tb_, pb, "float64", 4)
    assert found >= len(flat.pairs) and m == k == -1
    found, m, k, *_, out = _run(ta, pa, tb_, pb, "float64", found)
    assert m == len(flat.pairs)
    np.testing.assert_array_equal(out[0][:m], flat.pairs)


def test_many_leaf_pairs_grow_the_room():
    """A deep overlap of two 1,280-triangle spheres finds far more leaf pairs than the
    first room (64): the query runs again with room and returns the flat search's pairs."""
    tree = build_tree(shapes.icosphere(3), 0.01)
    pa, pb = Pose.identity(), Pose([1.9, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0])
    assert tree.views.leaf_pairs_hint == 64  # a fresh tree
    got = find_contacts(tree, pa, tree, pb)
    flat = find_contacts(tree, pa, tree, pb, kernel="exact", hierarchy=False)
    assert len(flat.pairs) > 64
    np.testing.assert_array_equal(got.pairs, flat.pairs)
    assert tree.views.leaf_pairs_hint >= len(flat.pairs)
    again = find_contacts(tree, pa, tree, pb)  # with the hint: one run
    np.testing.assert_array_equal(again.pairs, got.pairs)
    np.testing.assert_array_equal(again.points, got.points)
    assert again.stats == got.stats


def test_results_are_ordinary_frozen_dataclasses(trees):
    """The host builds ContactSet and ContactStats without their __init__: they compare,
    hash, copy and refuse assignment as the dataclasses do."""
    ta, tb_ = trees
    pa, pb = next(iter(_poses(3, 1)))
    got = find_contacts(ta, pa, tb_, pb)
    s = got.stats
    built = ContactStats(*(getattr(s, f.name) for f in dataclasses.fields(ContactStats)))
    assert s == built and hash(s) == hash(built) and repr(s) == repr(built)
    assert isinstance(got, ContactSet) and dataclasses.replace(s, iterative=0).iterative == 0
    with pytest.raises(dataclasses.FrozenInstanceError):
        s.iterative = 1
    with pytest.raises(dataclasses.FrozenInstanceError):
        got.points = None


def test_bounds_search_settles_only_what_the_traversal_leaves_empty(trees):
    """The bounds-only search runs after the traversal and only where it found no leaf
    pair in contact: a pose with contacts gives the traversal's own result and counters
    whatever ``bounds_margin`` says; a pose the node bounds show apart gives ``f = −1``
    and counters that hold the pruned root pair alone; the same pose without that search
    (negative margin) runs the traversal."""
    ta, tb_ = trees
    seen = {"contact": 0, "apart": 0}
    for pa, pb in _poses(11, 60):
        found, m, k, depth, unfoldings, counters, out = _run(ta, pa, tb_, pb, "float64", 4096)
        plain = _run(ta, pa, tb_, pb, "float64", 4096, bounds_margin=-1.0)
        apart = contacts.far_apart(ta, pa, tb_, pb)
        if apart:
            seen["apart"] += 1
            assert found == -1 and m == k == depth == unfoldings == 0
            want = np.zeros_like(counters)
            want[tb.STAT_SPHERES] = 1
            np.testing.assert_array_equal(counters, want)
            assert plain[0] == 0 and plain[1] == 0  # no contact either way
            continue
        assert (found, m, k, depth, unfoldings) == plain[:5]
        np.testing.assert_array_equal(counters, plain[5])
        for got, want, rows in zip(out, plain[6], (m, k, k, k), strict=True):
            np.testing.assert_array_equal(got[:rows], want[:rows])
        seen["contact"] += m > 0
    assert seen["contact"] > 0 and seen["apart"] > 0
