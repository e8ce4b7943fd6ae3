"""Requests the clients send and how they read the answers, shared by :class:`Client`
and :class:`AsyncClient` (which differ only in how they wait).

Retries: a request that never reached the server (connection refused or timed out while
connecting) and a 429 or 503 answer are retried with exponential backoff, honouring
``Retry-After``; a connection lost after the request was sent is retried for calls that
are safe to repeat: reads, state overwrites, deletes, content-addressed uploads, contact
queries, and creating or stepping a scene, which carry an ``Idempotency-Key`` (a new one
per call, the same on each of its tries): the service answers a repeated key with the
first answer instead of creating or stepping again.
"""

from __future__ import annotations

import math
import os
import random
import time
import uuid
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import httpx
import numpy as np

from .codec import decode
from .errors import BuildFailed, ClientError, ProblemError
from .models import BuildJob, MeshInfo

__all__ = [
    "Call",
    "Expired",
    "build_failure",
    "budget",
    "columnar_call",
    "contacts_call",
    "failed_build",
    "job_path",
    "keyed",
    "poll_delay",
    "RetryPolicy",
    "scene_call",
    "upload_call",
]

RETRY_STATUS = (429, 503)
POLL_FIRST = 0.05  # seconds before the first poll of a build job, doubled up to POLL_MAX
POLL_MAX = 2.0
JOBS = "/v1/meshes/jobs"
NEVER_SENT = (httpx.ConnectError, httpx.ConnectTimeout, httpx.PoolTimeout)


@dataclass
class Call:
    method: str
    path: str
    payload: Any = None
    files: dict | None = None
    data: dict | None = None
    repeatable: bool = True  # safe to send again after a connection lost mid-request
    waits: bool = False  # an upload: tells the service how long it may wait (``wait``)
    headers: dict = field(default_factory=dict)  # sent with every try


def keyed(method: str, path: str, payload) -> Call:
    """A call that changes state, made safe to repeat by an ``Idempotency-Key`` of its
    own (sent with each try of it)."""
    key = {"idempotency-key": uuid.uuid4().hex}
    return Call(method, path, payload=payload, headers=key)


class Expired(Exception):
    """The caller's deadline passed before the service answered (internal: the client
    turns it into :class:`~clients.errors.BuildTimeout`)."""


def budget(timeout: float | None, deadline: float | None) -> float | None:
    """Seconds one request may take: the client's ``timeout`` (None: no limit), cut to
    what is left before ``deadline`` (``time.monotonic()``); :class:`Expired` when
    nothing is left."""
    if deadline is None:
        return timeout
    left = deadline - time.monotonic()
    if left <= 0:
        raise Expired
    return left if timeout is None else min(timeout, left)


def service_wait(request_timeout: float | None) -> dict:
    """The ``wait`` query parameter of an upload sent with ``request_timeout``: half of
    it (the rest is for the transfer and the repair), so that the service answers — 202
    with the build job, if need be — before the client stops reading."""
    if request_timeout is None:
        return {}
    return {"wait": f"{max(0.0, request_timeout / 2):.3f}"}


def mesh_id(value) -> str:
    return value.id if isinstance(value, MeshInfo) else str(value)


def upload_call(
    source, epsilon: float | None, branching: int | None, strict: bool | None = None
) -> Call:
    """``source``: a path to a mesh file, a ``trimesh.Trimesh`` (anything with
    ``vertices`` and ``faces``) or a ``(vertices, faces)`` pair. ``None`` options are left
    to the service's defaults."""
    given = (("epsilon", epsilon), ("branching", branching), ("strict", strict))
    options = {k: v for k, v in given if v is not None}
    if isinstance(source, str | os.PathLike):
        path = Path(source)
        data = {k: (str(v).lower() if isinstance(v, bool) else str(v)) for k, v in options.items()}
        files = {"file": (path.name, path.read_bytes())}
        return Call("POST", "/v1/meshes", files=files, data=data, waits=True)
    if hasattr(source, "vertices") and hasattr(source, "faces"):
        vertices, faces = source.vertices, source.faces
    else:
        vertices, faces = source
    payload = {
        "vertices": np.ascontiguousarray(vertices, np.float64),
        "faces": np.ascontiguousarray(faces, np.int64),
        **options,
    }
    return Call("POST", "/v1/meshes", payload=payload, waits=True)


