"""RFC 9457 problem details as a model, and the paths of invalid fields."""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict, Field

__all__ = ["FieldError", "Problem", "field_errors", "joined", "path_text"]


class FieldError(BaseModel):
    """One invalid field of a request."""

    path: str = Field(description="where: 'bodies[2].orientation', 'a', 'query.wait'")
    message: str = Field(description="what was wrong and what is accepted")


class Problem(BaseModel):
    """An error the caller can act on (``application/problem+json``, RFC 9457)."""

    model_config = ConfigDict(
        extra="allow",
        json_schema_extra={
            "examples": [
                {
                    "type": "about:blank",
                    "title": "Unprocessable Content",
                    "status": 422,
                    "detail": "bodies[0].orientation: must be a unit quaternion (w, x, y, z);"
                    " its norm is 2 (norms within 1e-06 of 1 are normalised)",
                    "instance": "/v1/scenes",
                    "errors": [
                        {
                            "path": "bodies[0].orientation",
                            "message": "must be a unit quaternion (w, x, y, z); its norm is 2"
                            " (norms within 1e-06 of 1 are normalised)",
                        }
                    ],
                }
            ]
        },
    )

    type: str = Field("about:blank", description="always about:blank: the status says it")
    title: str = Field(description="the status's phrase")
    status: int = Field(description="the HTTP status code")
    detail: str = Field(description="what was wrong and what the caller can do")
    instance: str | None = Field(None, description="the request's path")
    errors: list[FieldError] | None = Field(
        None, description="each invalid field of the request (422 from validation)"
    )
    job: str | None = Field(None, description="a build job's location, when one is concerned")
    cause: str | None = Field(None, description="a failed build's cause")


def path_text(loc) -> str:
    """``("bodies", 2, "orientation")`` as ``bodies[2].orientation``."""
    out = ""
    for part in loc:
        if isinstance(part, int):
            out += f"[{part}]"
        else:
            out += ("." if out else "") + str(part)
    return out


def field_errors(errors) -> list[dict]:
    """Pydantic's errors as ``[{"path", "message"}]``, each message saying what the field
    must be and what it got; the ``body`` prefix of FastAPI's locations and tagged-union and
    validator parts are dropped (``query.wait`` keeps its prefix)."""
    out = []
    for error in errors:
        loc = [p for p in error.get("loc", ()) if p != "body" and not _internal(p)]
        ctx = error.get("ctx") or {}
        loc += [ctx["field"]] if "field" in ctx else []  # a model's check on one field
        loc += list(ctx.get("index", ()))  # an array's element
        out.append({"path": path_text(loc), "message": _message(error, bool(loc))})
    return out


_FIXED = {
    "missing": "is missing",
    "extra_forbidden": "is not a field of this request (check its spelling)",
    "bool_type": "must be true or false",
    "bool_parsing": "must be true or false",
    "float_type": "must be a number",
    "float_parsing": "must be a number",
    "int_type": "must be an integer",
    "int_parsing": "must be an integer",
    "int_from_float": "must be an integer",
    "string_type": "must be a string",
    "list_type": "must be a list",
    "dict_type": "must be an object",
    "model_type": "must be an object",
    "model_attributes_type": "must be an object",
    "finite_number": "must be a finite number",
}


def _message(error: dict, named: bool) -> str:
    kind, message = error.get("type", ""), str(error.get("msg", ""))
    if kind == "value_error":
        message = str(error.get("ctx", {}).get("error", message))
    elif kind == "literal_error":
        message = f"must be one of {error.get('ctx', {}).get('expected', '')}"
    elif kind in _FIXED:
        message = _FIXED[kind]
    else:
        for lead in ("Input should", "List should", "String should", "Value should"):
            if message.startswith(lead):
                message = "must" + message[len(lead) :].replace(" after validation", "")
                break
    if not named and message.startswith("must"):
        message = "the body " + message
    given = error.get("input", _NOTHING)
    if kind not in ("missing", "value_error") and _scalar(given) and "got" not in message:
        message += f", got {_short(given)}"
    return message


_NOTHING = object()


def _scalar(value) -> bool:
    return value is None or isinstance(value, bool | int | float | str)


def _short(value) -> str:
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def _internal(part) -> bool:
    """Location parts pydantic adds for unions and validators, not the request's fields."""
    return isinstance(part, str) and (
        part.startswith("function-") or part in _TAGS or "[" in part or "-" in part
    )


_TAGS = ("columnar", "per_pair")  # service.models.contacts.ContactsQuery


_VERBS = ("must", "is", "has", "holds", "needs")


def joined(errors: list[dict]) -> str:
    """The errors as one detail: ``vertices must have shape (n, 3), got [3, 2]; epsilon:
    Input should be greater than 0``."""
    parts = []
    for e in errors:
        path, message = e["path"], e["message"]
        if not path:
            parts.append(message)
        else:
            verb = message.split(" ", 1)[0]
            if message.startswith("'s "):  # the engine's "inertia's principal moments ..."
                parts.append(path + message)
            else:
                parts.append(f"{path} {message}" if verb in _VERBS else f"{path}: {message}")
    return "; ".join(parts)
