"""What the service acknowledged survives ``kill -9``: meshes, and build jobs (finished
after a restart, or reported failed with the reason); API keys isolate owners."""

from __future__ import annotations

import time

import httpx
import pytest
from harness import (
    ServiceProcess,
    assert_problem,
    msgpack_body,
    poll_job,
    post_msgpack,
    tetrahedron,
)

from engine import shapes


def _ball(epsilon: float) -> dict:
    mesh = shapes.icosphere(2, radius=0.5)
    return {"vertices": mesh.vertices.tolist(), "faces": mesh.faces.tolist(), "epsilon": epsilon}


def test_meshes_survive_kill_9_and_restart(tmp_path):
    data = tmp_path / "data"
    first = ServiceProcess(data).start()
    try:
        with httpx.Client(base_url=first.url, timeout=120) as client:
            facts = [client.post("/v1/meshes", json=_ball(e)).json() for e in (0.01, 0.02)]
            client.delete(f"/v1/meshes/{facts[1]['id']}")
    finally:
        first.kill()  # no shutdown: whatever was acknowledged must already be on disk
    second = ServiceProcess(data).start()
    try:
        with httpx.Client(base_url=second.url, timeout=120) as client:
            assert client.get(f"/v1/meshes/{facts[0]['id']}").json() == facts[0]
            assert client.get(f"/v1/meshes/{facts[1]['id']}").status_code == 404
            assert [m["id"] for m in client.get("/v1/meshes").json()["meshes"]] == [facts[0]["id"]]
            pair = {"a": facts[0]["id"], "b": facts[0]["id"], "pose_b": {"position": [0.99, 0, 0]}}
            found = client.post("/v1/contacts", json={"pairs": [pair]}).json()
            assert len(found["results"][0]["points"]) > 0  # the stored tree loads and works
            again = client.post("/v1/meshes", json=_ball(0.01))
            assert again.status_code == 200 and again.json() == facts[0]
    finally:
        second.stop()
    assert sorted(p.name for p in (data / "trees").iterdir()) == [f"{facts[0]['id']}.npz"]


def _accepted(client: httpx.Client, mesh, epsilon: float) -> dict:
    body = {"vertices": mesh.vertices, "faces": mesh.faces, "epsilon": epsilon}
    response = post_msgpack(client, "/v1/meshes", body)
    assert response.status_code == 202, response.text
    return msgpack_body(response)


def _after_restart(data, jobs: dict, lost: dict | None = None) -> None:
    """Restart on ``data`` with half-written files planted: ``jobs`` finish, ``lost``
    (whose mesh file is gone) is reported failed, the planted files are removed."""
    if lost is not None:
        (data / "jobs" / f"{lost['id']}.npz").unlink()
    planted = [data / "trees" / ".half.0123.tmp", data / "jobs" / ".half.4567.tmp"]
    planted.append(data / "jobs" / "0123456789abcdef.npz")  # a file with no job row
    planted.append(data / "trees" / f"{'ab' * 16}.npz")  # a tree nothing refers to
    for path in planted:
        path.write_bytes(b"partial")
    second = ServiceProcess(data, build_wait="0").start()
    try:
        with httpx.Client(base_url=second.url, timeout=120) as client:
            for job in jobs.values():
                done = poll_job(client, job["location"])
                assert done["status"] == "done", done
                assert done["facts"]["id"] == job["mesh"]
                assert done["facts"]["triangles"] == job["triangles"]
            mesh_id = jobs["big"]["mesh"]
            pair = {"a": mesh_id, "b": mesh_id, "pose_b": {"position": [1.99, 0, 0]}}
            found = client.post("/v1/contacts", json={"pairs": [pair]}).json()
            assert len(found["results"][0]["points"]) > 0  # the rebuilt tree works
            if lost is not None:
                failed = client.get(lost["location"]).json()
                assert failed["status"] == "failed" and failed["cause"] == "lost"
                assert "upload it again" in failed["error"]
                assert client.get(f"/v1/meshes/{lost['mesh']}").status_code == 404
                again = _accepted(client, shapes.icosphere(1, radius=0.5), 0.01)  # a retry
                assert again["id"] != lost["id"] and again["mesh"] == lost["mesh"]
                assert poll_job(client, again["location"])["status"] == "done"
    finally:
        second.stop()
    assert not any(path.exists() for path in planted)
    assert not list((data / "jobs").iterdir())


