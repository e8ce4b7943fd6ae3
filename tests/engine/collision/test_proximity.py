"""mesh_distance: the one-kernel branch and bound against every face pair.

Two oracles, both the exact kernel on every face pair:

* in A's frame, on the triangles the query evaluates (A's leaves in the query precision,
  B's moved by :func:`~engine.kernels.collision.rigid.move_kernel` with the query's
  relative pose): the query's distance must be their minimum *exactly*, and the exact
  distance of its face pair that same minimum (ties: any pair attaining it);
* in the world frame, from the meshes themselves (its own rounding: compared to 1e-12 of
  the scene's size), with the closest points on the returned faces.
"""

from __future__ import annotations

import dataclasses
import functools

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from engine import (
    InvalidArgumentError,
    MeshDistance,
    Pose,
    build_tree,
    mesh_distance,
    shapes,
    triangle_distances,
)
from engine.geometry.distance import TriangleSet
from engine.geometry.mesh import Mesh
from engine.kernels.collision import distance_bounds as db
from engine.kernels.collision import distance_search as ds
from engine.kernels.collision.batch import relative_pose
from engine.kernels.collision.rigid import move_kernel

MESHES = {
    "ico80": lambda: shapes.icosphere(1),
    "ico320": lambda: shapes.icosphere(2, radius=0.8),
    "ico1280": lambda: shapes.icosphere(3),
    "torus": lambda: shapes.torus(1.0, 0.3, 16, 8),
    "noisy": lambda: shapes.noisy_sphere(subdivisions=1, eta_r=1.4, seed=3),
    "box": lambda: shapes.box((1.6, 1.0, 0.6)),
    "triangle": lambda: Mesh(np.array([[0.0, 0, 0], [1, 0, 0], [0.2, 0.9, 0]]), [[0, 1, 2]]),
}
PAIRS = [
    ("ico80", "ico320"),
    ("torus", "torus"),
    ("ico320", "noisy"),
    ("noisy", "torus"),
    ("box", "box"),
    ("box", "ico80"),
    ("triangle", "torus"),
    ("triangle", "triangle"),
]
TOL = 1e-12  # relative to the scene's size
PROPS = settings(  # 25 random poses in the default run, 500 more under -m slow
    max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow], database=None
)


@functools.cache
def body(name: str):
    """(mesh, tree) of a test shape, built once; halo 0.02 (it plays no part)."""
    mesh = MESHES[name]()
    return mesh, build_tree(mesh, epsilon=0.02, seed=1)


def posed(mesh, pose: Pose) -> np.ndarray:
    """(F, 3, 3) float64 world-frame triangles."""
    return pose.apply(mesh.vertices)[mesh.faces]


def oracle(name_a: str, pose_a: Pose, name_b: str, pose_b: Pose):
    """Exact distance of every face pair, world frame: ``(d (Fa, Fb) float64, point_a,
    point_b (Fa, Fb, 3))``."""
    ta, tb = posed(body(name_a)[0], pose_a), posed(body(name_b)[0], pose_b)
    a = np.repeat(ta, len(tb), axis=0)
    b = np.tile(tb, (len(ta), 1, 1))
    found = triangle_distances(a, b, kernel="exact", precision="float64")
    shape = (len(ta), len(tb))
    return (
        found.distance.reshape(shape),
        found.point_a.reshape(*shape, 3),
        found.point_b.reshape(*shape, 3),
    )


