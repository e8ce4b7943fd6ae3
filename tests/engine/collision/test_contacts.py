"""Poses and contact detection: the multiresolution search equals the flat exact search."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from engine import InvalidArgumentError, build_tree, shapes
from engine.collision import contacts
from engine.collision.contacts import find_contacts
from engine.geometry.pose import Pose

SHAPES = {
    "noisy": lambda: shapes.noisy_sphere(subdivisions=1, eta_r=1.4, seed=3),
    "stretched": lambda: shapes.stretched_sphere(subdivisions=1, eta=1.8),
    "torus": lambda: shapes.torus(major_segments=12, minor_segments=6),
    "box": lambda: shapes.box(extents=(1.6, 1.0, 0.6)),
    "plane": lambda: shapes.plane(size=(3.0, 3.0), divisions=4),
}
PAIRS = [
    ("noisy", "noisy"),
    ("noisy", "torus"),
    ("stretched", "box"),
    ("torus", "torus"),
    ("box", "plane"),
    ("noisy", "plane"),
]
POSES_PER_CASE = 100  # x 6 shape pairs x 2 kernels x 2 precisions = 2,400 poses


def random_pose(rng: np.random.Generator, position=None) -> Pose:
    q = rng.normal(size=4)
    return Pose(rng.normal(size=3) if position is None else position, q / np.linalg.norm(q))


@pytest.fixture(scope="module")
def trees():
    return {name: build_tree(make(), epsilon=0.03, seed=0) for name, make in SHAPES.items()}


@pytest.mark.parametrize("precision", ["float64", "float32"])
@pytest.mark.parametrize("kernel", ["hybrid", "exact"])
@pytest.mark.parametrize(("name_a", "name_b"), PAIRS)
def test_multiresolution_equals_flat_exact_search(trees, name_a, name_b, kernel, precision):
    """Lemma 1: identical finest-level contact pairs for every pose."""
    rng = np.random.default_rng(abs(hash((name_a, name_b, kernel, precision))) % 2**32)
    ta, tb = trees[name_a], trees[name_b]
    reach = ta.bounding_radius + tb.bounding_radius
    kinds = {"separated": 0, "contact": 0}
    for _ in range(POSES_PER_CASE):
        direction = rng.normal(size=3)
        direction /= np.linalg.norm(direction)
        pa = random_pose(rng)
        pb = random_pose(rng, pa.position + direction * reach * rng.uniform(0.2, 1.1))
        flat = find_contacts(ta, pa, tb, pb, kernel="exact", hierarchy=False, precision=precision)
        tree = find_contacts(ta, pa, tb, pb, kernel=kernel, hierarchy=True, precision=precision)
        np.testing.assert_array_equal(tree.pairs, flat.pairs)
        assert tree.stats.comparisons <= flat.stats.comparisons + len(ta) * len(tb)
        kinds["contact" if len(flat.pairs) else "separated"] += 1
    assert kinds["contact"] > 0 and kinds["separated"] > 0, kinds


def test_contact_points_normals_and_overlaps():
    ta = tb = build_tree(shapes.icosphere(2), epsilon=0.03)  # surface radius 0.98 ... 1
    rng = np.random.default_rng(1)
    seen = 0
    for gap in np.linspace(-0.3, 0.05, 15):  # overlapping deeply ... just separated
        pa = random_pose(rng)
        direction = rng.normal(size=3)
        direction /= np.linalg.norm(direction)
        pb = random_pose(rng, pa.position + direction * (2.0 + gap))
        c = find_contacts(ta, pa, tb, pb)
        assert np.isfinite(c.points).all() and np.isfinite(c.normals).all()
        np.testing.assert_allclose(np.linalg.norm(c.normals, axis=1), 1.0, atol=1e-9)
        assert ((c.overlaps >= 0) & (c.overlaps <= 0.06 + 1e-12)).all()
        assert c.stats.merged_contacts == len(c.points) <= c.stats.raw_contacts == len(c.pairs)
        if len(c.points) and gap >= -0.06:
            seen += 1
            # within the halos (no deep interpenetration) normals point from A towards B
            assert (c.normals @ (pb.position - pa.position) > 0).mean() > 0.9
    assert seen >= 4


def test_touching_and_interpenetrating_faces_give_no_nan(trees):
    box = trees["box"]
    for offset in (0.0, 0.3, 0.6):  # faces touching, then boxes interpenetrating
        c = find_contacts(box, Pose.identity(), box, Pose([1.6 - offset, 0, 0], [1, 0, 0, 0]))
        assert len(c.pairs) and np.isfinite(c.normals).all() and np.isfinite(c.points).all()
        np.testing.assert_allclose(np.linalg.norm(c.normals, axis=1), 1.0, atol=1e-9)


def test_contacts_do_not_depend_on_where_the_pair_is(trees):
    ta = tb = trees["torus"]
    rng = np.random.default_rng(4)
    pa, pb = random_pose(rng, [0, 0, 0]), random_pose(rng, [0.9, 0.3, 0.1])
    near = find_contacts(ta, pa, tb, pb)
    shift = np.array([1e5, -2e5, 3e5])
    far = find_contacts(
        ta, Pose(pa.position + shift, pa.orientation), tb, Pose(pb.position + shift, pb.orientation)
    )
    np.testing.assert_array_equal(near.pairs, far.pairs)
    np.testing.assert_allclose(far.points - shift, near.points, atol=1e-8)


def test_pose_algebra():
    rng = np.random.default_rng(0)
    a, b = random_pose(rng), random_pose(rng)
    x = rng.normal(size=(5, 3))
    np.testing.assert_allclose(a.compose(b).apply(x), a.apply(b.apply(x)), atol=1e-12)
    np.testing.assert_allclose(a.inverse().apply(a.apply(x)), x, atol=1e-12)
    r = a.rotation
    np.testing.assert_allclose(r @ r.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(r) == pytest.approx(1.0)


@pytest.mark.parametrize(
    ("position", "orientation", "match"),
    [
        ([0, 0], [1, 0, 0, 0], "position"),
        ([0, 0, np.nan], [1, 0, 0, 0], "position"),
        ([0, 0, 0], [2, 0, 0, 0], "unit quaternion"),
        ([0, 0, 0], [1, 0, 0], "orientation"),
        ([0, 0, 0], ["a", 0, 0, 0], "orientation"),
    ],
)
def test_pose_validation(position, orientation, match):
    with pytest.raises(InvalidArgumentError, match=match):
        Pose(position, orientation)


def test_find_contacts_rejects_wrong_types(trees):
    with pytest.raises(InvalidArgumentError, match="SurrogateTree"):
        find_contacts("tree", Pose.identity(), trees["box"], Pose.identity())
    with pytest.raises(InvalidArgumentError, match="Pose"):
        find_contacts(trees["box"], (0, 0, 0), trees["box"], Pose.identity())


@pytest.mark.parametrize(("name_a", "name_b"), PAIRS[:4])
def test_active_sets_traversal_equals_flat_search(trees, name_a, name_b):
    """The paper's Algorithm 5 (traversal="sets") also returns exactly the flat pairs."""
    rng = np.random.default_rng(7)
    ta, tb = trees[name_a], trees[name_b]
    reach = ta.bounding_radius + tb.bounding_radius
    for _ in range(25):
        direction = rng.normal(size=3)
        direction /= np.linalg.norm(direction)
        pa = random_pose(rng)
        pb = random_pose(rng, pa.position + direction * reach * rng.uniform(0.2, 1.1))
        flat = find_contacts(ta, pa, tb, pb, kernel="exact", hierarchy=False)
        sets = find_contacts(ta, pa, tb, pb, traversal="sets")
        np.testing.assert_array_equal(sets.pairs, flat.pairs)


