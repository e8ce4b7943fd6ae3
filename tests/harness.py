"""Test harness for the service and the clients: the real app in this process behind
``httpx.ASGITransport`` (:class:`InProcessService`: most tests), a real uvicorn process of
the service on a free loopback port (:class:`ServiceProcess`: where the process is the
point — readiness, kill -9, the container command, subprocess clients, concurrency), each
with its store in a temporary directory (kernels load from the shared Numba cache), and
helpers for msgpack bodies and RFC 9457 problems."""

from __future__ import annotations

import asyncio
import subprocess
import sys
import threading
import time
from pathlib import Path

import httpx
import numpy as np

from mrdem_common import serving
from service.app import create_app
from service.codecs import MSGPACK, decode, encode_msgpack
from service.settings import Settings

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


class InProcessService:
    """The real app (:func:`service.app.create_app`, the real SQLite store in ``data_dir``)
    in this process: its lifespan runs in an event loop on a thread of its own, and
    requests reach it through ``httpx.ASGITransport`` inside that loop — from sync clients
    (:attr:`transport`) and async ones (:attr:`async_transport`) alike. ``settings`` by field
    name, as :class:`ServiceProcess` takes them. Kernels were warmed by ``mrdem warmup``
    before the tests; the app's own warm-up is off unless asked for."""

    url = "http://mrdem.test"

    def __init__(self, data_dir: Path, **settings) -> None:
        self.data_dir = Path(data_dir)
        settings.setdefault("warmup", False)
        self.settings = Settings(data_dir=self.data_dir, **settings)
        self.app = create_app(self.settings)
        self.loop = asyncio.new_event_loop()
        self._thread = threading.Thread(target=self.loop.run_forever, name="app", daemon=True)
        self._lifespan = None
        self.transport = _LoopTransport(self)
        self.async_transport = _AsyncLoopTransport(self)

    def start(self) -> InProcessService:
        self._thread.start()
        self._lifespan = self.app.router.lifespan_context(self.app)
        self.run(self._lifespan.__aenter__())
        return self

    def run(self, coroutine, timeout: float = 600.0):
        """``coroutine``'s result, run in the app's loop."""
        return asyncio.run_coroutine_threadsafe(coroutine, self.loop).result(timeout)

    def stop(self) -> None:
        if self._lifespan is not None:
            self.run(self._lifespan.__aexit__(None, None, None))
            self._lifespan = None
        self.loop.call_soon_threadsafe(self.loop.stop)
        self._thread.join(10)
        self.loop.close()

    def client(self, **kwargs) -> httpx.Client:
        return httpx.Client(base_url=self.url, transport=self.transport, **kwargs)

    def async_client(self, **kwargs) -> httpx.AsyncClient:
        return httpx.AsyncClient(base_url=self.url, transport=self.async_transport, **kwargs)

    def __enter__(self) -> InProcessService:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()


async def _asgi_call(app, request: httpx.Request, content: bytes) -> tuple:
    inner = httpx.ASGITransport(app=app)
    forwarded = httpx.Request(request.method, request.url, headers=request.headers, content=content)
    response = await inner.handle_async_request(forwarded)
    return response.status_code, response.headers.multi_items(), await response.aread()


class _LoopTransport(httpx.BaseTransport):
    """A sync transport: each request runs through ``httpx.ASGITransport`` in the app's
    loop."""

    def __init__(self, service: InProcessService) -> None:
        self.service = service

    def handle_request(self, request: httpx.Request) -> httpx.Response:
        content = request.read()
        status, headers, body = self.service.run(_asgi_call(self.service.app, request, content))
        return httpx.Response(status, headers=headers, content=body, request=request)


class _AsyncLoopTransport(httpx.AsyncBaseTransport):
    """The async transport: the same, awaited from the caller's loop."""

    def __init__(self, service: InProcessService) -> None:
        self.service = service

    async def handle_async_request(self, request: httpx.Request) -> httpx.Response:
        content = await request.aread()
        call = _asgi_call(self.service.app, request, content)
        future = asyncio.run_coroutine_threadsafe(call, self.service.loop)
        status, headers, body = await asyncio.wrap_future(future)
        return httpx.Response(status, headers=headers, content=body, request=request)


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


def server_timing(response: httpx.Response) -> dict[str, float]:
    """The answer's ``Server-Timing`` header as ``{name: milliseconds}``, in order."""
    entries = {}
    for entry in response.headers["server-timing"].split(","):
        name, duration = entry.strip().split(";dur=")
        entries[name] = float(duration)
    return entries


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


def run_readme_loop(url: str, monkeypatch, capsys) -> None:
    """The README's remote simulation loop (its ``python remote`` block), run as written
    against the service at ``url``, and what it must leave: 400 steps, the ball rolled and
    stopped, resting on the plane, its position printed."""
    import re

    readme = ROOT / "README.md"
    (block,) = re.findall(r"```python remote\n(.*?)```", readme.read_text(), re.S)
    monkeypatch.setenv("MRDEM_URL", url)
    namespace: dict = {}
    exec(compile(block, str(readme), "exec"), namespace)  # noqa: S102
    state = namespace["state"]
    assert state.steps == 400 and state.positions.shape == (2, 3)
    assert 0.3 < state.positions[0, 0] < 0.45  # it rolled, then was stopped
    assert abs(state.positions[0, 2] - 0.5) < 0.02  # resting on the plane
    assert "ball at" in capsys.readouterr().out


def near_pairs(mesh_ids, n: int, seed: int) -> dict:
    """``n`` pairs of the first mesh (a unit icosphere) with centres 2.0–2.06 apart: each
    pair near contact."""
    rng = np.random.default_rng(seed)
    d = rng.normal(size=(n, 3))
    d *= rng.uniform(2.0, 2.06, (n, 1)) / np.linalg.norm(d, axis=1, keepdims=True)
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    return {
        "meshes": mesh_ids,
        "a": np.zeros(n, np.int64),
        "b": np.zeros(n, np.int64),
        "position_a": np.zeros((n, 3)),
        "orientation_a": np.tile([1.0, 0.0, 0.0, 0.0], (n, 1)),
        "position_b": d,
        "orientation_b": q,
    }


def imported(code: str, watched: tuple[str, ...]) -> list[str]:
    """Run ``code`` in a fresh Python process from the repository root: the words it printed,
    then the names of ``watched`` (modules) it imported — a process's imports, measured
    where no other test has imported anything yet."""
    probe = f"{code}\nimport sys\nprint(' '.join(m for m in {watched!r} if m in sys.modules))"
    found = subprocess.run(
        [sys.executable, "-c", probe], cwd=ROOT, capture_output=True, text=True, timeout=120
    )
    assert found.returncode == 0, found.stderr
    return found.stdout.split()
