"""``/v1/meshes``: upload (a file or vertices and faces), list, inspect, delete, and the
surrogate triangles of one tree level.

An upload is repaired unless ``strict`` (duplicate vertices merged, faces with a repeated
index or zero area dropped, unreferenced vertices dropped; ``repair`` in the answer says
what changed). Its id is the content id of the repaired mesh, ε, branching and the tree
format. A tree already stored is reused (201, or 200 when this owner has the mesh);
otherwise the upload becomes a build job (:mod:`service.builds`) and waits up to
``MRDEM_BUILD_WAIT`` seconds (less when the query parameter ``wait`` asks for less): 201/200
with the facts if the build finished, a problem if it failed, else **202** with
``Location: /v1/meshes/jobs/{job}`` and the job's status.
"""

from __future__ import annotations

import io
from pathlib import PurePath
from typing import Annotated

import numpy as np
from fastapi import APIRouter, Query, Request
from fastapi.responses import Response
from pydantic import ValidationError

from engine import InvalidMeshError, Mesh, load_mesh, size_epsilon

from ..builds import content_id, mesh_facts
from ..codecs import respond
from ..deps import Banks, Builds, Config, Engine, Owner, Storage, validated
from ..errors import (
    BadRequest,
    Conflict,
    NotFound,
    ServiceError,
    Unavailable,
    Unprocessable,
    invalid,
)
from ..models import (
    BuildJob,
    MeshFacts,
    MeshForm,
    MeshList,
    MeshUpload,
    SurrogateLevel,
)
from ..openapi import documented
from ..store import ACTIVE
from .jobs import POLL_AFTER, job_location, job_view

router = APIRouter(prefix="/v1/meshes", tags=["meshes"])

FILE_TYPES = ("stl", "obj", "ply", "off", "glb", "gltf")
STRICT_ADVICE = "send strict=false (the default) to have them repaired"
MESH_FILE = {
    "type": "object",
    "required": ["file"],
    "properties": {
        "file": {"type": "string", "format": "binary", "description": "STL, OBJ, PLY, OFF, GLB"},
        "file_type": {
            "type": "string",
            "enum": list(FILE_TYPES),
            "description": "default: the file name's suffix",
        },
        **MeshForm.model_json_schema()["properties"],  # epsilon, branching, strict
    },
}


@router.post(
    "",
    summary="Upload a mesh (file or arrays); its surrogate tree is built",
    **documented(
        {
            200: (MeshFacts, "This API key had the mesh already"),
            201: (MeshFacts, "The mesh, its tree built and stored"),
            202: (BuildJob, "The tree is still being built: poll Location"),
        },
        (400, 401, 406, 409, 413, 415, 422, 503),
        body=MeshUpload,
        multipart=MESH_FILE,
    ),
)
async def upload_mesh(
    request: Request,
    owner: Owner,
    settings: Config,
    store: Storage,
    engine: Engine,
    builds: Builds,
    wait: Annotated[
        float | None,
        Query(
            ge=0,
            allow_inf_nan=False,
            description="seconds to wait for the build (at most"
            " MRDEM_BUILD_WAIT); a client sets it below its read timeout",
        ),
    ] = None,
):
    """A mesh file as multipart ``file`` (STL, OBJ, PLY, OFF, GLB; optional form fields
    ``epsilon``, ``branching``, ``strict``, ``file_type``), or a JSON/msgpack body
    ``{vertices (V, 3), faces (F, 3), epsilon?, branching?, strict?}``. 201 with the facts
    (200 when this owner has the mesh already) once its tree is stored; 202 with
    ``Location`` of the build job when the build takes longer than the wait: the query
    parameter ``wait`` (seconds, >= 0), at most ``MRDEM_BUILD_WAIT``."""
    wait = settings.build_wait if wait is None else min(settings.build_wait, wait)
    media = request.headers.get("content-type", "").split(";")[0].strip().lower()
    if media == "multipart/form-data":
        data, file_type, options = await _from_form(request, settings.max_body_bytes)
        mesh = await engine.run(
            "load_mesh", _repaired, load_mesh, io.BytesIO(data), file_type, options["strict"]
        )
    else:
        raw = await request.body()
        upload = await engine.io(validated, MeshUpload, raw, media)
        options = {"epsilon": upload.epsilon, "branching": upload.branching}
        options = {k: v for k, v in options.items() if v is not None}
        options["strict"] = upload.strict
        if len(upload.faces) > settings.max_triangles:
            raise _too_many(len(upload.faces), settings.max_triangles)
        mesh = await engine.run(
            "repair", _repaired, Mesh, upload.vertices, upload.faces, upload.strict
        )
        del upload
    if mesh.n_faces > settings.max_triangles:
        raise _too_many(mesh.n_faces, settings.max_triangles)
    epsilon, branching, mesh_id = await engine.run("mesh_id", _identify, mesh, options)
    extra = {"repair": mesh.repair.summary(), "epsilon_given": options.get("epsilon") is not None}
    facts = await engine.io(store.mesh, owner, mesh_id)
    if facts is not None:
        return await engine.io(
            respond, request, MeshFacts(**{**facts, "repair": extra["repair"]}), 200
        )
    if await engine.io(store.has_tree, mesh_id):  # built for another owner or a scene
        try:
            tree = await engine.run("load_tree", store.tree, mesh_id)
        except FileNotFoundError:  # its last owner deleted it just now: build it again
            pass
        else:
            facts = await engine.run(
                "mesh_facts", mesh_facts, mesh_id, mesh, tree, epsilon, branching
            )
            facts = {**facts, **extra}
            created = await engine.io(store.add_mesh, owner, mesh_id, facts)
            if created is not None:  # None: the tree file went meanwhile: build it again
                if not created:
                    facts = await engine.io(store.mesh, owner, mesh_id)
                return await engine.io(
                    respond, request, MeshFacts(**facts), 201 if created else 200
                )
    spec = {
        "epsilon": epsilon,
        "branching": branching,
        "triangles": mesh.n_faces,
        "vertices": mesh.n_vertices,
    }
    submitted = await engine.run("submit_build", builds.submit, owner, mesh, mesh_id, spec, extra)
    del mesh
    await builds.wait(submitted.job_id, wait)
    job = await engine.io(builds.job, submitted.job_id, owner)
    if job is None:  # this owner deleted the mesh while its upload waited
        raise Conflict(f"mesh {mesh_id!r} was deleted while its upload waited for the build")
    if job["status"] == "done":
        facts = await engine.io(store.mesh, owner, mesh_id)
        if facts is None:
            raise Conflict(f"mesh {mesh_id!r} was deleted while its upload waited for the build")
        facts = MeshFacts(**{**facts, "repair": extra["repair"]})
        return await engine.io(respond, request, facts, 201 if submitted.added else 200)
    if job["status"] == "failed":
        raise _failure(job)
    view = await engine.io(job_view, store, builds, owner, job)
    headers = {"Location": job_location(job["id"]), "Retry-After": POLL_AFTER}
    return await engine.io(respond, request, view, 202, headers)


