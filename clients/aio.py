"""The asyncio client (httpx.AsyncClient): the same calls as :class:`~clients.Client`,
awaited."""

from __future__ import annotations

import asyncio
import time
from collections.abc import Callable
from typing import Any

import httpx

from .base import ClientBase
from .calls import (
    Call,
    Expired,
    budget,
    build_failure,
    job_path,
    poll_delay,
    result,
)
from .errors import BuildTimeout, ProblemError, ServiceUnreachable
from .models import BuildJob, Contacts, MeshInfo, SceneState

__all__ = ["AsyncClient", "AsyncRemoteScene"]


class AsyncClient(ClientBase):
    """``async with AsyncClient(url) as client: await client.upload_mesh(...)``."""

    def __init__(
        self,
        base_url: str,
        api_key: str | None = None,
        timeout: float | None = 60.0,
        retries: int = 3,
        backoff: float = 0.25,
        wire: str = "msgpack",
        *,
        transport: httpx.AsyncBaseTransport | None = None,
    ) -> None:
        """The arguments of :class:`~clients.Client` (``transport`` an httpx async
        transport)."""
        super().__init__(base_url, api_key, timeout, retries, backoff, wire)
        self._http = httpx.AsyncClient(
            base_url=self.base_url, timeout=self.timeout, headers=self.headers, transport=transport
        )

    async def __aenter__(self) -> AsyncClient:
        return self

    async def __aexit__(self, *exc) -> None:
        await self.aclose()

    async def aclose(self) -> None:
        """Close the connections."""
        await self._http.aclose()

    async def _exchange(
        self, call: Call, deadline: float | None = None
    ) -> tuple[Any, httpx.Response]:
        """The decoded answer to ``call`` and the response, after the retries; every try
        and every pause before a retry end by ``deadline`` (``time.monotonic()``, None:
        no deadline), else :class:`~clients.calls.Expired`."""
        attempt = 0
        while True:
            timeout = budget(self.timeout, deadline)
            try:
                response = await self._http.request(
                    call.method, call.path, **self._arguments(call, timeout)
                )
            except httpx.TransportError as error:
                if deadline is not None and time.monotonic() >= deadline:
                    raise Expired from error
                delay = self.policy.delay(call, attempt, error)
                if delay is None:
                    raise ServiceUnreachable(f"{call.method} {call.path}: {error!r}") from error
            else:
                delay = self.policy.delay(call, attempt, None, response)
                if delay is None:
                    return result(response), response
            if deadline is not None and time.monotonic() + delay >= deadline:
                raise Expired
            await asyncio.sleep(delay)
            attempt += 1

    async def _send(self, call: Call) -> tuple[Any, int]:
        payload, response = await self._exchange(call)
        return payload, response.status_code

    async def upload_mesh(
        self,
        source,
        epsilon: float | None = None,
        branching: int | None = None,
        *,
        strict: bool | None = None,
        wait: bool = True,
        timeout: float | None = None,
        progress: Callable[[BuildJob], None] | None = None,
    ) -> MeshInfo | BuildJob:
        """:meth:`Client.upload_mesh`, awaited: waits for the tree unless ``wait=False``
        (polling the build job after a 202), ``BuildTimeout`` past ``timeout`` seconds,
        ``BuildFailed`` when the build fails; ``progress(job)`` with each job status."""
        deadline = None if timeout is None else time.monotonic() + timeout
        call = self._upload(source, epsilon, branching, strict)
        try:
            payload, response = await self._exchange(call, deadline)
        except ProblemError as error:
            failure = build_failure(error)
            if failure is None:
                raise
            raise failure from error
        except Expired:
            raise BuildTimeout(timeout, None) from None
        outcome = self._uploaded(payload, response)
        if isinstance(outcome, MeshInfo) or not wait:
            return outcome
        return await self._poll(outcome, deadline, timeout, progress)

    async def job(self, job: BuildJob | str) -> BuildJob:
        """The current status of a build job (its :class:`BuildJob`, URL or id)."""
        return await self._job(job)

    async def _job(self, job: BuildJob | str, deadline: float | None = None) -> BuildJob:
        url = job_path(job, self.base_url)
        payload, _ = await self._exchange(Call("GET", url), deadline)
        return BuildJob.from_payload(payload, url)

    async def wait_for_mesh(
        self,
        job: BuildJob | str,
        timeout: float | None = None,
        progress: Callable[[BuildJob], None] | None = None,
    ) -> MeshInfo:
        """:meth:`Client.wait_for_mesh`, awaited."""
        deadline = None if timeout is None else time.monotonic() + timeout
        if not isinstance(job, BuildJob):
            job = await self.job(job)
        return await self._poll(job, deadline, timeout, progress)

    async def _poll(self, job: BuildJob, deadline, timeout, progress) -> MeshInfo:
        polls = 0
        while True:
            if progress is not None:
                progress(job)
            mesh = self._settled(job)
            if mesh is not None:
                return mesh
            delay = poll_delay(polls)
            if deadline is not None:
                left = deadline - time.monotonic()
                if left <= 0:
                    raise BuildTimeout(timeout, job.url, job)
                delay = min(delay, left)
            await asyncio.sleep(delay)
            polls += 1
            try:
                job = await self._job(job, deadline)
            except Expired:
                raise BuildTimeout(timeout, job.url, job) from None

    async def mesh(self, mesh: MeshInfo | str) -> MeshInfo:
        """:meth:`Client.mesh`, awaited."""
        payload, _ = await self._send(Call("GET", f"/v1/meshes/{getattr(mesh, 'id', mesh)}"))
        return self._mesh(payload, 200)

    async def meshes(self) -> list[MeshInfo]:
        """:meth:`Client.meshes`, awaited."""
        payload, _ = await self._send(Call("GET", "/v1/meshes"))
        return [self._mesh(m, 200) for m in payload["meshes"]]

    async def delete_mesh(self, mesh: MeshInfo | str) -> None:
        """:meth:`Client.delete_mesh`, awaited."""
        await self._send(Call("DELETE", f"/v1/meshes/{getattr(mesh, 'id', mesh)}"))

    async def contacts(
        self,
        pairs,
        kernel: str = "hybrid",
        hierarchy: bool = True,
        precision: str | None = None,
    ) -> Contacts:
        """:meth:`Client.contacts`, awaited."""
        payload, _ = await self._send(self._contacts(pairs, kernel, hierarchy, precision))
        return self._found(payload)

    async def find_contacts(
        self,
        meshes,
        a,
        position_a,
        orientation_a,
        b,
        position_b,
        orientation_b,
        kernel: str = "hybrid",
        hierarchy: bool = True,
        precision: str | None = None,
    ) -> Contacts:
        """:meth:`Client.find_contacts`, awaited."""
        call = self._columnar(
            meshes,
            a,
            position_a,
            orientation_a,
            b,
            position_b,
            orientation_b,
            kernel,
            hierarchy,
            precision,
        )
        payload, _ = await self._send(call)
        return self._found(payload)

    async def create_scene(
        self,
        bodies,
        planes=None,
        gravity=None,
        dt: float | None = None,
        scheme: str | None = None,
        epsilon: float | None = None,
        contact_model: dict | None = None,
        kernel: str | None = None,
        max_halvings: int | None = None,
    ) -> AsyncRemoteScene:
        """:meth:`Client.create_scene`, awaited."""
        call = self._scene(
            bodies, planes, gravity, dt, scheme, epsilon, contact_model, kernel, max_halvings
        )
        payload, _ = await self._send(call)
        return AsyncRemoteScene(self, payload["id"], self._state(payload))


