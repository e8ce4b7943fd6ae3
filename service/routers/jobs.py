"""``/v1/meshes/jobs``: the tree-build jobs of uploads (:mod:`service.builds`).

``GET /v1/meshes/jobs/{job}`` → 200 with the job (``status``: ``queued`` | ``building`` |
``done`` | ``failed``; ``progress``; ``error`` when failed; the mesh ``facts`` when done),
``Retry-After: 1`` while unfinished; 404 for an unknown job or one the caller does not
wait for. ``GET /v1/meshes/jobs?limit=100`` lists the caller's newest ``limit`` jobs
(1 … 1000, default 100), oldest first.
"""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Query, Request

from ..codecs import respond
from ..deps import Builds, Engine, Owner, Storage
from ..errors import NotFound
from ..models import BuildJob, JobList
from ..openapi import documented
from ..store import ACTIVE

router = APIRouter(prefix="/v1/meshes/jobs", tags=["meshes"])

MAX_LISTED = 1000
POLL_AFTER = "1"  # Retry-After of an unfinished job: a hint for pollers, in seconds


def job_location(job_id: str) -> str:
    return f"{router.prefix}/{job_id}"


def job_view(store, builds, owner: str, job: dict) -> BuildJob:
    """The job as answered to ``owner`` (``job`` read with that owner); reads the store."""
    spec, extra = job["spec"], job.get("extra", {})
    levels, nodes = job["levels"], job["nodes"]
    if job["status"] in ACTIVE:
        live = builds.progress(job["id"])
        if live is not None:
            levels, nodes = live
    view = {
        "id": job["id"],
        "status": job["status"],
        "mesh": job["mesh"],
        "location": job_location(job["id"]),
        "triangles": spec["triangles"],
        "vertices": spec["vertices"],
        "epsilon": spec["epsilon"],
        "branching": spec["branching"],
        "progress": {"levels": levels, "nodes": nodes},
        "seconds": job["seconds"],
        "error": job["error"],
        "cause": job["cause"],
        "created": job["created"],
        "updated": job["updated"],
        "repair": extra.get("repair"),
    }
    if job["status"] == "done":
        view["mesh_url"] = f"/v1/meshes/{job['mesh']}"
        view["facts"] = store.mesh(owner, job["mesh"])  # None once deleted
    return BuildJob(**view)


def _jobs(store, builds, owner: str, limit: int) -> JobList:
    jobs = [builds.job(j["id"], owner) for j in store.jobs(owner, limit=limit)]
    return JobList(jobs=[job_view(store, builds, owner, j) for j in jobs if j])


@router.get(
    "",
    summary="This API key's build jobs",
    **documented({200: (JobList, "The newest jobs, oldest first")}, (401, 406, 422)),
)
async def list_jobs(
    request: Request,
    owner: Owner,
    store: Storage,
    builds: Builds,
    engine: Engine,
    limit: Annotated[int, Query(ge=1, le=MAX_LISTED, description="newest jobs listed")] = 100,
):
    jobs = await engine.io(_jobs, store, builds, owner, limit)
    return await engine.io(respond, request, jobs)


def _job(store, builds, owner: str, job_id: str) -> BuildJob:
    job = builds.job(job_id, owner)
    if job is None:
        raise NotFound(f"no build job {job_id!r}")
    return job_view(store, builds, owner, job)


@router.get(
    "/{job_id}",
    summary="A build job",
    **documented({200: (BuildJob, "The job (Retry-After while unfinished)")}, (401, 404, 406, 422)),
)
async def get_job(
    job_id: str, request: Request, owner: Owner, store: Storage, builds: Builds, engine: Engine
):
    job = await engine.io(_job, store, builds, owner, job_id)
    headers = {"Retry-After": POLL_AFTER} if job.status in ACTIVE else None
    return await engine.io(respond, request, job, 200, headers)
