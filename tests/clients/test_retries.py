"""Retries against real misbehaving servers: 503 then success, nobody listening, a server
that drops every connection after reading the request, and a proxy in front of the real
service that drops the connection after the service has answered."""

from __future__ import annotations

import asyncio
import socket
import threading
import time

import httpx
import numpy as np
import pytest
import uvicorn
from starlette.applications import Starlette
from starlette.responses import JSONResponse
from starlette.routing import Route

from clients import AsyncClient, Client, ProblemError, RemoteScene, ServiceUnreachable
from clients.calls import Call, RetryPolicy
from engine import shapes
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


class Listener:
    """A socket on loopback whose connections a thread hands to ``handle`` in turn."""

    def __init__(self, handle) -> None:
        self.sock = socket.socket()
        self.sock.bind(("127.0.0.1", 0))
        self.sock.listen(16)
        self.handle = handle
        threading.Thread(target=self._serve, daemon=True).start()

    def _serve(self) -> None:
        while True:
            try:
                conn, _ = self.sock.accept()
            except OSError:
                return
            with conn:
                self.handle(conn)

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self.sock.getsockname()[1]}"


class Dropper(Listener):
    """Reads each request and closes without answering; keeps each request's
    ``Idempotency-Key`` (None without one)."""

    def __init__(self) -> None:
        self.accepted = 0
        self.keys: list[str | None] = []
        super().__init__(self._drop)

    def _drop(self, conn: socket.socket) -> None:
        self.accepted += 1
        head = conn.recv(65536).split(b"\r\n\r\n")[0].decode("latin-1").lower()
        fields = dict(line.split(": ", 1) for line in head.split("\r\n")[1:])
        self.keys.append(fields.get("idempotency-key"))


def test_a_dropped_connection_is_retried_for_repeatable_and_keyed_calls():
    """A read is sent again; so is a step, with the same Idempotency-Key each time (a new
    one per call), which the service answers with the first answer instead of stepping
    again (below, against the real service)."""
    dropper = Dropper()
    try:
        with Client(dropper.url, retries=2, backoff=0.01) as client:
            with pytest.raises(ServiceUnreachable):
                client.meshes()  # a read: safe to repeat
            assert dropper.accepted == 3 and dropper.keys == [None] * 3
            scene = RemoteScene(client, "some-scene", None)
            with pytest.raises(ServiceUnreachable):
                scene.step(1)
            with pytest.raises(ServiceUnreachable):
                scene.step(1)
            assert dropper.accepted == 9
            first, second = dropper.keys[3:6], dropper.keys[6:9]
            assert len(set(first)) == len(set(second)) == 1 and first[0] != second[0]
            assert first[0] is not None and len(first[0]) == 32
    finally:
        dropper.sock.close()


class DropOnce(Listener):
    """A proxy in front of a real service: each request goes to the service, and the first
    request to each of ``paths`` (matched by prefix and suffix) has its connection closed
    after the service answered, before the answer is passed on: the service acted, the
    client cannot tell."""

    def __init__(self, target: str, drop: list[tuple[str, str]]) -> None:
        self.target, self.drop = target, list(drop)
        self.forwarded: list[tuple[str, str, str | None, int]] = []
        self.upstream = httpx.Client(base_url=target, timeout=120)
        super().__init__(self._forward)

    def _forward(self, conn: socket.socket) -> None:
        data = b""
        while b"\r\n\r\n" not in data:
            data += conn.recv(65536)
        head, body = data.split(b"\r\n\r\n", 1)
        lines = head.decode("latin-1").split("\r\n")
        method, path, _ = lines[0].split(" ")
        headers = dict(line.split(": ", 1) for line in lines[1:])
        length = int({k.lower(): v for k, v in headers.items()}.get("content-length", 0))
        while len(body) < length:
            body += conn.recv(65536)
        headers = {k: v for k, v in headers.items() if k.lower() not in ("host", "connection")}
        answer = self.upstream.request(method, path, content=body, headers=headers)
        key = {k.lower(): v for k, v in headers.items()}.get("idempotency-key")
        self.forwarded.append((method, path, key, answer.status_code))
        rule = next(((a, b) for a, b in self.drop if path.startswith(a) and path.endswith(b)), None)
        if method == "POST" and rule is not None:
            self.drop.remove(rule)
            return  # closed without an answer
        out = [f"HTTP/1.1 {answer.status_code} {answer.reason_phrase}"]
        for name, value in answer.headers.items():
            if name.lower() not in ("content-length", "connection", "transfer-encoding"):
                out.append(f"{name}: {value}")
        out += [f"content-length: {len(answer.content)}", "connection: close", "", ""]
        conn.sendall("\r\n".join(out).encode("latin-1") + answer.content)

    def close(self) -> None:
        self.sock.close()
        self.upstream.close()


def _bodies(client) -> list[dict]:
    ball = client.upload_mesh(shapes.icosphere(1, radius=0.2), epsilon=0.01)
    return [
        {"mesh": ball, "position": [0.0, 0.0, 0.25], "velocity": [0.1, 0.0, 0.0]},
        {"mesh": ball, "position": [1.0, 0.0, 0.25]},
    ]


