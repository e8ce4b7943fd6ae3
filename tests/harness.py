"""Test harness for the service and the clients: a real uvicorn process of the service on
a free loopback port with its store in a temporary directory (kernels load from the shared
Numba cache), and helpers for msgpack bodies and RFC 9457 problems."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import httpx
import numpy as np

from service.codecs import MSGPACK, decode, encode_msgpack

ROOT = Path(__file__).resolve().parents[1]
READY_TIMEOUT = 600.0  # a fresh kernel cache compiles everything first


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class ServiceProcess:
    """``python -m service`` with ``MRDEM_*`` settings; ``start`` waits for /readyz."""

    def __init__(self, data_dir: Path, **settings: str) -> None:
        self.data_dir, self.settings = Path(data_dir), settings
        self.proc: subprocess.Popen | None = None
        self.port = 0

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self.port}"

    def start(self) -> ServiceProcess:
        self.port = free_port()
        env = {
            **os.environ,
            "MRDEM_HOST": "127.0.0.1",
            "MRDEM_PORT": str(self.port),
            "MRDEM_DATA_DIR": str(self.data_dir),
            **{f"MRDEM_{k.upper()}": str(v) for k, v in self.settings.items()},
        }
        self.log_path = self.data_dir.parent / f"service-{self.port}.log"
        log = self.log = open(self.log_path, "wb")  # noqa: SIM115 -- open while it runs
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "service"], cwd=ROOT, env=env, stdout=log, stderr=log
        )
        deadline = time.monotonic() + READY_TIMEOUT
        while time.monotonic() < deadline:
            if self.proc.poll() is not None:
                log.close()
                raise RuntimeError(
                    f"service exited with {self.proc.returncode}:"
                    f" {self.log_path.read_text(errors='replace')[-2000:]}"
                )
            try:
                if httpx.get(f"{self.url}/readyz", timeout=2.0).status_code == 200:
                    return self
            except httpx.TransportError:
                pass
            time.sleep(0.2)
        self.stop()
        raise RuntimeError("service not ready in time")

    def kill(self) -> None:
        """SIGKILL: no shutdown, no flush."""
        self.proc.send_signal(signal.SIGKILL)
        self.proc.wait(10)
        self.log.close()

    def stop(self) -> None:
        if self.proc and self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(20)
            except subprocess.TimeoutExpired:
                self.kill()
        if self.proc:
            self.log.close()


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
