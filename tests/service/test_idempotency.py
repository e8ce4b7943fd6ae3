"""``Idempotency-Key`` on creating and stepping scenes: a repeated key answers the first
answer and changes nothing; another request under the key is refused; the key and the
effect are committed together, across a kill -9."""

from __future__ import annotations

import sqlite3
import uuid

import httpx
import numpy as np
import pytest
from harness import ServiceProcess, assert_problem

from mrdem_common.codec import MSGPACK, packb, unpackb
from service.errors import Conflict
from service.idempotency import InFlight, Key
from service.store import KeyTaken, Store


def _scene_spec(http: httpx.Client) -> dict:
    vertices = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], float) - 0.25
    faces = [[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]]
    mesh = http.post("/v1/meshes", json={"vertices": vertices.tolist(), "faces": faces})
    assert mesh.status_code in (200, 201), mesh.text
    return {
        "bodies": [
            {"mesh": mesh.json()["id"], "position": [0, 0, 0.3], "velocity": [0.2, 0, -0.5]},
            {"mesh": mesh.json()["id"], "position": [1.5, 0, 0.3]},
        ],
        "planes": [{"point": [0, 0, 0], "normal": [0, 0, 1], "size": 6.0}],
        "dt": 1e-3,
        "scheme": "explicit",
    }


def _scenes(data_dir) -> int:
    with sqlite3.connect(f"file:{data_dir}/mrdem.sqlite3?mode=ro", uri=True) as db:
        return db.execute("SELECT COUNT(*) FROM scenes").fetchone()[0]


def test_a_repeated_key_creates_one_scene_and_answers_the_first_answer(http, service):
    spec = _scene_spec(http)
    key = {"Idempotency-Key": uuid.uuid4().hex}
    before = _scenes(service.data_dir)
    first = http.post("/v1/scenes", json=spec, headers=key)
    assert first.status_code == 201, first.text
    assert "idempotent-replayed" not in first.headers
    again = http.post("/v1/scenes", json=spec, headers=key)
    assert again.status_code == 201 and again.headers["idempotent-replayed"] == "true"
    assert again.json() == first.json()
    assert _scenes(service.data_dir) == before + 1
    # the same answer in the media type the repeat asks for
    packed = http.post("/v1/scenes", json=spec, headers={**key, "accept": MSGPACK})
    assert packed.status_code == 201 and packed.headers["content-type"] == MSGPACK
    replay = unpackb(packed.content)
    assert replay["id"] == first.json()["id"]
    np.testing.assert_array_equal(replay["state"]["positions"], first.json()["state"]["positions"])
    # without a key, or with another, a new scene
    assert http.post("/v1/scenes", json=spec).json()["id"] != first.json()["id"]
    other = {"Idempotency-Key": uuid.uuid4().hex}
    assert http.post("/v1/scenes", json=spec, headers=other).json()["id"] != first.json()["id"]
    assert _scenes(service.data_dir) == before + 3


def test_a_repeated_step_steps_once(http):
    scene = http.post("/v1/scenes", json=_scene_spec(http)).json()["id"]
    path = f"/v1/scenes/{scene}/step"
    key = {"Idempotency-Key": uuid.uuid4().hex}
    first = http.post(path, json={"steps": 5}, headers=key)
    assert first.status_code == 200 and first.json()["steps"] == 5
    again = http.post(path, json={"steps": 5}, headers=key)
    assert again.status_code == 200 and again.headers["idempotent-replayed"] == "true"
    assert again.json() == first.json()
    assert http.get(f"/v1/scenes/{scene}").json()["steps"] == 5
    # the scene went on from the first answer's state, once
    later = http.post(path, json={"steps": 5}).json()
    assert later["steps"] == 10 and later["time"] == pytest.approx(10e-3)
    # still the first answer, after the scene moved on
    assert http.post(path, json={"steps": 5}, headers=key).json() == first.json()


def test_a_key_with_another_request_or_a_malformed_key_is_refused(http):
    spec = _scene_spec(http)
    key = {"Idempotency-Key": uuid.uuid4().hex}
    scene = http.post("/v1/scenes", json=spec, headers=key).json()["id"]
    changed = {**spec, "dt": 2e-3}
    assert_problem(http.post("/v1/scenes", json=changed, headers=key), 422, "Idempotency-Key")
    step = f"/v1/scenes/{scene}/step"  # the same key on another route: another request
    assert_problem(http.post(step, json={"steps": 1}, headers=key), 422, "different request")
    assert http.get(f"/v1/scenes/{scene}").json()["steps"] == 0
    for bad in ("has space", "x" * 256, "é"):
        header = {"Idempotency-Key": bad.encode()}
        assert_problem(http.post(step, json={"steps": 1}, headers=header), 400, "ASCII")
    assert http.get(f"/v1/scenes/{scene}").json()["steps"] == 0


