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
from typing import Annotated

import numpy as np
from fastapi import APIRouter, Request

from ..codecs import respond, server_timing
from ..deps import Banks, Config, Engine, Meter, Owner, Splitter, Storage, body
from ..errors import Unprocessable
from ..models import (
    CONTACTS_QUERY,
    ColumnarContacts,
    ColumnarQuery,
    ContactStatsOut,
    PairContacts,
    PerPairContacts,
    PerPairQuery,
)
from ..openapi import SERVER_TIMING, documented
from ..search import find
from .meshes import known

router = APIRouter(prefix="/v1", tags=["contacts"])


@router.post(
    "/contacts",
    summary="Contacts of posed mesh pairs (batched)",
    **documented(
        {200: ([ColumnarContacts, PerPairContacts], "The contacts, in the request's layout")},
        (400, 401, 404, 406, 413, 415, 422),
        body=[ColumnarQuery, PerPairQuery],
        headers=SERVER_TIMING,
    ),
)
async def contacts(
    request: Request,
    owner: Owner,
    settings: Config,
    store: Storage,
    engine: Engine,
    banks: Banks,
    metrics: Meter,
    splitter: Splitter,
    query: Annotated[ColumnarQuery | PerPairQuery, body(CONTACTS_QUERY)],
):
    """The contacts of n posed pairs of uploaded meshes, columnar (CSR) or per pair."""
    columnar = isinstance(query, ColumnarQuery)
    meshes, columns = _columns(query)
    n = len(columns[0])
    if n > settings.max_pairs:
        most = settings.max_pairs
        raise Unprocessable(f"{n:,} pairs in one request; this service takes <= {most:,}")

    def search():  # one worker-thread call: the meshes' check, the search, the encoding
        for mesh_id in meshes:
            known(store, owner, mesh_id)
        start = time.perf_counter()
        options = (query.kernel, query.hierarchy, query.precision)

        def here(run: tuple) -> dict:  # in this process: its engine threads, its banks
            return find(meshes, run, *options, settings.engine_threads, store, banks)

        if splitter is not None and splitter.applies(n):  # across the cluster's nodes
            found = splitter.find(meshes, columns, *options, here=here)
        else:
            found = here(columns)
        found["stats"]["seconds"] = time.perf_counter() - start
        timing = {"search": found["stats"]["seconds"], **found.pop("timing", {})}
        stats = ContactStatsOut(**found.pop("stats"))
        # the engine's arrays as they are (typed and finite by construction): not validated
        if columnar:
            answer = ColumnarContacts.model_construct(**found, stats=stats)
        else:
            results = [PairContacts.model_construct(**r) for r in _split(found)]
            answer = PerPairContacts.model_construct(results=results, stats=stats)
        encoding = time.perf_counter()
        response = respond(request, answer)
        timing["encode"] = time.perf_counter() - encoding
        response.headers["Server-Timing"] = server_timing(timing)
        return stats, response

    stats, response = await engine.run("contacts", search)
    _count(metrics, stats)
    return response


def _columns(query: ColumnarQuery | PerPairQuery) -> tuple[list[str], tuple]:
    """The meshes and the six columns ``(a, pa, qa, b, pb, qb)`` of either layout."""
    if isinstance(query, ColumnarQuery):
        q = query
        return q.meshes, (q.a, q.position_a, q.orientation_a, q.b, q.position_b, q.orientation_b)
    meshes: dict[str, int] = {}
    a = [meshes.setdefault(p.a, len(meshes)) for p in query.pairs]
    b = [meshes.setdefault(p.b, len(meshes)) for p in query.pairs]
    pairs = query.pairs
    return list(meshes), (
        np.array(a, np.int64),
        np.array([p.pose_a.position for p in pairs]),
        np.array([p.pose_a.orientation for p in pairs]),
        np.array(b, np.int64),
        np.array([p.pose_b.position for p in pairs]),
        np.array([p.pose_b.orientation for p in pairs]),
    )


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


def _count(metrics, stats: ContactStatsOut) -> None:
    metrics.contact_pairs.inc(stats.pairs)
    metrics.comparisons.inc(stats.comparisons)
    metrics.iterative.inc(stats.iterative)
    metrics.fallbacks.inc(stats.fallbacks)
