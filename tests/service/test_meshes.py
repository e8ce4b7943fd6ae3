"""Mesh uploads against a real server: formats, content addressing, listing, surrogates."""

from __future__ import annotations

import numpy as np
import pytest
from harness import as_array, msgpack_body, post_msgpack, tetrahedron

from engine import build_tree, load_mesh, shapes

FORMATS = ("stl", "obj", "ply", "off", "glb")


def test_json_upload_is_content_addressed(http):
    first = http.post("/v1/meshes", json=tetrahedron())
    assert first.status_code == 201, first.text
    facts = first.json()
    assert facts["triangles"] == 4 and facts["vertices"] == 4 and facts["watertight"]
    assert facts["volume"] == pytest.approx(1 / 6)
    np.testing.assert_allclose(facts["bounds"], [[0, 0, 0], [1, 1, 1]])
    again = http.post("/v1/meshes", json=tetrahedron())
    assert again.status_code == 200 and again.json() == facts
    other = http.post("/v1/meshes", json={**tetrahedron(), "epsilon": 0.05})
    assert other.status_code == 201 and other.json()["id"] != facts["id"]
    assert other.json()["epsilon"] == 0.05
    assert facts["epsilon_given"] is False and other.json()["epsilon_given"] is True
    assert facts["repair"]["changed"] is False and facts["repair"]["faces"] == 4
    assert http.get(f"/v1/meshes/{facts['id']}").json() == facts
    ids = [m["id"] for m in http.get("/v1/meshes").json()["meshes"]]
    assert facts["id"] in ids and other.json()["id"] in ids


def test_msgpack_upload_with_binary_arrays_gives_the_json_mesh(http):
    mesh = shapes.icosphere(1)
    payload = {"vertices": mesh.vertices, "faces": mesh.faces.astype(np.int32), "epsilon": 0.02}
    created = post_msgpack(http, "/v1/meshes", payload)
    assert created.status_code in (200, 201), created.text
    facts = msgpack_body(created)
    as_json = http.post(
        "/v1/meshes",
        json={"vertices": mesh.vertices.tolist(), "faces": mesh.faces.tolist(), "epsilon": 0.02},
    )
    assert as_json.status_code == 200 and as_json.json()["id"] == facts["id"]
    tree = build_tree(mesh, 0.02)
    assert facts["triangles"] == 80 and facts["nodes"] == len(tree)
    assert facts["levels"] == tree.stats.depth + 1


@pytest.mark.parametrize("file_type", FORMATS)
def test_file_upload_in_each_format(http, tmp_path, file_type):
    mesh = shapes.icosphere(2, radius=0.5)
    path = tmp_path / f"ball.{file_type}"
    mesh.to_trimesh().export(path)
    with open(path, "rb") as f:
        response = http.post("/v1/meshes", files={"file": (path.name, f)}, data={"epsilon": "0.01"})
    assert response.status_code in (200, 201), response.text
    facts = response.json()
    expected = load_mesh(path)  # what the engine reads from the same file
    assert facts["triangles"] == expected.n_faces == 320
    assert facts["epsilon"] == 0.01 and facts["watertight"]
    np.testing.assert_allclose(facts["bounds"], expected.bounds, atol=1e-6)


def test_an_obj_that_is_not_utf8_is_read(http):
    """A Latin-1 byte in a comment (many exporters write their locale's encoding): the
    file is read, not answered with a missing-module error."""
    mesh = shapes.icosphere(1, radius=0.5)
    lines = [b"# export\xe9 par un logiciel fran\xe7ais"]
    lines += [b"v %r %r %r" % tuple(v) for v in mesh.vertices.tolist()]
    lines += [b"f %d %d %d" % tuple(f) for f in (mesh.faces + 1).tolist()]
    data = b"\n".join(lines) + b"\n"
    with pytest.raises(UnicodeDecodeError):
        data.decode("utf-8")
    response = http.post(
        "/v1/meshes", files={"file": ("latin.obj", data)}, data={"epsilon": "0.02"}
    )
    assert response.status_code in (200, 201), response.text
    facts = response.json()
    assert facts["triangles"] == 80 and facts["watertight"]
    np.testing.assert_allclose(facts["bounds"], mesh.bounds, atol=1e-12)


def test_delete_then_unknown(http):
    facts = http.post("/v1/meshes", json={**tetrahedron(), "epsilon": 0.125}).json()
    assert http.delete(f"/v1/meshes/{facts['id']}").status_code == 204
    assert http.get(f"/v1/meshes/{facts['id']}").status_code == 404
    assert http.delete(f"/v1/meshes/{facts['id']}").status_code == 404
    # uploading it again builds it again
    assert http.post("/v1/meshes", json={**tetrahedron(), "epsilon": 0.125}).status_code == 201


def test_surrogates_of_each_level_cover_the_tree(http):
    mesh = shapes.icosphere(2)
    facts = http.post(
        "/v1/meshes", json={"vertices": mesh.vertices.tolist(), "faces": mesh.faces.tolist()}
    ).json()
    tree = build_tree(mesh, facts["epsilon"])
    total = 0
    for level in range(facts["levels"]):
        body = http.get(f"/v1/meshes/{facts['id']}/surrogates", params={"level": level}).json()
        nodes = np.flatnonzero(tree.level == level)
        np.testing.assert_allclose(as_array(body["triangles"]), tree.triangles[nodes])
        np.testing.assert_allclose(as_array(body["epsilon"]), tree.epsilon[nodes])
        assert body["leaf"] == (tree.face[nodes] >= 0).tolist()
        total += len(nodes)
    assert total == len(tree) == facts["nodes"]
    root = http.get(f"/v1/meshes/{facts['id']}/surrogates").json()  # level 0 by default
    assert len(root["triangles"]) == 1 and root["epsilon"][0] >= facts["epsilon"]
