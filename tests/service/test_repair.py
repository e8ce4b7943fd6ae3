"""Uploads are repaired by default and say what changed; ``strict`` rejects instead with
advice an HTTP caller can follow; clean meshes are untouched. Dirty meshes are generated
here (trimesh, STL/OBJ/PLY in temporary folders) with a near-duplicate vertex, a
zero-area face, a repeated-index face, an open edge, a flipped face and a non-manifold
edge."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from harness import assert_problem, msgpack_body, post_msgpack

from engine import Pose, build_tree, find_contacts_batch, load_mesh, shapes

EPSILON = 0.01


def _dirty() -> tuple[np.ndarray, np.ndarray, dict]:
    """A radius-0.5 icosphere made dirty; returns vertices, faces and what was done (the
    input face index of the zero-area and repeated-index faces, vertices to merge)."""
    base = shapes.icosphere(2, radius=0.5)
    v, f = base.vertices.copy(), base.faces.astype(np.int64)
    size = float(np.linalg.norm(np.ptp(v, axis=0)))
    # a near-duplicate of face 0's first corner (2e-7 of the size: distinct in float32,
    # within the default merge tolerance), used by face 0 instead of the original
    v = np.vstack([v, v[f[0, 0]] + [2e-7 * size, 0.0, 0.0]])
    f[0, 0] = len(v) - 1
    f[1] = f[1, ::-1]  # a flipped face
    f = np.delete(f, 2, axis=0)  # an open hole
    tip = v[f[3, :2]].mean(axis=0) * 1.5  # a fin on face 3's first edge: non-manifold
    v = np.vstack([v, tip])
    fin = [f[3, 0], f[3, 1], len(v) - 1]
    line = np.array([[0.125, 0.0, 0.0], [0.25, 0.0, 0.0], [0.375, 0.0, 0.0]])  # exact
    v = np.vstack([v, line])
    zero = [len(v) - 3, len(v) - 2, len(v) - 1]  # collinear in float32 too: zero area
    repeated = [f[5, 0], f[5, 0], f[5, 1]]
    f = np.vstack([f, [fin], [zero], [repeated]])
    return v, f, {"zero_area_face": len(f) - 2, "repeated_face": len(f) - 1, "merged": 1}


def _upload_file(http, path, **fields):
    with open(path, "rb") as stream:
        data = {k: str(v).lower() if isinstance(v, bool) else str(v) for k, v in fields.items()}
        return http.post("/v1/meshes", files={"file": (path.name, stream)}, data=data)


@pytest.mark.parametrize("file_type", ["stl", "obj", "ply"])
def test_a_dirty_file_is_repaired_reported_and_usable(http, tmp_path, file_type):
    vertices, faces, made = _dirty()
    path = tmp_path / f"dirty.{file_type}"
    trimesh.Trimesh(vertices, faces, process=False).export(path)
    response = _upload_file(http, path, epsilon=EPSILON)
    assert response.status_code in (200, 201), response.text
    facts = response.json()
    repair = facts["repair"]
    assert repair["changed"] is True and repair["input_faces"] == len(faces)
    assert repair["zero_area_faces_first"] == [made["zero_area_face"]]
    assert repair["repeated_index_faces_first"] == [made["repeated_face"]]
    assert repair["merged_vertices"] == made["merged"]
    assert repair["faces"] == facts["triangles"] == len(faces) - 2
    assert repair["vertices"] == facts["vertices"]
    assert facts["watertight"] is False  # the hole, the flip and the fin stay
    assert http.get(f"/v1/meshes/{facts['id']}").json()["repair"] == repair
    # the engine reads the same file to the same mesh, report and tree
    mesh = load_mesh(path)
    assert repair == mesh.repair.summary()
    tree = build_tree(mesh, EPSILON)
    assert facts["nodes"] == len(tree)
    poses = [Pose([0.99, 0.0, 0.0], [1, 0, 0, 0]), Pose([0.0, 0.98, 0.0], [0.8, 0.6, 0, 0])]
    pairs = [
        {
            "a": facts["id"],
            "b": facts["id"],
            "pose_b": {"position": p.position.tolist(), "orientation": p.orientation.tolist()},
        }
        for p in poses
    ]
    found = http.post("/v1/contacts", json={"pairs": pairs}).json()["results"]
    want = find_contacts_batch([(tree, Pose.identity(), tree, p) for p in poses])
    for got, expected in zip(found, want, strict=True):
        assert len(expected.points) > 0
        np.testing.assert_array_equal(np.asarray(got["points"]), expected.points)
        np.testing.assert_array_equal(np.asarray(got["overlaps"]), expected.overlaps)


def test_strict_rejects_a_mesh_that_needs_repair_with_http_advice(http, tmp_path):
    vertices, faces, made = _dirty()
    path = tmp_path / "dirty.obj"
    trimesh.Trimesh(vertices, faces, process=False).export(path)
    as_file = assert_problem(_upload_file(http, path, strict=True), 422, "needs repair")
    body = {"vertices": vertices, "faces": faces, "strict": True}
    as_msgpack = post_msgpack(http, "/v1/meshes", body)
    as_json = http.post(
        "/v1/meshes",
        json={"vertices": vertices.tolist(), "faces": faces.tolist(), "strict": True},
    )
    for problem in (as_file, assert_problem(as_json, 422, "needs repair")):
        detail = problem["detail"]
        assert detail.endswith("send strict=false (the default) to have them repaired")
        assert "have zero area" in detail and "repeat a vertex index" in detail
        assert f"indices {made['zero_area_face']}" in detail
        assert "=True" not in detail and "pass " not in detail  # no Python-only advice
    assert as_msgpack.status_code == 422
    # an unusable mesh gets its own reason, not the repair advice
    flat = {"vertices": [[0, 0, 0], [1, 0, 0], [2, 0, 0]], "faces": [[0, 1, 2]], "strict": True}
    problem = assert_problem(http.post("/v1/meshes", json=flat), 422, "no face is left")
    assert "strict=false" not in problem["detail"]
    assert_problem(http.post("/v1/meshes", json={**flat, "strict": "yes"}), 422, "strict")
    upload = _upload_file(http, path, strict="maybe")
    assert_problem(upload, 422, "strict must be true or false")
    # strict=false (the default) repairs the same file
    assert _upload_file(http, path, strict=False).json()["repair"]["changed"] is True


@pytest.mark.parametrize("file_type", ["stl", "obj", "ply"])
def test_a_clean_mesh_is_untouched(http, tmp_path, file_type):
    mesh = shapes.icosphere(2, radius=0.5)
    path = tmp_path / f"clean.{file_type}"
    mesh.to_trimesh().export(path)
    facts = _upload_file(http, path, epsilon=EPSILON, strict=True).json()
    assert facts["repair"]["changed"] is False and facts["triangles"] == mesh.n_faces
    loaded = load_mesh(path)
    arrays = {"vertices": loaded.vertices, "faces": loaded.faces, "epsilon": EPSILON}
    same = msgpack_body(post_msgpack(http, "/v1/meshes", arrays))
    assert same["id"] == facts["id"] and same["repair"]["changed"] is False


def test_repair_reports_are_per_upload(http):
    """The repaired mesh of a dirty upload is the clean mesh: same id, and each upload's
    answer reports its own repair."""
    mesh = shapes.icosphere(1, radius=0.25)
    clean = {"vertices": mesh.vertices.tolist(), "faces": mesh.faces.tolist(), "epsilon": 0.007}
    first = http.post("/v1/meshes", json=clean).json()
    extra = [[0.0, 0.0, 0.0]]  # an unreferenced vertex, and a repeated-index face
    dirty = {
        **clean,
        "vertices": clean["vertices"] + extra,
        "faces": clean["faces"] + [[0, 0, 1]],
    }
    again = http.post("/v1/meshes", json=dirty)
    assert again.status_code == 200 and again.json()["id"] == first["id"]
    report = again.json()["repair"]
    assert report["unreferenced_vertices"] == 1 and report["repeated_index_faces"] == 1
    assert first["repair"]["changed"] is False
    assert http.get(f"/v1/meshes/{first['id']}").json()["repair"]["changed"] is False
