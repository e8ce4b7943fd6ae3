"""The container's command, environment and health check, run outside Docker (no Docker
engine here): ``docker/Dockerfile``'s CMD with its ENV answers its HEALTHCHECK."""

from __future__ import annotations

import json
import os
import re
import shlex
import subprocess
import sys
import time
from pathlib import Path

import httpx
from harness import ROOT, free_port

DOCKERFILE = ROOT / "docker" / "Dockerfile"


def _instructions() -> list[tuple[str, str]]:
    text = re.sub(r"\\\n\s*", " ", DOCKERFILE.read_text())
    out = []
    for line in text.splitlines():
        line = line.strip()
        if line and not line.startswith("#"):
            word, _, rest = line.partition(" ")
            out.append((word.upper(), rest.strip()))
    return out


def _exec_form(text: str) -> list[str]:
    return json.loads(text) if text.startswith("[") else shlex.split(text)


def test_the_image_runs_as_a_non_root_user_with_volumes():
    steps = dict(_instructions())
    assert steps["FROM"].startswith("python:3.11-slim")
    assert steps["USER"] == "mrdem"
    assert "/data" in steps["VOLUME"] and "/var/cache/numba" in steps["VOLUME"]
    env = dict(shlex.split(kv)[0].split("=", 1) for kv in re.findall(r"\S+=\S+", steps["ENV"]))
    assert env["NUMBA_CACHE_DIR"] == "/var/cache/numba" and env["NUMBA_NUM_THREADS"]
    assert "--start-period=300s" in steps["HEALTHCHECK"]
    compose = (ROOT / "docker" / "compose.yaml").read_text()
    assert "mrdem-data:/data" in compose and "dockerfile: docker/Dockerfile" in compose


def test_the_container_command_serves_and_passes_its_health_check(tmp_path):
    steps = _instructions()
    env_line = next(rest for word, rest in steps if word == "ENV")
    env = {**os.environ, **dict(kv.split("=", 1) for kv in shlex.split(env_line))}
    port = free_port()
    # the paths and port of this machine instead of the image's; the kernel cache of the
    # test run (the image's cache volume starts empty and compiles once)
    env.update(
        MRDEM_DATA_DIR=str(tmp_path / "data"),
        MRDEM_PORT=str(port),
        MRDEM_HOST="127.0.0.1",
        NUMBA_CACHE_DIR=os.environ.get("NUMBA_CACHE_DIR", str(ROOT / ".numba-cache")),
    )
    command = _exec_form(next(rest for word, rest in steps if word == "CMD"))
    assert command == ["python", "-m", "service"]
    check = next(rest for word, rest in steps if word == "HEALTHCHECK").split(" CMD ", 1)[1]
    check = [sys.executable if a == "python" else a for a in _exec_form(check)]
    check = [a.replace(":8000/", f":{port}/") for a in check]
    proc = subprocess.Popen([sys.executable, *command[1:]], cwd=ROOT, env=env)
    try:
        deadline = time.monotonic() + 600
        healthy = False
        while time.monotonic() < deadline and not healthy:
            assert proc.poll() is None, "the container command exited"
            healthy = subprocess.run(check, capture_output=True, timeout=30).returncode == 0
            time.sleep(0.2)
        assert healthy
        assert httpx.get(f"http://127.0.0.1:{port}/readyz").json()["status"] == "ready"
        assert (Path(env["MRDEM_DATA_DIR"]) / "mrdem.sqlite3").exists()
    finally:
        proc.terminate()
        proc.wait(20)