def test_keys_survive_kill_9_with_their_effect_and_belong_to_their_owner(tmp_path):
    data = tmp_path / "data"
    keys = {"api_keys": "first-key-123,second-key-456"}
    first = ServiceProcess(data, **keys).start()
    key = {"Idempotency-Key": "retry-me"}
    try:
        auth = {"authorization": "Bearer first-key-123"}
        with httpx.Client(base_url=first.url, timeout=120, headers=auth) as client:
            created = client.post("/v1/scenes", json=_scene_spec(client), headers=key)
            scene = created.json()["id"]
            stepped = client.post(f"/v1/scenes/{scene}/step", json={"steps": 3}, headers=key)
            assert stepped.status_code == 422  # the key is the scene's creation's
            step_key = {"Idempotency-Key": "step-once"}
            stepped = client.post(f"/v1/scenes/{scene}/step", json={"steps": 3}, headers=step_key)
            assert stepped.status_code == 200
    finally:
        first.kill()
    second = ServiceProcess(data, **keys).start()
    try:
        auth = {"authorization": "Bearer first-key-123"}
        with httpx.Client(base_url=second.url, timeout=120, headers=auth) as client:
            path = f"/v1/scenes/{scene}/step"
            again = client.post(path, json={"steps": 3}, headers=step_key)
            assert again.headers["idempotent-replayed"] == "true"
            assert again.json() == stepped.json()
            assert client.get(f"/v1/scenes/{scene}").json()["steps"] == 3
        other = {"authorization": "Bearer second-key-456"}
        with httpx.Client(base_url=second.url, timeout=120, headers=other) as client:
            mine = client.post("/v1/scenes", json=_scene_spec(client), headers=key)
            assert mine.status_code == 201 and "idempotent-replayed" not in mine.headers
            assert mine.json()["id"] != scene  # another owner's key of the same name
    finally:
        second.stop()


def test_a_key_whose_first_request_runs_is_busy():
    running = InFlight()
    key = Key("k", "fingerprint")
    with running.claim("owner", key):
        with pytest.raises(Conflict) as busy, running.claim("owner", key):
            pass
        assert busy.value.headers["Retry-After"] == "1"
        with running.claim("another owner", key), running.claim("owner", None):
            pass
    with running.claim("owner", key):  # released
        pass


def test_the_store_keeps_a_key_with_its_effect_or_neither(tmp_path):
    store = Store(tmp_path, key_retention=3600.0)
    try:
        row = Key("k", "f").remember(201, {"id": "a", "x": np.arange(3.0)})
        assert store.add_scene("o", "a", {}, b"state", [], row) == []
        assert store.remembered("o", "k")[:2] == ("f", 201)
        np.testing.assert_array_equal(unpackb(store.remembered("o", "k")[2])["x"], np.arange(3.0))
        with pytest.raises(KeyTaken):  # the key taken: the second scene is not recorded
            store.add_scene("o", "b", {}, b"state", [], row)
        assert store.scene("o", "b") is None
        with pytest.raises(KeyTaken):  # nor a new state
            store.save_state("o", "a", b"new", 1, row)
        assert store.scene("o", "a")[1:] == (b"state", 0)
        assert not store.save_state("o", "gone", b"new", 1, Key("k2", "f").remember(200, {}))
        assert store.remembered("o", "k2") is None  # no scene, no key
        assert store.save_state("o", "a", b"new", 1, ("k3", "f", 200, packb({})))
        assert store.scene("o", "a")[1:] == (b"new", 1) and store.remembered("o", "k3")
        # keys older than the retention go when another is stored
        store.db.connection.execute(
            "UPDATE idempotency SET created = created - 7200 WHERE key = 'k'"
        )
        assert store.save_state("o", "a", b"newer", 2, ("k4", "f", 200, packb({})))
        assert store.remembered("o", "k") is None and store.remembered("o", "k3")
    finally:
        store.close()
