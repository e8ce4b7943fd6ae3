"""Tree builds as jobs against real servers: 202 with a Location, progress, done, one
build for joined uploads (across owners), deleting while building, and a failed build
(a real storage failure) that says why and is retried by uploading again."""

from __future__ import annotations

import re
import shutil
import time

import httpx
import numpy as np
import pytest
from harness import InProcessService, assert_problem, msgpack_body, poll_job, post_msgpack

from engine import Pose, build_tree, find_contacts_batch, shapes

ALPHA = {"authorization": "Bearer alpha-key-0001"}
BETA = {"authorization": "Bearer beta-key-00002"}
ORDER = {"queued": 0, "building": 1, "done": 2, "failed": 2}


def _body(mesh, epsilon: float | None = None) -> dict:
    body = {"vertices": mesh.vertices, "faces": mesh.faces}
    return body if epsilon is None else {**body, "epsilon": epsilon}


def _metric(client: httpx.Client, name: str, labels: str = "") -> float:
    text = client.get("/metrics").text
    match = re.search(rf"^{name}{re.escape(labels)} (\S+)$", text, re.MULTILINE)
    return float(match.group(1)) if match else 0.0


@pytest.fixture(scope="module")
def jobs_service(tmp_path_factory):
    """Every upload that builds answers 202 at once (``build_wait`` 0); one build at a
    time, so a large build keeps later jobs queued."""
    process = InProcessService(
        tmp_path_factory.mktemp("jobs") / "data",
        build_wait=0,
        build_concurrency=1,
        api_keys="alpha-key-0001,beta-key-00002",
    ).start()
    yield process
    process.stop()


def test_an_upload_is_a_job_until_its_tree_is_built(jobs_service):
    mesh = shapes.icosphere(3, radius=0.5)
    with jobs_service.client(headers=ALPHA, timeout=60) as http:
        built = _metric(http, "mrdem_build_seconds_count")
        accepted = post_msgpack(http, "/v1/meshes", _body(mesh, 0.01))
        assert accepted.status_code == 202, accepted.text
        job = msgpack_body(accepted)
        location = accepted.headers["location"]
        assert location == job["location"] == f"/v1/meshes/jobs/{job['id']}"
        assert accepted.headers["retry-after"] == "1"
        assert job["status"] in ("queued", "building") and job["error"] is None
        assert job["triangles"] == 1280 and job["epsilon"] == 0.01 and job["branching"] == 8
        done = poll_job(http, location)
        assert done["status"] == "done" and done["error"] is None and done["seconds"] > 0
        steps = [(ORDER[s], levels, nodes) for s, levels, nodes in done["seen"]]
        assert steps == sorted(steps)  # status and progress never go back
        facts = http.get(f"/v1/meshes/{done['mesh']}").json()
        assert done["facts"] == facts and done["mesh_url"] == f"/v1/meshes/{facts['id']}"
        assert done["progress"] == {"levels": facts["levels"], "nodes": facts["nodes"]}
        tree = build_tree(mesh, 0.01)  # the engine's own tree of the same mesh
        assert facts["nodes"] == len(tree) and facts["levels"] == tree.stats.depth + 1
        assert facts["epsilon_given"] is True
        assert "Retry-After" not in http.get(location).headers  # finished
        # the stored tree answers contacts like the engine's
        pair = {"a": facts["id"], "b": facts["id"], "pose_b": {"position": [0.99, 0, 0]}}
        found = http.post("/v1/contacts", json={"pairs": [pair]}).json()["results"][0]
        near = Pose([0.99, 0, 0], [1, 0, 0, 0])
        want = find_contacts_batch([(tree, Pose.identity(), tree, near)])[0]
        assert len(want.points) > 0
        np.testing.assert_allclose(found["points"], want.points, atol=1e-12)
        # now stored: the same upload answers at once, no job
        again = post_msgpack(http, "/v1/meshes", _body(mesh, 0.01))
        assert again.status_code == 200 and msgpack_body(again)["id"] == facts["id"]
        assert _metric(http, "mrdem_build_seconds_count") == built + 1
        listed = http.get("/v1/meshes/jobs").json()["jobs"]
        assert [j["status"] for j in listed if j["id"] == job["id"]] == ["done"]


