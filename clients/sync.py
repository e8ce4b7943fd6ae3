"""The blocking client (httpx)."""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any, Literal, overload

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

__all__ = ["Client", "RemoteScene"]


class Client(ClientBase):
    """A connection to an mrdem service; use as a context manager (or call :meth:`close`).

    >>> with Client("http://127.0.0.1:8000") as client:   # doctest: +SKIP
    ...     ball = client.upload_mesh("ball.stl", epsilon=0.01)
    """

    def __init__(
        self,
        base_url: str,
        api_key: str | None = None,
        timeout: float | None = 60.0,
        retries: int = 3,
        backoff: float = 0.25,
        wire: str = "msgpack",
        *,
        transport: httpx.BaseTransport | None = None,
    ) -> None:
        """``base_url`` of the service; ``api_key`` sent as a bearer token; ``timeout``
        seconds per request (None: none); ``retries`` after the first try and ``backoff``
        seconds, doubled per retry, with jitter (:class:`~clients.calls.RetryPolicy`);
        ``wire`` "msgpack" (default: arrays as typed binary) or "json"; ``transport`` an
        httpx transport (tests, proxies)."""
        super().__init__(base_url, api_key, timeout, retries, backoff, wire)
        self._http = httpx.Client(
            base_url=self.base_url, timeout=self.timeout, headers=self.headers, transport=transport
        )

    def __enter__(self) -> Client:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        """Close the connections."""
        self._http.close()

    def _exchange(self, call: Call, deadline: float | None = None) -> tuple[Any, httpx.Response]:
        """The decoded answer to ``call`` and the response, after the retries; every try
        and every pause before a retry end by ``deadline`` (``time.monotonic()``, None:
        no deadline), else :class:`~clients.calls.Expired`."""
        attempt = 0
        while True:
            timeout = budget(self.timeout, deadline)
            try:
                response = self._http.request(
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
            time.sleep(delay)
            attempt += 1

    def _send(self, call: Call) -> tuple[Any, int]:
        payload, response = self._exchange(call)
        return payload, response.status_code

    # ------------------------------------------------------------------ API
    @overload
    def upload_mesh(
        self,
        source,
        epsilon: float | None = ...,
        branching: int | None = ...,
        *,
        strict: bool | None = ...,
        wait: Literal[True] = ...,
        timeout: float | None = ...,
        progress: Callable[[BuildJob], None] | None = ...,
    ) -> MeshInfo: ...
    @overload
    def upload_mesh(
        self,
        source,
        epsilon: float | None = ...,
        branching: int | None = ...,
        *,
        strict: bool | None = ...,
        wait: Literal[False],
        timeout: float | None = ...,
        progress: Callable[[BuildJob], None] | None = ...,
    ) -> MeshInfo | BuildJob: ...
    def upload_mesh(
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
        """Upload a mesh file path, a ``trimesh.Trimesh`` or ``(vertices, faces)`` and
        wait for its surrogate tree; returns its :class:`MeshInfo` (``created`` False when
        the service had it; ``repair`` what the service's repair changed).

        ``strict=True``: the service rejects a mesh that needs repair (422,
        :class:`ProblemError`) instead of repairing it. The service answers 202 when the
        tree build outlasts its own short wait; then this polls the build job (backing
        off from 0.05 s to 2 s) until it is done, calling ``progress(job)`` with each
        :class:`BuildJob` seen. ``timeout``: seconds to wait in all (None: as long as the
        build takes) — past it, :class:`BuildTimeout` with the job's URL (the build goes
        on; :meth:`wait_for_mesh` resumes). A failed build raises :class:`BuildFailed`
        with the service's reason. ``wait=False`` returns the :class:`BuildJob` of a 202
        at once."""
        deadline = None if timeout is None else time.monotonic() + timeout
        call = self._upload(source, epsilon, branching, strict)
        try:
            payload, response = self._exchange(call, deadline)
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
        return self._poll(outcome, deadline, timeout, progress)

    def job(self, job: BuildJob | str) -> BuildJob:
        """The current status of a build job (its :class:`BuildJob`, URL or id)."""
        return self._job(job)

    def _job(self, job: BuildJob | str, deadline: float | None = None) -> BuildJob:
        url = job_path(job, self.base_url)
        payload, _ = self._exchange(Call("GET", url), deadline)
        return BuildJob.from_payload(payload, url)

    def wait_for_mesh(
        self,
        job: BuildJob | str,
        timeout: float | None = None,
        progress: Callable[[BuildJob], None] | None = None,
    ) -> MeshInfo:
        """Poll a build job (its :class:`BuildJob`, URL or id) until its mesh is ready, as
        :meth:`upload_mesh` does; ``timeout`` seconds at most (None: no limit), then
        :class:`BuildTimeout`."""
        deadline = None if timeout is None else time.monotonic() + timeout
        if not isinstance(job, BuildJob):
            job = self.job(job)
        return self._poll(job, deadline, timeout, progress)

    def _poll(self, job: BuildJob, deadline, timeout, progress) -> MeshInfo:
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
            time.sleep(delay)
            polls += 1
            try:
                job = self._job(job, deadline)
            except Expired:
                raise BuildTimeout(timeout, job.url, job) from None

    def mesh(self, mesh: MeshInfo | str) -> MeshInfo:
        """The facts of one uploaded mesh (by :class:`MeshInfo` or id)."""
        payload, _ = self._send(Call("GET", f"/v1/meshes/{getattr(mesh, 'id', mesh)}"))
        return self._mesh(payload, 200)

    def meshes(self) -> list[MeshInfo]:
        """Every finished mesh of the caller."""
        payload, _ = self._send(Call("GET", "/v1/meshes"))
        return [self._mesh(m, 200) for m in payload["meshes"]]

    def delete_mesh(self, mesh: MeshInfo | str) -> None:
        """Delete one of the caller's meshes (by :class:`MeshInfo` or id); scenes that use
        it keep its tree."""
        self._send(Call("DELETE", f"/v1/meshes/{getattr(mesh, 'id', mesh)}"))

    def contacts(
        self,
        pairs,
        kernel: str = "hybrid",
        hierarchy: bool = True,
        precision: str | None = None,
    ) -> Contacts:
        """Contacts of ``(a, pose_a, b, pose_b)`` pairs; a pose is ``(position,
        orientation)``, a position, or a dict. ``precision`` "float32" or "float64"; None
        takes the service's default (float64)."""
        payload, _ = self._send(self._contacts(pairs, kernel, hierarchy, precision))
        return self._found(payload)

    def find_contacts(
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
        """Contacts of ``n`` pairs given as arrays: ``a, b (n,)`` indices into ``meshes``
        (ids or :class:`MeshInfo`), ``position_* (n, 3)``, ``orientation_* (n, 4)`` unit
        quaternions (w, x, y, z) — :meth:`contacts` without a Python loop over the pairs."""
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
        payload, _ = self._send(call)
        return self._found(payload)

    def create_scene(
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
    ) -> RemoteScene:
        """A scene with the fields of ``POST /v1/scenes``; returns its handle."""
        call = self._scene(
            bodies, planes, gravity, dt, scheme, epsilon, contact_model, kernel, max_halvings
        )
        payload, _ = self._send(call)
        return RemoteScene(self, payload["id"], self._state(payload))


class RemoteScene:
    """A scene on the service: ``step``, ``state``, ``set_state``, ``delete``."""

    def __init__(self, client: Client, scene_id: str, state: SceneState) -> None:
        self.client, self.id, self.last = client, scene_id, state

    def step(self, n: int = 1, dt: float | None = None) -> SceneState:
        """Advance ``n`` steps (of the scene's dt unless given); the new state, with the
        statistics of each step in ``stats``."""
        payload, _ = self.client._send(self.client._step(self.id, n, dt))
        self.last = self.client._state(payload)
        return self.last

    @property
    def state(self) -> SceneState:
        """The scene's current state, read from the service."""
        payload, _ = self.client._send(Call("GET", f"/v1/scenes/{self.id}"))
        self.last = self.client._state(payload)
        return self.last

    def set_state(
        self, positions=None, orientations=None, velocities=None, angular_velocities=None
    ) -> SceneState:
        """Overwrite any of ``positions (n, 3)``, ``orientations (n, 4)``, ``velocities``,
        ``angular_velocities (n, 3)``; the new state, with ``overlaps`` when positions or
        orientations were set."""
        call = self.client._set_state(
            self.id, positions, orientations, velocities, angular_velocities
        )
        payload, _ = self.client._send(call)
        self.last = self.client._state(payload)
        return self.last

    def delete(self) -> None:
        """Delete the scene on the service."""
        self.client._send(Call("DELETE", f"/v1/scenes/{self.id}"))
