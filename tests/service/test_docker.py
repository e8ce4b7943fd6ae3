"""The container's command, environment and health check, run outside Docker (no Docker
engine here): ``docker/Dockerfile``'s CMD with its ENV answers its HEALTHCHECK."""

from __future__ import annotations

import json
import os
import re
import shlex
import subprocess
import sys

import httpx
from harness import ROOT

from mrdem_common.serving import ServiceProcess, free_port

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


def test_the_image_copies_every_package_it_installs():
    pyproject = (ROOT / "pyproject.toml").read_text()  # (no tomllib on Python 3.10)
    find = pyproject.split("[tool.setuptools.packages.find]", 1)[1]
    include = re.search(r"^include\s*=\s*\[([^\]]*)\]", find, re.MULTILINE).group(1)
    packages = [name.rstrip("*") for name in json.loads(f"[{include}]")]
    assert "mrdem_common" in packages  # the service and the clients import it
    copied = [rest for word, rest in _instructions() if word == "COPY"]
    for package in packages:
        assert f"{package} {package}" in copied, f"docker/Dockerfile does not COPY {package}/"


def test_the_container_command_serves_and_passes_its_health_check(tmp_path):
    steps = _instructions()
    env_line = next(rest for word, rest in steps if word == "ENV")
    env = {**os.environ, **dict(kv.split("=", 1) for kv in shlex.split(env_line))}
    # the kernel cache of the test run (the image's cache volume starts empty and compiles
    # once); the service process sets this machine's data dir, host and port over the image's
    env["NUMBA_CACHE_DIR"] = os.environ.get("NUMBA_CACHE_DIR", str(ROOT / ".numba-cache"))
    command = _exec_form(next(rest for word, rest in steps if word == "CMD"))
    assert command == ["python", "-m", "service"]  # what ServiceProcess runs
    port = free_port()
    check = next(rest for word, rest in steps if word == "HEALTHCHECK").split(" CMD ", 1)[1]
    check = [sys.executable if a == "python" else a for a in _exec_form(check)]
    check = [a.replace(":8000/", f":{port}/") for a in check]
    assert any(f":{port}/readyz" in a for a in check)

    def healthy() -> bool:
        return subprocess.run(check, capture_output=True, timeout=30).returncode == 0

    data = tmp_path / "data"
    service = ServiceProcess(data, port=port, env=env, cwd=ROOT, log_dir=tmp_path)
    try:
        service.start(ready=healthy)  # the health check passes (else: the log's tail)
        assert httpx.get(f"{service.url}/readyz").json()["status"] == "ready"
        assert (data / "mrdem.sqlite3").exists()
    finally:
        service.stop()


def test_the_cluster_compose_file_runs_the_tested_commands_with_real_settings():
    """docker/compose.cluster.yaml (no Docker engine here): the head runs the two commands
    tests/cluster/test_cli.py runs for real (``ray start --head``, ``mrdem cluster serve``)
    with options the command line has; every MRDEM_* variable is a setting; the image is
    built with the cluster extra; Ray containers get a big /dev/shm."""
    import yaml

    from service.settings import Settings

    compose = yaml.safe_load((ROOT / "docker" / "compose.cluster.yaml").read_text())
    services = compose["services"]
    assert {"ray-head", "ray-worker", "postgres", "s3"} <= set(services)
    head = " ".join(services["ray-head"]["command"])
    assert "ray start --head" in head and "mrdem cluster serve" in head
    serve_options = re.findall(r"(--[a-z-]+)", head.split("mrdem cluster serve", 1)[1])
    help_text = subprocess.run(
        [sys.executable, "-m", "service.cli", "cluster", "serve", "--help"],
        capture_output=True,
        text=True,
        check=True,
    ).stdout
    for option in serve_options:
        assert option in help_text, f"mrdem cluster serve has no {option}"
    assert services["ray-worker"]["command"][:2] == ["ray", "start"]
    fields = set(Settings.model_fields)
    for name in ("ray-head", "ray-worker"):
        service = services[name]
        assert service["build"]["args"]["EXTRAS"] == "cluster"
        assert service["shm_size"] == "2gb"
        for variable in service["environment"]:
            if variable.startswith("MRDEM_"):
                assert variable[len("MRDEM_") :].lower() in fields, f"{variable} is no setting"
        # the values compose gives when the operator sets nothing (${NAME:-default}) are valid
        defaults = {
            variable[len("MRDEM_") :].lower(): re.sub(r"\$\{\w+:-([^}]*)\}", r"\1", str(value))
            for variable, value in service["environment"].items()
            if variable.startswith("MRDEM_")
        }
        settings = Settings(**defaults)
        assert settings.replicas == 2 and settings.replicas_max is None
        assert service["environment"]["RAY_SERVE_ENABLE_HA_PROXY"] == "1"  # as tested
        assert service["environment"]["RAY_SERVE_ENABLE_DIRECT_INGRESS"] == "1"
        assert service["environment"]["RAY_worker_niceness"] == "0"  # as the README's
        assert service["environment"]["RAY_idle_worker_killing_time_threshold_ms"] == "600000"
    assert 'pip install ".${EXTRAS:+[$EXTRAS]}"' in DOCKERFILE.read_text()
