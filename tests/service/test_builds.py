"""Build jobs and the store under the races and failures a review found: a tree file
that goes while a mesh or a scene is recorded, a crash loop, an unreadable job file at
start-up, a cancellation racing a join, tree files left behind, job retention, the
upload's ``wait``. The real store in a temporary directory and the real ASGI app
(in-process, its lifespan run by the test client)."""

from __future__ import annotations

import time
import warnings

import numpy as np
import pytest
from harness import assert_problem, msgpack_body, post_msgpack

from engine import Mesh, build_tree, shapes
from service.app import create_app
from service.builds import MAX_ATTEMPTS, content_id
from service.settings import Settings
from service.store import Store

TETRA = Mesh(
    np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], float),
    np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]]),
)
with warnings.catch_warnings():  # starlette would rather see httpx2; httpx serves
    warnings.simplefilter("ignore")
    from fastapi.testclient import TestClient

SPEC = {"epsilon": 0.05, "branching": 8, "triangles": 4, "vertices": 4}


def _app(data, **settings) -> TestClient:
    return TestClient(create_app(Settings(data_dir=data, warmup=False, **settings)))


def _stored_tree(store: Store) -> str:
    mesh_id = content_id(TETRA, SPEC["epsilon"], SPEC["branching"])
    store.put_tree(mesh_id, build_tree(TETRA, SPEC["epsilon"]))
    return mesh_id


def test_a_mesh_or_scene_is_not_recorded_when_its_tree_file_went(tmp_path):
    """The file is gone (another owner's delete just removed it): the row is refused, so
    that no acknowledged mesh or scene lacks its tree (the upload then builds again)."""
    store = Store(tmp_path)
    try:
        mesh_id = _stored_tree(store)
        store.blobs.path(f"trees/{mesh_id}.npz").unlink()
        assert store.add_mesh("alpha", mesh_id, {"id": mesh_id}) is None
        assert store.mesh("alpha", mesh_id) is None
        assert store.add_scene("alpha", "s1", {}, b"", [mesh_id]) == [mesh_id]
        assert store.scene("alpha", "s1") is None
        _stored_tree(store)
        assert store.add_mesh("alpha", mesh_id, {"id": mesh_id}) is True
        assert store.add_mesh("alpha", mesh_id, {"id": mesh_id}) is False
        assert store.add_scene("alpha", "s1", {}, b"", [mesh_id]) == []
        assert store.scene("alpha", "s1") is not None
    finally:
        store.close()


def test_cancelling_a_job_that_gained_an_owner_does_nothing(tmp_path):
    store = Store(tmp_path)
    try:
        store.add_job("j1", "m1", SPEC, "alpha", {})
        assert store.leave_job("alpha", "m1") == ("j1", 0)
        assert store.join_job("j1", "beta", {}) is True  # joins before the cancel lands
        assert store.cancel_job("j1") is False
        assert store.job("j1")["status"] == "queued"
        assert store.leave_job("beta", "m1") == ("j1", 0)
        assert store.cancel_job("j1") is True
        job = store.job("j1")
        assert job["status"] == "failed" and job["cause"] == "cancelled"
        assert store.join_job("j1", "gamma", {}) is None  # too late: a new job then
    finally:
        store.close()


def test_a_failed_job_removes_its_tree_unless_something_uses_it(tmp_path):
    store = Store(tmp_path)
    try:
        mesh_id = _stored_tree(store)
        store.add_job("j1", mesh_id, SPEC, "alpha", {})
        store.fail_job("j1", "internal", "boom")
        assert not store.has_tree(mesh_id)
        _stored_tree(store)
        assert store.add_mesh("beta", mesh_id, {"id": mesh_id})
        store.add_job("j2", mesh_id, SPEC, "alpha", {})
        store.fail_job("j2", "internal", "boom")
        assert store.has_tree(mesh_id)  # beta's mesh uses it
        assert store.job("j2")["status"] == "failed"
    finally:
        store.close()


