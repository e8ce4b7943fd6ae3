"""mrdem_common.serving: the one way to start ``python -m service`` (its successful start is what
every service and client test's server goes through: tests/harness.py); here what it says
when the service cannot start."""

from __future__ import annotations

import socket
import sys

import pytest
from harness import ROOT

from mrdem_common.serving import ServiceProcess, ServiceStartError, free_port, readyz


def test_a_free_port_can_be_bound_and_answers_not_ready():
    port = free_port()
    with socket.socket() as s:
        s.bind(("127.0.0.1", port))
    assert not readyz(f"http://127.0.0.1:{port}")


def test_a_service_that_exits_is_an_error_with_its_log_tail(tmp_path):
    process = ServiceProcess(
        tmp_path / "data", settings={"max_pairs": "many"}, cwd=ROOT, log_dir=tmp_path
    )
    with pytest.raises(ServiceStartError, match="the service exited with") as error:
        process.start()
    assert "MRDEM_MAX_PAIRS" in str(error.value)  # the settings error, quoted from the log
    assert process.log_path.parent == tmp_path and process.log is None  # closed
    assert process.proc.returncode not in (None, 0)


def test_a_service_not_ready_in_time_is_stopped(tmp_path):
    process = ServiceProcess(tmp_path / "data", cwd=ROOT, log_dir=tmp_path, ready_timeout=0.5)
    with pytest.raises(ServiceStartError, match="was not ready in 0.5 s"):
        process.start(ready=lambda: False)
    assert process.proc.poll() is not None  # not left running
    assert sys.executable in process.proc.args
