"""Retries against real misbehaving servers: 503 then success, nobody listening, and a
server that drops every connection after reading the request."""

from __future__ import annotations

import socket
import threading
import time

import pytest
import uvicorn
from starlette.applications import Starlette
from starlette.responses import JSONResponse
from starlette.routing import Route

from clients import Client, ProblemError, RemoteScene, ServiceUnreachable
from mrdem_common.serving import free_port


class Flaky:
    """A real HTTP server whose ``GET /v1/meshes`` answers 503 ``failures`` times
    (with ``Retry-After``), then 200."""

    def __init__(self, failures: int) -> None:
        self.failures, self.calls = failures, 0

        async def meshes(request):
            self.calls += 1
            if self.calls <= self.failures:
                problem = {"title": "Service Unavailable", "status": 503, "detail": "warming up"}
                return JSONResponse(
                    problem,
                    status_code=503,
                    headers={"Retry-After": "0.05"},
                    media_type="application/problem+json",
                )
            return JSONResponse({"meshes": []})

        app = Starlette(routes=[Route("/v1/meshes", meshes)])
        self.port = free_port()
        self.server = uvicorn.Server(
            uvicorn.Config(app, host="127.0.0.1", port=self.port, log_level="error")
        )
        self.thread = threading.Thread(target=self.server.run, daemon=True)

    def __enter__(self) -> Flaky:
        self.thread.start()
        deadline = time.monotonic() + 30
        while not self.server.started and time.monotonic() < deadline:
            time.sleep(0.01)
        return self

    def __exit__(self, *exc) -> None:
        self.server.should_exit = True
        self.thread.join(10)

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self.port}"


def test_503_then_success_is_retried_after_retry_after():
    with Flaky(failures=2) as server, Client(server.url, retries=3, wire="json") as client:
        start = time.monotonic()
        assert client.meshes() == []
        assert server.calls == 3
        assert time.monotonic() - start >= 0.1  # two waits of Retry-After: 0.05


def test_503_beyond_the_retries_raises_the_problem():
    with Flaky(failures=5) as server, Client(server.url, retries=1, wire="json") as client:
        with pytest.raises(ProblemError) as error:
            client.meshes()
        assert error.value.status == 503 and error.value.detail == "warming up"
        assert server.calls == 2


def test_nobody_listening():
    client = Client(f"http://127.0.0.1:{free_port()}", retries=2, backoff=0.01)
    with client, pytest.raises(ServiceUnreachable):
        client.meshes()


class Dropper:
    """Accepts connections, reads the request, closes without answering."""

    def __init__(self) -> None:
        self.sock = socket.socket()
        self.sock.bind(("127.0.0.1", 0))
        self.sock.listen(16)
        self.accepted = 0
        self.thread = threading.Thread(target=self._serve, daemon=True)
        self.thread.start()

    def _serve(self) -> None:
        while True:
            try:
                conn, _ = self.sock.accept()
            except OSError:
                return
            self.accepted += 1
            conn.recv(65536)
            conn.close()

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self.sock.getsockname()[1]}"


def test_a_dropped_connection_is_retried_only_for_repeatable_calls():
    dropper = Dropper()
    try:
        with Client(dropper.url, retries=2, backoff=0.01) as client:
            with pytest.raises(ServiceUnreachable):
                client.meshes()  # a read: safe to repeat
            assert dropper.accepted == 3
            with pytest.raises(ServiceUnreachable):
                RemoteScene(client, "some-scene", None).step(1)  # would step twice
            assert dropper.accepted == 4
    finally:
        dropper.sock.close()