def frame_oracle(name_a, pose_a, name_b, pose_b, precision="float64") -> np.ndarray:
    """``(Fa, Fb)`` exact distances (query dtype) of every face pair in A's frame, on the
    triangles the query evaluates: A's leaves in ``precision``, B's moved by
    ``move_kernel`` with the relative pose and rounded to ``precision``."""
    tree_a, tree_b = body(name_a)[1], body(name_b)[1]
    set_a = tree_a.views.geometry.node_set(precision, True)  # faces in face order
    rows_b = tree_b.views.geometry.node_set("float64", True)
    _, rotation, shift = relative_pose(
        pose_a.position, pose_a.orientation, pose_b.position, pose_b.orientation
    )
    fb = len(rows_b)
    coords_b = np.empty((fb, 9), set_a.dtype)
    frames_b = np.empty((fb, 14), set_a.dtype)
    move_kernel(
        rows_b.coords_rm, rows_b.frames_rm, np.arange(fb), rotation, shift, coords_b, frames_b
    )
    fa = len(set_a)
    a = TriangleSet.prepared(*(np.repeat(x, fb, axis=1) for x in (set_a.coords, set_a.frames)))
    b = TriangleSet.prepared(np.tile(coords_b.T, (1, fa)), np.tile(frames_b.T, (1, fa)))
    found = triangle_distances(a, b, kernel="exact", precision=precision)
    return found.distance.reshape(fa, fb)


def scale(name_a: str, pose_a: Pose, name_b: str, pose_b: Pose) -> float:
    points = np.concatenate(
        [posed(body(n)[0], p).reshape(-1, 3) for n, p in ((name_a, pose_a), (name_b, pose_b))]
    )
    return float(np.abs(points).max())


def point_to_triangle(point: np.ndarray, triangle: np.ndarray) -> float:
    """Exact distance from ``point (3,)`` to ``triangle (3, 3)`` (a point is a zero-area
    triangle)."""
    found = triangle_distances(np.repeat(point[None, None], 3, axis=1), triangle[None], "exact")
    return float(found.distance[0])


def check_against_oracle(name_a, pose_a, name_b, pose_b, precision="float64") -> MeshDistance:
    """The query's distance is the frame oracle's minimum exactly, its faces attain it;
    within rounding it is the world oracle's minimum, and its points lie on its faces,
    that distance apart."""
    result = mesh_distance(body(name_a)[1], pose_a, body(name_b)[1], pose_b, precision=precision)
    assert isinstance(result, MeshDistance)
    assert result.faces.dtype == np.int64 and result.faces.shape == (2,)
    assert result.point_a.shape == result.point_b.shape == (3,)
    assert result.faces.tolist() == [result.face_a, result.face_b]
    np.testing.assert_array_equal(result.closest_points, [result.point_a, result.point_b])
    assert result.point_a is result.point_a  # made once, at first use
    fa, fb = result.faces
    exact = frame_oracle(name_a, pose_a, name_b, pose_b, precision)
    assert result.distance == float(exact.min()), (result.distance, exact.min())
    assert float(exact[fa, fb]) == result.distance
    every, _, _ = oracle(name_a, pose_a, name_b, pose_b)
    size = scale(name_a, pose_a, name_b, pose_b)
    tol = (TOL if precision == "float64" else 1e-5) * size
    assert abs(result.distance - every.min()) <= tol, (result.distance, every.min())
    assert abs(every[fa, fb] - every.min()) <= tol
    tri_a = posed(body(name_a)[0], pose_a)[fa]
    tri_b = posed(body(name_b)[0], pose_b)[fb]
    assert point_to_triangle(result.point_a, tri_a) <= tol
    assert point_to_triangle(result.point_b, tri_b) <= tol
    assert abs(np.linalg.norm(result.point_b - result.point_a) - result.distance) <= tol
    assert result.node_pairs >= 1 and result.probes >= 1
    assert result.largest_front <= result.node_pairs
    return result


unit = st.tuples(*[st.floats(-1, 1) for _ in range(4)]).map(np.array)


def quaternion(values: np.ndarray) -> np.ndarray:
    norm = np.linalg.norm(values)
    assume(norm > 0.1)
    return values / norm


RANDOM_POSES = dict(
    pair=st.sampled_from(PAIRS),
    qa=unit,
    qb=unit,
    direction=unit,
    reach=st.floats(0.0, 3.0),
    kind=st.sampled_from(["as drawn", "touching", "near"]),
    precision=st.sampled_from(["float64", "float64", "float32"]),
)


