"""The OpenAPI document as tools use it: it validates (openapi-spec-validator); every ``/v1``
operation documents its request body (JSON and msgpack, with an example), its success
answer and its problem answers, and the bearer scheme; and a client generated from it
(openapi-python-client, in a temporary directory) uploads a mesh, runs a contact query and
steps a scene against the live service, with the answers of plain HTTP calls."""

from __future__ import annotations

import importlib
import json
import subprocess
import sys

import httpx
import numpy as np
import pytest
from harness import tetrahedron
from jsonschema import Draft202012Validator
from openapi_spec_validator import validate

from service.app import create_app
from service.settings import Settings

PROBLEM = "application/problem+json"


@pytest.fixture(scope="module")
def document(tmp_path_factory):
    settings = Settings(data_dir=tmp_path_factory.mktemp("openapi") / "data", warmup=False)
    return create_app(settings).openapi()


def test_the_document_validates(document):
    validate(document)
    assert document["openapi"].startswith("3.1")


def _operations(document):
    for path, operations in document["paths"].items():
        for method, operation in operations.items():
            yield path, method, operation


def _resolves(document, schema: dict) -> bool:
    refs = [schema["$ref"]] if "$ref" in schema else [s["$ref"] for s in schema.get("oneOf", [])]
    names = [r.removeprefix("#/components/schemas/") for r in refs]
    return bool(names) and all(n in document["components"]["schemas"] for n in names)


def test_every_v1_operation_documents_its_body_its_answers_and_its_problems(document):
    assert document["components"]["securitySchemes"]["HTTPBearer"]["scheme"] == "bearer"
    operations = [(p, m, o) for p, m, o in _operations(document) if p.startswith("/v1/")]
    assert len(operations) == 13
    for path, method, operation in operations:
        where = f"{method.upper()} {path}"
        assert operation["security"] == [{"HTTPBearer": []}], where
        responses = operation["responses"]
        successes = [s for s in responses if s.startswith("2")]
        assert successes, where
        for status in successes:
            if status == "204":
                assert "content" not in responses[status], where
                continue
            content = responses[status]["content"]
            assert set(content) == {"application/json", "application/msgpack"}, where
            assert _resolves(document, content["application/json"]["schema"]), where
            assert "406" in responses, where  # an Accept it cannot answer
        problems = [s for s in responses if s[0] in "45"]
        assert "401" in problems, where
        for status in problems:
            assert set(responses[status]["content"]) == {PROBLEM}, (where, status)
            schema = responses[status]["content"][PROBLEM]["schema"]
            assert schema == {"$ref": "#/components/schemas/Problem"}, (where, status)
        if method in ("post", "put") and path != "/v1/meshes/jobs":
            content = operation["requestBody"]["content"]
            assert {"application/json", "application/msgpack"} <= set(content), where
            assert _resolves(document, content["application/json"]["schema"]), where
            assert "example" in content["application/json"], where
            assert "415" in problems and "413" in problems and "422" in problems, where
    assert "HTTPValidationError" not in document["components"]["schemas"]


def _examples(document):
    """Every example of the document with the schema it claims to fit."""
    for name, schema in document["components"]["schemas"].items():
        for example in schema.get("examples", []):
            yield f"components {name}", {"$ref": f"#/components/schemas/{name}"}, example
    for path, method, operation in _operations(document):
        bodies = [("request", operation.get("requestBody", {}))]
        bodies += [(status, r) for status, r in operation["responses"].items()]
        for status, part in bodies:
            for media, content in part.get("content", {}).items():
                if "example" in content:
                    where = f"{method.upper()} {path} {status} {media}"
                    yield where, content["schema"], content["example"]


def test_every_example_fits_its_schema_and_every_v1_answer_has_one(document):
    checked = 0
    for where, schema, example in _examples(document):
        validator = Draft202012Validator({**schema, "components": document["components"]})
        errors = [e.message for e in validator.iter_errors(example)]
        assert not errors, (where, errors)
        checked += 1
    for path, method, operation in _operations(document):
        if not path.startswith("/v1/"):
            continue
        for status, answer in operation["responses"].items():
            for media, content in answer.get("content", {}).items():
                if media != "application/msgpack":
                    assert "example" in content, (method, path, status, media)
    assert checked > 90


def test_the_limits_of_the_settings_are_in_the_schemas(tmp_path):
    settings = Settings(data_dir=tmp_path / "data", warmup=False, max_steps=7, max_pairs=9)
    schemas = create_app(settings).openapi()["components"]["schemas"]
    assert schemas["StepRequest"]["properties"]["steps"]["maximum"] == 7
    assert schemas["PerPairQuery"]["properties"]["pairs"]["maxItems"] == 9
    assert schemas["ColumnarQuery"]["properties"]["position_b"]["maxItems"] == 9


