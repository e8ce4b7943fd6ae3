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

import numpy as np
from fastapi import APIRouter, Depends, Request
from fastapi.responses import Response

from engine import InvalidMeshError, Mesh, load_mesh, size_epsilon

from ..auth import owner_of
from ..builds import content_id, mesh_facts
from ..codecs import decode, respond
from ..errors import BadRequest, Conflict, NotFound, NotReady, ServiceError, Unprocessable
from ..inputs import array, field, flag, number
from ..store import ACTIVE
from .jobs import POLL_AFTER, job_location, job_view

router = APIRouter(prefix="/v1/meshes", tags=["meshes"])

FILE_TYPES = ("stl", "obj", "ply", "off", "glb", "gltf")
MAX_BRANCHING = 64
STRICT_ADVICE = "send strict=false (the default) to have them repaired"


@router.post("")
async def upload_mesh(request: Request, owner: str = Depends(owner_of)):
    """A mesh file as multipart ``file`` (STL, OBJ, PLY, OFF, GLB; optional form fields
    ``epsilon``, ``branching``, ``strict``, ``file_type``), or a JSON/msgpack body
    ``{vertices (V, 3), faces (F, 3), epsilon?, branching?, strict?}``. 201 with the facts
    (200 when this owner has the mesh already) once its tree is stored; 202 with
    ``Location`` of the build job when the build takes longer than the wait: the query
    parameter ``wait`` (seconds, >= 0; a client sets it below its read timeout), at most
    ``MRDEM_BUILD_WAIT``."""
    state = request.app.state
    wait = state.settings.build_wait
    if "wait" in request.query_params:
        asked = request.query_params["wait"]
        try:
            wait = min(wait, number(float(asked), "wait", 0.0))
        except ValueError:
            raise Unprocessable(f"wait must be a number of seconds >= 0, got {asked!r}") from None
    media = request.headers.get("content-type", "").split(";")[0].strip().lower()
    if media == "multipart/form-data":
        data, file_type, options = await _from_form(request)
        mesh = await state.engine.run(
            "load_mesh", _repaired, load_mesh, io.BytesIO(data), file_type, options["strict"]
        )
    else:
        body = decode(await request.body(), media)
        vertices = array(field(body, "vertices"), "vertices", (None, 3))
        faces = array(field(body, "faces"), "faces", (None, 3), integer=True)
        options = {k: body[k] for k in ("epsilon", "branching") if body.get(k) is not None}
        options["strict"] = flag(body.get("strict", False), "strict")
        _check_faces(vertices, faces, state.settings.max_triangles)
        mesh = await state.engine.run("repair", _repaired, Mesh, vertices, faces, options["strict"])
    limit = state.settings.max_triangles
    if mesh.n_faces > limit:
        raise Unprocessable(f"mesh has {mesh.n_faces:,} triangles; this service takes <= {limit:,}")
    epsilon, branching, mesh_id = await state.engine.run("mesh_id", _identify, mesh, options)
    extra = {"repair": mesh.repair.summary(), "epsilon_given": options.get("epsilon") is not None}
    facts = state.store.mesh(owner, mesh_id)
    if facts is not None:
        return respond(request, {**facts, "repair": extra["repair"]}, 200)
    if state.store.tree_path(mesh_id).exists():  # built for another owner (or a scene)
        try:
            tree = await state.engine.run("load_tree", state.store.tree, mesh_id)
        except FileNotFoundError:  # its last owner deleted it just now: build it again
            pass
        else:
            facts = await state.engine.run(
                "mesh_facts", mesh_facts, mesh_id, mesh, tree, epsilon, branching
            )
            facts = {**facts, **extra}
            created = state.store.add_mesh(owner, mesh_id, facts)
            if created is not None:  # None: the tree file went meanwhile: build it again
                return respond(
                    request,
                    facts if created else state.store.mesh(owner, mesh_id),
                    201 if created else 200,
                )
    spec = {
        "epsilon": epsilon,
        "branching": branching,
        "triangles": mesh.n_faces,
        "vertices": mesh.n_vertices,
    }
    submitted = await state.engine.run(
        "submit_build", state.builds.submit, owner, mesh, mesh_id, spec, extra
    )
    del mesh
    await state.builds.wait(submitted.job_id, wait)
    job = state.builds.job(submitted.job_id, owner)
    if job is None:  # this owner deleted the mesh while its upload waited
        raise Conflict(f"mesh {mesh_id!r} was deleted while its upload waited for the build")
    if job["status"] == "done":
        facts = state.store.mesh(owner, mesh_id)
        if facts is None:
            raise Conflict(f"mesh {mesh_id!r} was deleted while its upload waited for the build")
        return respond(
            request, {**facts, "repair": extra["repair"]}, 201 if submitted.added else 200
        )
    if job["status"] == "failed":
        raise _failure(job)
    location = job_location(job["id"])
    return respond(
        request,
        job_view(request, owner, job),
        202,
        headers={"Location": location, "Retry-After": POLL_AFTER},
    )


@router.get("")
async def list_meshes(request: Request, owner: str = Depends(owner_of)):
    return respond(request, {"meshes": request.app.state.store.meshes(owner)})