@PROPS
@given(**RANDOM_POSES)
def test_equals_the_minimum_over_every_face_pair(pair, qa, qb, direction, reach, kind, precision):
    """Random poses from deep overlap (reach 0) to far apart (reach 3 bounding radii), the
    same poses moved until the closest points touch, or 1e-3 apart along their offset."""
    check_random_pose(pair, qa, qb, direction, reach, kind, precision)


@pytest.mark.slow
@settings(PROPS, max_examples=500)
@given(**RANDOM_POSES)
def test_equals_the_minimum_over_every_face_pair_at_length(
    pair, qa, qb, direction, reach, kind, precision
):
    """The same property on 500 random poses (``-m slow``)."""
    check_random_pose(pair, qa, qb, direction, reach, kind, precision)


def check_random_pose(pair, qa, qb, direction, reach, kind, precision) -> None:
    """B at ``reach`` bounding radii from A along ``direction``; ``kind`` "touching" or
    "near" then moves B by the oracle's closest-point offset (to 0, or 1e-3 apart), and the
    query must equal the oracle."""
    name_a, name_b = pair
    direction = quaternion(direction)[:3]
    assume(np.linalg.norm(direction) > 0.1)
    direction = direction / np.linalg.norm(direction)
    radii = body(name_a)[1].bounding_radius + body(name_b)[1].bounding_radius
    pose_a = Pose([0.3, -0.2, 0.1], quaternion(qa))
    pose_b = Pose(pose_a.position + reach * radii * direction, quaternion(qb))
    if kind != "as drawn":  # move B by the oracle's closest-point offset: distance ≈ 0
        every, pa, pb = oracle(name_a, pose_a, name_b, pose_b)
        k = np.unravel_index(np.argmin(every), every.shape)
        offset = pb[k] - pa[k]
        norm = np.linalg.norm(offset)
        keep = 1e-3 / norm if kind == "near" and norm > 0 else 0.0
        pose_b = Pose(pose_b.position - (1 - keep) * offset, pose_b.orientation)
    check_against_oracle(name_a, pose_a, name_b, pose_b, precision)


@pytest.mark.parametrize("gap", [0.3, 0.02, 1e-6, 0.0, -0.01, -0.1])
def test_interlocked_tori(gap):
    """A chain link: B's ring through A's hole, tube surfaces ``gap`` apart (for the
    smooth tori; the meshes' faces lie inside them, so the mesh distance is larger)."""
    quarter = [np.cos(np.pi / 4), np.sin(np.pi / 4), 0.0, 0.0]  # B's ring in the xz plane
    pose_a, pose_b = Pose.identity(), Pose([0.6 + gap, 0.0, 0.0], quarter)
    result = check_against_oracle("torus", pose_a, "torus", pose_b)
    assert (result.distance > 0) == (oracle("torus", pose_a, "torus", pose_b)[0].min() > 0)


@pytest.mark.parametrize("gap", [1.0, 0.02, -0.01, -0.1])
def test_icospheres_side_by_side(gap):
    """The benchmark's poses (many face pairs tie at the minimum: vertex against vertex)."""
    check_against_oracle("ico80", Pose.identity(), "ico80", Pose([2 + gap, 0, 0], [1, 0, 0, 0]))


