"""Test harness for the service and the clients: a real uvicorn process of the service on
a free loopback port with its store in a temporary directory (kernels load from the shared
Numba cache; :mod:`mrdem_common.serving` starts it), and helpers for msgpack bodies and RFC 9457
problems."""

from __future__ import annotations

import time
from pathlib import Path

import httpx
import numpy as np

from mrdem_common import serving
from service.codecs import MSGPACK, decode, encode_msgpack

ROOT = Path(__file__).resolve().parents[1]
READY_TIMEOUT = 600.0  # a fresh kernel cache compiles everything first


class ServiceProcess(serving.ServiceProcess):
    """``python -m service`` from the repository root with ``MRDEM_*`` ``settings`` (by field
    name: ``build_wait="0"``), its log next to ``data_dir`` (``log_path``); ``start`` waits
    for /readyz and raises :class:`mrdem_common.serving.ServiceStartError` with the log's tail."""

    def __init__(self, data_dir: Path, **settings: str) -> None:
        super().__init__(
            data_dir,
            settings=settings,
            cwd=ROOT,
            log_dir=Path(data_dir).parent,
            ready_timeout=READY_TIMEOUT,
        )


def tetrahedron() -> dict:
    return {
        "vertices": [[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]],
        "faces": [[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]],
    }


def post_msgpack(client: httpx.Client, path: str, payload, **kwargs) -> httpx.Response:
    return client.post(
        path,
        content=encode_msgpack(payload),
        headers={"content-type": MSGPACK, "accept": MSGPACK},
        **kwargs,
    )


def msgpack_body(response: httpx.Response):
    assert response.headers["content-type"] == MSGPACK
    return decode(response.content, MSGPACK)


def assert_problem(response: httpx.Response, status: int, detail: str = "") -> dict:
    """An RFC 9457 problem with ``status`` whose detail contains ``detail``."""
    assert response.status_code == status, response.text
    assert response.headers["content-type"].startswith("application/problem+json")
    body = response.json()
    assert body["status"] == status and body["title"] and body["detail"]
    assert detail.lower() in body["detail"].lower(), body["detail"]
    return body


def as_array(values) -> np.ndarray:
    return np.asarray(values, dtype=float)


def poll_job(client: httpx.Client, location: str, timeout: float = 120.0) -> dict:
    """GET a build job until it is ``done`` or ``failed``; every status seen, in order, is
    in the returned job's ``seen`` list of ``(status, levels, nodes)``."""
    seen = []
    deadline = time.monotonic() + timeout
    while True:
        response = client.get(location)
        assert response.status_code == 200, response.text
        job = response.json()
        seen.append((job["status"], job["progress"]["levels"], job["progress"]["nodes"]))
        if job["status"] in ("done", "failed"):
            return {**job, "seen": seen}
        assert time.monotonic() < deadline, f"job not finished in {timeout} s: {job}"
        time.sleep(0.02)
