"""Scenes over HTTP step exactly as in process, keep their state across kill -9, and
refuse bad input with a problem that names the field."""

from __future__ import annotations

import httpx
import numpy as np
import pytest
from harness import ServiceProcess, assert_problem, msgpack_body, post_msgpack

from engine import Scene, build_tree, shapes

STATE = ("positions", "orientations", "velocities", "angular_velocities")


def _ball():
    return shapes.icosphere(2, radius=0.5)


def _upload(client: httpx.Client) -> str:
    mesh = _ball()
    payload = {"vertices": mesh.vertices.tolist(), "faces": mesh.faces.tolist(), "epsilon": 0.01}
    return client.post("/v1/meshes", json=payload).json()["id"]


def _spec(mesh_id: str, scheme: str) -> dict:
    return {
        "bodies": [
            {"mesh": mesh_id, "position": [0, 0, 0.6], "velocity": [0.3, 0, -0.5]},
            {"mesh": mesh_id, "position": [1.2, 0, 0.6], "velocity": [-0.3, 0, 0], "mass": 2.0},
        ],
        "planes": [{"point": [0, 0, 0], "normal": [0, 0, 1], "size": 6.0, "divisions": 4}],
        "gravity": [0, 0, -9.81],
        "dt": 2e-3,
        "scheme": scheme,
        "contact_model": {"law": "paper", "damping": 0.2, "friction": 0.4},
    }


def _in_process(scheme: str) -> Scene:
    """The same scene built with the engine directly."""
    from engine import PaperSpring

    tree = build_tree(_ball(), 0.01)
    scene = Scene(
        gravity=(0, 0, -9.81),
        contact_model=PaperSpring(damping=0.2, friction=0.4),
        scheme=scheme,
    )
    scene.add_body(tree, position=(0, 0, 0.6), velocity=(0.3, 0, -0.5))
    scene.add_body(tree, position=(1.2, 0, 0.6), velocity=(-0.3, 0, 0), mass=2.0)
    scene.add_plane((0, 0, 0), (0, 0, 1), size=6.0, divisions=4, epsilon=0.01)
    return scene


def _close(remote: dict, scene: Scene, atol: float = 1e-12) -> None:
    for name in STATE:
        np.testing.assert_allclose(
            np.asarray(remote[name], float), getattr(scene, name), rtol=0, atol=atol
        )


@pytest.mark.parametrize("scheme", ["explicit", "implicit-surrogate", "multiscale"])
def test_remote_steps_equal_in_process_steps(http, scheme):
    mesh_id = _upload(http)
    created = http.post("/v1/scenes", json=_spec(mesh_id, scheme))
    assert created.status_code == 201, created.text
    scene_id = created.json()["id"]
    assert created.json()["bodies"] == 2 and created.json()["planes"] == 1
    local = _in_process(scheme)
    _close(created.json()["state"], local)
    contacts = 0
    for n in (5, 40, 15):  # through the ball's landing on the plane
        response = post_msgpack(http, f"/v1/scenes/{scene_id}/step", {"steps": n})
        assert response.status_code == 200, response.text
        body = msgpack_body(response)
        stats = [local.step(2e-3) for _ in range(n)]
        _close(body["state"], local)
        assert [s["picard_iterations"] for s in body["stats"]] == [
            s.picard_iterations for s in stats
        ]
        contacts += sum(s["contacts"] for s in body["stats"])
    assert contacts > 0  # the ball touched the plane
    assert body["steps"] == 60 and body["time"] == pytest.approx(local.time)
    again = http.get(f"/v1/scenes/{scene_id}").json()
    assert again["steps"] == 60
    _close(again["state"], local)


def test_state_can_be_overwritten_then_stepped(http):
    mesh_id = _upload(http)
    scene_id = http.post("/v1/scenes", json=_spec(mesh_id, "explicit")).json()["id"]
    local = _in_process("explicit")
    velocities = np.array([[0.0, 0.0, 1.0], [0.0, 0.5, 0.0], [0.0, 0.0, 0.0]])
    put = http.put(f"/v1/scenes/{scene_id}/state", json={"velocities": velocities.tolist()})
    assert put.status_code == 200, put.text
    local.set_state(velocities=velocities)
    _close(put.json()["state"], local)
    body = http.post(f"/v1/scenes/{scene_id}/step", json={"steps": 10}).json()
    for _ in range(10):
        local.step(2e-3)
    _close(body["state"], local)
    assert http.delete(f"/v1/scenes/{scene_id}").status_code == 204
    assert_problem(http.get(f"/v1/scenes/{scene_id}"), 404, "no scene")


