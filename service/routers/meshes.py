"""``/v1/meshes``: upload (a file or vertices and faces), list, inspect, delete, and the
surrogate triangles of one tree level."""

from __future__ import annotations

import hashlib
import io
from pathlib import PurePath

import numpy as np
from fastapi import APIRouter, Depends, Request
from fastapi.responses import Response

from engine import Mesh, build_tree, load_mesh
from engine.scene import DEFAULT_RELATIVE_EPSILON
from engine.tree import TREE_FORMAT

from ..auth import owner_of
from ..codecs import decode, respond
from ..errors import BadRequest, NotFound, ServiceError, Unprocessable
from ..inputs import array, field, number

router = APIRouter(prefix="/v1/meshes", tags=["meshes"])

FILE_TYPES = ("stl", "obj", "ply", "off", "glb", "gltf")
MAX_BRANCHING = 64


@router.post("")
async def upload_mesh(request: Request, owner: str = Depends(owner_of)):
    """A mesh file as multipart ``file`` (STL, OBJ, PLY, OFF, GLB; optional form fields
    ``epsilon``, ``branching``), or a JSON/msgpack body ``{vertices (V, 3), faces (F, 3),
    epsilon?, branching?}``. Builds and stores the surrogate tree; 201 the first time,
    200 when this owner has the same mesh with the same parameters."""
    state = request.app.state
    media = request.headers.get("content-type", "").split(";")[0].strip().lower()
    if media == "multipart/form-data":
        vertices, faces, options = await _from_form(request)
    else:
        body = decode(await request.body(), media)
        vertices = array(field(body, "vertices"), "vertices", (None, 3))
        faces = array(field(body, "faces"), "faces", (None, 3), integer=True)
        options = {k: body[k] for k in ("epsilon", "branching") if k in body}
    limit = state.settings.max_triangles
    if len(faces) > limit:
        raise Unprocessable(f"mesh has {len(faces):,} triangles; this service takes <= {limit:,}")
    if len(faces) and (faces.min() < 0 or faces.max() >= len(vertices)):
        bad = int(faces.max() if faces.max() >= len(vertices) else faces.min())
        raise Unprocessable(
            f"faces refer to vertex {bad} but there are {len(vertices)} vertices"
            f" (indices 0 … {len(vertices) - 1})"
        )
    mesh = Mesh(vertices, faces.astype(np.int32))
    epsilon = options.get("epsilon")
    if epsilon is None:
        spread = mesh.vertices - mesh.vertices.mean(axis=0)
        epsilon = DEFAULT_RELATIVE_EPSILON * 2 * float(np.sqrt((spread**2).sum(1).max()))
    epsilon = number(epsilon, "epsilon", 0.0)
    if epsilon <= 0:
        raise Unprocessable("epsilon must be > 0")
    branching = number(options.get("branching", 8), "branching", 2, MAX_BRANCHING, integer=True)
    mesh_id = _content_id(mesh, epsilon, branching)
    facts = state.store.mesh(owner, mesh_id)
    if facts is not None:
        return respond(request, facts, 200)
    if not state.store.tree_path(mesh_id).exists():
        tree = await state.engine.run("build_tree", build_tree, mesh, epsilon, branching)
        await state.engine.run("store_tree", state.store.put_tree, mesh_id, tree)
        state.metrics.meshes_built.inc()
    else:
        tree = await state.engine.run("load_tree", state.store.tree, mesh_id)
    facts = _facts(mesh_id, mesh, tree, epsilon, branching)
    created = state.store.add_mesh(owner, mesh_id, facts)
    return respond(request, facts, 201 if created else 200)


@router.get("")
async def list_meshes(request: Request, owner: str = Depends(owner_of)):
    return respond(request, {"meshes": request.app.state.store.meshes(owner)})


@router.get("/{mesh_id}")
async def get_mesh(mesh_id: str, request: Request, owner: str = Depends(owner_of)):
    return respond(request, known_mesh(request, owner, mesh_id))


@router.delete("/{mesh_id}", status_code=204)
async def delete_mesh(mesh_id: str, request: Request, owner: str = Depends(owner_of)):
    if not request.app.state.store.delete_mesh(owner, mesh_id):
        raise NotFound(f"no mesh {mesh_id!r}")
    request.app.state.banks.forget(mesh_id)
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
    """The facts of ``owner``'s mesh, or 404."""
    facts = request.app.state.store.mesh(owner, mesh_id)
    if facts is None:
        raise NotFound(f"no mesh {mesh_id!r}")
    return facts


async def _from_form(request: Request):
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
            " *.off or *.glb, or send a 'file_type' field"
        )
    data = await upload.read()
    if not data:
        raise Unprocessable(f"the uploaded file {upload.filename!r} is empty")
    mesh = await request.app.state.engine.run("load_mesh", load_mesh, io.BytesIO(data), file_type)
    options = {}
    for name in ("epsilon", "branching"):
        if form.get(name) not in (None, ""):
            try:
                options[name] = float(form[name]) if name == "epsilon" else int(form[name])
            except ValueError:
                raise Unprocessable(f"{name} must be a number, got {form[name]!r}") from None
    return mesh.vertices, mesh.faces.astype(np.int64), options


def _content_id(mesh: Mesh, epsilon: float, branching: int) -> str:
    digest = hashlib.sha256(f"mrdem-tree-{TREE_FORMAT}\0".encode())
    digest.update(np.ascontiguousarray(mesh.vertices, "<f8").tobytes())
    digest.update(np.ascontiguousarray(mesh.faces, "<i8").tobytes())
    digest.update(f"\0{epsilon!r}\0{branching}".encode())
    return digest.hexdigest()[:32]


def _facts(mesh_id: str, mesh: Mesh, tree, epsilon: float, branching: int) -> dict:
    stats = tree.stats
    closed = bool(mesh.is_watertight)
    return {
        "id": mesh_id,
        "triangles": int(mesh.n_faces),
        "vertices": int(mesh.n_vertices),
        "epsilon": epsilon,
        "branching": branching,
        "levels": int(stats.depth) + 1,
        "nodes": len(tree),
        "nodes_per_level": list(stats.nodes_per_level),
        "bounds": mesh.bounds.tolist(),
        "watertight": closed,
        "volume": float(mesh.volume) if closed else None,
    }
