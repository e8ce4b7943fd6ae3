"""``POST /v1/contacts`` against a real server equals the in-process engine call."""

from __future__ import annotations

import numpy as np
import pytest
from harness import as_array, msgpack_body, post_msgpack, server_timing

from engine import Pose, build_tree, find_contacts_batch, shapes


@pytest.fixture(scope="module")
def spheres(service):

    meshes = {"small": shapes.icosphere(2, radius=0.5), "large": shapes.icosphere(3, radius=1.0)}
    ids, trees = {}, {}
    with service.client(timeout=120) as client:
        for name, mesh in meshes.items():
            payload = {
                "vertices": mesh.vertices.tolist(),
                "faces": mesh.faces.tolist(),
                "epsilon": 0.02,
            }
            ids[name] = client.post("/v1/meshes", json=payload).json()["id"]
            trees[name] = build_tree(mesh, 0.02)
    return ids, trees


def _poses(rng, n):
    """Poses of B around A: close enough to touch for most of them."""
    out = []
    for _ in range(n):
        direction = rng.normal(size=3)
        direction /= np.linalg.norm(direction)
        q = rng.normal(size=4)
        out.append((direction * rng.uniform(1.45, 1.56), q / np.linalg.norm(q)))
    return out


@pytest.mark.parametrize("kernel", ["hybrid", "exact"])
@pytest.mark.parametrize("transport", ["json", "msgpack"])
def test_contacts_equal_the_in_process_engine(http, spheres, kernel, transport):
    ids, trees = spheres
    rng = np.random.default_rng(7)
    poses = _poses(rng, 12)
    request = {
        "pairs": [
            {
                "a": ids["small"],
                "pose_a": {"position": [0.0, 0.0, 0.0], "orientation": [1.0, 0.0, 0.0, 0.0]},
                "b": ids["large"],
                "pose_b": {"position": p.tolist(), "orientation": q.tolist()},
            }
            for p, q in poses
        ],
        "kernel": kernel,
    }
    if transport == "json":
        response = http.post("/v1/contacts", json=request)
        assert response.status_code == 200, response.text
        body = response.json()
    else:
        response = post_msgpack(http, "/v1/contacts", request)
        assert response.status_code == 200, response.text
        body = msgpack_body(response)
    expected = find_contacts_batch(
        [(trees["small"], Pose.identity(), trees["large"], Pose(p, q)) for p, q in poses],
        kernel=kernel,
    )
    assert len(body["results"]) == len(expected)
    touching = 0
    for got, want in zip(body["results"], expected, strict=True):
        for name in ("points", "normals", "overlaps"):
            np.testing.assert_allclose(
                as_array(got[name]).reshape(np.shape(getattr(want, name))),
                getattr(want, name),
                rtol=0,
                atol=1e-12,
            )
        np.testing.assert_array_equal(np.asarray(got["pairs"]).reshape(-1, 2), want.pairs)
        touching += len(want.points) > 0
    assert 0 < touching < len(poses)  # both touching and separated pairs were asked
    stats = body["stats"]
    assert stats["pairs"] == len(poses)
    assert stats["comparisons"] == sum(c.stats.comparisons for c in expected)
    assert stats["contacts"] == sum(len(c.points) for c in expected)


def test_flat_search_over_http_matches_the_hierarchy(http, spheres):
    ids, _ = spheres
    pair = {
        "a": ids["small"],
        "b": ids["large"],
        "pose_b": {"position": [1.5, 0.0, 0.0], "orientation": [1.0, 0.0, 0.0, 0.0]},
    }
    deep = http.post("/v1/contacts", json={"pairs": [pair]}).json()
    flat = http.post("/v1/contacts", json={"pairs": [pair], "hierarchy": False}).json()
    assert len(deep["results"][0]["points"]) > 0
    assert deep["results"][0]["pairs"] == flat["results"][0]["pairs"]
    assert flat["stats"]["comparisons"] > 10 * deep["stats"]["comparisons"]


def test_metrics_count_requests_and_comparisons(http, spheres):
    ids, _ = spheres
    pair = {"a": ids["small"], "b": ids["small"], "pose_b": {"position": [0.99, 0, 0]}}
    assert http.post("/v1/contacts", json={"pairs": [pair]}).status_code == 200
    text = http.get("/metrics").text
    assert 'mrdem_http_requests_total{method="POST",route="/v1/contacts",status="200"}' in text
    comparisons = [line for line in text.splitlines() if line.startswith("mrdem_triangle_comp")]
    assert comparisons and float(comparisons[0].split()[-1]) > 0


@pytest.mark.parametrize("layout", ["pairs", "columnar"])
def test_the_answer_says_where_its_time_went(http, spheres, layout):
    """``Server-Timing``: the search (the ``stats.seconds`` of the body) and the encoding of
    the answer, in milliseconds."""
    ids, _ = spheres
    if layout == "pairs":
        pair = {"a": ids["small"], "b": ids["large"], "pose_b": {"position": [1.5, 0, 0]}}
        request = {"pairs": [pair] * 3}
    else:
        request = {
            "meshes": [ids["small"], ids["large"]],
            "a": [0, 0, 1],
            "b": [1, 1, 1],
            "position_a": [[0, 0, 0]] * 3,
            "orientation_a": [[1, 0, 0, 0]] * 3,
            "position_b": [[1.5, 0, 0], [0, 1.5, 0], [0, 0, 2.1]],
            "orientation_b": [[1, 0, 0, 0]] * 3,
        }
    response = http.post("/v1/contacts", json=request)
    assert response.status_code == 200, response.text
    timing = server_timing(response)
    assert list(timing) == ["search", "encode"]
    assert timing["search"] == pytest.approx(response.json()["stats"]["seconds"] * 1e3, abs=1e-3)
    assert 0 < timing["encode"] < 1e4
