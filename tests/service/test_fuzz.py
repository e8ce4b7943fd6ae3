"""The OpenAPI document as a contract, fuzzed: schemathesis (its CLI, every phase: examples,
coverage, fuzzing, stateful) against a live service with an API key, JSON and msgpack
bodies, real mesh and scene ids among the generated ones. No answer may be a server error,
every answer must match its documented status, media type and schema, and the server must
be alive afterwards. The requests are counted by the server itself (``/metrics``)."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import httpx
import pytest
from conftest import in_ci
from harness import ROOT, ServiceProcess, tetrahedron

KEY = "fuzz-key-0123456789"
AUTH = {"Authorization": f"Bearer {KEY}"}
LIMITS = {  # small, so that no generated request runs long
    "api_keys": KEY,
    "max_steps": "20",
    "max_triangles": "2000",
    "max_pairs": "50",
    "max_bodies": "20",
    "build_wait": "2",
}
CHECKS = (
    "not_a_server_error",
    "status_code_conformance",
    "content_type_conformance",
    "response_schema_conformance",
    "response_headers_conformance",
)


@pytest.fixture(scope="module")
def fuzzed(tmp_path_factory):
    directory = tmp_path_factory.mktemp("fuzz")
    with (
        ServiceProcess(directory / "data", **LIMITS) as service,
        httpx.Client(base_url=service.url, headers=AUTH, timeout=60) as http,
    ):
        mesh = http.post("/v1/meshes", json={**tetrahedron(), "epsilon": 0.02})
        assert mesh.status_code == 201, mesh.text
        mesh_id = mesh.json()["id"]
        spec = {"bodies": [{"mesh": mesh_id, "position": [0, 0, 0.5]}], "planes": [{}]}
        scene = http.post("/v1/scenes", json=spec)
        assert scene.status_code == 201, scene.text
        yield service, http, directory, mesh_id, scene.json()["id"]


def _config(path: Path, mesh_id: str, scene_id: str) -> Path:
    """A schemathesis.toml: the real ids among the generated ones."""
    bindings = {
        "path.mesh_id": "meshes",
        "body.bodies[*].mesh": "meshes",
        "body.meshes[*]": "meshes",
        "body.pairs[*].a": "meshes",
        "body.pairs[*].b": "meshes",
        "path.scene_id": "scenes",
    }
    lines = [
        f"[dictionaries.meshes]\nvalues = [{json.dumps(mesh_id)}]",
        f"[dictionaries.scenes]\nvalues = [{json.dumps(scene_id)}]",
        "[parameters]",
        *(f'"{k}" = {{ dictionary = "{v}", probability = 0.7 }}' for k, v in bindings.items()),
    ]
    path.write_text("\n".join(lines) + "\n")
    return path


def _requests(http: httpx.Client) -> dict[str, float]:
    """The server's request counts by status, from ``/metrics``."""
    counts: dict[str, float] = {}
    for line in http.get("/metrics").text.splitlines():
        found = re.match(r'mrdem_http_requests_total\{.*status="(\d+)"\} ([0-9.e+]+)', line)
        if found:
            counts[found[1]] = counts.get(found[1], 0.0) + float(found[2])
    return counts


def _schemathesis(service, config: Path, examples: int, *selection: str) -> str:
    """Run the schemathesis CLI on the service's document; its report if it failed."""
    command = [
        *(sys.executable, "-m", "schemathesis.cli"),
        *("--config-file", str(config), "--no-color", "run", f"{service.url}/openapi.json"),
        *("--header", f"Authorization: Bearer {KEY}", "--checks", ",".join(CHECKS)),
        *("--max-examples", str(examples), "--suppress-health-check", "all"),
        *("--request-timeout", "60", "--workers", "1", *selection),
        *(["--generation-deterministic"] if in_ci() else []),
    ]
    env = {
        **os.environ,
        "SCHEMATHESIS_HOOKS": "fuzz_hooks",
        "PYTHONPATH": os.pathsep.join([str(Path(__file__).parent), str(ROOT)]),
    }
    run = subprocess.run(  # in the config's directory: schemathesis keeps its cache there
        command, env=env, cwd=config.parent, capture_output=True, text=True, timeout=1500
    )
    return "" if run.returncode == 0 else run.stdout[-6000:] + run.stderr[-2000:]


def _fuzz(fuzzed, examples: int, least: int) -> None:
    service, http, directory, mesh_id, scene_id = fuzzed
    before = _requests(http)
    config = _config(directory / "schemathesis.toml", mesh_id, scene_id)
    # everything but deleting first (a deleted scene answers 404 to every later step), then
    # the deletes
    assert not (report := _schemathesis(service, config, examples, "--exclude-method", "DELETE"))
    assert not (report := _schemathesis(service, config, examples, "--include-method", "DELETE"))
    after = _requests(http)
    sent = sum(after.values()) - sum(before.values())
    errors = sum(after.get(s, 0) - before.get(s, 0) for s in after if s.startswith("5"))
    assert errors == 0, report
    assert sent >= least, f"{sent:.0f} requests"
    assert http.get("/healthz").status_code == 200
    assert http.get("/readyz").status_code == 200


def test_fuzzed_api_has_no_server_error_and_keeps_its_contract(fuzzed):
    _fuzz(fuzzed, examples=15, least=500)


@pytest.mark.slow
def test_fuzzed_api_longer(fuzzed):
    _fuzz(fuzzed, examples=200, least=4000)