def test_a_front_past_the_kernels_stack_buffers_grows_them():
    """Far apart, 1,280-triangle icospheres keep more node pairs waiting than the search's
    heap starts with in its stack frame (``HEAP_START``): it grows onto the heap, and the
    answer is still the minimum over the face pairs that face each other (the faces of
    either sphere on its side towards the other: every other pair is farther)."""
    mesh, tree = body("ico1280")
    pose_b = Pose([3.0, 0, 0], [1, 0, 0, 0])
    result = mesh_distance(tree, Pose.identity(), tree, pose_b)
    assert result.largest_front > ds.HEAP_START
    tri_a, tri_b = posed(mesh, Pose.identity()), posed(mesh, pose_b)
    near_a = np.flatnonzero(tri_a[:, :, 0].mean(axis=1) > 0.5)
    near_b = np.flatnonzero(tri_b[:, :, 0].mean(axis=1) < 2.5)
    found = triangle_distances(
        np.repeat(tri_a[near_a], len(near_b), axis=0),
        np.tile(tri_b[near_b], (len(near_a), 1, 1)),
        kernel="exact",
    )
    d = found.distance.reshape(len(near_a), len(near_b))
    assert result.distance == pytest.approx(d.min(), rel=1e-12)
    at = (near_a == result.face_a, near_b == result.face_b)
    assert d[np.flatnonzero(at[0])[0], np.flatnonzero(at[1])[0]] == pytest.approx(
        d.min(), rel=1e-12
    )


@pytest.mark.parametrize("pair", PAIRS[:4])
def test_float32_within_its_rounding(pair):
    rng = np.random.default_rng(7)
    for _ in range(5):
        q = rng.normal(size=(2, 4))
        pose_a = Pose(rng.normal(size=3), q[0] / np.linalg.norm(q[0]))
        offset = rng.normal(size=3)
        offset *= rng.uniform(0.5, 2.5) / np.linalg.norm(offset)
        pose_b = Pose(pose_a.position + offset, q[1] / np.linalg.norm(q[1]))
        check_against_oracle(*pair[:1], pose_a, pair[1], pose_b, precision="float32")


def test_identical_bodies_are_at_distance_zero():
    _, tree = body("noisy")
    pose = Pose([1.0, 2.0, 3.0], [0.5, 0.5, 0.5, 0.5])
    result = mesh_distance(tree, pose, tree, pose)
    assert result.distance == 0.0
    np.testing.assert_allclose(result.point_a, result.point_b, atol=1e-12)


def test_separated_bodies_prune_most_pairs():
    """Far apart, the search bounds a small part of the face pairs and evaluates few."""
    _, tree = body("ico320")
    result = mesh_distance(tree, Pose.identity(), tree, Pose([3.0, 0.5, 0.0], [1, 0, 0, 0]))
    faces = int(tree.is_leaf.sum())
    assert result.node_pairs + result.probes < faces * faces / 20
    assert result.probes < faces
    assert result.sphere_pruned > 0 and result.rounds > 0


def test_result_is_a_frozen_dataclass():
    _, tree = body("ico80")
    result = mesh_distance(tree, Pose.identity(), tree, Pose([2.5, 0, 0], [1, 0, 0, 0]))
    with pytest.raises(AttributeError):
        result.distance = 0.0
    again = mesh_distance(tree, Pose.identity(), tree, Pose([2.5, 0, 0], [1, 0, 0, 0]))
    assert repr(again) == repr(result) and again.distance == result.distance
    # built without __init__: every field, nothing else
    assert set(vars(result)) == {f.name for f in dataclasses.fields(MeshDistance)}


@pytest.mark.parametrize("precision", ["float64", "float32"])
def test_the_kernels_entry_point_gets_the_types_it_was_compiled_for(precision):
    """``mesh_distance`` calls the distance kernel's compiled entry point directly for exact
    types: the trees' rows and the poses' packed arrays must have the types it was compiled
    for however the tree or the pose was made, or it would read memory wrongly."""
    import copy
    import io
    import pickle

    import numba

    from engine.collision import proximity
    from engine.trees.tree import SurrogateTree

    mesh, built = body("ico80")
    buffer = io.BytesIO()
    built.save(buffer)
    buffer.seek(0)
    loaded = SurrogateTree.load(buffer)
    pose = Pose([0.5, -0.2, 2.0], [0.8, 0.0, 0.6, 0.0])
    poses = [
        pose,
        Pose.identity(),
        pose.inverse(),
        pose.compose(pose),
        pickle.loads(pickle.dumps(pose)),
        copy.copy(pose),
        copy.deepcopy(pose),
        dataclasses.replace(pose, position=[1.0, 2.0, 3.0]),
    ]
    dtype = np.dtype(precision).type
    entry = proximity._compiled_kernel(dtype)
    for tree in (built, loaded):
        rows = tree.views.kernel_distance_rows
        prepared = rows if precision == "float64" else tree.views.kernel_prepared_rows(precision)
        for other in poses:
            args = (prepared, rows, rows, other._packed, pose._packed, np.empty((2, 3)))
            key = tuple(numba.typeof(x) for x in args)
            assert ds.distance_kernel.overloads[key].entry_point is entry
            dispatched, points = ds.distance_kernel(*args), args[-1].copy()
            assert entry(*args) == dispatched
            np.testing.assert_array_equal(args[-1], points)
            result = mesh_distance(tree, other, tree, pose, precision)
            assert result.distance == dispatched[0]
            np.testing.assert_array_equal(result.closest_points, points)


