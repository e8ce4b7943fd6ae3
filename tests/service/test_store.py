"""The store (service/store/) on its two back ends: embedded (a real SQLite database and
tree files in a temporary directory) and shared (a real PostgreSQL server and an
S3-compatible server, moto, on loopback): tree files, meshes per owner, scenes and their
states, build jobs, what keeps a tree file, pruning, and durability across closing and
reopening. (The races between uploads, deletions and builds are in test_builds.py; kill -9
in test_durability.py; migrations and the back ends' own parts in test_store_backends.py.)"""

from __future__ import annotations

import sqlite3
import time

import numpy as np
import pytest

from engine import build_tree, shapes
from service.store import Store

SPEC = {"epsilon": 0.05, "branching": 8}


@pytest.fixture(params=["embedded", "shared"])
def backend(request, tmp_path):
    """Opens stores on one back end: ``backend()`` opens the same store again (the same
    directory, database and bucket)."""
    if request.param == "embedded":
        return lambda **kw: Store(tmp_path, **kw)
    from service.store import PostgresDatabase, S3Blobs

    url = request.getfixturevalue("postgres").database()
    s3 = request.getfixturevalue("s3")
    bucket = s3.bucket()

    def open_shared(**kw):
        return Store(
            tmp_path,
            database=PostgresDatabase(url, pool_size=4),
            blobs=S3Blobs(bucket, s3.endpoint, tmp_path / "tree-cache"),
            **kw,
        )

    return open_shared


@pytest.fixture()
def store(backend):
    store = backend()
    yield store
    store.close()


@pytest.fixture(scope="module")
def trees():
    """Two different trees (ids as the service would give content: any string)."""
    return {
        "t-box": build_tree(shapes.box(), 0.05),
        "t-ball": build_tree(shapes.icosphere(1), 0.02),
    }


def same_tree(a, b) -> bool:
    names = ("triangles", "epsilon", "level", "parent", "first_child", "child_count", "face")
    return all(np.array_equal(getattr(a, n), getattr(b, n)) for n in names) and (
        a.leaf_epsilon,
        a.branching,
        a.seed,
        a.bounding_radius,
    ) == (b.leaf_epsilon, b.branching, b.seed, b.bounding_radius)


def tree_files(store) -> set[str]:
    return {n[len("trees/") : -len(".npz")] for n in store.blobs.names("trees")}


# ------------------------------------------------------------------ layout and trees
def test_a_new_store_creates_its_layout(tmp_path):
    store = Store(tmp_path / "fresh" / "data")
    try:
        assert store.ping() and not store.shared
        for name in ("mrdem.sqlite3", "trees", "jobs"):
            assert (tmp_path / "fresh" / "data" / name).exists()
        connection = store.db.connection
        assert connection.execute("PRAGMA journal_mode").fetchone()[0] == "wal"
        assert connection.execute("PRAGMA synchronous").fetchone()[0] == 2  # FULL
    finally:
        store.close()


def test_put_tree_writes_a_file_and_tree_reads_it_back(store, trees, tmp_path):
    store.put_tree("t-box", trees["t-box"])
    assert tree_files(store) == {"t-box"} and store.has_tree("t-box")
    assert not store.has_tree("t-ball")
    assert same_tree(store.tree("t-box"), trees["t-box"])
    store._cache.clear()  # from the stored bytes this time
    assert same_tree(store.tree("t-box"), trees["t-box"])
    if not store.shared:
        assert (tmp_path / "trees" / "t-box.npz").exists()
        assert not list((tmp_path / "trees").glob(".*"))  # no temporary left behind


def test_put_tree_is_content_addressed_a_second_put_changes_nothing(store, trees):
    store.put_tree("t-box", trees["t-box"])
    before = store.blobs.get("trees/t-box.npz")
    store.put_tree("t-box", trees["t-ball"])  # the id names the content: nothing to write
    assert store.blobs.get("trees/t-box.npz") == before


def test_recently_used_trees_come_from_memory_and_the_oldest_are_dropped(backend, trees):
    store = backend(tree_cache=1)
    try:
        store.put_tree("t-box", trees["t-box"])
        assert store.tree("t-box") is trees["t-box"]  # kept in memory by the put
        store.put_tree("t-ball", trees["t-ball"])  # the cache holds one: t-box goes
        assert store.tree("t-ball") is trees["t-ball"]
        loaded = store.tree("t-box")  # from its file
        assert loaded is not trees["t-box"] and same_tree(loaded, trees["t-box"])
        assert store.tree("t-box") is loaded
    finally:
        store.close()