def test_unknown_traversal_is_rejected(trees):
    with pytest.raises(InvalidArgumentError, match="traversal"):
        find_contacts(
            trees["box"], Pose.identity(), trees["box"], Pose.identity(), traversal="depth-first"
        )


def test_merge_averages_clusters_of_close_points():
    from engine.kernels.collision.contact_merge import _merge

    points = np.array([[0, 0, 0], [0.004, 0, 0], [1, 0, 0], [1, 0.004, 0], [5, 5, 5]], float)
    normals = np.array([[1, 0, 0], [0, 1, 0], [0, 0, 1], [0, 0, -1], [1, 0, 0]], float)
    overlaps = np.array([0.02, 0.01, 0.015, 0.005, 0.001])
    p, n, o = np.empty((5, 3)), np.empty((5, 3)), np.empty(5)
    k = _merge(points, normals, overlaps, np.ones(5), 0.01, p, n, o)
    p, n, o = p[:k], n[:k], o[:k]
    assert k == 3  # clusters {0, 1}, {2, 3}, {4}; deepest first
    np.testing.assert_allclose(p[0], [0.002, 0, 0])
    np.testing.assert_allclose(n[0], [1, 0, 0])  # the deepest member's normal
    np.testing.assert_allclose(o[0], 0.015)
    np.testing.assert_allclose(p[1], [1, 0.002, 0])
    np.testing.assert_allclose(n[1], [0, 0, 1])
    np.testing.assert_allclose(o[1], 0.01)
    np.testing.assert_allclose(p[2], [5, 5, 5])
    np.testing.assert_allclose(n[2], [1, 0, 0])
    # equal depths: the first of the stable order (the contact kernel sorts by face pair)
    k = _merge(points[:2], normals[:2], np.array([0.01, 0.01]), np.ones(2), 0.01, p, n, o)
    assert k == 1
    np.testing.assert_allclose(n[0], [1, 0, 0])


