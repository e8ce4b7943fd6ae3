"""Oriented bounding boxes of tree nodes: they hold what the spheres hold, their separating-axis
test never prunes a pair the flat exact search reports, and the early-out that uses them
settles only queries with no contact."""

from __future__ import annotations

import numpy as np
import pytest

from engine import build_tree, shapes
from engine.collision import contacts
from engine.collision.contacts import find_contacts
from engine.geometry.pose import Pose
from engine.kernels.collision.boxes import box_apart, place_box
from engine.kernels.collision.pair_query import roots_apart

SHAPES = {
    "stretched": lambda: shapes.stretched_sphere(subdivisions=2, eta=3.0),
    "torus": lambda: shapes.torus(major_segments=16, minor_segments=6),
    "rod": lambda: shapes.box(extents=(3.0, 0.3, 0.2)),
    "noisy": lambda: shapes.noisy_sphere(subdivisions=2, eta_r=1.4, seed=5),
}


@pytest.fixture(scope="module")
def trees():
    return {name: build_tree(make(), epsilon=0.02, seed=1) for name, make in SHAPES.items()}


def _unit(rng: np.random.Generator, n: int) -> np.ndarray:
    v = rng.normal(size=n)
    return v / np.linalg.norm(v)


@pytest.mark.parametrize("name", list(SHAPES))
def test_boxes_hold_every_covered_leaf_with_its_epsilon(trees, name):
    """Each node's box holds every vertex of its covered leaves grown by the leaf ε (along
    each of its axes), its axes are orthonormal, and it is no larger than the body-axes box."""
    tree = trees[name]
    boxes = tree.views.boxes
    assert boxes.shape == (len(tree), 15) and boxes.dtype == np.float64
    axes = boxes[:, 3:12].reshape(-1, 3, 3)
    np.testing.assert_allclose(
        axes @ axes.transpose(0, 2, 1), np.broadcast_to(np.eye(3), axes.shape), atol=1e-12
    )
    leaves = np.flatnonzero(tree.face >= 0)
    node, verts = leaves, tree.triangles[leaves]
    checked = 0
    while len(node):
        along = np.einsum("nki,nvi->nvk", axes[node], verts - boxes[node, None, :3])
        assert (np.abs(along) + tree.leaf_epsilon <= boxes[node, None, 12:]).all()
        checked += len(node)
        keep = tree.parent[node] >= 0
        node, verts = tree.parent[node][keep], verts[keep]
    assert checked > len(leaves)  # every leaf checked against its ancestors too
    # no box is larger than the body-frame box of the same points (the fallback)
    low, high = tree.triangles[leaves].min((0, 1)), tree.triangles[leaves].max((0, 1))
    volume = np.prod(2 * boxes[0, 12:])
    assert volume <= np.prod(high - low + 2 * tree.leaf_epsilon) * (1 + 1e-9)


def _corners(box: np.ndarray) -> np.ndarray:
    """(8, 3) corners of a box row."""
    signs = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float)
    return box[:3] + (signs * box[12:]) @ box[3:12].reshape(3, 3)


