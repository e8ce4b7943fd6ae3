"""The OpenAPI document: request bodies (JSON and msgpack, validated by the same models),
success answers and problem answers of every ``/v1`` operation, with examples.

Routes read their bodies themselves (one decoding path for both media types,
:mod:`service.deps`), so their request bodies are declared here (``openapi_extra``) by
model name, and :func:`install` adds every model's JSON schema to the document's
components. msgpack bodies have the JSON schema's structure; their arrays may travel as
typed binary (extension type 1: ``[dtype, shape, data]``).
"""

from __future__ import annotations

from typing import Any

from fastapi import FastAPI
from fastapi.openapi.utils import get_openapi
from pydantic import BaseModel
from pydantic.json_schema import models_json_schema

from mrdem_common.codec import JSON, MSGPACK

from . import models
from .errors import PROBLEM

__all__ = ["REQUESTS", "RESPONSES", "documented", "install"]

REQUESTS: tuple[type[BaseModel], ...] = (
    models.MeshUpload,
    models.ColumnarQuery,
    models.PerPairQuery,
    models.SceneSpec,
    models.StateUpdate,
    models.StepRequest,
)
RESPONSES: tuple[type[BaseModel], ...] = (
    models.MeshFacts,
    models.MeshList,
    models.BuildJob,
    models.JobList,
    models.SurrogateLevel,
    models.ColumnarContacts,
    models.PerPairContacts,
    models.SceneSummary,
    models.StepAnswer,
    models.Problem,
)

_PHRASES = {
    400: "The body cannot be decoded (malformed JSON or msgpack, empty), or a malformed"
    " Idempotency-Key",
    401: "Missing or unknown API key (when the service has keys)",
    404: "No such resource for this API key",
    406: "The Accept header asks for a media type other than JSON or msgpack",
    409: "A conflict: the mesh went while the request waited, or the Idempotency-Key's first"
    " request is still running (Retry-After)",
    413: "The body is larger than the service takes (MRDEM_MAX_BODY_BYTES)",
    415: "The body's media type is not JSON, msgpack (or multipart where files are taken)",
    422: "The request is well formed but invalid: `errors` names each field and why",
    503: "The service cannot do it now (kernels compiling, a build out of memory, no room in"
    " a cluster for a scene's actor); try later (Retry-After)",
}
_RETRY_AFTER = {"Retry-After": {"description": "seconds to wait", "schema": {"type": "string"}}}
#: where a contacts request's time went (W3C Server Timing: ``name;dur=milliseconds``)
SERVER_TIMING = {
    "Server-Timing": {
        "description": "milliseconds of the search and the encoding of the answer; of a"
        " request split across a cluster's nodes also: submit, here, task, wait, merge",
        "schema": {"type": "string"},
    }
}


def _ref(model: type[BaseModel] | str) -> dict:
    name = model if isinstance(model, str) else model.__name__
    return {"$ref": f"#/components/schemas/{name}"}


def _content(schema: dict, example: Any = None, problem: bool = False) -> dict:
    one = {"schema": schema}
    if example is not None:
        one["example"] = example
    if problem:
        return {PROBLEM: one}
    return {JSON: one, MSGPACK: {"schema": schema}}


def _example(model: type[BaseModel]) -> Any:
    examples = (model.model_config.get("json_schema_extra") or {}).get("examples")
    return examples[0] if examples else None


def _problem_example(status: int) -> dict:
    if status == 422:
        return _example(models.Problem)
    return {
        "type": "about:blank",
        "title": _TITLES[status],
        "status": status,
        "detail": _PHRASES[status].split(":")[0],
    }


_TITLES = {
    400: "Bad Request",
    401: "Unauthorized",
    404: "Not Found",
    406: "Not Acceptable",
    409: "Conflict",
    413: "Content Too Large",
    415: "Unsupported Media Type",
    422: "Unprocessable Content",
    503: "Service Unavailable",
}


