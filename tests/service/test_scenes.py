"""Scenes over HTTP step exactly as in process, keep their state across kill -9, and
refuse bad input with a problem that names the field."""

from __future__ import annotations

import httpx
import numpy as np
import pytest
from harness import ServiceProcess, assert_problem, msgpack_body, post_msgpack

from engine import Mesh, Scene, build_tree, shapes
from engine.trees.halos import FIXED_EPSILON_FRACTION, size_epsilon

STATE = ("positions", "orientations", "velocities", "angular_velocities")


def _ball():
    return shapes.icosphere(2, radius=0.5)


def _upload(client: httpx.Client, mesh=None, epsilon: float | None = 0.01) -> str:
    mesh = _ball() if mesh is None else mesh
    payload = {"vertices": mesh.vertices.tolist(), "faces": mesh.faces.tolist()}
    if epsilon is not None:
        payload["epsilon"] = epsilon
    response = client.post("/v1/meshes", json=payload)
    assert response.status_code in (200, 201), response.text
    return response.json()["id"]


def _open_box():
    """A unit box without its top: an open mesh."""
    box = shapes.box()
    faces = box.faces[box.face_normals[:, 2] < 0.5]
    used, inverse = np.unique(faces, return_inverse=True)
    return Mesh(box.vertices[used], inverse.reshape(-1, 3))