@router.get("/{mesh_id}")
async def get_mesh(mesh_id: str, request: Request, owner: str = Depends(owner_of)):
    return respond(request, known_mesh(request, owner, mesh_id))


@router.delete("/{mesh_id}", status_code=204)
async def delete_mesh(mesh_id: str, request: Request, owner: str = Depends(owner_of)):
    """Forget the mesh; while its tree is still being built, withdraw this owner's upload
    (the job is then gone for this owner, and stops when nobody else waits for it)."""
    state = request.app.state
    if await state.engine.run("delete_mesh", state.store.delete_mesh, owner, mesh_id):
        state.banks.forget(mesh_id)
    elif not await state.engine.run("leave_job", state.builds.leave, owner, mesh_id):
        raise NotFound(f"no mesh {mesh_id!r}")
    return Response(status_code=204)


@router.get("/{mesh_id}/surrogates")
async def surrogates(
    mesh_id: str, request: Request, level: int = 0, owner: str = Depends(owner_of)
):
    """The nodes of one tree level (0: the root): ``triangles (k, 3, 3)``, ``epsilon (k,)``,
    ``leaf (k,)`` (original triangles at that level)."""
    facts = known_mesh(request, owner, mesh_id)
    if not 0 <= level < facts["levels"]:
        raise Unprocessable(f"level must be in 0 … {facts['levels'] - 1}, got {level}")
    tree = await request.app.state.engine.run("load_tree", request.app.state.store.tree, mesh_id)
    nodes = np.flatnonzero(tree.level == level)
    return respond(
        request,
        {
            "id": mesh_id,
            "level": level,
            "levels": facts["levels"],
            "triangles": tree.triangles[nodes],
            "epsilon": tree.epsilon[nodes],
            "leaf": tree.face[nodes] >= 0,
        },
    )


def known_mesh(request: Request, owner: str, mesh_id: str) -> dict:
    """The facts of ``owner``'s mesh, or 404 (which names the build job when the mesh's
    tree is still being built)."""
    store = request.app.state.store
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


async def _from_form(request: Request) -> tuple[bytes, str, dict]:
    """The file's bytes, its format and the form's options (``epsilon``, ``branching``,
    ``strict``)."""
    limit = request.app.state.settings.max_body_bytes
    try:
        form = await request.form(max_files=1, max_fields=8, max_part_size=limit)
    except ServiceError:  # e.g. the body limit, raised while the form streams in
        raise
    except Exception as exc:  # the multipart parser's own errors: a malformed body
        raise BadRequest(f"malformed multipart body: {exc}") from None
    upload = form.get("file")
    if upload is None or isinstance(upload, str):
        raise Unprocessable("multipart upload needs a 'file' part")
    suffix = PurePath(upload.filename or "").suffix.lower().lstrip(".")
    file_type = (form.get("file_type") or suffix or "").lower()
    if file_type not in FILE_TYPES:
        raise Unprocessable(
            f"cannot tell the format of {upload.filename!r}: name the file *.stl, *.obj, *.ply,"
            f" *.off, *.glb or *.gltf, or send a 'file_type' field (one of {', '.join(FILE_TYPES)})"
        )
    data = await upload.read()
    if not data:
        raise Unprocessable(f"the uploaded file {upload.filename!r} is empty")
    options: dict = {}
    for name in ("epsilon", "branching"):
        if form.get(name) not in (None, ""):
            try:
                options[name] = float(form[name]) if name == "epsilon" else int(form[name])
            except ValueError:
                raise Unprocessable(f"{name} must be a number, got {form[name]!r}") from None
    strict = str(form.get("strict") or "false").strip().lower()
    if strict not in ("true", "false", "1", "0"):
        raise Unprocessable(f"strict must be true or false, got {form['strict']!r}")
    options["strict"] = strict in ("true", "1")
    return data, file_type, options


def _check_faces(vertices: np.ndarray, faces: np.ndarray, limit: int) -> None:
    if len(faces) > limit:
        raise Unprocessable(f"mesh has {len(faces):,} triangles; this service takes <= {limit:,}")
    if len(faces) and (faces.min() < 0 or faces.max() >= len(vertices)):
        bad = int(faces.max() if faces.max() >= len(vertices) else faces.min())
        raise Unprocessable(
            f"faces refer to vertex {bad} but there are {len(vertices)} vertices"
            f" (indices 0 … {len(vertices) - 1})"
        )


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
    epsilon = size_epsilon(mesh) if epsilon is None else number(epsilon, "epsilon", 0.0)
    if not epsilon > 0:
        raise Unprocessable(f"epsilon must be > 0, got {epsilon!r}")
    branching = number(options.get("branching", 8), "branching", 2, MAX_BRANCHING, integer=True)
    return epsilon, branching, content_id(mesh, epsilon, branching)


def _failure(job: dict) -> ServiceError:
    """The problem answering an upload whose build failed while it waited."""
    where = job_location(job["id"])
    detail = f"{job['error']} (job {where})"
    cls = {"engine": Unprocessable, "memory": NotReady, "cancelled": Conflict}.get(
        job["cause"], ServiceError
    )
    return cls(detail, job=where, cause=job["cause"])