def test_bad_scene_requests(http):
    mesh_id = _upload(http)
    good = _spec(mesh_id, "explicit")
    body0 = good["bodies"][0]
    cases = [
        ({**good, "bodies": []}, 422, "at least one body"),
        ({**good, "bodies": [{**body0, "mesh": "cafe"}]}, 404, "no mesh 'cafe'"),
        ({**good, "bodies": [{**body0, "density": 1.0, "mass": 1.0}]}, 422, "not both"),
        ({**good, "bodies": [{**body0, "orientation": [2, 0, 0, 0]}]}, 422, "unit quaternion"),
        ({**good, "bodies": [{**body0, "position": [0, 0]}]}, 422, "bodies[0].position"),
        ({**good, "bodies": [{**body0, "mass": -1}]}, 422, "bodies[0].mass"),
        ({**good, "scheme": "verlet"}, 422, "scheme must be one of"),
        ({**good, "dt": 0}, 422, "dt must be"),
        ({**good, "planes": [{"normal": [0, 0, 0]}]}, 422, "planes[0].normal must not be zero"),
        ({**good, "contact_model": {"law": "magic"}}, 422, "contact_model.law"),
        ({**good, "contact_model": {"stiffness": 0}}, 422, "stiffness"),
        ({**good, "gravity": [0, 0]}, 422, "gravity must have shape (3,)"),
    ]
    for body, status, words in cases:
        assert_problem(http.post("/v1/scenes", json=body), status, words)
    scene_id = http.post("/v1/scenes", json=good).json()["id"]
    step = f"/v1/scenes/{scene_id}/step"
    assert_problem(http.post(step, json={"steps": 0}), 422, "steps must be")
    assert_problem(http.post(step, json={"steps": 10**9}), 422, "steps must be")
    assert_problem(http.post(step, json={"steps": 2.5}), 422, "steps must be an integer")
    assert_problem(http.post(step, json={"dt": -1}), 422, "dt must be")
    state = f"/v1/scenes/{scene_id}/state"
    assert_problem(http.put(state, json={"positions": [[0, 0, 0]]}), 422, "shape (3, 3)")
    assert_problem(http.put(state, json={"spin": [[0, 0, 0]]}), 422, "any of")
    assert_problem(http.put(state, json={"positions": [[0, 0, 0]] * 3, "x": 1}), 422, "unknown")
    assert_problem(http.post("/v1/scenes/0000/step", json={}), 404, "no scene")
    assert http.post(step).status_code == 200  # no body: one step of the scene's dt
    assert http.get("/healthz").status_code == 200


def test_scene_state_survives_kill_9(tmp_path):
    data = tmp_path / "data"
    first = ServiceProcess(data).start()
    try:
        with httpx.Client(base_url=first.url, timeout=120) as client:
            mesh_id = _upload(client)
            scene_id = client.post("/v1/scenes", json=_spec(mesh_id, "explicit")).json()["id"]
            stepped = client.post(f"/v1/scenes/{scene_id}/step", json={"steps": 30}).json()
            # the scene keeps its tree even when the mesh is deleted
            assert client.delete(f"/v1/meshes/{mesh_id}").status_code == 204
    finally:
        first.kill()
    second = ServiceProcess(data).start()
    try:
        with httpx.Client(base_url=second.url, timeout=120) as client:
            restored = client.get(f"/v1/scenes/{scene_id}").json()
            assert restored["steps"] == 30
            for name in STATE:
                assert restored["state"][name] == stepped["state"][name]  # bit for bit
            more = client.post(f"/v1/scenes/{scene_id}/step", json={"steps": 20}).json()
    finally:
        second.stop()
    local = _in_process("explicit")
    for _ in range(50):
        local.step(2e-3)
    _close(more["state"], local)
    assert more["steps"] == 50