@pytest.fixture(scope="module")
def generated(live_service, tmp_path_factory):
    """The package openapi-python-client generates from the live service's document."""
    directory = tmp_path_factory.mktemp("generated")
    spec = directory / "openapi.json"
    spec.write_text(httpx.get(f"{live_service.url}/openapi.json").text)
    config = directory / "config.yaml"
    config.write_text("post_hooks: []\n")  # no formatter run over the generated files
    command = [sys.executable, "-m", "openapi_python_client", "generate", "--path", str(spec)]
    command += ["--output-path", str(directory / "mrdem_api"), "--meta", "none"]
    run = subprocess.run(command + ["--config", str(config)], capture_output=True, text=True)
    assert run.returncode == 0, run.stdout + run.stderr
    sys.path.insert(0, str(directory))
    try:
        yield importlib.import_module("mrdem_api")
    finally:
        sys.path.remove(str(directory))
        for name in [m for m in sys.modules if m.split(".")[0] == "mrdem_api"]:
            del sys.modules[name]


def test_a_generated_client_uploads_queries_and_steps(generated, live_service):
    url = live_service.url
    with (
        generated.AuthenticatedClient(base_url=url, token="no-keys") as client,
        httpx.Client(base_url=url, timeout=60) as http,
    ):
        _round_trip(client, http)


def _round_trip(client, http) -> None:
    meshes = importlib.import_module("mrdem_api.api.meshes.upload_mesh")
    get_mesh = importlib.import_module("mrdem_api.api.meshes.get_mesh")
    contacts = importlib.import_module("mrdem_api.api.contacts.contacts")
    create_scene = importlib.import_module("mrdem_api.api.scenes.create_scene")
    step_scene = importlib.import_module("mrdem_api.api.scenes.step_scene")
    models = importlib.import_module("mrdem_api.models")

    tet = tetrahedron()
    upload = models.MeshUpload(vertices=tet["vertices"], faces=tet["faces"], epsilon=0.015)
    answer = meshes.sync_detailed(client=client, body=upload)
    assert answer.status_code in (200, 201), answer.content
    mesh = answer.parsed
    assert isinstance(mesh, models.MeshFacts) and mesh.triangles == 4 and mesh.epsilon == 0.015

    missing = get_mesh.sync_detailed(mesh_id="cafe", client=client)
    assert missing.status_code == 404 and isinstance(missing.parsed, models.Problem)
    assert missing.parsed.status == 404 and "cafe" in missing.parsed.detail

    columns = {
        "meshes": [mesh.id],
        "a": [0, 0],
        "b": [0, 0],
        "position_a": [[0, 0, 0], [0, 0, 0]],
        "orientation_a": [[1, 0, 0, 0], [1, 0, 0, 0]],
        "position_b": [[0.3, 0.2, 0.1], [3, 0, 0]],
        "orientation_b": [[1, 0, 0, 0], [0, 1, 0, 0]],
    }
    found = contacts.sync_detailed(client=client, body=models.ColumnarQuery.from_dict(columns))
    assert found.status_code == 200, found.content
    plain = http.post("/v1/contacts", json=columns).json()
    assert isinstance(found.parsed, models.ColumnarContacts)
    assert found.parsed.offsets == plain["offsets"] and plain["offsets"][1] > 0
    np.testing.assert_array_equal(found.parsed.points, plain["points"])
    np.testing.assert_array_equal(found.parsed.pairs, plain["pairs"])

    spec = {
        "bodies": [{"mesh": mesh.id, "position": [0, 0, 0.3], "velocity": [0.1, 0, 0]}],
        "planes": [{}],
        "scheme": "explicit",
        "dt": 1e-3,
    }
    created = create_scene.sync_detailed(client=client, body=models.SceneSpec.from_dict(spec))
    assert created.status_code == 201, created.content
    scene = created.parsed
    assert isinstance(scene, models.SceneSummary) and scene.bodies == 1 and scene.planes == 1
    stepped = step_scene.sync_detailed(
        scene_id=scene.id, client=client, body=models.StepRequest(steps=20)
    )
    assert stepped.status_code == 200, stepped.content
    assert isinstance(stepped.parsed, models.StepAnswer) and stepped.parsed.steps == 20
    assert len(stepped.parsed.stats) == 20

    twin = http.post("/v1/scenes", json=spec).json()["id"]
    expected = http.post(f"/v1/scenes/{twin}/step", json={"steps": 20}).json()["state"]
    assert stepped.parsed.state.positions == expected["positions"]
    assert stepped.parsed.state.velocities == expected["velocities"]
    assert expected["positions"][0][2] < 0.3  # it fell
    assert json.loads(json.dumps(stepped.parsed.to_dict()))["id"] == scene.id