@router.get(
    "",
    summary="This API key's meshes",
    **documented({200: (MeshList, "The meshes, oldest first")}, (401, 406)),
)
async def list_meshes(request: Request, owner: Owner, store: Storage, engine: Engine):
    meshes = await engine.io(store.meshes, owner)
    return await engine.io(respond, request, MeshList(meshes=meshes))


@router.get(
    "/{mesh_id}",
    summary="A mesh's facts",
    **documented({200: (MeshFacts, "The mesh")}, (401, 404, 406, 422)),
)
async def get_mesh(mesh_id: str, request: Request, owner: Owner, store: Storage, engine: Engine):
    facts = MeshFacts(**await known_mesh(engine, store, owner, mesh_id))
    return await engine.io(respond, request, facts)


@router.delete(
    "/{mesh_id}",
    status_code=204,
    summary="Forget a mesh (or withdraw its upload while it builds)",
    **documented({204: (None, "Forgotten")}, (401, 404, 422)),
)
async def delete_mesh(
    mesh_id: str, owner: Owner, store: Storage, engine: Engine, builds: Builds, banks: Banks
):
    """Forget the mesh; while its tree is still being built, withdraw this owner's upload
    (the job is then gone for this owner, and stops when nobody else waits for it)."""
    if await engine.run("delete_mesh", store.delete_mesh, owner, mesh_id):
        banks.forget(mesh_id)
    elif not await engine.run("leave_job", builds.leave, owner, mesh_id):
        raise NotFound(f"no mesh {mesh_id!r}")
    return Response(status_code=204)


@router.get(
    "/{mesh_id}/surrogates",
    summary="The surrogate triangles of one tree level",
    **documented({200: (SurrogateLevel, "The level's nodes")}, (401, 404, 406, 422)),
)
async def surrogates(
    mesh_id: str,
    request: Request,
    owner: Owner,
    store: Storage,
    engine: Engine,
    level: Annotated[int, Query(ge=0, description="0: the root")] = 0,
):
    """The nodes of one tree level (0: the root): ``triangles (k, 3, 3)``, ``epsilon (k,)``,
    ``leaf (k,)`` (original triangles at that level)."""
    facts = await known_mesh(engine, store, owner, mesh_id)
    if not level < facts["levels"]:
        raise Unprocessable(f"level must be in 0 … {facts['levels'] - 1}, got {level}")
    tree = await engine.run("load_tree", store.tree, mesh_id)
    nodes = np.flatnonzero(tree.level == level)
    answer = SurrogateLevel(
        id=mesh_id,
        level=level,
        levels=facts["levels"],
        triangles=tree.triangles[nodes],
        epsilon=tree.epsilon[nodes],
        leaf=(tree.face[nodes] >= 0).tolist(),
    )
    return await engine.io(respond, request, answer)