# ------------------------------------------------------------------ meshes
def test_meshes_per_owner(store, trees):
    assert store.add_mesh("alpha", "t-box", {"id": "t-box"}) is None  # no tree file yet
    store.put_tree("t-box", trees["t-box"])
    store.put_tree("t-ball", trees["t-ball"])
    assert store.add_mesh("alpha", "t-box", {"id": "t-box", "name": "box"}) is True
    assert store.add_mesh("alpha", "t-box", {"id": "t-box", "name": "other"}) is False
    assert store.add_mesh("alpha", "t-ball", {"id": "t-ball"}) is True
    assert store.add_mesh("beta", "t-box", {"id": "t-box", "name": "beta's"}) is True
    assert store.mesh("alpha", "t-box") == {"id": "t-box", "name": "box"}  # the first kept
    assert store.mesh("beta", "t-box") == {"id": "t-box", "name": "beta's"}
    assert store.mesh("gamma", "t-box") is None
    assert [m["id"] for m in store.meshes("alpha")] == ["t-box", "t-ball"]  # oldest first
    assert store.meshes("gamma") == []


def test_a_tree_file_lives_while_some_owner_has_the_mesh(store, trees):
    store.put_tree("t-box", trees["t-box"])
    store.add_mesh("alpha", "t-box", {"id": "t-box"})
    store.add_mesh("beta", "t-box", {"id": "t-box"})
    assert store.delete_mesh("alpha", "t-box") is True
    assert store.delete_mesh("alpha", "t-box") is False
    assert store.mesh("beta", "t-box") is not None and tree_files(store) == {"t-box"}
    assert store.delete_mesh("beta", "t-box") is True
    assert tree_files(store) == set()
    # and the memory copy went with it: the next read is of the (missing) file
    with pytest.raises(FileNotFoundError):
        store.tree("t-box")


# ------------------------------------------------------------------ scenes
def test_scenes_hold_a_spec_and_the_latest_state(store, trees):
    store.put_tree("t-box", trees["t-box"])
    spec = {"bodies": [{"mesh": "t-box"}], "dt": 0.001}
    assert store.add_scene("alpha", "s1", spec, b"state-0", ["t-box", "t-box"]) == []
    assert store.scene("alpha", "s1") == (spec, b"state-0", 0)
    assert store.scene("beta", "s1") is None
    assert store.save_state("alpha", "s1", b"state-7", 7) is True
    assert store.scene("alpha", "s1") == (spec, b"state-7", 7)
    assert store.save_state("beta", "s1", b"x", 1) is False
    assert store.save_state("alpha", "nope", b"x", 1) is False
    assert store.add_scene("alpha", "s2", spec, b"", ["t-gone"]) == ["t-gone"]
    assert store.scene("alpha", "s2") is None
    with pytest.raises(Exception, match="(?i)unique|duplicate"):  # one scene per (owner, id)
        store.add_scene("alpha", "s1", spec, b"again", ["t-box"])
    assert store.scene("alpha", "s1") == (spec, b"state-7", 7)


def test_a_scene_keeps_its_trees_after_their_meshes_are_deleted(store, trees):
    store.put_tree("t-box", trees["t-box"])
    store.put_tree("t-ball", trees["t-ball"])
    store.add_mesh("alpha", "t-box", {"id": "t-box"})
    store.add_mesh("alpha", "t-ball", {"id": "t-ball"})
    store.add_scene("alpha", "s1", {}, b"", ["t-box"])
    store.delete_mesh("alpha", "t-box")
    store.delete_mesh("alpha", "t-ball")
    assert tree_files(store) == {"t-box"}  # the scene uses it; nothing uses t-ball
    assert same_tree(store.tree("t-box"), trees["t-box"])
    assert store.delete_scene("alpha", "s1") is True
    assert store.delete_scene("alpha", "s1") is False
    assert tree_files(store) == set()


