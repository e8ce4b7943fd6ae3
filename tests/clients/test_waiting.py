"""The client waits for tree builds: polling a 202's job with progress, its own deadline
(the build goes on), a failed build's reason (a real storage failure), the async client,
and ``mrdem upload``'s progress line — all against real servers."""

from __future__ import annotations

import asyncio
import shutil

import pytest
from harness import ServiceProcess

from clients import AsyncClient, BuildFailed, BuildJob, BuildTimeout, Client, MeshInfo
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
        with pytest.raises(BuildTimeout) as error:
            client.upload_mesh((mesh.vertices, mesh.faces), epsilon=0.03, timeout=0)
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


def test_a_failed_build_raises_with_the_services_reason(tmp_path):
    """The tree directory replaced by a file: builds fail for real. A small mesh fails
    within the service's wait (the upload's problem), a larger one after it (polled)."""
    process = ServiceProcess(tmp_path / "data", build_wait="0.5").start()
    trees = process.data_dir / "trees"
    try:
        with Client(process.url) as client:
            shutil.rmtree(trees)
            trees.write_bytes(b"")
            small, large = shapes.icosphere(1), shapes.icosphere(5)
            for mesh in (small, large):
                with pytest.raises(BuildFailed) as error:
                    client.upload_mesh((mesh.vertices, mesh.faces), epsilon=0.01)
                assert error.value.cause == "storage"
                assert "the tree could not be stored" in error.value.reason
                assert error.value.job_url.startswith("/v1/meshes/jobs/")
                job = client.job(error.value.job_url)
                assert job.status == "failed" and job.error in error.value.reason
    finally:
        process.stop()


def test_mrdem_upload_shows_progress(lazy, tmp_path, capsys):
    path = tmp_path / "ball.stl"
    shapes.icosphere(4, radius=0.5).to_trimesh().export(path)
    assert upload_main([str(path), "--url", lazy.url, "--epsilon", "0.004"]) == 0
    out, err = capsys.readouterr()
    assert "ball.stl: " in out and "5,120 triangles" in out and "watertight" in out
    assert "level" in err and "nodes" in err  # the progress line
    missing = tmp_path / "nothing.stl"
    assert upload_main([str(missing), "--url", lazy.url, "--quiet"]) == 1
    assert "nothing.stl" in capsys.readouterr().out