async def known_mesh(engine, store, owner: str, mesh_id: str) -> dict:
    """:func:`known` off the event loop."""
    return await engine.io(known, store, owner, mesh_id)


def known(store, owner: str, mesh_id: str) -> dict:
    """The facts of ``owner``'s mesh, or 404 (which names the build job when the mesh's
    tree is still being built); reads the store."""
    facts = store.mesh(owner, mesh_id)
    if facts is None:
        pending = [j for j in store.jobs(owner, ACTIVE) if j["mesh"] == mesh_id]
        if pending:
            where = job_location(pending[0]["id"])
            raise NotFound(
                f"no mesh {mesh_id!r} yet: its tree is being built (GET {where})", job=where
            )
        raise NotFound(f"no mesh {mesh_id!r}")
    return facts


def _too_many(triangles: int, limit: int) -> Unprocessable:
    return Unprocessable(f"mesh has {triangles:,} triangles; this service takes <= {limit:,}")


async def _from_form(request: Request, limit: int) -> tuple[bytes, str, dict]:
    """The file's bytes, its format and the form's options (``epsilon``, ``branching``,
    ``strict``)."""
    try:
        form = await request.form(max_files=1, max_fields=8, max_part_size=limit)
    except ServiceError:  # e.g. the body limit, raised while the form streams in
        raise
    except Exception as exc:  # the multipart parser's own errors: a malformed body
        raise BadRequest(f"malformed multipart body: {exc}") from None
    try:
        upload = form.get("file")
        if upload is None or isinstance(upload, str):
            raise Unprocessable("multipart upload needs a 'file' part")
        suffix = PurePath(upload.filename or "").suffix.lower().lstrip(".")
        file_type = (form.get("file_type") or suffix or "").lower()
        if file_type not in FILE_TYPES:
            raise Unprocessable(
                f"cannot tell the format of {upload.filename!r}: name the file *.stl, *.obj,"
                " *.ply, *.off, *.glb or *.gltf, or send a 'file_type' field (one of"
                f" {', '.join(FILE_TYPES)})"
            )
        data = await upload.read()
        if not data:
            raise Unprocessable(f"the uploaded file {upload.filename!r} is empty")
        fields = {
            k: form[k] for k in ("epsilon", "branching", "strict") if form.get(k) not in (None, "")
        }
        try:
            chosen = MeshForm.model_validate(fields)
        except ValidationError as error:
            raise invalid(error) from None
        options = {k: v for k, v in chosen.model_dump().items() if v is not None}
    finally:
        await form.close()  # the spooled temporary file of the part
    return data, file_type, options


def _repaired(make, *args) -> Mesh:
    """``make(*args, strict=strict)`` (``Mesh`` or ``load_mesh``; the last argument is
    ``strict``). A strict mesh that only needs repair gets a 422 whose detail says what
    and how to have it repaired; one that cannot be used either way gets the reason."""
    *args, strict = args
    try:
        return make(*args, strict=strict)
    except InvalidMeshError as exc:
        if not strict:
            raise
        for arg in args:  # rewind a stream for the second reading
            if hasattr(arg, "seek"):
                arg.seek(0)
        make(*args, strict=False)  # raises when repair cannot save it either
        raise Unprocessable(f"{str(exc).rstrip(' .;')}; {STRICT_ADVICE}") from None


def _identify(mesh: Mesh, options: dict) -> tuple[float, int, str]:
    """``(epsilon, branching, mesh id)`` of an upload: ε as given (> 0) or the size
    default (:func:`engine.size_epsilon`: the engine's one rule), branching in 2 … 64
    (default 8)."""
    epsilon = options.get("epsilon")
    epsilon = size_epsilon(mesh) if epsilon is None else float(epsilon)
    branching = int(options.get("branching", 8))
    return epsilon, branching, content_id(mesh, epsilon, branching)


def _failure(job: dict) -> ServiceError:
    """The problem answering an upload whose build failed while it waited."""
    where = job_location(job["id"])
    detail = f"{job['error']} (job {where})"
    cls = {"engine": Unprocessable, "memory": Unavailable, "cancelled": Conflict}.get(
        job["cause"], ServiceError
    )
    return cls(detail, job=where, cause=job["cause"])