def _spec(mesh_id: str, scheme: str) -> dict:
    return {
        "bodies": [
            {"mesh": mesh_id, "position": [0, 0, 0.6], "velocity": [0.3, 0, -0.5]},
            {"mesh": mesh_id, "position": [1.2, 0, 0.6], "velocity": [-0.3, 0, 0], "mass": 2.0},
        ],
        "planes": [{"point": [0, 0, 0], "normal": [0, 0, 1], "size": 6.0, "divisions": 4}],
        "epsilon": 0.01,
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
    assert put.json()["overlaps"] is None  # no body moved
    local.set_state(velocities=velocities)
    _close(put.json()["state"], local)
    body = http.post(f"/v1/scenes/{scene_id}/step", json={"steps": 10}).json()
    for _ in range(10):
        local.step(2e-3)
    _close(body["state"], local)
    assert http.delete(f"/v1/scenes/{scene_id}").status_code == 204
    assert_problem(http.get(f"/v1/scenes/{scene_id}"), 404, "no scene")


def test_moving_bodies_reports_the_pairs_whose_surfaces_cross(http):
    mesh_id = _upload(http)
    scene_id = http.post("/v1/scenes", json=_spec(mesh_id, "explicit")).json()["id"]
    state = f"/v1/scenes/{scene_id}/state"
    # ball 0 sinks 5 mm into the plane (row 2), ball 1 rests 5 mm into its halo: ε = 0.01
    positions = [[0.0, 0.0, 0.495], [1.2, 0.0, 0.505], [0.0, 0.0, 0.0]]
    put = http.put(state, json={"positions": positions})
    assert put.status_code == 200, put.text
    overlaps = put.json()["overlaps"]
    assert overlaps["pairs"] == [[0, 2]]
    assert overlaps["largest"] == pytest.approx(1.0)
    local = _in_process("explicit")
    report = local.set_state(positions=np.array(positions))
    np.testing.assert_array_equal(report.pairs, overlaps["pairs"])
    apart = [[0.0, 0.0, 0.6], [1.2, 0.0, 0.505], [0.0, 0.0, 0.0]]
    overlaps = http.put(state, json={"positions": apart}).json()["overlaps"]
    assert overlaps["pairs"] == []
    assert overlaps["largest"] == pytest.approx(0.75, rel=1e-2)  # 15 mm of a 20 mm reach


def test_bad_scene_requests(http):
    mesh_id = _upload(http)
    flat = _upload(http, shapes.plane(size=(2.0, 2.0)), epsilon=None)  # a free flat mesh: 422
    good = _spec(mesh_id, "explicit")
    body0 = good["bodies"][0]
    cases = [
        ({**good, "bodies": []}, 422, "bodies must have at least 1 item"),
        ({**good, "separation_speed": 0}, 422, "separation_speed must be greater than 0"),
        ({**good, "separation_speed": "fast"}, 422, "separation_speed must be a number"),
        ({**good, "contact_model": {"tangential_stiffness": -1}}, 422, "tangential_stiffness"),
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
        ({**good, "epsilon": 0}, 422, "epsilon must be a finite number > 0"),
        ({**good, "bodies": [{**body0, "epsilon": -1}]}, 422, "bodies[0].epsilon must be"),
        ({**good, "bodies": [{**body0, "epsilon": "thin"}]}, 422, "bodies[0].epsilon must be"),
        (
            {**good, "bodies": [{**body0, "inertia": [1, 1, 1]}]},
            422,
            "bodies[0].inertia needs mass",
        ),
        (
            {**good, "bodies": [body0, {**body0, "center_of_mass": [0, 0, 0]}]},
            422,
            "bodies[1].center_of_mass needs mass",
        ),
        (
            {
                **good,
                "bodies": [{**body0, "mass": 1, "inertia": [[1, 2, 0], [0, 1, 0], [0, 0, 1]]}],
            },
            422,
            "bodies[0].inertia must be symmetric: [0][1] = 2 but [1][0] = 0",
        ),
        (
            {**good, "bodies": [{**body0, "mass": 1, "inertia": [1, 1, 3]}]},
            422,
            "bodies[0].inertia's principal moments (1, 1, 3) violate the triangle inequality",
        ),
        (
            {**good, "bodies": [{**body0, "mass": 1, "inertia": [1, -1, 1]}]},
            422,
            "bodies[0].inertia must be positive definite",
        ),
        ({**good, "bodies": [{**body0, "mass": 1, "inertia": [1, 1]}]}, 422, "shape (3,)"),
        ({**good, "bodies": [{**body0, "mass": 1, "inertia": "I"}]}, 422, "bodies[0].inertia"),
        (
            {**good, "bodies": [{**body0, "mass": 1, "center_of_mass": [0, 0]}]},
            422,
            "bodies[0].center_of_mass must have shape (3,)",
        ),
        (
            {**good, "bodies": [body0, {**body0, "mesh": flat}]},
            422,
            "bodies[1]: a free body takes its mass properties from its convex hull",
        ),
    ]
    for body, status, words in cases:
        assert_problem(http.post("/v1/scenes", json=body), status, words)
    arrays = [  # msgpack arrays where a number or a name belongs: 422, never a 500
        ({**good, "bodies": [{**body0, "epsilon": np.array([1.0, 2.0])}]}, "bodies[0].epsilon"),
        ({**good, "bodies": [{**body0, "epsilon": np.array([1.0])}]}, "bodies[0].epsilon"),
        ({**good, "epsilon": np.array([1.0, 2.0])}, "epsilon"),
        ({**good, "scheme": np.array([1, 2])}, "scheme"),
        ({**good, "contact_model": {"law": np.array([1.0, 2.0])}}, "contact_model.law"),
    ]
    for body, words in arrays:
        assert_problem(post_msgpack(http, "/v1/scenes", body), 422, words)
    scene_id = http.post("/v1/scenes", json=good).json()["id"]
    step = f"/v1/scenes/{scene_id}/step"
    assert_problem(http.post(step, json={"steps": 0}), 422, "steps must be")
    assert_problem(http.post(step, json={"steps": 10**9}), 422, "steps must be")
    assert_problem(http.post(step, json={"steps": 2.5}), 422, "steps must be an integer")
    assert_problem(http.post(step, json={"dt": -1}), 422, "dt must be")
    state = f"/v1/scenes/{scene_id}/state"
    assert_problem(http.put(state, json={"positions": [[0, 0, 0]]}), 422, "shape (3, 3)")
    assert_problem(http.put(state, json={"spin": [[0, 0, 0]]}), 422, "spin is not a field")
    assert_problem(
        http.put(state, json={"positions": [[0, 0, 0]] * 3, "x": 1}), 422, "x is not a field"
    )
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


@pytest.mark.parametrize("floor", ["uploaded mesh", "plane"])
def test_a_ball_rests_within_one_percent_of_its_radius_with_no_epsilon_anywhere(http, floor):
    """A radius-0.5 ball and a 10 m floor, both uploaded without ε (or the scene's plane
    without one): the floor takes a tenth of the ball's ε, and the ball, dropped 10 cm,
    rests with its centre less than 1 % of its radius above the floor, and not below."""
    ball = _upload(http, _ball(), epsilon=None)
    spec = {
        "bodies": [{"mesh": ball, "position": [0.2, 0.1, 0.6]}],
        "planes": [],
        "dt": 1e-3,
        "contact_model": {"law": "paper", "damping": 0.3},
    }
    if floor == "plane":
        spec["planes"] = [{"size": 10.0}]
    else:
        plate = _upload(http, shapes.plane(size=(10.0, 10.0), divisions=8), epsilon=None)
        spec["bodies"].insert(0, {"mesh": plate, "fixed": True})
    created = http.post("/v1/scenes", json=spec)
    assert created.status_code == 201, created.text
    summary = created.json()
    row = 1 if floor != "plane" else 0  # the ball's row: bodies in order, then planes
    eps = np.asarray(summary["epsilon"], float)
    assert eps[row] == pytest.approx(size_epsilon(_ball()), rel=1e-12)
    assert eps[1 - row] == pytest.approx(FIXED_EPSILON_FRACTION * eps[row], rel=1e-12)
    assert summary["mass_source"][row] == "mesh" and summary["mass_source"][1 - row] == "fixed"
    for _ in range(3):
        response = post_msgpack(http, f"/v1/scenes/{summary['id']}/step", {"steps": 500})
        assert response.status_code == 200, response.text
    state = msgpack_body(response)["state"]
    height = float(np.asarray(state["positions"])[row, 2]) - 0.5  # the ball's lowest vertex
    assert 0.0 <= height <= 0.01 * 0.5
    assert np.linalg.norm(np.asarray(state["velocities"])[row]) < 1e-6


def test_mass_properties_from_the_mesh_the_hull_or_the_caller(http):
    ball, shell = _upload(http), _upload(http, _open_box())
    spec = {
        "bodies": [
            {"mesh": ball, "position": [0, 0, 3]},
            {"mesh": shell, "position": [3, 0, 3], "density": 2.0},
            {
                "mesh": shell,
                "position": [-3, 0, 3],
                "mass": 2.0,
                "inertia": [[0.3, 0.0, 0.0], [0.0, 0.3, 0.0], [0.0, 0.0, 0.5]],
                "center_of_mass": [0.0, 0.0, -0.1],
                "epsilon": 0.02,
            },
        ],
        "planes": [{"size": 10.0}],
    }
    created = http.post("/v1/scenes", json=spec)
    assert created.status_code == 201, created.text
    summary = created.json()
    assert summary["mass_source"] == ["mesh", "convex_hull", "given", "fixed"]
    assert summary["epsilon"][2] == 0.02 and summary["spec"]["bodies"][2]["epsilon"] == 0.02
    local = Scene()  # the same bodies in process
    ball_tree, shell_tree = build_tree(_ball(), 0.01), build_tree(_open_box(), 0.01)
    local.add_body(ball_tree, position=(0, 0, 3))
    local.add_body(shell_tree, position=(3, 0, 3), density=2.0)
    assert local.masses[1] == pytest.approx(2.0)  # the hull: the unit box
    given = {k: spec["bodies"][2][k] for k in ("mass", "inertia", "center_of_mass", "epsilon")}
    local.add_body(shell_tree, position=(-3, 0, 3), **given)
    local.add_plane(size=10.0)
    _close(summary["state"], local)
    stepped = http.post(f"/v1/scenes/{summary['id']}/step", json={"steps": 20}).json()
    for _ in range(20):
        local.step(1e-3)
    _close(stepped["state"], local, atol=1e-12)


def test_the_gentle_start_and_the_friction_law_are_scene_settings(http):
    """``separation_speed`` (default 0.5 m/s, null: none) and the contact model's
    ``tangential_stiffness`` reach the engine: a ball sunk 5 mm into the plane is let go
    at 0.5 m/s at most by default and pushed out faster without a gentle start."""
    mesh_id = _upload(http)
    fastest = {}
    for speed in ("default", None):
        spec = _spec(mesh_id, "implicit-surrogate")
        spec["bodies"] = [{"mesh": mesh_id, "position": [0, 0, 0.495]}]
        spec["contact_model"] = {"law": "paper", "tangential_stiffness": 0.0}
        if speed is None:
            spec["separation_speed"] = None
        created = http.post("/v1/scenes", json=spec)
        assert created.status_code == 201, created.text
        assert created.json()["spec"]["separation_speed"] == (0.5 if speed else None)
        assert created.json()["spec"]["contact_model"]["tangential_stiffness"] == 0.0
        body = http.post(f"/v1/scenes/{created.json()['id']}/step", json={"steps": 5}).json()
        fastest[speed] = max(abs(s[2]) for s in np.asarray(body["state"]["velocities"]))
    assert fastest["default"] <= 0.5 + 1e-9 < fastest[None]


def test_a_snapshot_keeps_whether_the_next_step_starts_gently():
    """Restoring a snapshot (a restart, a rolled-back step) is not a change from outside:
    the next step starts gently exactly when it would have."""
    from service.scenes import pack_state, restore_state

    built = _in_process("explicit")  # bodies just added: the next step starts gently
    assert built.gentle_start
    fresh = pack_state(built)
    built.step(2e-3)
    assert not built.gentle_start
    stepped = pack_state(built)
    other = _in_process("explicit")
    restore_state(other, stepped)
    assert not other.gentle_start
    restore_state(other, fresh)
    assert other.gentle_start
