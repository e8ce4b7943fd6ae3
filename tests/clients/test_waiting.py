"""The client waits for tree builds: polling a 202's job with progress, its own deadline
(the build goes on), a failed build's reason (a real storage failure), the async client,
and ``mrdem upload``'s progress line — all against real servers."""

from __future__ import annotations

import asyncio

import pytest
from harness import ServiceProcess

from clients import (
    AsyncClient,
    BuildFailed,
    BuildJob,
    BuildTimeout,
    Client,
    ClientError,
    MeshInfo,
    ProblemError,
)
from clients.calls import job_path
from clients.upload import main as upload_main
from engine import build_tree, shapes


@pytest.fixture(scope="module")
def lazy(tmp_path_factory):
    """A service that answers every upload that builds with 202 at once."""
    process = ServiceProcess(
        tmp_path_factory.mktemp("lazy") / "data", build_wait="0", build_concurrency="1"
    ).start()
    yield process
    process.stop()


@pytest.fixture(scope="module")
def patient(tmp_path_factory):
    """A service that waits up to 30 s for a build before answering 202."""
    process = ServiceProcess(tmp_path_factory.mktemp("patient") / "data", build_wait="30")
    yield process.start()
    process.stop()


def test_upload_waits_for_the_tree_and_reports_progress(lazy):
    mesh = shapes.icosphere(4, radius=0.5)
    seen: list[BuildJob] = []
    with Client(lazy.url) as client:
        info = client.upload_mesh((mesh.vertices, mesh.faces), epsilon=0.01, progress=seen.append)
        assert isinstance(info, MeshInfo) and info.created and info.triangles == 5120
        assert all(isinstance(job, BuildJob) for job in seen) and len(seen) >= 2
        assert seen[0].status in ("queued", "building") and seen[-1].status == "done"
        assert [job.nodes for job in seen] == sorted(job.nodes for job in seen)
        assert seen[-1].levels == info.levels and seen[-1].nodes == info.facts["nodes"]
        assert len({job.url for job in seen}) == 1 and seen[0].mesh == info.id
        assert len(build_tree(mesh, 0.01)) == info.facts["nodes"]
        again = client.upload_mesh((mesh.vertices, mesh.faces), epsilon=0.01)
        assert again.id == info.id and not again.created  # stored: no job


def test_wait_false_returns_the_job_to_wait_for_later(lazy):
    mesh = shapes.icosphere(3, radius=0.5)
    with Client(lazy.url, wire="json") as client:
        job = client.upload_mesh((mesh.vertices, mesh.faces), epsilon=0.02, wait=False)
        assert isinstance(job, BuildJob) and job.url.startswith("/v1/meshes/jobs/")
        assert job.triangles == 1280 and not job.finished
        assert client.job(job.id).url == job.url  # by id, URL or job
        info = client.wait_for_mesh(job.url)
        assert info.id == job.mesh and info.created
        assert client.job(job).status == "done"


def test_the_clients_deadline_names_the_job_and_the_build_goes_on(lazy):
    mesh = shapes.icosphere(4, radius=0.5)
    with Client(lazy.url) as client:
        with pytest.raises(BuildTimeout) as error:  # no time even for the upload itself
            client.upload_mesh((mesh.vertices, mesh.faces), epsilon=0.03, timeout=0)
        assert error.value.job_url is None and "upload the mesh again" in str(error.value)
        job = client.upload_mesh((mesh.vertices, mesh.faces), epsilon=0.03, wait=False)
        assert isinstance(job, BuildJob)
        with pytest.raises(BuildTimeout) as error:
            client.wait_for_mesh(job, timeout=0)
        url = error.value.job_url
        assert url.startswith("/v1/meshes/jobs/") and url in str(error.value)
        assert error.value.job.status in ("queued", "building")
        info = client.wait_for_mesh(url, timeout=120)  # keep polling where it stopped
        assert info.id == error.value.job.mesh and info.triangles == 5120


def test_the_async_client_waits_too(lazy):
    mesh = shapes.icosphere(3, radius=0.25)
    seen: list[str] = []

    async def main():
        async with AsyncClient(lazy.url) as client:
            info = await client.upload_mesh(
                (mesh.vertices, mesh.faces), epsilon=0.005, progress=lambda j: seen.append(j.status)
            )
            job = await client.upload_mesh((mesh.vertices, mesh.faces), epsilon=0.006, wait=False)
            with pytest.raises(BuildTimeout):
                await client.wait_for_mesh(job, timeout=0)
            return info, await client.wait_for_mesh(job.url)

    info, later = asyncio.run(main())
    assert isinstance(info, MeshInfo) and info.triangles == 1280 and seen[-1] == "done"
    assert seen[0] in ("queued", "building")
    assert later.epsilon == 0.006 and later.created


