"""``POST /v1/contacts``: batched multiresolution contacts between posed meshes."""

from __future__ import annotations

import time

from fastapi import APIRouter, Depends, Request

from engine import Pose, find_contacts_batch
from engine.arguments import KERNELS, PRECISIONS

from ..auth import owner_of
from ..codecs import decode, respond
from ..errors import Unprocessable
from ..inputs import choice, field, flag, pose
from .meshes import known_mesh

router = APIRouter(prefix="/v1", tags=["contacts"])

IDENTITY = {"position": [0.0, 0.0, 0.0], "orientation": [1.0, 0.0, 0.0, 0.0]}


@router.post("/contacts")
async def contacts(request: Request, owner: str = Depends(owner_of)):
    """``{"pairs": [{"a": id, "pose_a": {position, orientation}, "b": id, "pose_b": …}],
    "kernel": "hybrid", "hierarchy": true, "precision": "float64"}`` → per pair the merged
    contacts ``points (k, 3)``, ``normals (k, 3)`` (unit, from A to B), ``overlaps (k,)``
    and the triangle pairs in contact ``pairs (m, 2)`` (face of A, face of B), world
    frame; with the summed counters."""
    state = request.app.state
    body = decode(await request.body(), request.headers.get("content-type"))
    items = field(body, "pairs")
    if not isinstance(items, list) or not items:
        raise Unprocessable("pairs must be a non-empty list of {a, pose_a, b, pose_b}")
    if len(items) > state.settings.max_pairs:
        most = state.settings.max_pairs
        raise Unprocessable(f"{len(items):,} pairs in one request; this service takes <= {most:,}")
    kernel = choice(body.get("kernel", "hybrid"), "kernel", KERNELS)
    hierarchy = flag(body.get("hierarchy", True), "hierarchy")
    precision = choice(body.get("precision", "float64"), "precision", PRECISIONS)
    trees: dict[str, object] = {}
    queries = []
    for i, item in enumerate(items):
        where = f"pairs[{i}]"
        ids = [field(item, side, where) for side in ("a", "b")]
        for side, mesh_id in zip(("a", "b"), ids, strict=True):
            if not isinstance(mesh_id, str):
                raise Unprocessable(f"{where}.{side} must be a mesh id (string)")
            if mesh_id not in trees:
                known_mesh(request, owner, mesh_id)
                trees[mesh_id] = await state.engine.run("load_tree", state.store.tree, mesh_id)
        poses = [
            Pose(*pose(item.get(f"pose_{side}", IDENTITY), f"{where}.pose_{side}"))
            for side in ("a", "b")
        ]
        queries.append((trees[ids[0]], poses[0], trees[ids[1]], poses[1]))
    start = time.perf_counter()
    found = await state.engine.run(
        "contacts",
        find_contacts_batch,
        queries,
        kernel=kernel,
        hierarchy=hierarchy,
        precision=precision,
        threads=state.settings.engine_threads,
    )
    seconds = time.perf_counter() - start
    stats = {
        "pairs": len(found),
        "contacts": sum(len(c.points) for c in found),
        "comparisons": sum(c.stats.comparisons for c in found),
        "iterative": sum(c.stats.iterative for c in found),
        "fallbacks": sum(c.stats.fallbacks for c in found),
        "sphere_pruned": sum(c.stats.sphere_pruned for c in found),
        "seconds": seconds,
    }
    m = state.metrics
    m.contact_pairs.inc(stats["pairs"])
    m.comparisons.inc(stats["comparisons"])
    m.iterative.inc(stats["iterative"])
    m.fallbacks.inc(stats["fallbacks"])
    results = [
        {"points": c.points, "normals": c.normals, "overlaps": c.overlaps, "pairs": c.pairs}
        for c in found
    ]
    return respond(request, {"results": results, "stats": stats})