def test_bad_arguments():
    _, tree = body("ico80")
    pose = Pose.identity()
    with pytest.raises(InvalidArgumentError, match="tree_a"):
        mesh_distance(None, pose, tree, pose)
    with pytest.raises(InvalidArgumentError, match="tree_b"):
        mesh_distance(tree, pose, body("ico80")[0], pose)
    with pytest.raises(InvalidArgumentError, match="pose_a"):
        mesh_distance(tree, np.zeros(3), tree, pose)
    with pytest.raises(InvalidArgumentError, match="pose_b"):
        mesh_distance(tree, pose, tree, (np.zeros(3), [1, 0, 0, 0]))
    with pytest.raises(InvalidArgumentError, match="precision"):
        mesh_distance(tree, pose, tree, pose, precision="float16")


def covered_faces(tree) -> list[np.ndarray]:
    """Per node, the (sorted) faces of the leaves below it."""
    covered: list[list[int]] = [[] for _ in range(len(tree))]
    for leaf in np.flatnonzero(tree.face >= 0):
        node = leaf
        while node >= 0:
            covered[node].append(int(tree.face[leaf]))
            node = tree.parent[node]
    return [np.array(sorted(c)) for c in covered]


@pytest.mark.parametrize("pair", PAIRS)
def test_node_bounds_never_exceed_the_distance_of_the_covered_faces(pair):
    """On random poses (overlapping to apart, and moved to touching), for random node pairs
    and every leaf pair's ancestors: the box bound, the sphere bound, the children's bound
    (``child_bounds``: at least both), and the node triangles' exact distance less g never
    exceed the least exact distance between a face covered by A's node and one covered by
    B's (up to rounding)."""
    name_a, name_b = pair
    tree_a, tree_b = body(name_a)[1], body(name_b)[1]
    rows_a, rows_b = tree_a.views.distance_rows, tree_b.views.distance_rows
    cover_a, cover_b = covered_faces(tree_a), covered_faces(tree_b)
    rng = np.random.default_rng(15)
    radii = tree_a.bounding_radius + tree_b.bounding_radius
    placed = np.empty((db.N_PLACED, 1))
    node, low, row = np.empty((db.PLACED, 1)), np.empty((1, 1)), np.empty(1, np.int64)
    for pose in range(6):
        q = rng.normal(size=(2, 4))
        pose_a = Pose(rng.normal(size=3), q[0] / np.linalg.norm(q[0]))
        offset = rng.normal(size=3)
        offset *= rng.uniform(0.0, 1.5) * radii / np.linalg.norm(offset)
        pose_b = Pose(pose_a.position + offset, q[1] / np.linalg.norm(q[1]))
        every, pa, pb = oracle(name_a, pose_a, name_b, pose_b)
        if pose % 2:  # touching: B moved by the closest-point offset
            k = np.unravel_index(np.argmin(every), every.shape)
            pose_b = Pose(pose_b.position - (pb[k] - pa[k]), pose_b.orientation)
            every = oracle(name_a, pose_a, name_b, pose_b)[0]
        _, rotation, shift = relative_pose(
            pose_a.position, pose_a.orientation, pose_b.position, pose_b.orientation
        )
        r, s = tuple(rotation.ravel()), tuple(shift)
        tol = 1e-12 * scale(name_a, pose_a, name_b, pose_b)
        nodes = zip(
            rng.integers(0, len(tree_a), 300), rng.integers(0, len(tree_b), 300), strict=True
        )
        for i, j in nodes:
            true = every[np.ix_(cover_a[i], cover_b[j])].min()
            box = db.box_gap(rows_a, i, rows_b, j, r, s)
            assert box <= true + tol, (pose, i, j, box, true)
            db.place_box(rows_b, j, r, s, placed, 0)  # B's box moved once: the same bound
            assert abs(db.placed_gap(rows_a, i, placed, 0) - box) <= tol, (pose, i, j)
            centre_b = rotation @ rows_b[j, ds.CENTRE : ds.CENTRE + 3] + shift
            sphere = np.linalg.norm(centre_b - rows_a[i, ds.CENTRE : ds.CENTRE + 3])
            sphere -= rows_a[i, ds.RADIUS] + rows_b[j, ds.RADIUS]
            assert sphere <= true + tol, (pose, i, j, sphere, true)
            # the children's vectorised bound: at least both, never beyond the faces
            db.place_node(rows_b, j, r, s, node, 0)
            row[0] = i
            db.child_bounds(rows_a, row, 1, node, 1, low)
            assert max(box, sphere) - tol <= low[0, 0] <= true + tol, (pose, i, j, low, true)
        for i, j in nodes_near(every, tree_a, tree_b):
            true = every[np.ix_(cover_a[i], cover_b[j])].min()
            assert db.box_gap(rows_a, i, rows_b, j, r, s) <= true + tol, (pose, i, j)
            db.place_node(rows_b, j, r, s, node, 0)
            row[0] = i
            db.child_bounds(rows_a, row, 1, node, 1, low)
            assert low[0, 0] <= true + tol, (pose, i, j, low, true)
            tri = pose_a.apply(tree_a.triangles[i])[None], pose_b.apply(tree_b.triangles[j])[None]
            node_d = triangle_distances(*tri, kernel="exact").distance[0]
            gap = rows_a[i, ds.GAP] + rows_b[j, ds.GAP]
            assert node_d - gap <= true + tol, (pose, i, j, node_d - gap, true)


