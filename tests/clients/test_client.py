"""The client library against a real service: numpy results equal to the engine's."""

from __future__ import annotations

import asyncio

import numpy as np
import pytest

from clients import AsyncClient, Client, MeshInfo, Overlaps, ProblemError, SceneState
from clients.calls import contacts_call
from engine import Pose, build_tree, find_contacts_batch, shapes


@pytest.fixture()
def client(service):
    with Client(service.url, timeout=120, transport=service.transport) as c:
        yield c


def test_upload_from_a_path_a_trimesh_and_arrays(client, tmp_path):
    mesh = shapes.icosphere(2, radius=0.5)
    path = tmp_path / "ball.stl"
    mesh.to_trimesh().export(path)
    from_file = client.upload_mesh(path, epsilon=0.01)
    from_trimesh = client.upload_mesh(mesh.to_trimesh(), epsilon=0.01)
    from_arrays = client.upload_mesh((mesh.vertices, mesh.faces), epsilon=0.01)
    assert isinstance(from_file, MeshInfo) and from_file.triangles == 320
    assert from_trimesh.id == from_arrays.id  # the same vertices and faces
    assert not client.upload_mesh((mesh.vertices, mesh.faces), epsilon=0.01).created
    assert from_arrays.bounds.shape == (2, 3) and from_arrays.watertight
    assert from_arrays.id in [m.id for m in client.meshes()]


def test_contacts_equal_the_engine(client):
    mesh = shapes.icosphere(2, radius=0.5)
    info = client.upload_mesh((mesh.vertices, mesh.faces), epsilon=0.02)
    offsets = [0.98, 1.01, 1.2]
    found = client.contacts([(info, None, info, ([d, 0.0, 0.0], [1, 0, 0, 0])) for d in offsets])
    tree = build_tree(mesh, 0.02)
    expected = find_contacts_batch(
        [(tree, Pose.identity(), tree, Pose([d, 0, 0], [1, 0, 0, 0])) for d in offsets]
    )
    assert len(found) == 3
    for got, want in zip(found, expected, strict=True):
        assert isinstance(got.points, np.ndarray) and got.points.shape[1] == 3
        np.testing.assert_allclose(got.points, want.points, atol=1e-12)
        np.testing.assert_allclose(got.overlaps, want.overlaps, atol=1e-12)
        np.testing.assert_array_equal(got.pairs, want.pairs)
    assert len(found[2].points) == 0 and found.stats["pairs"] == 3


def test_precision_is_the_services_default_unless_asked(client):
    mesh = shapes.icosphere(2, radius=0.5)
    info = client.upload_mesh((mesh.vertices, mesh.faces), epsilon=0.02)
    pairs = [(info, None, info, ([0.99, 0.0, 0.0], [0.8, 0.6, 0, 0]))]
    tree = build_tree(mesh, 0.02)
    query = [(tree, Pose.identity(), tree, Pose([0.99, 0, 0], [0.8, 0.6, 0, 0]))]
    for asked in (None, "float64", "float32"):
        found = client.contacts(pairs, precision=asked)[0]
        want = find_contacts_batch(query, **({"precision": asked} if asked else {}))[0]
        assert len(want.points) > 0
        np.testing.assert_array_equal(found.overlaps, want.overlaps)  # bit for bit
    single = client.contacts(pairs, precision="float32")[0]
    double = client.contacts(pairs)[0]
    assert not np.array_equal(single.overlaps, double.overlaps)  # the default is float64
    # unasked, the client leaves the choice to the service: no precision on the wire
    assert "precision" not in contacts_call(pairs, "hybrid", True, None).payload
    assert contacts_call(pairs, "hybrid", True, "float32").payload["precision"] == "float32"


