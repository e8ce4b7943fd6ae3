"""The two clients offer the same calls with the same signatures, each documented, and the
package says it is typed (PEP 561)."""

from __future__ import annotations

import inspect
from importlib import resources

import pytest

from clients import AsyncClient, AsyncRemoteScene, Client, RemoteScene


def _public(cls) -> dict:
    return {
        name: member
        for name, member in vars(cls).items()
        if not name.startswith("_") and (callable(member) or isinstance(member, property))
    }


def _signature(member) -> inspect.Signature:
    if isinstance(member, property):
        member = member.fget
    signature = inspect.signature(member, eval_str=True)
    return signature.replace(return_annotation=inspect.Signature.empty)


def _parameters(member) -> list:
    return [p for name, p in _signature(member).parameters.items() if name != "self"]


@pytest.mark.parametrize(
    ("blocking", "awaited", "renamed"),
    [(Client, AsyncClient, {"close": "aclose"}), (RemoteScene, AsyncRemoteScene, {})],
)
def test_the_async_client_mirrors_the_blocking_one(blocking, awaited, renamed):
    ours, theirs = _public(blocking), _public(awaited)
    assert {renamed.get(name, name) for name in ours} == set(theirs)
    for name, member in ours.items():
        other = theirs[renamed.get(name, name)]
        assert _parameters(member) == _parameters(other), name
        assert inspect.iscoroutinefunction(other), name
        assert (member.__doc__ or "").strip() and (other.__doc__ or "").strip(), name


@pytest.mark.parametrize("cls", [Client, AsyncClient])
def test_the_constructors_say_what_they_take(cls):
    parameters = inspect.signature(cls.__init__).parameters
    kinds = {p.kind for p in parameters.values()}
    assert inspect.Parameter.VAR_POSITIONAL not in kinds
    assert inspect.Parameter.VAR_KEYWORD not in kinds
    assert list(parameters)[1:] == [
        "base_url", "api_key", "timeout", "retries", "backoff", "wire", "transport"
    ]  # fmt: skip
    assert cls.__init__.__doc__


def test_the_package_is_typed():
    assert resources.files("clients").joinpath("py.typed").is_file()