def _plane() -> list[dict]:
    return [{"point": [0, 0, 0], "normal": [0, 0, 1], "size": 4.0}]


def test_a_connection_dropped_after_the_service_acted_creates_and_steps_once(live_service):
    """The connection of the first create and the first step is dropped after the service
    created or stepped the scene; the client sends each again with its key and gets the
    first answer: one scene, stepped once, the same state as an undisturbed run."""
    proxy = DropOnce(live_service.url, [("/v1/scenes", "/v1/scenes"), ("/v1/scenes/", "/step")])
    try:
        with Client(proxy.url, retries=3, backoff=0.01) as client:
            scene = client.create_scene(_bodies(client), planes=_plane(), dt=1e-3)
            stepped = scene.step(4)
            assert stepped.steps == 4 and scene.state.steps == 4
        with Client(live_service.url) as direct:
            again = direct.create_scene(_bodies(direct), planes=_plane(), dt=1e-3).step(4)
        np.testing.assert_array_equal(stepped.positions, again.positions)
        creates = [f for f in proxy.forwarded if f[:2] == ("POST", "/v1/scenes")]
        steps = [f for f in proxy.forwarded if f[0] == "POST" and f[1].endswith("/step")]
        assert len(creates) == 2 and creates[0][2] == creates[1][2] is not None
        assert len(steps) == 2 and steps[0][2] == steps[1][2] is not None
    finally:
        proxy.close()


def test_the_async_client_sends_a_keyed_call_again_too(live_service):
    proxy = DropOnce(live_service.url, [("/v1/scenes/", "/step")])

    async def main():
        async with AsyncClient(proxy.url, retries=3, backoff=0.01) as client:
            ball = await client.upload_mesh(shapes.icosphere(1, radius=0.2), epsilon=0.01)
            bodies = [{"mesh": ball, "position": [0.0, 0.0, 0.25]}]
            scene = await client.create_scene(bodies, planes=_plane(), dt=1e-3)
            stepped = await scene.step(3)
            return stepped.steps, (await scene.state()).steps

    try:
        assert asyncio.run(main()) == (3, 3)
        steps = [f for f in proxy.forwarded if f[0] == "POST" and f[1].endswith("/step")]
        assert len(steps) == 2 and steps[0][2] == steps[1][2]
    finally:
        proxy.close()


def test_a_busy_key_is_waited_out_and_other_conflicts_are_not():
    """409 with ``Retry-After`` for a keyed call (its first try is still running on the
    service) is tried again after it; a 409 without it (a conflict of the request itself),
    or for a call without a key, is not."""
    client = Client("http://127.0.0.1:9", retries=2)
    keyed_call, plain_call = (
        client._step("s", 1, None),
        client._set_state("s", None, None, None, None),
    )
    busy = httpx.Response(409, headers={"retry-after": "1.5"})
    conflict = httpx.Response(409)
    assert "idempotency-key" in keyed_call.headers and not plain_call.headers
    assert client.policy.delay(keyed_call, 0, None, busy) == 1.5
    assert client.policy.delay(keyed_call, 0, None, conflict) is None
    assert client.policy.delay(plain_call, 0, None, busy) is None
    assert client.policy.delay(keyed_call, 2, None, busy) is None  # the retries used up
    client.close()


def test_the_pause_backs_off_with_jitter_and_honours_retry_after():
    """Without ``Retry-After`` the pause before retry k is between half of and all of
    backoff × 2^k, spread (clients failing together do not all return at once); with it,
    its value, at most 60 s; 429 and 503 are retried, other answers and a lost connection
    of a call that is not safe to repeat are not."""
    policy = RetryPolicy(retries=5, backoff=0.1)
    read = Call("GET", "/v1/meshes")
    once = Call("POST", "/v1/x", repeatable=False)
    for attempt in range(4):
        pauses = [policy.delay(read, attempt, httpx.ConnectError("refused")) for _ in range(200)]
        ceiling = 0.1 * 2**attempt
        assert all(ceiling / 2 <= p <= ceiling for p in pauses)
        assert np.std(pauses) > ceiling / 20
    assert policy.delay(read, 0, None, httpx.Response(503, headers={"retry-after": "7"})) == 7
    assert policy.delay(read, 0, None, httpx.Response(429, headers={"retry-after": "900"})) == 60
    for unusable in ("nan", "inf", "soon"):  # the backoff instead
        after = policy.delay(read, 0, None, httpx.Response(429, headers={"retry-after": unusable}))
        assert 0.05 <= after <= 0.1
    assert policy.delay(read, 0, None, httpx.Response(429)) is not None
    assert policy.delay(read, 0, None, httpx.Response(500)) is None
    assert policy.delay(once, 0, httpx.ReadError("lost")) is None
    assert policy.delay(once, 0, httpx.ConnectError("refused")) is not None  # never sent
    assert policy.delay(read, 0, httpx.ReadError("lost")) is not None
    assert policy.delay(read, 5, httpx.ConnectError("refused")) is None