def _gaps(box_a: np.ndarray, box_b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Projection gaps of two boxes (same frame) along the 15 axes, unnormalised (as the
    test uses them) and normalised (true separations)."""
    a, b = box_a[3:12].reshape(3, 3), box_b[3:12].reshape(3, 3)
    axes = [*a, *b, *(np.cross(u, v) for u in a for v in b)]
    ca, cb = _corners(box_a), _corners(box_b)
    raw, unit = [], []
    for axis in axes:
        pa, pb = ca @ axis, cb @ axis
        gap = max(pb.min() - pa.max(), pa.min() - pb.max())
        raw.append(gap)
        norm = np.linalg.norm(axis)
        unit.append(gap / norm if norm > 1e-12 else -np.inf)
    return np.array(raw), np.array(unit)


def test_separating_axis_test_matches_the_corner_projections():
    """Random boxes at random relative poses: the kernel says "apart" exactly when some of
    the 15 axes separates the boxes' corner projections by more than the margin (away from
    the threshold), and then their true separation exceeds the margin."""
    rng = np.random.default_rng(7)
    decided = {True: 0, False: 0}
    for _ in range(400):
        rows = []
        for _ in range(2):
            q = _unit(rng, 4)
            frame = Pose([0, 0, 0], q).rotation.T  # rows: orthonormal axes
            rows.append(
                np.concatenate([rng.normal(size=3), frame.ravel(), rng.uniform(0.05, 1.5, 3)])
            )
        box_a, box_b = rows
        q = _unit(rng, 4)
        rotation, shift = Pose([0, 0, 0], q).rotation, rng.normal(size=3) * 2.0
        placed, done = np.empty((1, 15)), np.zeros(1, np.bool_)
        place_box(box_b[None].copy(), 0, rotation, shift, placed, done)
        margin = rng.uniform(0.0, 0.3)
        got = box_apart(box_a[None].copy(), 0, placed, 0, margin)
        raw, unit = _gaps(box_a, placed[0])
        if np.abs(raw - margin).min() < 1e-9:
            continue  # at the threshold: rounding decides
        assert got == bool((raw > margin).any())
        if got:
            assert unit.max() > margin  # a true gap above the margin
        decided[got] += 1
    assert min(decided.values()) > 50, decided


def _posed_near(rng, ta, tb, scale: float):
    """A random pose of B about ``scale`` of the bodies' reach from A (A at a random pose)."""
    pa = Pose(rng.normal(size=3), _unit(rng, 4))
    reach = ta.bounding_radius + tb.bounding_radius
    pb = Pose(pa.position + _unit(rng, 3) * reach * scale, _unit(rng, 4))
    return pa, pb


@pytest.mark.parametrize("precision", ["float64", "float32"])
@pytest.mark.parametrize(
    ("name_a", "name_b"),
    [("stretched", "rod"), ("torus", "torus"), ("rod", "rod"), ("noisy", "torus")],
)
def test_box_pruned_search_equals_flat_exact_search(trees, name_a, name_b, precision):
    """Lemma 1 with boxes: on seeded random poses from touching to far, the multiresolution
    search (spheres, then boxes) returns the flat exact search's pairs; the boxes prune node
    pairs the spheres keep (more pairs pruned and fewer comparisons than spheres alone), and
    whenever the early-out settles a query the flat search has no contact."""
    ta, tb = trees[name_a], trees[name_b]
    rng = np.random.default_rng([11, len(name_a), len(name_b), len(precision)])
    kinds = {"contact": 0, "separated": 0, "early": 0, "box_early": 0}
    for _ in range(60):
        pa, pb = _posed_near(rng, ta, tb, rng.uniform(0.15, 1.0))
        flat = find_contacts(ta, pa, tb, pb, kernel="exact", hierarchy=False, precision=precision)
        got = find_contacts(ta, pa, tb, pb, precision=precision)
        np.testing.assert_array_equal(got.pairs, flat.pairs)
        kinds["contact" if len(flat.pairs) else "separated"] += 1
        if contacts.far_apart(ta, pa, tb, pb):
            assert len(flat.pairs) == 0 and got is contacts.FAR_APART
            kinds["early"] += 1
            if not _spheres_settle(ta, pa, tb, pb):
                kinds["box_early"] += 1
    assert kinds["contact"] > 0 and kinds["separated"] > 0, kinds


def _spheres_settle(ta, pa, tb, pb) -> bool:
    """The early-out's sphere tests alone: the root spheres (placed in the world frame, or
    about the positions whatever the rotations) apart by more than the early-out's slack."""
    distance = float(np.linalg.norm(pb.position - pa.position))
    slack = contacts._FAR_SLACK * (
        np.sqrt(3.0) * (ta.views.geometry.extent + tb.views.geometry.extent) + distance
    )
    if distance > ta.views.root_reach + tb.views.root_reach + slack:
        return True
    (ca, ra), (cb, rb) = ta.views.root_sphere, tb.views.root_sphere
    gap = np.linalg.norm(pb.apply(np.array(cb)) - pa.apply(np.array(ca))) - ra - rb
    return bool(gap > slack)


