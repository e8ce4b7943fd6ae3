"""What the tests that need real servers share: a free port, and :func:`missing` for a
server this machine lacks (the servers themselves: :mod:`mrdem_common.loopback`)."""

from __future__ import annotations

import os
import time
from pathlib import Path

import pytest

from mrdem_common.serving import free_port

__all__ = [
    "HAPROXY_INGRESS",
    "IDLE_WORKERS",
    "descendants",
    "free_port",
    "missing",
    "process_name",
    "titled",
    "until_none_titled",
    "until_titled",
]

#: Serve's HAProxy ingress straight to the replicas' own HTTP servers (Ray 2.60 feature
#: flags, read by the processes a Ray node starts): what docker/compose.cluster.yaml and the
#: README's commands set.
HAPROXY_INGRESS = {"RAY_SERVE_ENABLE_HA_PROXY": "1", "RAY_SERVE_ENABLE_DIRECT_INGRESS": "1"}
#: how long a node keeps an idle worker, as the README's ``ray start`` sets it
#: (``service.cluster.batches.IDLE_WORKERS``): its raylet and workers read it from the
#: environment
IDLE_WORKERS = {"RAY_idle_worker_killing_time_threshold_ms": "600000"}


def missing(what: str):
    """Skip (or, under CI: ``CI=true``, fail) a test that needs ``what``."""
    if os.environ.get("CI", "").lower() in ("1", "true", "yes"):
        pytest.fail(f"{what} is needed by this test and missing on this machine")
    pytest.skip(f"{what} is missing on this machine")


def descendants(pid: int) -> list[int]:
    """The processes started by ``pid``, their children and so on (from ``/proc``)."""
    children: dict[int, list[int]] = {}
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            parent = int(stat.read_text().rsplit(")", 1)[1].split()[1])
        except (OSError, ValueError, IndexError):  # gone meanwhile
            continue
        children.setdefault(parent, []).append(int(stat.parent.name))
    found, todo = [], [pid]
    while todo:
        for child in children.get(todo.pop(), []):
            found.append(child)
            todo.append(child)
    return found


def process_name(pid: int) -> str:
    """The command name of ``pid`` (``""`` once it is gone)."""
    try:
        return Path(f"/proc/{pid}/comm").read_text().strip()
    except OSError:
        return ""


def titled(title: str) -> int | None:
    """The pid of a process whose title (Ray's: ``ray::<function>`` while it runs one)
    starts with ``title``, if any."""
    wanted = title.encode()
    for cmdline in Path("/proc").glob("[0-9]*/cmdline"):
        try:
            if cmdline.read_bytes().startswith(wanted):
                return int(cmdline.parent.name)
        except OSError:  # gone meanwhile
            continue
    return None


def until_titled(title: str, deadline: float) -> int:
    """The pid of a process titled ``title…`` as soon as there is one (before
    ``deadline``, ``time.monotonic``)."""
    while time.monotonic() < deadline:
        if (pid := titled(title)) is not None:
            return pid
    raise AssertionError(f"no process {title!r} ran")


def until_none_titled(title: str, deadline: float) -> None:
    """Until no process is titled ``title…`` (before ``deadline``)."""
    while titled(title) is not None:
        assert time.monotonic() < deadline, f"a process {title!r} still runs"
        time.sleep(0.1)