def documented(
    success: dict[int, tuple[Any, str]],
    problems: tuple[int, ...],
    body: Any = None,
    multipart: dict | None = None,
    body_required: bool = True,
    headers: dict | None = None,
) -> dict:
    """Keyword arguments of a route decorator documenting its answers and its body.

    success : {status: (model, a list of models for oneOf, or None for no body; text)}
    problems : the 4xx/5xx statuses it answers with a problem
    body : its body's model (or a list of models for oneOf); multipart : a form's schema
    headers : the headers of its successful answers ({name: OpenAPI header object})
    """
    responses: dict[int | str, dict] = {}
    for status, (model, text) in success.items():
        answer: dict = {"description": text}
        if model is not None:
            schema = {"oneOf": [_ref(m) for m in model]} if isinstance(model, list) else _ref(model)
            first = model[0] if isinstance(model, list) else model
            answer["content"] = _content(schema, _example(first))
        if status == 202:
            answer["headers"] = {
                "Location": {"description": "the build job", "schema": {"type": "string"}},
                **_RETRY_AFTER,
            }
        if headers:
            answer["headers"] = {**answer.get("headers", {}), **headers}
        responses[status] = answer
    for status in problems:
        responses[status] = {
            "description": _PHRASES[status],
            "content": _content(_ref(models.Problem), _problem_example(status), problem=True),
        }
        if status in (409, 503):
            responses[status]["headers"] = _RETRY_AFTER
    extra: dict = {}
    if body is not None:
        if isinstance(body, list):
            schema = {"oneOf": [_ref(m) for m in body]}
            example = _example(body[0])
        else:
            schema, example = _ref(body), _example(body)
        content = _content(schema, example)
        if multipart is not None:
            content["multipart/form-data"] = {"schema": multipart}
        extra["requestBody"] = {"required": body_required, "content": content}
    return {"responses": responses, "openapi_extra": extra}


def install(app: FastAPI, limits: dict[str, int]) -> None:
    """Make ``app.openapi()`` add every request and answer model to the components, with
    this service's ``limits`` (``max_steps``, ``max_pairs``, ``max_bodies``,
    ``max_triangles``: its settings) as the schemas' bounds."""

    def openapi() -> dict:
        if app.openapi_schema is not None:
            return app.openapi_schema
        document = get_openapi(
            title=app.title,
            version=app.version,
            summary=app.summary,
            description=app.description,
            routes=app.routes,
        )
        pairs = [(m, "validation") for m in REQUESTS] + [(m, "serialization") for m in RESPONSES]
        _, schemas = models_json_schema(pairs, ref_template="#/components/schemas/{model}")
        components = document.setdefault("components", {}).setdefault("schemas", {})
        components.update(schemas.get("$defs", {}))
        missing = {m.__name__ for m in REQUESTS + RESPONSES} - set(components)
        if missing:  # a name pydantic suffixed (-Input/-Output): the refs above would dangle
            raise RuntimeError(f"models missing from the OpenAPI components: {sorted(missing)}")
        _bound(components, limits)
        app.openapi_schema = document
        return document

    app.openapi = openapi  # type: ignore[method-assign]


def _bound(schemas: dict, limits: dict[str, int]) -> None:
    """The settings' limits as ``maximum`` / ``maxItems`` of the fields they bound."""
    steps = schemas["StepRequest"]["properties"]["steps"]
    steps["maximum"] = limits["max_steps"]
    for name, field in (("SceneSpec", "bodies"), ("SceneSpec", "planes")):
        schemas[name]["properties"][field]["maxItems"] = limits["max_bodies"]
    schemas["PerPairQuery"]["properties"]["pairs"]["maxItems"] = limits["max_pairs"]
    columns = ("a", "b", "position_a", "orientation_a", "position_b", "orientation_b")
    for field in columns:
        schemas["ColumnarQuery"]["properties"][field]["maxItems"] = limits["max_pairs"]
    schemas["MeshUpload"]["properties"]["faces"]["maxItems"] = limits["max_triangles"]
