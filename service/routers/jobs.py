"""``/v1/meshes/jobs``: the tree-build jobs of uploads (:mod:`service.builds`).

``GET /v1/meshes/jobs/{job}`` → 200 with the job (``status``: ``queued`` | ``building`` |
``done`` | ``failed``; ``progress``; ``error`` when failed; the mesh ``facts`` when done),
``Retry-After: 1`` while unfinished; 404 for an unknown job or one the caller does not
wait for. ``GET /v1/meshes/jobs?limit=100`` lists the caller's newest ``limit`` jobs
(1 … 1000, default 100), oldest first.
"""

from __future__ import annotations

from fastapi import APIRouter, Depends, Query, Request

from ..auth import owner_of
from ..codecs import respond
from ..errors import NotFound
from ..store import ACTIVE

router = APIRouter(prefix="/v1/meshes/jobs", tags=["meshes"])

MAX_LISTED = 1000
POLL_AFTER = "1"  # Retry-After of an unfinished job: a hint for pollers, in seconds


def job_location(job_id: str) -> str:
    return f"{router.prefix}/{job_id}"


def job_view(request: Request, owner: str, job: dict) -> dict:
    """The job as answered to ``owner`` (``job`` read with that owner)."""
    state = request.app.state
    spec, extra = job["spec"], job.get("extra", {})
    levels, nodes = job["levels"], job["nodes"]
    if job["status"] in ACTIVE:
        live = state.builds.progress(job["id"])
        if live is not None:
            levels, nodes = live
    body = {
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
        body["mesh_url"] = f"/v1/meshes/{job['mesh']}"
        body["facts"] = state.store.mesh(owner, job["mesh"])  # None once deleted
    return body


@router.get("")
async def list_jobs(
    request: Request,
    owner: str = Depends(owner_of),
    limit: int = Query(100, ge=1, le=MAX_LISTED),
):
    state = request.app.state
    jobs = [state.builds.job(j["id"], owner) for j in state.store.jobs(owner, limit=limit)]
    return respond(request, {"jobs": [job_view(request, owner, j) for j in jobs if j]})


@router.get("/{job_id}")
async def get_job(job_id: str, request: Request, owner: str = Depends(owner_of)):
    job = request.app.state.builds.job(job_id, owner)
    if job is None:
        raise NotFound(f"no build job {job_id!r}")
    headers = {"Retry-After": POLL_AFTER} if job["status"] in ACTIVE else None
    return respond(request, job_view(request, owner, job), headers=headers)