def pose_payload(pose) -> dict:
    """A pose as ``{"position", "orientation"}``: from that dict, a ``(position,
    orientation)`` pair, or a position alone (identity orientation)."""
    if pose is None:
        return {"position": [0.0, 0.0, 0.0], "orientation": [1.0, 0.0, 0.0, 0.0]}
    if isinstance(pose, dict):
        return pose
    parts = list(pose)
    if len(parts) == 2 and np.size(parts[0]) == 3:
        return {"position": np.asarray(parts[0], float), "orientation": np.asarray(parts[1], float)}
    return {"position": np.asarray(parts, float), "orientation": [1.0, 0.0, 0.0, 0.0]}


def contacts_call(pairs, kernel: str, hierarchy: bool, precision: str | None) -> Call:
    """``pairs``: ``(a, pose_a, b, pose_b)`` tuples or ``{"a", "pose_a", "b", "pose_b"}``;
    sent in the service's columnar layout (one array per field). ``precision=None`` leaves
    the arithmetic to the service's default."""
    meshes: dict[str, int] = {}
    index = {"a": [], "b": []}
    poses = {k: [] for k in ("position_a", "orientation_a", "position_b", "orientation_b")}
    for pair in pairs:
        if isinstance(pair, dict):
            items = [pair.get(k) for k in ("a", "pose_a", "b", "pose_b")]
        else:
            items = list(pair)
        for side, mesh, pose in (("a", items[0], items[1]), ("b", items[2], items[3])):
            index[side].append(meshes.setdefault(mesh_id(mesh), len(meshes)))
            p = pose_payload(pose)
            poses[f"position_{side}"].append(p["position"])
            poses[f"orientation_{side}"].append(p["orientation"])
    payload = {
        "meshes": list(meshes),
        "a": np.array(index["a"], np.int64),
        "b": np.array(index["b"], np.int64),
        **{k: np.array(v, np.float64).reshape(len(v), -1) for k, v in poses.items()},
        "kernel": kernel,
        "hierarchy": hierarchy,
    }
    if precision is not None:
        payload["precision"] = precision
    return Call("POST", "/v1/contacts", payload=payload)


def columnar_call(meshes, a, position_a, orientation_a, b, position_b, orientation_b, options):
    """The columnar contacts request from arrays (no per-pair Python work)."""
    payload = {
        "meshes": [mesh_id(m) for m in meshes],
        "a": np.ascontiguousarray(a, np.int64),
        "b": np.ascontiguousarray(b, np.int64),
        "position_a": np.ascontiguousarray(position_a, np.float64),
        "orientation_a": np.ascontiguousarray(orientation_a, np.float64),
        "position_b": np.ascontiguousarray(position_b, np.float64),
        "orientation_b": np.ascontiguousarray(orientation_b, np.float64),
        **{k: v for k, v in options.items() if v is not None},  # None: the service's default
    }
    return Call("POST", "/v1/contacts", payload=payload)


def scene_call(bodies, **fields) -> Call:
    """``POST /v1/scenes``; ``bodies`` may name meshes by :class:`MeshInfo` or id."""
    out = []
    for body in bodies:
        body = dict(body)
        body["mesh"] = mesh_id(body["mesh"])
        out.append(body)
    payload = {"bodies": out, **{k: v for k, v in fields.items() if v is not None}}
    return keyed("POST", "/v1/scenes", payload)


