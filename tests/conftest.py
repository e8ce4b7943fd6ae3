"""Fixtures shared by tests/service and tests/clients (see harness.py), and the Hypothesis
profiles: "ci" (derandomised: the same examples on every run, no deadline, the reproduction
blob printed on failure) when the ``CI`` environment variable is set (``.ci/run`` sets it),
"dev" (Hypothesis' defaults: new random examples each run, failures replayed from
``.hypothesis/``) otherwise. ``pytest --hypothesis-profile=ci`` selects one by hand."""

from __future__ import annotations

import os

import pytest
from harness import InProcessService, ServiceProcess
from hypothesis import settings

# Both on Hypothesis' "default" profile explicitly: registering takes the current default as
# the parent otherwise, and Hypothesis loads its own "ci" profile on import whenever CI is set.
settings.register_profile(
    "ci",
    settings.get_profile("default"),
    derandomize=True,
    deadline=None,
    print_blob=True,
    database=None,
)
settings.register_profile("dev", settings.get_profile("default"))


def in_ci(environ=os.environ) -> bool:
    """Whether ``CI`` is set to anything but empty, ``0`` or ``false``."""
    return environ.get("CI", "").strip().lower() not in ("", "0", "false")


# Loaded here, before any test module builds its settings(...) objects on top of the profile.
settings.load_profile("ci" if in_ci() else "dev")


@pytest.fixture(scope="session")
def service(tmp_path_factory):
    """The real app in this process (through ``httpx.ASGITransport``) for the tests that
    only need a server: ``service.client()``, or ``transport=service.transport``."""
    with InProcessService(tmp_path_factory.mktemp("service") / "data") as app:
        yield app


@pytest.fixture(scope="session")
def live_service(tmp_path_factory):
    """One real uvicorn process, for the tests whose callers need a socket (subprocesses,
    a proxy, a generated client against a live server)."""
    with ServiceProcess(tmp_path_factory.mktemp("live") / "data") as process:
        yield process


@pytest.fixture()
def http(service):
    with service.client(timeout=120.0) as client:
        yield client


@pytest.fixture(scope="session")
def postgres():
    """A PostgreSQL server of this test process (:class:`mrdem_common.loopback.
    PostgresServer`)."""
    from servers import missing

    from mrdem_common.loopback import PostgresServer, postgres_bin

    if postgres_bin() is None:
        missing("PostgreSQL (initdb, pg_ctl)")
    server = PostgresServer()
    yield server
    server.stop()


@pytest.fixture(scope="session")
def s3():
    """An S3-compatible server (moto) of this test process (:class:`mrdem_common.loopback.
    S3Server`)."""
    from mrdem_common.loopback import S3Server

    server = S3Server()
    yield server
    server.stop()