@pytest.mark.parametrize("traversal", ["pairs", "sets"])
def test_statistics_count_the_work(trees, traversal):
    ta = tb = trees["torus"]
    pa, pb = Pose.identity(), Pose([0.9, 0.2, 0.0], [1, 0, 0, 0])
    tree = find_contacts(ta, pa, tb, pb, traversal=traversal)
    flat = find_contacts(ta, pa, tb, pb, kernel="exact", hierarchy=False)
    assert len(tree.pairs) > 0
    # every level after the root pair exists because some node pair was unfolded
    assert tree.stats.unfoldings >= len(tree.stats.comparisons_per_level) - 1 >= 1
    assert tree.stats.comparisons == sum(tree.stats.comparisons_per_level) < flat.stats.comparisons
    leaves = int((ta.face >= 0).sum()) * int((tb.face >= 0).sum())
    assert flat.stats.unfoldings == 0 and flat.stats.comparisons == leaves


@pytest.mark.parametrize("traversal", ["pairs", "sets"])
def test_iteration_count_changes_the_work_not_the_pairs(trees, traversal):
    """More sweeps of the iterative kernel certify more pairs (fewer exact fallbacks);
    the contact pairs stay those of the flat exact search."""
    ta, tb = trees["noisy"], trees["torus"]
    rng = np.random.default_rng(11)
    fallbacks = {1: 0, 8: 0}
    for _ in range(30):
        pa = random_pose(rng)
        direction = rng.normal(size=3)
        pb = random_pose(rng, pa.position + direction / np.linalg.norm(direction) * 1.1)
        flat = find_contacts(ta, pa, tb, pb, kernel="exact", hierarchy=False)
        for iterations in fallbacks:
            got = find_contacts(ta, pa, tb, pb, traversal=traversal, iterations=iterations)
            np.testing.assert_array_equal(got.pairs, flat.pairs)
            fallbacks[iterations] += got.stats.fallbacks
        assert len(find_contacts(ta, pa, tb, pb, hierarchy=False, iterations=3).pairs) == len(
            flat.pairs
        )
    assert fallbacks[8] < fallbacks[1], fallbacks


