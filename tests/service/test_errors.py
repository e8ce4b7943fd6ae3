"""Every bad input gets a 4xx RFC 9457 problem with a useful detail; the server stays
healthy and no half-written file is left behind."""

from __future__ import annotations

import json
import math

import msgpack
import pytest
from harness import ServiceProcess, assert_problem, tetrahedron

from service.codecs import MSGPACK, NDARRAY_EXT, encode_msgpack

JSON_HEADERS = {"content-type": "application/json"}
MSGPACK_HEADERS = {"content-type": MSGPACK}
TET = tetrahedron()
UNIT = {"position": [0, 0, 0], "orientation": [1, 0, 0, 0]}


def _ext(dtype: str, shape, data: bytes) -> bytes:
    payload = msgpack.packb([dtype, shape, data])
    return msgpack.packb({"vertices": msgpack.ExtType(NDARRAY_EXT, payload), "faces": [[0, 1, 2]]})


# (name, method, path, request kwargs, status, words of the detail)
MESH_CASES = [
    (
        "malformed JSON",
        "POST",
        "/v1/meshes",
        {"content": b"{", "headers": JSON_HEADERS},
        400,
        "malformed json",
    ),
    (
        "empty body",
        "POST",
        "/v1/meshes",
        {"content": b"", "headers": JSON_HEADERS},
        400,
        "empty request body",
    ),
    (
        "other media type",
        "POST",
        "/v1/meshes",
        {"content": b"v 0 0 0", "headers": {"content-type": "text/plain"}},
        415,
        "text/plain",
    ),
    (
        "NaN in JSON",
        "POST",
        "/v1/meshes",
        {"content": b'{"vertices": [[0, 0, NaN]], "faces": []}', "headers": JSON_HEADERS},
        400,
        "non-finite",
    ),
    (
        "wrong vertex shape",
        "POST",
        "/v1/meshes",
        {"json": {"vertices": [[0, 0], [1, 0], [0, 1]], "faces": [[0, 1, 2]]}},
        422,
        "vertices must have shape (n, 3)",
    ),
    (
        "strings as coordinates",
        "POST",
        "/v1/meshes",
        {"json": {"vertices": [["a", "b", "c"]] * 3, "faces": [[0, 1, 2]]}},
        422,
        "vertices must be an array of numbers",
    ),
    (
        "float face indices",
        "POST",
        "/v1/meshes",
        {"json": {**TET, "faces": [[0.5, 1, 2]]}},
        422,
        "faces must be an array of integers",
    ),
    (
        "index out of range",
        "POST",
        "/v1/meshes",
        {"json": {**TET, "faces": [[0, 1, 7]]}},
        422,
        "faces refer to vertex 7",
    ),
    (
        "negative index",
        "POST",
        "/v1/meshes",
        {"json": {**TET, "faces": [[0, 1, -1]]}},
        422,
        "faces refer to vertex -1",
    ),
    (
        "missing faces",
        "POST",
        "/v1/meshes",
        {"json": {"vertices": TET["vertices"]}},
        422,
        "faces is missing",
    ),
    ("not an object", "POST", "/v1/meshes", {"json": [1, 2, 3]}, 422, "body must be an object"),
    (
        "only degenerate faces (repair leaves none)",
        "POST",
        "/v1/meshes",
        {"json": {"vertices": [[0, 0, 0], [1, 0, 0], [2, 0, 0]], "faces": [[0, 1, 2]]}},
        422,
        "no face is left",
    ),
    (
        "strict and a face to drop",
        "POST",
        "/v1/meshes",
        {"json": {**TET, "faces": [*TET["faces"], [0, 0, 1]], "strict": True}},
        422,
        "send strict=false (the default) to have them repaired",
    ),
    (
        "strict not a boolean",
        "POST",
        "/v1/meshes",
        {"json": {**TET, "strict": 1}},
        422,
        "strict must be true or false",
    ),
    (
        "no faces",
        "POST",
        "/v1/meshes",
        {"json": {"vertices": TET["vertices"], "faces": []}},
        422,
        "faces",
    ),
    ("negative epsilon", "POST", "/v1/meshes", {"json": {**TET, "epsilon": -1}}, 422, "epsilon"),
    (
        "boolean epsilon",
        "POST",
        "/v1/meshes",
        {"json": {**TET, "epsilon": True}},
        422,
        "epsilon must be a number",
    ),
    ("branching 1", "POST", "/v1/meshes", {"json": {**TET, "branching": 1}}, 422, "branching"),
    (
        "msgpack garbage",
        "POST",
        "/v1/meshes",
        {"content": b"\xc1\xc1\xc1", "headers": MSGPACK_HEADERS},
        400,
        "malformed msgpack",
    ),
    (
        "msgpack NaN",
        "POST",
        "/v1/meshes",
        {
            "content": encode_msgpack({"vertices": [[0, 0, math.nan]] * 3, "faces": [[0, 1, 2]]}),
            "headers": MSGPACK_HEADERS,
        },
        422,
        "vertices[0][2] must hold finite numbers only",
    ),
    (
        "msgpack unknown extension",
        "POST",
        "/v1/meshes",
        {
            "content": msgpack.packb({"vertices": msgpack.ExtType(42, b"x")}),
            "headers": MSGPACK_HEADERS,
        },
        400,
        "unknown msgpack extension type 42",
    ),
    (
        "msgpack array of wrong size",
        "POST",
        "/v1/meshes",
        {"content": _ext("<f8", [3, 3], b"\0" * 8), "headers": MSGPACK_HEADERS},
        400,
        "needs 72 bytes, got 8",
    ),
    (
        "msgpack object dtype",
        "POST",
        "/v1/meshes",
        {"content": _ext("|O", [1], b"\0" * 8), "headers": MSGPACK_HEADERS},
        400,
        "not accepted",
    ),
    (
        "file without a name",
        "POST",
        "/v1/meshes",
        {"files": {"file": ("blob", b"solid x\nendsolid x\n")}},
        422,
        "cannot tell the format",
    ),
    ("empty file", "POST", "/v1/meshes", {"files": {"file": ("empty.stl", b"")}}, 422, "is empty"),
    (
        "garbage STL",
        "POST",
        "/v1/meshes",
        {"files": {"file": ("junk.stl", b"this is not a mesh at all")}},
        422,
        "cannot read stl",
    ),
    (
        "garbage GLB",
        "POST",
        "/v1/meshes",
        {"files": {"file": ("junk.glb", b"glTF" + b"\x01" * 13)}},
        422,
        "cannot read glb",
    ),
    (
        "multipart without file",
        "POST",
        "/v1/meshes",
        {"data": {"epsilon": "0.1"}, "files": {"other": ("a.stl", b"x")}},
        422,
        "needs a 'file' part",
    ),
    ("unknown mesh", "GET", "/v1/meshes/0123456789abcdef", {}, 404, "no mesh"),
    ("delete unknown", "DELETE", "/v1/meshes/nope", {}, 404, "no mesh"),
    ("level not a number", "GET", "/v1/meshes/nope/surrogates?level=top", {}, 422, "level"),
    ("unknown route", "GET", "/v1/nothing", {}, 404, "no route"),
    ("wrong method", "PUT", "/v1/meshes", {"json": TET}, 405, "method not allowed"),
    (
        "accept nothing we speak",
        "GET",
        "/v1/meshes",
        {"headers": {"accept": "text/html"}},
        406,
        "text/html",
    ),
]


