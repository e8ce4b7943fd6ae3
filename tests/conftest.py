"""Fixtures shared by tests/service and tests/clients (see harness.py)."""

from __future__ import annotations

import httpx
import pytest
from harness import ServiceProcess


@pytest.fixture(scope="session")
def service(tmp_path_factory):
    """One running service for the tests that only need a server."""
    process = ServiceProcess(tmp_path_factory.mktemp("service") / "data").start()
    yield process
    process.stop()


@pytest.fixture()
def http(service):
    with httpx.Client(base_url=service.url, timeout=120.0) as client:
        yield client