@pytest.mark.parametrize("wire", ["msgpack", "json"])
def test_a_remote_scene_loop(service, wire):
    mesh = shapes.icosphere(2, radius=0.5)
    with Client(service.url, wire=wire, transport=service.transport) as client:
        ball = client.upload_mesh((mesh.vertices, mesh.faces), epsilon=0.01)
        scene = client.create_scene(
            bodies=[{"mesh": ball, "position": [0, 0, 0.56]}],
            planes=[{"point": [0, 0, 0], "normal": [0, 0, 1], "size": 4.0, "divisions": 4}],
            epsilon=0.01,  # the planes' (without it: a tenth of the ball's)
            dt=2e-3,
            scheme="implicit-surrogate",
            contact_model={"damping": 0.3},
        )
        heights = []
        for _ in range(10):
            state = scene.step(5)
            assert isinstance(state, SceneState) and len(state.stats) == 5
            heights.append(state.positions[0, 2])
        assert state.steps == 50 and state.positions.shape == (2, 3)
        assert min(heights) < 0.52  # it fell onto the plane and rests on it
        assert abs(heights[-1] - heights[-2]) < 1e-3
        kicked = scene.set_state(velocities=np.array([[0.0, 0.0, 2.0], [0.0, 0.0, 0.0]]))
        assert kicked.velocities[0, 2] == 2.0 and kicked.overlaps is None
        sunk = scene.set_state(positions=np.array([[0.0, 0.0, 0.49], [0.0, 0.0, 0.0]]))
        assert isinstance(sunk.overlaps, Overlaps) and sunk.overlaps.largest == 1.0
        np.testing.assert_array_equal(sunk.overlaps.pairs, [[0, 1]])
        assert scene.state.steps == 50
        scene.delete()
        with pytest.raises(ProblemError) as error:
            scene.step()
        assert error.value.status == 404 and "no scene" in error.value.detail


def test_problems_carry_the_server_detail(client):
    with pytest.raises(ProblemError) as error:
        client.upload_mesh(([[0, 0, 0], [1, 0, 0], [2, 0, 0]], [[0, 1, 2]]))
    assert error.value.status == 422 and "no face is left" in error.value.detail
    assert error.value.problem["instance"] == "/v1/meshes"


def test_repair_is_reported_and_strict_rejects(client):
    mesh = shapes.icosphere(1, radius=0.5)
    faces = np.vstack([mesh.faces, [[0, 0, 1]]])  # a face that repeats a vertex index
    info = client.upload_mesh((mesh.vertices, faces), epsilon=0.02)
    assert info.repair["changed"] and info.repair["repeated_index_faces_first"] == [80]
    assert info.triangles == 80 and info.watertight
    clean = client.upload_mesh((mesh.vertices, mesh.faces), epsilon=0.02, strict=True)
    assert clean.id == info.id and clean.repair["changed"] is False
    with pytest.raises(ProblemError) as error:
        client.upload_mesh((mesh.vertices, faces), epsilon=0.02, strict=True)
    assert error.value.status == 422 and "strict=false" in error.value.detail


def test_the_async_client(service):
    mesh = shapes.icosphere(1, radius=0.5)

    async def main():
        async with AsyncClient(service.url, transport=service.async_transport) as client:
            info = await client.upload_mesh((mesh.vertices, mesh.faces), epsilon=0.02)
            found = await client.contacts([(info, None, info, [0.99, 0.0, 0.0])])
            scene = await client.create_scene(
                [{"mesh": info, "velocity": [1.0, 0, 0]}], gravity=[0, 0, 0], dt=1e-3
            )
            state = await scene.step(10)
            await scene.delete()
            return found, state

    found, state = asyncio.run(main())
    assert len(found[0].points) > 0
    np.testing.assert_allclose(state.positions[0], [0.01, 0.0, 0.0], atol=1e-12)


def test_columnar_contacts_equal_the_pairwise_call(client):
    mesh = shapes.icosphere(2, radius=0.5)
    info = client.upload_mesh((mesh.vertices, mesh.faces), epsilon=0.02)
    rng = np.random.default_rng(3)
    n = 20
    direction = rng.normal(size=(n, 3))
    position = direction / np.linalg.norm(direction, axis=1)[:, None] * 1.0
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1)[:, None]
    zero, identity = np.zeros((n, 3)), np.tile([1.0, 0, 0, 0], (n, 1))
    index = np.zeros(n, np.int64)
    columns = client.find_contacts([info], index, zero, identity, index, position, q)
    pairwise = client.contacts([(info, None, info, (position[i], q[i])) for i in range(n)])
    assert len(columns) == len(pairwise) == n and len(columns.points) > 0
    for name in ("offsets", "points", "normals", "overlaps", "pair_offsets", "pairs"):
        np.testing.assert_array_equal(getattr(columns, name), getattr(pairwise, name))


def test_mesh_lookup_and_delete(client):
    mesh = shapes.icosphere(1, radius=0.25)
    info = client.upload_mesh((mesh.vertices, mesh.faces), epsilon=0.005)
    assert client.mesh(info).id == info.id and client.mesh(info.id).triangles == 80
    client.delete_mesh(info)
    with pytest.raises(ProblemError) as error:
        client.mesh(info)
    assert error.value.status == 404