def nodes_near(every: np.ndarray, tree_a, tree_b) -> list[tuple[int, int]]:
    """Every pair of ancestors (leaves included) of the leaves of a closest face pair."""
    fa, fb = np.unravel_index(np.argmin(every), every.shape)
    chain = []
    for tree, f in ((tree_a, fa), (tree_b, fb)):
        node, nodes = int(tree.views.geometry.face_nodes[f]), []
        while node >= 0:
            nodes.append(node)
            node = int(tree.parent[node])
        chain.append(nodes)
    return [(i, j) for i in chain[0] for j in chain[1]]


@pytest.mark.parametrize("name", sorted(MESHES))
def test_node_boxes_hold_their_covered_vertices(name):
    """Unit, orthogonal axes; every vertex of every covered face within the box (up to
    rounding)."""
    mesh, tree = body(name)
    boxes = tree.views.distance_boxes
    axes = boxes[:, 3:12].reshape(-1, 3, 3)
    np.testing.assert_allclose(
        axes @ np.swapaxes(axes, 1, 2), np.broadcast_to(np.eye(3), axes.shape), atol=1e-12
    )
    tol = 1e-12 * float(np.abs(mesh.vertices).max())
    faces = mesh.vertices[mesh.faces]
    for node, cover in enumerate(covered_faces(tree)):
        points = faces[cover].reshape(-1, 3) - boxes[node, 0:3]
        along = np.abs(points @ axes[node].T)
        assert (along <= boxes[node, 12:15] + tol).all(), node