@pytest.mark.parametrize("iterations", [0, -1, 1.5, True, "3"])
def test_bad_iteration_counts_are_rejected(trees, iterations):
    t, p = trees["box"], Pose.identity()
    with pytest.raises(InvalidArgumentError, match="iterations"):
        find_contacts(t, p, t, p, iterations=iterations)


def _turning(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """A unit quaternion (w, x, y, z) whose rotation takes unit ``u`` to unit ``v``."""
    w = 1.0 + float(u @ v)
    if w < 1e-9:  # opposite: half a turn about any axis perpendicular to u
        axis = np.cross(u, [1.0, 0.0, 0.0] if abs(u[0]) < 0.9 else [0.0, 1.0, 0.0])
        return np.array([0.0, *(axis / np.linalg.norm(axis))])
    q = np.array([w, *np.cross(u, v)])
    return q / np.linalg.norm(q)


def _off_centre(offset) -> object:
    """A box whose mesh-frame origin lies outside it: its root sphere centre is far from
    the origin, so the early-out's rotation-free bound is tight only when both centres
    face each other."""
    mesh = shapes.box(extents=(0.8, 0.5, 0.3))
    matrix = np.eye(4)
    matrix[:3, 3] = offset
    return build_tree(mesh.transformed(matrix), epsilon=0.02, seed=0)


OFF_CENTRE = {
    "a": _off_centre([0.9, -0.4, 0.2]),
    "b": _off_centre([-0.3, 0.7, -0.5]),
    "sphere": build_tree(shapes.icosphere(1), epsilon=0.02, seed=0),
}


def _at_threshold(tree_a, tree_b, excess: float, turn_a, turn_b) -> tuple[Pose, Pose]:
    """Poses whose root spheres face each other along x (up to small extra turns
    ``turn_* (4,)``) with positions ``R_a + R_b + excess`` apart."""
    ca, cb = tree_a.views.spheres[0, :3], tree_b.views.spheres[0, :3]
    x = np.array([1.0, 0.0, 0.0])
    qa = _turning(ca / np.linalg.norm(ca), x) if np.linalg.norm(ca) > 1e-9 else [1, 0, 0, 0]
    qb = _turning(cb / np.linalg.norm(cb), -x) if np.linalg.norm(cb) > 1e-9 else [1, 0, 0, 0]
    pa = Pose([0.0, 0.0, 0.0], qa).compose(Pose([0.0, 0.0, 0.0], turn_a))
    pa = Pose([0.3, -0.2, 0.1], pa.orientation)
    pb = Pose([0.0, 0.0, 0.0], qb).compose(Pose([0.0, 0.0, 0.0], turn_b))
    distance = tree_a.views.root_reach + tree_b.views.root_reach + excess
    pb = Pose(pa.position + distance * x, pb.orientation)
    return pa, pb


def _small_turn(angle: float, axis) -> np.ndarray:
    axis = np.asarray(axis, float)
    axis = axis / np.linalg.norm(axis) if np.linalg.norm(axis) > 1e-9 else np.array([0, 0, 1.0])
    return np.array([np.cos(angle / 2), *(np.sin(angle / 2) * axis)])


def _slack(tree_a, tree_b, distance: float) -> float:
    scale = np.sqrt(3) * (tree_a.views.geometry.extent + tree_b.views.geometry.extent) + distance
    return contacts._FAR_SLACK * scale


@settings(max_examples=150, deadline=None)
@given(
    pair=st.sampled_from([("a", "b"), ("b", "a"), ("a", "sphere"), ("sphere", "sphere")]),
    excess=st.floats(-3.0, 3.0),
    ulps=st.integers(-8, 8),
    angle_a=st.floats(0.0, 1e-3),
    angle_b=st.floats(0.0, 1e-3),
    axis=st.tuples(*[st.floats(-1.0, 1.0)] * 3),
    kernel=st.sampled_from(["hybrid", "exact"]),
    precision=st.sampled_from(["float64", "float32"]),
)
def test_far_early_out_never_drops_what_the_kernel_keeps(
    pair, excess, ulps, angle_a, angle_b, axis, kernel, precision
):
    """Poses right at the early-out's threshold (``excess`` in units of its slack, plus a
    few ulp): whenever :func:`far_apart` settles a query, the multiresolution kernel run
    on the same arguments prunes the root pair too, so both return no contact and the
    same counters; otherwise ``find_contacts`` is the kernel's result."""
    ta, tb = OFF_CENTRE[pair[0]], OFF_CENTRE[pair[1]]
    reach = ta.views.root_reach + tb.views.root_reach
    gap = excess * _slack(ta, tb, reach)
    gap = float(np.nextafter(gap, np.inf if ulps > 0 else -np.inf)) if ulps else gap
    turn_a, turn_b = _small_turn(angle_a, axis), _small_turn(angle_b, axis[::-1])
    pa, pb = _at_threshold(ta, tb, gap, turn_a, turn_b)
    got = find_contacts(ta, pa, tb, pb, kernel=kernel, precision=precision)
    ref = contacts._search(ta, pa, tb, pb, kernel, True, precision, "pairs", 1)
    np.testing.assert_array_equal(got.pairs, ref.pairs)
    np.testing.assert_array_equal(got.points, ref.points)
    assert got.stats == ref.stats
    if contacts.far_apart(ta, pa, tb, pb):
        assert got is contacts.FAR_APART
        assert ref.stats == contacts.FAR_APART.stats  # the kernel pruned the root pair


@pytest.mark.parametrize("pair", [("a", "b"), ("b", "a")])
def test_coherent_early_out_gives_the_same_result_either_way(pair):
    """``find_contacts`` remembers whether the last query of a tree pair got past the
    early-out (``TreeViews.near_partner``) and then leaves the early-out's bounds-only
    search to the kernel. Around the threshold, near and far alike, the query gives the
    same contacts and counters with the hint set and cleared, equal to the kernel's own
    result, and the shared :data:`FAR_APART` exactly when :func:`far_apart` settles it."""
    ta, tb = OFF_CENTRE[pair[0]], OFF_CENTRE[pair[1]]
    reach = ta.views.root_reach + tb.views.root_reach
    slack = _slack(ta, tb, reach)
    turn = _small_turn(0.3, (0.2, -0.5, 0.8))
    unit = np.array([1.0, 0.0, 0.0, 0.0])
    for excess in (-40.0, -1.0, 0.5, 0.99, 1.01, 2.5, 50.0):
        for turn_a, turn_b in ((unit, unit), (turn, unit), (unit, turn)):
            pa, pb = _at_threshold(ta, tb, excess * slack, turn_a, turn_b)
            ref = contacts._search(ta, pa, tb, pb, "hybrid", True, "float64", "pairs", 1)
            apart = contacts.far_apart(ta, pa, tb, pb)
            for hint in (0, id(tb.views), id(tb.views), 0):
                ta.views.near_partner = hint
                got = find_contacts(ta, pa, tb, pb)
                assert (got is contacts.FAR_APART) == apart
                np.testing.assert_array_equal(got.pairs, ref.pairs)
                np.testing.assert_array_equal(got.points, ref.points)
                np.testing.assert_array_equal(got.overlaps, ref.overlaps)
                assert got.stats == ref.stats
                if not apart:  # a query past the early-out marks the pair
                    assert ta.views.near_partner == id(tb.views)


@pytest.mark.parametrize("precision", ["float64", "float32"])
def test_bounds_search_is_skipped_only_where_it_cannot_end_apart(precision):
    """Two icospheres whose closest leaves (vertex to vertex) are from 0 to 64 of the
    early-out's slacks beyond their reach: no contact (but at 0 in float32), so the
    kernel's bounds-only search decides between the traversal's result and the pruned
    root pair, unless a leaf pair the traversal evaluated is within half a slack of
    contact (then the bounds cannot show them apart and the search is skipped). With
    the hint set or cleared, the query equals the kernel's own result and is the shared
    FAR_APART exactly when ``far_apart`` settles it; both outcomes occur."""
    mesh = shapes.icosphere(2)
    tree = build_tree(mesh, epsilon=0.01)
    reach = 2 * tree.leaf_epsilon
    pa = Pose([0.0, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0])
    tip = float(np.asarray(mesh.vertices)[:, 0].max())  # a vertex on the x axis, (1, 0, 0)
    seen = {True: 0, False: 0}
    for excess in (0.0, 0.25, 0.45, 0.55, 1.0, 2.0, 4.0, 16.0, 64.0):
        slack = contacts._far_slack(tree, pa, tree, Pose([2 * tip + reach, 0, 0], pa.orientation))[
            1
        ]
        pb = Pose([2 * tip + reach + excess * slack, 0.0, 0.0], pa.orientation)
        ref = contacts._search(tree, pa, tree, pb, "hybrid", True, precision, "pairs", 1)
        apart = contacts.far_apart(tree, pa, tree, pb)
        for hint in (0, id(tree.views), 0):
            tree.views.near_partner = hint
            got = find_contacts(tree, pa, tree, pb, precision=precision)
            assert (got is contacts.FAR_APART) == apart
            np.testing.assert_array_equal(got.pairs, ref.pairs)
            assert got.stats == ref.stats
        seen[apart] += 1
    assert seen[True] > 0 and seen[False] > 0, seen


def test_far_early_out_threshold_and_result():
    """Just above the spheres' threshold (the host's first test fires only at twice the
    slack, so here the look-ahead's sphere test settles it) the early-out returns the shared
    empty result (read-only, the kernel's counters for a pruned root); just below it the root
    boxes settle it; two spheres touching, the kernel no longer prunes the root."""
    ta, tb = OFF_CENTRE["a"], OFF_CENTRE["b"]
    reach = ta.views.root_reach + tb.views.root_reach
    slack = _slack(ta, tb, reach)
    unit_turn = np.array([1.0, 0.0, 0.0, 0.0])
    above = _at_threshold(ta, tb, 1.01 * slack, unit_turn, unit_turn)
    below = _at_threshold(ta, tb, 0.99 * slack, unit_turn, unit_turn)
    assert contacts.far_apart(ta, *above[:1], tb, above[1])
    res = find_contacts(ta, above[0], tb, above[1])
    assert res is contacts.FAR_APART and len(res.pairs) == len(res.points) == 0
    assert res.stats.sphere_pruned == 1 and res.stats.comparisons_per_level == ()
    assert not res.points.flags.writeable and not res.pairs.flags.writeable
    assert (
        res.stats
        == contacts._search(
            ta, *above[:1], tb, above[1], "hybrid", True, "float64", "pairs", 1
        ).stats
    )
    # just below the spheres' threshold the root boxes (far tighter than the spheres of
    # these boxes) still settle it, and the kernel prunes the root pair by its boxes too
    # (test_boxes.py sweeps the boxes' own threshold)
    assert contacts.far_apart(ta, below[0], tb, below[1])
    assert (
        contacts._search(ta, *below[:1], tb, below[1], "hybrid", True, "float64", "pairs", 1).stats
        == contacts.FAR_APART.stats
    )
    # two spheres whose root spheres overlap by 1e-6 (their boxes are no tighter there):
    # the kernel evaluates the root pair
    sphere = OFF_CENTRE["sphere"]
    touching = _at_threshold(sphere, sphere, -1e-6, unit_turn, unit_turn)
    near = find_contacts(sphere, touching[0], sphere, touching[1])
    assert near.stats.comparisons_per_level[:1] == (1,)  # the root pair was evaluated
    # the flat and active-set searches keep their own counters (no early-out)
    flat = find_contacts(ta, above[0], tb, above[1], hierarchy=False)
    assert flat.stats.comparisons > 0 and flat.stats.sphere_pruned == 0


@settings(max_examples=150, deadline=None)
@given(
    pair=st.sampled_from([("a", "b"), ("b", "a"), ("a", "sphere")]),
    excess=st.floats(-3.0, 3.0),
    qa=st.tuples(*[st.floats(-1.0, 1.0)] * 4).filter(lambda q: np.linalg.norm(q) > 0.1),
    qb=st.tuples(*[st.floats(-1.0, 1.0)] * 4).filter(lambda q: np.linalg.norm(q) > 0.1),
    direction=st.tuples(*[st.floats(-1.0, 1.0)] * 3).filter(lambda d: np.linalg.norm(d) > 0.1),
    precision=st.sampled_from(["float64", "float32"]),
)
def test_far_early_out_with_turned_off_centre_bodies(pair, excess, qa, qb, direction, precision):
    """Off-centre bodies at any rotations, their root spheres' world-frame centres
    ``r_a + r_b + excess·slack`` apart: the early-out's second (world-frame) test fires
    only where the kernel prunes the root pair too."""
    ta, tb = OFF_CENTRE[pair[0]], OFF_CENTRE[pair[1]]
    pa = Pose([0.2, -0.1, 0.3], np.array(qa) / np.linalg.norm(qa))
    rotation_b = Pose([0, 0, 0], np.array(qb) / np.linalg.norm(qb))
    u = np.array(direction) / np.linalg.norm(direction)
    (ca, ra), (cb, rb) = ta.views.root_sphere, tb.views.root_sphere
    centre_a = pa.apply(np.array(ca))
    distance = np.linalg.norm(centre_a + 3 * u - pa.position)  # about the positions' gap
    centre_b = centre_a + (ra + rb + excess * _slack(ta, tb, distance)) * u
    pb = Pose(centre_b - rotation_b.rotation @ np.array(cb), rotation_b.orientation)
    got = find_contacts(ta, pa, tb, pb, precision=precision)
    ref = contacts._search(ta, pa, tb, pb, "hybrid", True, precision, "pairs", 1)
    np.testing.assert_array_equal(got.pairs, ref.pairs)
    assert got.stats == ref.stats
    if contacts.far_apart(ta, pa, tb, pb):
        assert ref.stats == contacts.FAR_APART.stats


def test_far_early_out_places_off_centre_spheres():
    """Two off-centre bodies whose positions nearly coincide but whose root spheres are
    turned apart: the rotation-free bound cannot settle it, the world-frame test does."""
    ta, tb = OFF_CENTRE["a"], OFF_CENTRE["b"]
    (ca, ra), (cb, rb) = ta.views.root_sphere, tb.views.root_sphere
    x = np.array([1.0, 0.0, 0.0])
    pa = Pose([0.0, 0.0, 0.0], _turning(np.array(ca) / np.linalg.norm(ca), -x))
    pb = Pose([0.05, 0.0, 0.0], _turning(np.array(cb) / np.linalg.norm(cb), x))
    gap = np.linalg.norm(pb.apply(np.array(cb)) - pa.apply(np.array(ca))) - ra - rb
    assert gap > 0.1 and ta.views.root_reach + tb.views.root_reach > 0.05
    assert contacts.far_apart(ta, pa, tb, pb)
    got = find_contacts(ta, pa, tb, pb)
    assert got is contacts.FAR_APART
    assert contacts._search(ta, pa, tb, pb, "hybrid", True, "float64", "pairs", 1).stats == (
        got.stats
    )
