"""``POST /v1/contacts``: batched multiresolution contacts between posed meshes.

Two request layouts, each answered in kind:

* **columnar** (what the client sends; no per-pair work in Python): ``{"meshes": [id, …],
  "a": (n,), "b": (n,)`` indices into ``meshes``, ``"position_a": (n, 3), "orientation_a":
  (n, 4), "position_b", "orientation_b"}`` → ``{"offsets": (n + 1,), "points": (c, 3),
  "normals": (c, 3), "overlaps": (c,), "pair_offsets": (n + 1,), "pairs": (m, 2),
  "stats"}``: pair q owns rows ``offsets[q]:offsets[q + 1]`` (CSR);
* **per pair** (readable JSON): ``{"pairs": [{"a": id, "pose_a": {position, orientation},
  "b": id, "pose_b": …}]}`` → ``{"results": [{"points", "normals", "overlaps", "pairs"}],
  "stats"}``.

Options: ``kernel`` (exact, iterative, hybrid), ``hierarchy`` (false: the flat search),
``precision`` (float32, or float64: the default). Points and normals are in the world frame,
normals unit from A to B, overlaps ε_a + ε_b − d, pairs (face of A, face of B).
"""

from __future__ import annotations

import time

import numpy as np
from fastapi import APIRouter, Depends, Request

from engine import DEFAULT_PRECISION, Pose, find_contacts_batch
from engine.arguments import KERNELS, PRECISIONS
from engine.kernels.collision import batch as kb

from ..auth import owner_of
from ..codecs import decode, respond
from ..errors import Unprocessable
from ..inputs import QUATERNION_TOLERANCE, array, choice, field, flag, pose
from .meshes import known_mesh

router = APIRouter(prefix="/v1", tags=["contacts"])

IDENTITY = {"position": [0.0, 0.0, 0.0], "orientation": [1.0, 0.0, 0.0, 0.0]}


@router.post("/contacts")
async def contacts(request: Request, owner: str = Depends(owner_of)):
    state = request.app.state
    body = decode(await request.body(), request.headers.get("content-type"))
    if not isinstance(body, dict):
        raise Unprocessable("body must be an object")
    kernel = choice(body.get("kernel", "hybrid"), "kernel", KERNELS)
    hierarchy = flag(body.get("hierarchy", True), "hierarchy")
    precision = choice(body.get("precision", DEFAULT_PRECISION), "precision", PRECISIONS)
    columnar = "pairs" not in body
    meshes, query = _columnar(body) if columnar else _per_pair(field(body, "pairs"))
    n = len(query[0])
    if n > state.settings.max_pairs:
        most = state.settings.max_pairs
        raise Unprocessable(f"{n:,} pairs in one request; this service takes <= {most:,}")
    for mesh_id in meshes:
        known_mesh(request, owner, mesh_id)
    start = time.perf_counter()
    if hierarchy:
        bank = await state.engine.run("load_trees", state.banks.get, tuple(meshes), precision)
        a, pa, qa, b, pb, qb = query
        batch = await state.engine.run(
            "contacts",
            bank.find_contacts,
            a,
            pa,
            qa,
            b,
            pb,
            qb,
            kernel=kernel,
            threads=state.settings.engine_threads,
        )
        found = _from_batch(batch)
    else:
        trees = [await state.engine.run("load_tree", state.store.tree, m) for m in meshes]
        found = await state.engine.run("contacts", _flat, trees, query, kernel, precision)
    found["stats"]["seconds"] = time.perf_counter() - start
    _count(state.metrics, found["stats"])
    if columnar:
        return respond(request, found)
    return respond(request, {"results": _split(found), "stats": found["stats"]})


def _columnar(body: dict):
    meshes = field(body, "meshes")
    if not isinstance(meshes, list) or not meshes or not all(isinstance(m, str) for m in meshes):
        raise Unprocessable("meshes must be a non-empty list of mesh ids")
    a = array(field(body, "a"), "a", (None,), integer=True)
    n = len(a)
    if n == 0:
        raise Unprocessable("a must name at least one pair")
    b = array(field(body, "b"), "b", (n,), integer=True)
    for name, index in (("a", a), ("b", b)):
        if index.min() < 0 or index.max() >= len(meshes):
            raise Unprocessable(f"{name} holds indices outside meshes (0 … {len(meshes) - 1})")
    pa = array(field(body, "position_a"), "position_a", (n, 3))
    qa = _unit_rows(field(body, "orientation_a"), "orientation_a", n)
    pb = array(field(body, "position_b"), "position_b", (n, 3))
    qb = _unit_rows(field(body, "orientation_b"), "orientation_b", n)
    return meshes, (a, pa, qa, b, pb, qb)


