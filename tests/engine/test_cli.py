"""The ``mrdem`` command line, run as a real subprocess."""

from __future__ import annotations

import json
import subprocess
import sys


def run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "engine.cli", *args], capture_output=True, text=True, timeout=300
    )


def test_info_reports_versions_and_cache():
    proc = run("info")
    assert proc.returncode == 0, proc.stderr
    info = json.loads(proc.stdout)
    assert info["kernel_cache"].endswith(f"kernels-{info['kernel_source_hash']}")
    assert info["default_iterations"] >= 1


def test_warmup_compiles_or_loads_the_kernels():
    proc = run("warmup")
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.startswith("kernels ready in ")


def test_unknown_command_is_a_usage_error():
    proc = run("frobnicate")
    assert proc.returncode == 2
    assert "invalid choice" in proc.stderr


def test_warmup_refuses_a_worker_count_it_cannot_use():
    proc = run("warmup", "--workers", "0")
    assert proc.returncode == 2
    assert "workers must be" in proc.stderr