def test_a_failed_build_raises_with_the_services_reason(lazy, patient):
    """The tree directory replaced by a file: builds fail for real. On a service that
    waits 30 s, a small mesh fails within the wait (the upload's own problem); on one that
    answers 202 at once, a larger one fails after it (seen while polling)."""
    servers = [(patient, shapes.icosphere(1), False), (lazy, shapes.icosphere(5), True)]
    for process, mesh, polled in servers:
        trees = process.data_dir / "trees"
        aside = trees.with_name("trees-aside")
        trees.rename(aside)
        trees.write_bytes(b"")
        try:
            with Client(process.url) as client:
                with pytest.raises(BuildFailed) as error:
                    client.upload_mesh((mesh.vertices, mesh.faces), epsilon=0.0123)
                job = client.job(error.value.job_url)
        finally:
            trees.unlink()
            aside.rename(trees)
        assert error.value.cause == "storage" and error.value.__cause__ is not error.value
        assert "the tree could not be stored" in error.value.reason
        assert error.value.job_url.startswith("/v1/meshes/jobs/")
        assert job.status == "failed" and job.error in error.value.reason
        if polled:  # the failed job seen while polling
            assert isinstance(error.value.job, BuildJob) and error.value.job.status == "failed"
        else:  # the upload's problem (members job and cause)
            assert error.value.job is None and isinstance(error.value.__cause__, ProblemError)


def test_the_upload_asks_the_service_to_answer_before_the_client_stops_reading(patient):
    """The service may wait 30 s for a build; a client that reads for 2 s per request
    (no retries) asks it to answer within half of that: a 202, then polls. An upload
    deadline of 1.5 s bounds the upload request too: the job's URL when it passes."""
    mesh = shapes.icosphere(6)  # 81,920 triangles: seconds to build
    seen: list[BuildJob] = []
    with Client(patient.url, timeout=2.0, retries=0) as client:
        info = client.upload_mesh((mesh.vertices, mesh.faces), epsilon=0.0029, progress=seen.append)
    assert info.triangles == 81920 and info.created
    assert seen and seen[0].status in ("queued", "building") and seen[-1].status == "done"
    with Client(patient.url) as client:
        with pytest.raises(BuildTimeout) as error:
            client.upload_mesh((mesh.vertices, mesh.faces), epsilon=0.0028, timeout=1.5)
        assert error.value.job_url is not None
        assert error.value.job.status in ("queued", "building")
        client.delete_mesh(error.value.job.mesh)  # withdraw it: the build stops


def test_job_urls_stay_on_the_service():
    """A job's absolute URL is followed only on the service's own origin (the API key
    goes with every request)."""
    base = "http://127.0.0.1:8000"
    assert job_path("abc", base) == "/v1/meshes/jobs/abc"
    assert job_path(f"{base}/v1/meshes/jobs/abc", base) == "/v1/meshes/jobs/abc"
    for elsewhere in ("http://evil.example/v1/meshes/jobs/abc", "http://127.0.0.1:9/x"):
        with pytest.raises(ClientError, match="not on the service"):
            job_path(elsewhere, base)
    with Client(base) as client, pytest.raises(ClientError, match="not on the service"):
        client.job("https://127.0.0.1:8000/v1/meshes/jobs/abc")  # another scheme


def test_a_rejected_upload_is_its_problem_alone(lazy):
    with Client(lazy.url) as client, pytest.raises(ProblemError) as error:
        client.upload_mesh(([[0, 0, 0], [1, 0, 0]], [[0, 1, 2]]))
    assert error.value.status == 422 and error.value.__cause__ is None


def test_mrdem_upload_shows_progress(lazy, tmp_path, capsys):
    path = tmp_path / "ball.stl"
    shapes.icosphere(4, radius=0.5).to_trimesh().export(path)
    assert upload_main([str(path), "--url", lazy.url, "--epsilon", "0.004"]) == 0
    out, err = capsys.readouterr()
    assert "ball.stl: " in out and "5,120 triangles" in out and "watertight" in out
    assert "level" in err and "nodes" in err  # the progress line
    assert "\r" not in err  # stderr is not a terminal here: plain lines
    missing = tmp_path / "nothing.stl"
    assert upload_main([str(missing), "--url", lazy.url, "--quiet"]) == 1
    assert "nothing.stl" in capsys.readouterr().out