# ------------------------------------------------------------------ jobs
def test_job_mesh_files_round_trip(store):
    mesh = shapes.box()
    vertices, faces = mesh.vertices.astype(np.float64), mesh.faces.astype(np.int32)
    store.put_job_mesh("j1", vertices, faces)
    got_vertices, got_faces = store.job_mesh("j1")
    np.testing.assert_array_equal(got_vertices, vertices)
    np.testing.assert_array_equal(got_faces, faces)
    assert got_vertices.dtype == np.float64 and got_faces.dtype == np.int32
    assert store.job_meshes() == ["j1"] and store.job_meshes(older_than=3600) == []
    store.drop_job_mesh("j1")
    assert store.job_meshes() == []
    with pytest.raises(OSError):
        store.job_mesh("j1")


def test_a_job_from_queued_to_done_adds_every_waiting_owners_mesh(store, trees):
    store.add_job("j1", "t-box", SPEC, "alpha", {"name": "a.stl"})
    job = store.job("j1")
    assert (job["id"], job["mesh"], job["status"], job["spec"]) == ("j1", "t-box", "queued", SPEC)
    assert (job["levels"], job["nodes"], job["attempts"]) == (0, 0, 0)
    assert job["seconds"] is None and job["cause"] is None and job["error"] is None
    assert store.active_job("t-box") == "j1" and store.active_job("t-ball") is None
    assert store.join_job("j1", "beta", {"name": "b.obj"}) is True
    assert store.join_job("j1", "beta", {"name": "again"}) is False
    assert store.join_job("nope", "beta", {}) is None
    assert store.owners("j1") == 2
    assert store.job("j1", "beta")["extra"] == {"name": "b.obj"}
    assert store.job("j1", "gamma") is None  # gamma does not wait for it
    assert store.start_job("j1") == 1
    assert store.job("j1")["status"] == "building"
    store.set_job("j1", "building", levels=3, nodes=40)
    assert (store.job("j1")["levels"], store.job("j1")["nodes"]) == (3, 40)
    store.put_tree("t-box", trees["t-box"])
    owners = store.finish_job("j1", {"id": "t-box", "faces": 12}, 4, 57, 0.25)
    assert sorted(owners) == ["alpha", "beta"]
    done = store.job("j1")
    assert (done["status"], done["levels"], done["nodes"], done["seconds"]) == (
        "done",
        4,
        57,
        0.25,
    )
    assert store.mesh("alpha", "t-box") == {"id": "t-box", "faces": 12, "name": "a.stl"}
    assert store.mesh("beta", "t-box") == {"id": "t-box", "faces": 12, "name": "b.obj"}
    assert store.active_job("t-box") is None
    assert store.join_job("j1", "gamma", {}) is None  # finished: a new upload, a new job


def test_a_job_nobody_waits_for_any_more_finishes_as_cancelled(store, trees):
    store.add_job("j1", "t-box", SPEC, "alpha", {})
    store.put_tree("t-box", trees["t-box"])
    assert store.leave_job("alpha", "t-box") == ("j1", 0)
    assert store.leave_job("alpha", "t-box") is None
    assert store.finish_job("j1", {"id": "t-box"}, 1, 1, 0.1) == []
    job = store.job("j1")
    assert job["status"] == "failed" and job["cause"] == "cancelled"
    assert store.mesh("alpha", "t-box") is None
    assert tree_files(store) == set()  # nothing refers to the tree it wrote


def test_an_unfinished_job_keeps_its_tree_file_from_the_sweep(store, trees):
    store.put_tree("t-box", trees["t-box"])
    store.put_tree("t-ball", trees["t-ball"])
    store.add_job("j1", "t-box", SPEC, "alpha", {})
    assert store.sweep_trees() == 1  # t-ball: nothing refers to it
    assert tree_files(store) == {"t-box"}
    store.fail_job("j1", "internal", "boom")
    job = store.job("j1")
    assert (job["status"], job["cause"], job["error"]) == ("failed", "internal", "boom")
    assert tree_files(store) == set()  # the failed job was its only user
    assert store.sweep_trees() == 0