def job_path(job: BuildJob | str, base_url: str | None = None) -> str:
    """The address of a build job: its :class:`BuildJob`, its URL or path, or its id. An
    absolute URL must have the origin of ``base_url`` (scheme, host, port): the API key
    is never sent to another server (:class:`ClientError` otherwise)."""
    url = job.url if isinstance(job, BuildJob) else str(job)
    if "://" in url:
        absolute, base = httpx.URL(url), httpx.URL(base_url or "")
        origin = (absolute.scheme, absolute.host, absolute.port)
        if base_url is None or origin != (base.scheme, base.host, base.port):
            raise ClientError(f"build job URL {url!r} is not on the service {base_url!r}")
        return absolute.raw_path.decode("ascii")
    return url if "/" in url else f"{JOBS}/{url}"


def poll_delay(polls: int) -> float:
    """Seconds before polling a build job again after ``polls`` polls: 0.05 s, doubled
    each time, at most 2 s."""
    return min(POLL_MAX, POLL_FIRST * 2**polls)


def build_failure(error: ProblemError) -> BuildFailed | None:
    """An upload's problem as :class:`BuildFailed` when it reports a failed build job
    (members ``job`` and ``cause``), else None."""
    job, cause = error.problem.get("job"), error.problem.get("cause")
    if not job or not cause:
        return None
    return BuildFailed(str(error.detail), str(cause), str(job))


def failed_build(response: httpx.Response) -> bool:
    """Whether an error answer reports a failed build job (a problem with ``job`` and
    ``cause``): such an upload is not retried by itself."""
    try:
        problem = decode(response.content, response.headers.get("content-type", ""))
    except (ValueError, TypeError):
        return False
    return isinstance(problem, dict) and bool(problem.get("job")) and bool(problem.get("cause"))


@dataclass(frozen=True)
class RetryPolicy:
    """When, and after how long, both clients send a call again: after a try that never
    reached the server (connection refused, connect timeout), or — for a call that is
    safe to repeat (:attr:`Call.repeatable`) — any transport error; after a 429 or 503
    answer (not a failed build's 503); after a 409 with ``Retry-After`` for a call with an
    ``Idempotency-Key`` (its first try still runs on the service). At most ``retries``
    times after the first try. The pause: the answer's ``Retry-After`` (capped at 60 s),
    else ``backoff`` × 2^attempt with jitter (between half of it and all of it), so that
    clients that failed together do not all come back at once."""

    retries: int
    backoff: float

    def delay(
        self,
        call: Call,
        attempt: int,
        error: Exception | None = None,
        response: httpx.Response | None = None,
    ) -> float | None:
        """Seconds to wait before trying ``call`` again after its try ``attempt`` (0-based)
        failed with the transport ``error`` or the answer ``response``; None: not again."""
        if attempt >= self.retries:
            return None
        if response is not None:
            status = response.status_code
            busy = status == 409 and "idempotency-key" in call.headers
            if busy and "retry-after" not in response.headers:
                return None
            if not busy and (status not in RETRY_STATUS or failed_build(response)):
                return None
            try:
                after = float(response.headers.get("retry-after", ""))
            except ValueError:
                after = math.nan
            if math.isfinite(after):  # not "inf" or "nan" either
                return min(max(after, 0.0), 60.0)
        elif not isinstance(error, NEVER_SENT) and not (
            call.repeatable and isinstance(error, httpx.TransportError)
        ):
            return None
        return self.backoff * 2**attempt * (0.5 + 0.5 * random.random())


def result(response: httpx.Response) -> Any:
    """The decoded body of a success, or the server's problem as :class:`ProblemError`."""
    media = response.headers.get("content-type", "")
    if response.is_success:
        return decode(response.content, media) if response.content else None
    try:
        problem = decode(response.content, media) if response.content else {}
    except ValueError:
        problem = {}
    if not isinstance(problem, dict):
        problem = {}
    raise ProblemError(
        response.status_code,
        str(problem.get("title", response.reason_phrase)),
        str(problem.get("detail", response.text[:500])),
        problem,
    )