def test_boxes_settle_parallel_rods_that_spheres_cannot(trees):
    """Two long rods side by side, 0.2 apart (their ε reach 0.04): the root spheres overlap,
    the root boxes do not, so the early-out settles the query; 0.03 apart they touch and the
    search finds the flat search's pairs."""
    rod = trees["rod"]
    pa = Pose.identity()
    for gap, apart in ((0.2, True), (0.03, False)):
        pb = Pose([0.0, 0.3 + gap, 0.0], [1.0, 0.0, 0.0, 0.0])
        assert not _spheres_settle(rod, pa, rod, pb)
        assert contacts.far_apart(rod, pa, rod, pb) == apart
        got = find_contacts(rod, pa, rod, pb)
        flat = find_contacts(rod, pa, rod, pb, kernel="exact", hierarchy=False)
        np.testing.assert_array_equal(got.pairs, flat.pairs)
        assert (got is contacts.FAR_APART) == apart and (len(flat.pairs) == 0) == apart


def test_box_early_out_never_settles_what_the_kernel_keeps(trees):
    """Rods turned a little about a random axis, their boxes' gap swept through the
    early-out's slack: whenever :func:`far_apart` settles a query, the kernel run on the same
    arguments prunes the root pair too (same counters), and near the threshold the search
    equals the flat search."""
    rod = trees["rod"]
    rng = np.random.default_rng(3)
    reach = 2 * (0.15 + rod.leaf_epsilon)  # the boxes' half-widths across, both rods
    settled = 0
    for _ in range(200):
        slack = contacts._FAR_SLACK * (2 * np.sqrt(3.0) * rod.views.geometry.extent + reach)
        axis, angle = _unit(rng, 3), rng.uniform(0.0, 1e-4)
        turn = np.array([np.cos(angle / 2), *(np.sin(angle / 2) * axis)])
        pa = Pose([0.0, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0])
        pb = Pose([0.0, reach + rng.uniform(-3.0, 3.0) * slack, 0.0], turn)
        got = find_contacts(rod, pa, rod, pb)
        ref = contacts._search(rod, pa, rod, pb, "hybrid", True, "float64", "pairs", 1)
        flat = find_contacts(rod, pa, rod, pb, kernel="exact", hierarchy=False)
        np.testing.assert_array_equal(got.pairs, ref.pairs)
        np.testing.assert_array_equal(got.pairs, flat.pairs)
        assert got.stats == ref.stats
        if contacts.far_apart(rod, pa, rod, pb):
            settled += 1
            assert ref.stats == contacts.FAR_APART.stats and len(flat.pairs) == 0
    assert 0 < settled < 200


def test_roots_children_settle_a_chain_link_held_apart():
    """Two linked tori 0.3 apart (a chain link pulled taut): their root spheres and root
    boxes overlap, but the bounds-only search below the roots finds every node pair apart,
    so the early-out settles the query, the search prunes the root pair the same way, and
    the flat search finds no contact; 0.01 apart the early-out does not fire and the pairs
    are the flat search's."""
    torus = build_tree(shapes.torus(1.0, 0.3, 32, 16), epsilon=0.01, seed=0)
    quarter = [np.cos(np.pi / 4), np.sin(np.pi / 4), 0.0, 0.0]  # B's ring through A's hole
    pa = Pose.identity()
    for gap, apart in ((0.3, True), (0.01, False)):
        pb = Pose([0.6 + gap, 0.0, 0.0], quarter)
        root = torus.views.bounds_table[:1].copy()  # the roots' own bounds only
        root[0, 20] = 0.0
        args = (pa.position, pa.orientation, pb.position, pb.orientation, 1e-6)
        assert not _spheres_settle(torus, pa, torus, pb) and not roots_apart(root, root, *args)
        assert contacts.far_apart(torus, pa, torus, pb) == apart
        ref = contacts._search(torus, pa, torus, pb, "hybrid", True, "float64", "pairs", 1)
        flat = find_contacts(torus, pa, torus, pb, kernel="exact", hierarchy=False)
        np.testing.assert_array_equal(ref.pairs, flat.pairs)
        assert (ref.stats == contacts.FAR_APART.stats) == apart
        assert (len(flat.pairs) == 0) == apart