def test_joined_uploads_share_one_build_and_delete_cancels(jobs_service):
    big = shapes.icosphere(6)  # 81,920 triangles: seconds to build (cancelled mid-way)
    small = shapes.icosphere(2, radius=0.5)
    alpha = jobs_service.client(headers=ALPHA, timeout=60)
    beta = jobs_service.client(headers=BETA, timeout=60)
    with alpha, beta:
        counts = {
            s: _metric(alpha, "mrdem_build_jobs_finished_total", f'{{status="{s}"}}')
            for s in ("done", "failed")
        }
        trees = _metric(alpha, "mrdem_meshes_built_total")
        blocker = post_msgpack(alpha, "/v1/meshes", _body(big, 0.001))
        assert blocker.status_code == 202
        blocker = msgpack_body(blocker)
        first = post_msgpack(alpha, "/v1/meshes", _body(small, 0.02))
        second = post_msgpack(alpha, "/v1/meshes", _body(small, 0.02))
        other = post_msgpack(beta, "/v1/meshes", _body(small, 0.02))
        assert first.status_code == second.status_code == other.status_code == 202
        jobs = [msgpack_body(r) for r in (first, second, other)]
        assert len({j["id"] for j in jobs}) == 1  # one job for the same content
        assert len({j["mesh"] for j in jobs}) == 1
        job, mesh_id = jobs[0]["location"], jobs[0]["mesh"]
        queued = alpha.get(job).json()["status"]
        if alpha.get(blocker["location"]).json()["status"] in ("queued", "building"):
            assert queued == "queued"  # one build at a time: behind the unfinished large one
        # the pending mesh is not listed yet and its 404 names the job
        assert mesh_id not in [m["id"] for m in alpha.get("/v1/meshes").json()["meshes"]]
        pending = assert_problem(alpha.get(f"/v1/meshes/{mesh_id}"), 404, "being built")
        assert pending["job"] == job
        # other owners do not see a job they did not upload
        assert_problem(beta.get(blocker["location"]), 404, "no build job")
        assert alpha.get("/readyz").status_code == 200  # readiness ignores builds
        # the large build reports its levels as they finish
        deadline = time.monotonic() + 120
        seen = alpha.get(blocker["location"]).json()
        while seen["status"] == "queued" or seen["progress"]["levels"] < 2:
            assert seen["status"] in ("queued", "building"), seen
            assert time.monotonic() < deadline, seen
            time.sleep(0.01)
            seen = alpha.get(blocker["location"]).json()
        assert seen["status"] == "building" and seen["progress"]["nodes"] > 0
        # deleting it while it builds withdraws the upload and stops the build
        assert alpha.delete(f"/v1/meshes/{blocker['mesh']}").status_code == 204
        assert_problem(alpha.get(blocker["location"]), 404, "no build job")
        for client in (alpha, beta):
            done = poll_job(client, job)
            assert done["status"] == "done"
            assert client.get(f"/v1/meshes/{mesh_id}").json() == done["facts"]
        assert alpha.get(f"/v1/meshes/{blocker['mesh']}").status_code == 404
        after = {
            s: _metric(alpha, "mrdem_build_jobs_finished_total", f'{{status="{s}"}}')
            for s in ("done", "failed")
        }
        assert after == {"done": counts["done"] + 1, "failed": counts["failed"] + 1}
        assert _metric(alpha, "mrdem_meshes_built_total") == trees + 1  # one tree built
        assert _metric(alpha, "mrdem_build_jobs", '{status="building"}') == 0
        stored = {p.stem for p in (jobs_service.data_dir / "trees").iterdir()}
        assert mesh_id in stored and blocker["mesh"] not in stored
        assert not list((jobs_service.data_dir / "jobs").iterdir())  # job files removed


def test_a_failed_build_says_why_and_uploading_again_retries(tmp_path, caplog):
    """A real failure: the tree directory is replaced by a file, so the tree cannot be
    stored. Within the upload's wait the failure is the answer; later, the job says it."""
    process = InProcessService(tmp_path / "data", build_wait=30).start()
    trees = process.data_dir / "trees"
    mesh = shapes.icosphere(2, radius=0.5)
    try:
        with process.client(timeout=60) as http:
            shutil.rmtree(trees)
            trees.write_bytes(b"")
            failed = post_msgpack(http, "/v1/meshes", _body(mesh))
            problem = assert_problem(failed, 500, "the tree could not be stored")
            assert problem["cause"] == "storage" and problem["job"] in problem["detail"]
            job = http.get(problem["job"]).json()
            assert job["status"] == "failed" and job["cause"] == "storage"
            assert job["error"] in problem["detail"]
            assert str(process.data_dir) not in problem["detail"]  # no server internals…
            assert "NotADirectoryError" not in problem["detail"]
            assert "NotADirectoryError" in caplog.text  # …they are logged
            assert http.get("/readyz").status_code == 200  # the server is fine
            assert http.get(f"/v1/meshes/{job['mesh']}").status_code == 404
            trees.unlink()
            trees.mkdir()
            retried = post_msgpack(http, "/v1/meshes", _body(mesh))
            assert retried.status_code == 201, retried.text
            facts = msgpack_body(retried)
            assert facts["id"] == job["mesh"] and facts["epsilon_given"] is False
            assert http.get(problem["job"]).json()["status"] == "failed"  # history kept
    finally:
        process.stop()


def test_a_client_that_disconnects_does_not_cancel_its_build(live_service):
    """The upload's request gives up (client timeout) while the service waits for the
    build; the build goes on and its job is found and finishes."""
    mesh = shapes.icosphere(6)  # 81,920 triangles: seconds to build, the client waits 0.5
    impatient = httpx.Client(base_url=live_service.url, timeout=0.5)
    with impatient, pytest.raises(httpx.ReadTimeout):
        post_msgpack(impatient, "/v1/meshes", _body(mesh, 0.0031))
    with httpx.Client(base_url=live_service.url, timeout=60) as http:
        jobs = [
            j
            for j in http.get("/v1/meshes/jobs").json()["jobs"]
            if j["epsilon"] == 0.0031 and j["triangles"] == 81920
        ]
        assert len(jobs) == 1
        done = poll_job(http, jobs[0]["location"])
        assert done["status"] == "done" and done["facts"]["triangles"] == 81920