@pytest.fixture()
def mesh_id(http):
    return http.post("/v1/meshes", json={**TET, "epsilon": 0.1}).json()["id"]


def _pair(mesh_id, **change):
    return {"a": mesh_id, "pose_a": UNIT, "b": mesh_id, "pose_b": UNIT, **change}


def _contact_cases(mesh_id):
    return [
        ("no pairs", {"pairs": []}, 422, "pairs must have at least 1 item"),
        ("pairs not a list", {"pairs": {"a": 1}}, 422, "pairs must be a list"),
        ("unknown mesh", {"pairs": [_pair("feedbeef")]}, 404, "no mesh 'feedbeef'"),
        ("id not a string", {"pairs": [_pair(12)]}, 422, "pairs[0].a must be a string"),
        (
            "non-unit quaternion",
            {
                "pairs": [
                    _pair(mesh_id, pose_b={"position": [1, 0, 0], "orientation": [1, 1, 0, 0]})
                ]
            },
            422,
            "pairs[0].pose_b.orientation must be a unit quaternion",
        ),
        (
            "position of 2",
            {"pairs": [_pair(mesh_id, pose_a={"position": [1, 0]})]},
            422,
            "pairs[0].pose_a.position must have shape (3,)",
        ),
        (
            "missing position",
            {"pairs": [_pair(mesh_id, pose_a={"orientation": [1, 0, 0, 0]})]},
            422,
            "position is missing",
        ),
        (
            "huge but finite is fine; inf is not",
            {"pairs": [_pair(mesh_id, pose_b={"position": [1e308 * 10, 0, 0]})]},
            400,
            "non-finite",
        ),
        ("unknown kernel", {"pairs": [_pair(mesh_id)], "kernel": "fast"}, 422, "kernel must be"),
        (
            "hierarchy not a flag",
            {"pairs": [_pair(mesh_id)], "hierarchy": "yes"},
            422,
            "hierarchy must be true or false",
        ),
        (
            "unknown precision",
            {"pairs": [_pair(mesh_id)], "precision": "float16"},
            422,
            "precision must be",
        ),
        (
            "columnar: no meshes",
            {**_columns(mesh_id), "meshes": []},
            422,
            "meshes must have at least 1 item",
        ),
        (
            "columnar: index outside meshes",
            {**_columns(mesh_id), "b": [0, 3]},
            422,
            "b holds indices outside meshes",
        ),
        (
            "columnar: rows differ",
            {**_columns(mesh_id), "position_b": [[0, 0, 0]]},
            422,
            "position_b must have 2 rows (one per pair, as a), got 1",
        ),
        (
            "columnar: non-unit row",
            {**_columns(mesh_id), "orientation_a": [[1, 0, 0, 0], [0, 0, 0, 0.5]]},
            422,
            "orientation_a[1] must be a unit quaternion",
        ),
        (
            "columnar: missing field",
            {k: v for k, v in _columns(mesh_id).items() if k != "orientation_b"},
            422,
            "orientation_b is missing",
        ),
    ]