def test_start_up_fails_crash_looping_and_unreadable_jobs_and_sweeps_trees(tmp_path):
    """Before the start: a job whose builds were interrupted MAX_ATTEMPTS times (a build
    that kills the process), a job whose mesh file is truncated, a tree file nothing
    refers to. After: both jobs failed with their causes; the tree file removed."""
    store = Store(tmp_path)
    store.add_job("crashy", "m-crashy", SPEC, "", {})
    store.put_job_mesh("crashy", TETRA.vertices, TETRA.faces)
    attempts = [store.start_job("crashy") for _ in range(MAX_ATTEMPTS)]
    assert attempts == list(range(1, MAX_ATTEMPTS + 1))
    store.add_job("broken", "m-broken", SPEC, "", {})
    store.blobs.path("jobs/broken.npz").write_bytes(b"")  # np.load: EOFError
    orphan = _stored_tree(store)
    store.close()
    with _app(tmp_path) as client:
        crashed = client.get("/v1/meshes/jobs/crashy").json()
        assert crashed["status"] == "failed" and crashed["cause"] == "crashed"
        assert f"interrupted {MAX_ATTEMPTS} times" in crashed["error"]
        lost = client.get("/v1/meshes/jobs/broken").json()
        assert lost["status"] == "failed" and lost["cause"] == "lost"
        assert "EOFError" in lost["error"] and "upload it again" in lost["error"]
        assert client.get("/readyz").status_code == 200
    assert not (tmp_path / "trees" / f"{orphan}.npz").exists()
    assert not list((tmp_path / "jobs").iterdir())


def test_finished_jobs_are_pruned_while_running_and_the_list_is_limited(tmp_path):
    """Retention 0.2 s: a finished job is forgotten by a later build's end, without a
    restart. ``limit`` keeps the newest jobs."""
    with _app(tmp_path, job_retention=0.2) as client:
        first = client.post("/v1/meshes", json={**_tetra_body(), "epsilon": 0.01})
        assert first.status_code == 201, first.text
        [old] = client.get("/v1/meshes/jobs").json()["jobs"]
        deadline = time.monotonic() + 20
        step = 0
        while client.get(old["location"]).status_code == 200:
            assert time.monotonic() < deadline, "the finished job was never pruned"
            step += 1
            answer = client.post("/v1/meshes", json={**_tetra_body(), "epsilon": 0.01 + step})
            assert answer.status_code == 201, answer.text
        for n in range(2):  # two more within the retention
            eps = 100.0 + n
            assert client.post("/v1/meshes", json={**_tetra_body(), "epsilon": eps}).is_success
        listed = client.get("/v1/meshes/jobs", params={"limit": 1}).json()["jobs"]
        assert [j["epsilon"] for j in listed] == [101.0]  # the newest
        assert 101.0 in [j["epsilon"] for j in client.get("/v1/meshes/jobs").json()["jobs"]]
        assert_problem(client.get("/v1/meshes/jobs", params={"limit": 0}), 422, "limit")


def _tetra_body() -> dict:
    return {"vertices": TETRA.vertices.tolist(), "faces": TETRA.faces.tolist()}


def test_the_upload_waits_no_longer_than_asked(tmp_path):
    """MRDEM_BUILD_WAIT 30 s, the upload asks ``wait=0``: 202 at once (a 20,480-triangle
    build takes far longer than the hop to the answer); a bad ``wait`` is a 422."""
    mesh = shapes.icosphere(5)
    body = {"vertices": mesh.vertices, "faces": mesh.faces, "epsilon": 0.001}
    with _app(tmp_path, build_wait=30) as client:
        started = time.monotonic()
        accepted = post_msgpack(client, "/v1/meshes", body, params={"wait": "0"})
        assert accepted.status_code == 202, accepted.text
        assert time.monotonic() - started < 20
        job = msgpack_body(accepted)
        assert job["status"] in ("queued", "building")
        for bad in ("-1", "soon", "nan"):
            assert_problem(
                client.post("/v1/meshes", json=_tetra_body(), params={"wait": bad}), 422, "wait"
            )
        deadline = time.monotonic() + 120
        while client.get(job["location"]).json()["status"] != "done":
            assert time.monotonic() < deadline
            time.sleep(0.05)


@pytest.mark.parametrize("null", ["epsilon", "branching"])
def test_null_options_take_the_defaults(tmp_path, null):
    with _app(tmp_path) as client:
        given = client.post("/v1/meshes", json={**_tetra_body(), null: None})
        assert given.status_code == 201, given.text
        default = client.post("/v1/meshes", json=_tetra_body())
        assert default.status_code == 200 and default.json()["id"] == given.json()["id"]