def test_acknowledged_builds_survive_kill_9(tmp_path):
    """Uploads answered 202 and killed before their builds finish: after a restart they
    are built from the stored meshes; one whose stored mesh is gone is reported failed."""
    data = tmp_path / "data"
    first = ServiceProcess(data, build_wait="0", build_concurrency="1").start()
    try:
        with httpx.Client(base_url=first.url, timeout=120) as client:
            jobs = {
                "big": _accepted(client, shapes.icosphere(5), 0.002),  # ~1 s to build
                "queued": _accepted(client, shapes.icosphere(3, radius=0.5), 0.01),
            }
            lost = _accepted(client, shapes.icosphere(1, radius=0.5), 0.01)
            status = client.get(jobs["big"]["location"]).json()["status"]
            assert status in ("queued", "building")  # acknowledged, not finished
    finally:
        first.kill()
    _after_restart(data, jobs, lost)


@pytest.mark.slow
def test_a_build_killed_midway_finishes_after_restart(tmp_path):
    """The kill lands while a large build reports progress (levels done)."""
    data = tmp_path / "data"
    first = ServiceProcess(data, build_wait="0").start()
    try:
        with httpx.Client(base_url=first.url, timeout=120) as client:
            jobs = {"big": _accepted(client, shapes.icosphere(6), 0.001)}  # 81,920 triangles
            deadline = time.monotonic() + 120
            while (seen := client.get(jobs["big"]["location"]).json())["progress"]["levels"] < 3:
                assert seen["status"] in ("queued", "building"), seen
                assert time.monotonic() < deadline, seen
                time.sleep(0.01)
    finally:
        first.kill()
    _after_restart(data, jobs)


@pytest.fixture(scope="module")
def keyed(tmp_path_factory):
    process = ServiceProcess(
        tmp_path_factory.mktemp("keyed") / "data", api_keys="alpha-key-0001, beta-key-00002"
    ).start()
    yield process
    process.stop()


def test_api_keys_are_required(keyed):
    with httpx.Client(base_url=keyed.url) as client:
        missing = client.get("/v1/meshes")
        assert_problem(missing, 401, "missing api key")
        assert missing.headers["www-authenticate"] == "Bearer"
        wrong = client.get("/v1/meshes", headers={"authorization": "Bearer nope-nope-nope"})
        assert_problem(wrong, 401, "unknown api key")
        assert_problem(client.post("/v1/meshes", json=tetrahedron()), 401, "missing api key")
        assert client.get("/healthz").status_code == 200  # probes need no key
        assert client.get("/readyz").status_code == 200


def test_a_key_sees_only_its_own_meshes(keyed):
    alpha = httpx.Client(base_url=keyed.url, headers={"authorization": "Bearer alpha-key-0001"})
    beta = httpx.Client(base_url=keyed.url, headers={"authorization": "Bearer beta-key-00002"})
    with alpha, beta:
        mine = alpha.post("/v1/meshes", json=tetrahedron())
        assert mine.status_code == 201
        mesh_id = mine.json()["id"]
        assert_problem(beta.get(f"/v1/meshes/{mesh_id}"), 404, "no mesh")
        assert_problem(beta.delete(f"/v1/meshes/{mesh_id}"), 404, "no mesh")
        pair = {"a": mesh_id, "b": mesh_id, "pose_b": {"position": [0.5, 0, 0]}}
        assert_problem(beta.post("/v1/contacts", json={"pairs": [pair]}), 404, "no mesh")
        assert beta.get("/v1/meshes").json()["meshes"] == []
        # the same content uploaded by beta is beta's own (same id, shared tree file)
        assert beta.post("/v1/meshes", json=tetrahedron()).status_code == 201
        assert alpha.delete(f"/v1/meshes/{mesh_id}").status_code == 204
        assert beta.get(f"/v1/meshes/{mesh_id}").status_code == 200
        assert beta.post("/v1/contacts", json={"pairs": [pair]}).status_code == 200
        assert alpha.get("/v1/meshes").json()["meshes"] == []


def test_a_key_sees_only_its_own_scenes(keyed):
    alpha = httpx.Client(base_url=keyed.url, headers={"authorization": "Bearer alpha-key-0001"})
    beta = httpx.Client(base_url=keyed.url, headers={"authorization": "Bearer beta-key-00002"})
    with alpha, beta:
        mesh_id = alpha.post("/v1/meshes", json=_ball(0.03)).json()["id"]
        spec = {"bodies": [{"mesh": mesh_id}], "gravity": [0, 0, 0]}
        assert_problem(beta.post("/v1/scenes", json=spec), 404, "no mesh")  # not beta's mesh
        scene_id = alpha.post("/v1/scenes", json=spec).json()["id"]
        for response in (
            beta.get(f"/v1/scenes/{scene_id}"),
            beta.post(f"/v1/scenes/{scene_id}/step", json={"steps": 1}),
            beta.put(f"/v1/scenes/{scene_id}/state", json={"positions": [[1, 2, 3]]}),
            beta.delete(f"/v1/scenes/{scene_id}"),
        ):
            assert_problem(response, 404, "no scene")
        assert alpha.post(f"/v1/scenes/{scene_id}/step", json={"steps": 2}).json()["steps"] == 2