def _columns(mesh_id):
    return {
        "meshes": [mesh_id],
        "a": [0, 0],
        "b": [0, 0],
        "position_a": [[0, 0, 0], [0, 0, 0]],
        "orientation_a": [[1, 0, 0, 0], [1, 0, 0, 0]],
        "position_b": [[0.5, 0, 0], [3, 0, 0]],
        "orientation_b": [[1, 0, 0, 0], [1, 0, 0, 0]],
    }


@pytest.mark.parametrize("case", MESH_CASES, ids=[c[0] for c in MESH_CASES])
def test_bad_mesh_requests(http, case):
    _, method, path, kwargs, status, words = case
    assert_problem(http.request(method, path, **kwargs), status, words)
    assert http.get("/healthz").status_code == 200


def test_bad_contact_requests(http, mesh_id):
    for _, body, status, words in _contact_cases(mesh_id):
        text = json.dumps(body)  # Python writes inf as Infinity, which the service rejects
        response = http.post("/v1/contacts", content=text.encode(), headers=JSON_HEADERS)
        assert_problem(response, status, words)
    assert http.post("/v1/contacts", json={"pairs": [_pair(mesh_id)]}).status_code == 200
    columnar = http.post("/v1/contacts", json=_columns(mesh_id)).json()
    assert columnar["offsets"][0] == 0 and len(columnar["offsets"]) == 3


def test_surrogate_level_out_of_range(http, mesh_id):
    levels = http.get(f"/v1/meshes/{mesh_id}").json()["levels"]
    response = http.get(f"/v1/meshes/{mesh_id}/surrogates", params={"level": levels})
    assert_problem(response, 422, f"level must be in 0 … {levels - 1}")


def test_failed_uploads_leave_no_files(service, http):
    trees = service.data_dir / "trees"
    before = sorted(p.name for p in trees.iterdir())
    for case in MESH_CASES:
        _, method, path, kwargs, status, _ = case
        if method == "POST":
            assert http.request(method, path, **kwargs).status_code == status
    assert sorted(p.name for p in trees.iterdir()) == before
    assert not [p for p in trees.iterdir() if p.name.endswith(".tmp")]


def test_limits(tmp_path):
    """Bodies over the byte limit get 413 (before or while streaming); too many triangles
    or pairs get 422 — and the server answers the next request."""
    import httpx

    process = ServiceProcess(
        tmp_path / "data", max_body_bytes="2048", max_triangles="3", max_pairs="2"
    ).start()
    try:
        with httpx.Client(base_url=process.url, timeout=60) as client:
            big = {"vertices": [[0.0, 0.0, 0.0]] * 200, "faces": [[0, 1, 2]]}
            assert_problem(client.post("/v1/meshes", json=big), 413, "limit of 2048 bytes")

            def chunks():  # no Content-Length: the limit applies while streaming
                for _ in range(8):
                    yield b" " * 512

            streamed = client.post("/v1/meshes", content=chunks(), headers=JSON_HEADERS)
            assert_problem(streamed, 413, "limit of 2048 bytes")
            assert_problem(client.post("/v1/meshes", json=TET), 422, "takes <= 3")
            three = {"vertices": TET["vertices"], "faces": TET["faces"][:3]}
            mesh = client.post("/v1/meshes", json=three).json()["id"]
            pairs = [_pair(mesh)] * 3
            assert_problem(client.post("/v1/contacts", json={"pairs": pairs}), 422, "takes <= 2")
            assert client.get("/healthz").status_code == 200
            assert client.post("/v1/contacts", json={"pairs": pairs[:2]}).status_code == 200
    finally:
        process.stop()