def test_jobs_listing_filters_and_limits(store):
    for k, owner in enumerate(["alpha", "beta", "alpha", "alpha"]):
        store.add_job(f"j{k}", f"m{k}", SPEC, owner, {})
        time.sleep(0.002)  # distinct creation times
    store.set_job("j0", "done")
    store.fail_job("j3", "invalid", "bad mesh")
    assert [j["id"] for j in store.jobs()] == ["j0", "j1", "j2", "j3"]  # oldest first
    assert [j["id"] for j in store.jobs("alpha")] == ["j0", "j2", "j3"]
    assert [j["id"] for j in store.jobs(statuses=("queued",))] == ["j1", "j2"]
    assert [j["id"] for j in store.jobs("alpha", ("done", "failed"))] == ["j0", "j3"]
    assert [j["id"] for j in store.jobs(limit=2)] == ["j2", "j3"]  # the newest, oldest first
    assert [j["id"] for j in store.jobs("alpha", limit=1)] == ["j3"]
    assert store.jobs("nobody") == []


def test_prune_forgets_finished_jobs_updated_before_the_cut(store):
    store.add_job("old-done", "m1", SPEC, "alpha", {})
    store.add_job("old-failed", "m2", SPEC, "alpha", {})
    store.add_job("queued", "m3", SPEC, "alpha", {})
    store.set_job("old-done", "done")
    store.fail_job("old-failed", "internal", "boom")
    time.sleep(0.01)
    cut = time.time()
    time.sleep(0.01)
    store.add_job("new-done", "m4", SPEC, "alpha", {})
    store.set_job("new-done", "done")
    assert store.prune_jobs(cut) == 2
    assert [j["id"] for j in store.jobs()] == ["queued", "new-done"]
    assert store.job("old-done") is None and store.job("old-done", "alpha") is None
    assert store.owners("old-done") == 0  # its owners' rows went too
    assert store.prune_jobs(cut) == 0


# ------------------------------------------------------------------ durability
def test_everything_acknowledged_is_there_after_reopening(backend, trees):
    store = backend()
    store.put_tree("t-box", trees["t-box"])
    store.add_mesh("alpha", "t-box", {"id": "t-box"})
    store.add_scene("alpha", "s1", {"dt": 0.01}, b"\x00\x01state", ["t-box"])
    store.save_state("alpha", "s1", b"\x02later", 3)
    store.add_job("j1", "t-ball", SPEC, "beta", {"name": "ball"})
    store.put_job_mesh("j1", np.eye(3), np.array([[0, 1, 2]], np.int32))
    store.start_job("j1")
    store.close()

    again = backend()
    try:
        assert again.mesh("alpha", "t-box") == {"id": "t-box"}
        assert same_tree(again.tree("t-box"), trees["t-box"])
        assert again.scene("alpha", "s1") == ({"dt": 0.01}, b"\x02later", 3)
        job = again.job("j1", "beta")
        assert (job["status"], job["attempts"], job["extra"]) == ("building", 1, {"name": "ball"})
        np.testing.assert_array_equal(again.job_mesh("j1")[0], np.eye(3))
        assert again.start_job("j1") == 2  # attempts count across restarts
    finally:
        again.close()


def test_opening_removes_temporaries_a_crash_left(tmp_path, trees):
    store = Store(tmp_path)
    store.put_tree("t-box", trees["t-box"])
    store.close()
    (tmp_path / "trees" / ".t-ball.0123abcd.tmp").write_bytes(b"half a tree")
    (tmp_path / "jobs" / ".j9.4567ef.tmp").write_bytes(b"half a mesh")
    Store(tmp_path).close()
    assert sorted(p.name for p in (tmp_path / "trees").iterdir()) == ["t-box.npz"]
    assert list((tmp_path / "jobs").iterdir()) == []


def test_a_store_from_before_attempts_were_counted_is_upgraded(tmp_path):
    db = sqlite3.connect(tmp_path / "mrdem.sqlite3")
    db.execute(
        "CREATE TABLE jobs (id TEXT PRIMARY KEY, mesh TEXT NOT NULL, status TEXT NOT NULL,"
        " spec TEXT NOT NULL, levels INTEGER NOT NULL DEFAULT 0, nodes INTEGER NOT NULL"
        " DEFAULT 0, seconds REAL, cause TEXT, error TEXT, created REAL NOT NULL,"
        " updated REAL NOT NULL)"
    )
    db.execute(
        "INSERT INTO jobs (id, mesh, status, spec, created, updated)"
        " VALUES ('old', 'm1', 'queued', '{}', 1.0, 1.0)"
    )
    db.commit()
    db.close()
    store = Store(tmp_path)
    try:
        assert store.job("old")["attempts"] == 0
        assert store.start_job("old") == 1
    finally:
        store.close()