class AsyncRemoteScene:
    """:class:`~clients.RemoteScene`, awaited (``state`` is a method here: ``await
    scene.state()``)."""

    def __init__(self, client: AsyncClient, scene_id: str, state: SceneState) -> None:
        self.client, self.id, self.last = client, scene_id, state

    async def step(self, n: int = 1, dt: float | None = None) -> SceneState:
        """:meth:`RemoteScene.step <clients.RemoteScene.step>`, awaited."""
        payload, _ = await self.client._send(self.client._step(self.id, n, dt))
        self.last = self.client._state(payload)
        return self.last

    async def state(self) -> SceneState:
        """The scene's current state, read from the service."""
        payload, _ = await self.client._send(Call("GET", f"/v1/scenes/{self.id}"))
        self.last = self.client._state(payload)
        return self.last

    async def set_state(
        self, positions=None, orientations=None, velocities=None, angular_velocities=None
    ) -> SceneState:
        """:meth:`RemoteScene.set_state <clients.RemoteScene.set_state>`, awaited."""
        call = self.client._set_state(
            self.id, positions, orientations, velocities, angular_velocities
        )
        payload, _ = await self.client._send(call)
        self.last = self.client._state(payload)
        return self.last

    async def delete(self) -> None:
        """Delete the scene on the service."""
        await self.client._send(Call("DELETE", f"/v1/scenes/{self.id}"))