def _unit_rows(value, name: str, n: int) -> np.ndarray:
    q = array(value, name, (n, 4))
    norms = np.linalg.norm(q, axis=1)
    bad = np.flatnonzero(np.abs(norms - 1.0) > QUATERNION_TOLERANCE)
    if len(bad):
        raise Unprocessable(
            f"{name}[{bad[0]}] must be a unit quaternion (w, x, y, z); its norm is"
            f" {norms[bad[0]]:.9g} (norms within {QUATERNION_TOLERANCE:g} of 1 are normalised)"
        )
    return q / norms[:, None]


def _per_pair(items):
    if not isinstance(items, list) or not items:
        raise Unprocessable("pairs must be a non-empty list of {a, pose_a, b, pose_b}")
    meshes: dict[str, int] = {}
    columns = [[] for _ in range(6)]
    for i, item in enumerate(items):
        where = f"pairs[{i}]"
        for side, (index, position, orientation) in zip(
            ("a", "b"), ((0, 1, 2), (3, 4, 5)), strict=True
        ):
            mesh_id = field(item, side, where)
            if not isinstance(mesh_id, str):
                raise Unprocessable(f"{where}.{side} must be a mesh id (string)")
            p, q = pose(item.get(f"pose_{side}", IDENTITY), f"{where}.pose_{side}")
            columns[index].append(meshes.setdefault(mesh_id, len(meshes)))
            columns[position].append(p)
            columns[orientation].append(q)
    a, pa, qa, b, pb, qb = (np.array(c) for c in columns)
    return list(meshes), (a, pa, qa, b, pb, qb)


def _from_batch(batch) -> dict:
    counts = batch.counts
    return {
        "offsets": batch.contact_offsets,
        "points": batch.points,
        "normals": batch.normals,
        "overlaps": batch.overlaps,
        "pair_offsets": batch.pair_offsets,
        "pairs": batch.pairs,
        "stats": {
            "pairs": len(batch),
            "contacts": len(batch.points),
            "comparisons": int(counts[:, kb.COUNT_COMPARISONS].sum()),
            "iterative": int(counts[:, kb.COUNT_ITERATIVE].sum()),
            "fallbacks": int(counts[:, kb.COUNT_FALLBACKS].sum()),
            "sphere_pruned": int(counts[:, kb.COUNT_SPHERES].sum()),
        },
    }


def _flat(trees, query, kernel: str, precision: str) -> dict:
    a, pa, qa, b, pb, qb = query
    found = find_contacts_batch(
        [(trees[a[i]], Pose(pa[i], qa[i]), trees[b[i]], Pose(pb[i], qb[i])) for i in range(len(a))],
        kernel=kernel,
        hierarchy=False,
        precision=precision,
    )

    def offsets(sizes):
        return np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64)

    return {
        "offsets": offsets([len(c.points) for c in found]),
        "points": np.concatenate([c.points for c in found]).reshape(-1, 3),
        "normals": np.concatenate([c.normals for c in found]).reshape(-1, 3),
        "overlaps": np.concatenate([c.overlaps for c in found]),
        "pair_offsets": offsets([len(c.pairs) for c in found]),
        "pairs": np.concatenate([c.pairs for c in found]).reshape(-1, 2),
        "stats": {
            "pairs": len(found),
            "contacts": int(sum(len(c.points) for c in found)),
            "comparisons": sum(c.stats.comparisons for c in found),
            "iterative": sum(c.stats.iterative for c in found),
            "fallbacks": sum(c.stats.fallbacks for c in found),
            "sphere_pruned": sum(c.stats.sphere_pruned for c in found),
        },
    }


def _split(found: dict) -> list[dict]:
    c, p = found["offsets"], found["pair_offsets"]
    return [
        {
            "points": found["points"][c[q] : c[q + 1]],
            "normals": found["normals"][c[q] : c[q + 1]],
            "overlaps": found["overlaps"][c[q] : c[q + 1]],
            "pairs": found["pairs"][p[q] : p[q + 1]],
        }
        for q in range(len(c) - 1)
    ]


def _count(metrics, stats: dict) -> None:
    metrics.contact_pairs.inc(stats["pairs"])
    metrics.comparisons.inc(stats["comparisons"])
    metrics.iterative.inc(stats["iterative"])
    metrics.fallbacks.inc(stats["fallbacks"])
