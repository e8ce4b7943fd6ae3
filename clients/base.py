"""What :class:`~clients.Client` and :class:`~clients.AsyncClient` share: settings,
headers, request arguments, and turning answers into models."""

from __future__ import annotations

import httpx

from .calls import (
    Call,
    RetryPolicy,
    columnar_call,
    contacts_call,
    job_path,
    keyed,
    scene_call,
    service_wait,
    upload_call,
)
from .codec import JSON, MSGPACK, encode
from .errors import BuildFailed, ClientError
from .models import STATE, BuildJob, Contacts, MeshInfo, SceneState

__all__ = ["ClientBase"]


class ClientBase:
    """``base_url``; ``api_key`` (bearer); ``timeout`` seconds per request; ``retries``
    after the first try and ``backoff`` seconds (doubled per retry) for the calls that
    may be retried (see :mod:`clients.calls`); ``wire``: "msgpack" (default) or "json"."""

    def __init__(
        self,
        base_url: str,
        api_key: str | None = None,
        timeout: float = 60.0,
        retries: int = 3,
        backoff: float = 0.25,
        wire: str = "msgpack",
    ) -> None:
        if wire not in ("msgpack", "json"):
            raise ClientError(f"wire must be 'msgpack' or 'json', got {wire!r}")
        self.base_url, self.timeout = base_url.rstrip("/"), timeout
        self.retries, self.backoff = int(retries), float(backoff)
        self.policy = RetryPolicy(self.retries, self.backoff)
        self.media = MSGPACK if wire == "msgpack" else JSON
        self.headers = {"accept": self.media}
        if api_key:
            self.headers["authorization"] = f"Bearer {api_key}"

    def _arguments(self, call: Call, timeout: float | None) -> dict:
        """httpx's arguments of one try of ``call`` that may take ``timeout`` seconds."""
        arguments: dict = {"timeout": timeout}
        if call.headers:
            arguments["headers"] = dict(call.headers)
        if call.waits:
            arguments["params"] = service_wait(timeout)
        if call.files is not None:
            return {**arguments, "files": call.files, "data": call.data}
        if call.payload is None:
            return arguments
        return {
            **arguments,
            "content": encode(call.payload, self.media),
            "headers": {**call.headers, "content-type": self.media},
        }

    # ---------------------------------------------------------------- calls
    @staticmethod
    def _upload(source, epsilon, branching, strict=None) -> Call:
        return upload_call(source, epsilon, branching, strict)

    @staticmethod
    def _contacts(pairs, kernel, hierarchy, precision) -> Call:
        return contacts_call(pairs, kernel, hierarchy, precision)

    @staticmethod
    def _columnar(meshes, a, pa, qa, b, pb, qb, kernel, hierarchy, precision) -> Call:
        options = {"kernel": kernel, "hierarchy": hierarchy, "precision": precision}
        return columnar_call(meshes, a, pa, qa, b, pb, qb, options)

    @staticmethod
    def _scene(bodies, *fields) -> Call:
        """``POST /v1/scenes`` of ``bodies`` and the fields of ``create_scene``, in its
        order (planes, gravity, dt, scheme, epsilon, contact_model, kernel,
        max_halvings); the unset ones (None) left out."""
        names = ("planes", "gravity", "dt", "scheme", "epsilon", "contact_model", "kernel")
        given = dict(zip((*names, "max_halvings"), fields, strict=True))
        return scene_call(bodies, **{k: v for k, v in given.items() if v is not None})

    @staticmethod
    def _step(scene_id: str, n: int, dt: float | None) -> Call:
        payload = {"steps": int(n), **({"dt": float(dt)} if dt is not None else {})}
        return keyed("POST", f"/v1/scenes/{scene_id}/step", payload)

    @staticmethod
    def _set_state(scene_id: str, *arrays) -> Call:
        """``PUT /v1/scenes/{id}/state`` of the arrays of ``set_state`` in its order
        (positions, orientations, velocities, angular_velocities); None ones left out."""
        payload = {k: v for k, v in zip(STATE, arrays, strict=True) if v is not None}
        return Call("PUT", f"/v1/scenes/{scene_id}/state", payload=payload)

    # --------------------------------------------------------------- models
    @staticmethod
    def _mesh(payload: dict, status: int) -> MeshInfo:
        return MeshInfo.from_payload(payload, created=status == 201)

    def _uploaded(self, payload: dict, response: httpx.Response) -> MeshInfo | BuildJob:
        """An upload's answer: the mesh (200, 201) or its unfinished build job (202)."""
        if response.status_code == 202:
            location = response.headers.get("location") or payload.get("location")
            return BuildJob.from_payload(payload, job_path(location, self.base_url))
        return MeshInfo.from_payload(payload, created=response.status_code == 201)

    @staticmethod
    def _settled(job: BuildJob) -> MeshInfo | None:
        """The mesh of a done job, None while it is unfinished; :class:`BuildFailed` for
        a failed one. A mesh built after a 202 is new to its owner (``created``)."""
        if job.status == "failed":
            raise BuildFailed(str(job.error), job.cause, job.url, job)
        if job.status != "done":
            return None
        facts = job.payload.get("facts")
        if facts is None:
            raise ClientError(f"mesh {job.mesh} was built but has been deleted since ({job.url})")
        return MeshInfo.from_payload(facts, created=True)

    @staticmethod
    def _found(payload: dict) -> Contacts:
        return Contacts.from_payload(payload)

    @staticmethod
    def _state(payload: dict) -> SceneState:
        return SceneState.from_payload(payload)
