"""The store's back ends on real servers: versioned migrations (SQLite and PostgreSQL), two
stores sharing one PostgreSQL database and one S3 bucket as two replicas do (what one
records the other reads; a tree's check-and-reference waits for the other's
check-and-remove; one unfinished build per content; a claimed job is nobody else's until
its holder lets go or dies; compare-and-set of a scene's state), the bounded local copy of
trees, and the service on the shared back end chosen by its settings."""

from __future__ import annotations

import sqlite3
import threading
import time

import numpy as np
import psycopg
import pytest
from harness import InProcessService

from engine import build_tree, shapes
from service.store import MIGRATIONS, PostgresDatabase, S3Blobs, SqliteDatabase, Store
from service.store.blobs import _DiskCache

SPEC = {"epsilon": 0.05, "branching": 8}
LATEST = [version for version, _, _ in MIGRATIONS]


@pytest.fixture(scope="module")
def box_tree():
    return build_tree(shapes.box(), 0.05)


@pytest.fixture()
def shared(postgres, s3, tmp_path):
    """Two stores on one PostgreSQL database and one bucket, as two replicas have."""
    url, bucket = postgres.database(), s3.bucket()
    stores = [
        Store(
            tmp_path / name,
            database=PostgresDatabase(url, pool_size=4),
            blobs=S3Blobs(bucket, s3.endpoint, tmp_path / name / "tree-cache"),
        )
        for name in ("a", "b")
    ]
    yield stores
    for store in stores:
        store.close()


# ------------------------------------------------------------------ migrations
def test_a_new_sqlite_store_is_at_the_latest_schema_and_migrating_again_does_nothing(tmp_path):
    database = SqliteDatabase(tmp_path / "m.sqlite3")
    try:
        assert database.migrate() == LATEST
        assert database.versions() == LATEST
        assert database.migrate() == []
    finally:
        database.close()


def test_a_store_from_before_versioned_migrations_adopts_them(tmp_path):
    """A store written before migrations were versioned (its tables there, no
    schema_migrations): opening it records every version and keeps the rows."""
    old = sqlite3.connect(tmp_path / "mrdem.sqlite3")
    old.execute(
        "CREATE TABLE meshes (owner TEXT NOT NULL, id TEXT NOT NULL, facts TEXT NOT NULL,"
        " created REAL NOT NULL, PRIMARY KEY (owner, id))"
    )
    old.execute("INSERT INTO meshes VALUES ('alpha', 'm1', '{\"id\": \"m1\"}', 1.0)")
    old.commit()
    old.close()
    store = Store(tmp_path)
    try:
        assert store.db.versions() == LATEST
        assert store.mesh("alpha", "m1") == {"id": "m1"}
    finally:
        store.close()


def test_postgres_migrations_run_once_when_replicas_start_together(postgres):
    url = postgres.database()
    results: list = []

    def start():
        database = PostgresDatabase(url, pool_size=2)
        try:
            results.append(database.migrate())
        except Exception as exc:
            results.append(exc)
        finally:
            database.close()

    threads = [threading.Thread(target=start) for _ in range(3)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join(60)
    assert sorted(results, key=len) == [[], [], LATEST]  # one applied them, two found them
    with psycopg.connect(url) as connection:
        rows = connection.execute("SELECT version FROM schema_migrations").fetchall()
        assert sorted(r[0] for r in rows) == LATEST
        indexes = connection.execute("SELECT indexname FROM pg_indexes").fetchall()
        assert "jobs_one_active" in {r[0] for r in indexes}


# ------------------------------------------------------------------ two replicas
def test_what_one_replica_records_the_other_reads(shared, box_tree):
    a, b = shared
    a.put_tree("m1", box_tree)
    assert a.add_mesh("alpha", "m1", {"id": "m1"}) is True
    assert b.mesh("alpha", "m1") == {"id": "m1"} and b.has_tree("m1")
    loaded = b.tree("m1")  # from the bucket, then from b's local copy
    np.testing.assert_array_equal(loaded.triangles, box_tree.triangles)
    assert (b.blobs.cache.root / "trees" / "m1.npz").exists()
    assert b.add_mesh("alpha", "m1", {"id": "m1"}) is False
    b.add_scene("alpha", "s1", {"dt": 0.01}, b"state-0", ["m1"])
    assert b.scene_version("alpha", "s1") == 0
    assert a.save_state("alpha", "s1", b"state-1", 1, after=0) is True
    assert b.scene_row("alpha", "s1") == ({"dt": 0.01}, b"state-1", 1, 1)
    # a replica stepping a stale copy (it read version 0) records nothing
    assert b.save_state("alpha", "s1", b"stale", 1, after=0) is False
    assert a.scene("alpha", "s1")[1:] == (b"state-1", 1)
    assert b.save_state("alpha", "s1", b"state-2", 2, after=1) is True
    assert a.scene_version("alpha", "s1") == 2 and a.scene_version("alpha", "s9") is None
    assert a.delete_mesh("alpha", "m1") and b.has_tree("m1")  # the scene keeps it
    assert b.delete_scene("alpha", "s1") and not a.has_tree("m1")


def test_referencing_a_tree_waits_for_another_replica_removing_it(shared, box_tree):
    """Replica a holds the tree's lock (as while it checks that nothing refers to the tree
    and removes it); b's add_mesh waits, then finds the tree gone and records nothing."""
    a, b = shared
    a.put_tree("m1", box_tree)
    answer: list = []
    adding = threading.Thread(target=lambda: answer.append(b.add_mesh("beta", "m1", {})))
    with a.db.transaction() as tx:
        a.db.lock(tx, "tree:m1")
        adding.start()
        time.sleep(0.5)
        assert answer == []  # waiting for a's lock
        a.blobs.delete("trees/m1.npz")  # nothing referred to it: removed
    adding.join(30)
    assert answer == [None] and b.mesh("beta", "m1") is None


def test_one_unfinished_build_per_content_across_replicas(shared):
    a, b = shared
    assert a.add_job("j1", "m1", SPEC, "alpha", {}) is True
    assert b.add_job("j2", "m1", SPEC, "beta", {}) is False  # a's job builds it
    assert b.job("j2") is None and b.active_job("m1") == "j1"
    a.fail_job("j1", "internal", "boom")
    assert b.add_job("j2", "m1", SPEC, "beta", {}) is True


def test_a_claimed_job_is_nobody_elses_until_its_holder_lets_go_or_dies(postgres, s3, tmp_path):
    url = postgres.database()
    a, b = PostgresDatabase(url, pool_size=2), PostgresDatabase(url, pool_size=2)
    try:
        with a.claim("build:j1") as mine:
            assert mine
            with b.claim("build:j1") as theirs:
                assert not theirs
        with b.claim("build:j1") as theirs:
            assert theirs
        claimed, release = threading.Event(), threading.Event()

        def hold():
            with a.claim("build:j2"):
                claimed.set()
                release.wait(30)

        holder = threading.Thread(target=hold)
        holder.start()
        claimed.wait(30)
        with b.claim("build:j2") as theirs:
            assert not theirs
        a.pool.close(timeout=0)  # a dies: the server drops its connections and locks
        release.set()
        holder.join(30)
        deadline = time.monotonic() + 10
        while True:
            with b.claim("build:j2") as theirs:
                if theirs or time.monotonic() > deadline:
                    break
            time.sleep(0.1)
        assert theirs
    finally:
        release.set()
        b.close()
        a.close()


# ------------------------------------------------------------------ local copies
def test_the_local_copy_of_trees_stays_within_its_bytes(tmp_path):
    cache = _DiskCache(tmp_path / "cache", limit=2500)
    for k in range(3):
        cache.put(f"trees/t{k}.npz", bytes([k]) * 1000)
    assert cache.get("trees/t0.npz") is None  # least recently used: removed
    assert cache.get("trees/t1.npz") == b"\x01" * 1000 and cache.bytes() <= 2500
    cache.put("trees/t3.npz", b"\x03" * 1000)  # t2 is now the least recently used
    assert cache.get("trees/t2.npz") is None and cache.get("trees/t1.npz") is not None
    cache.put("trees/huge.npz", b"x" * 5000)  # bigger than the whole cache: not kept
    assert cache.get("trees/huge.npz") is None
    on_disk = sum(f.stat().st_size for f in (tmp_path / "cache" / "trees").glob("*.npz"))
    assert cache.bytes() == on_disk  # the running total is what the files hold
    cache.drop("trees/t1.npz")
    assert cache.bytes() == on_disk - 1000
    again = _DiskCache(tmp_path / "cache", limit=1000)  # reopened smaller: trimmed
    assert again.bytes() <= 1000


def test_a_missing_blob_and_a_malformed_bucket_url_are_clear_errors(s3, tmp_path):
    blobs = S3Blobs(s3.bucket(), s3.endpoint)
    with pytest.raises(FileNotFoundError):
        blobs.get("trees/nothing.npz")
    assert blobs.exists("trees/nothing.npz") is False and blobs.ping()
    with pytest.raises(ValueError, match="s3://bucket/prefix"):
        S3Blobs("http://not-a-bucket", s3.endpoint)


# ------------------------------------------------------------------ the service
def test_the_service_on_the_shared_store(postgres, s3, tmp_path):
    """Two in-process apps on one PostgreSQL database and one bucket: a mesh uploaded to
    one is found by the other, the two answer the same contacts, and a scene created on
    one steps on the other from the stored state."""
    settings = {
        "store_url": postgres.database(),
        "object_store_url": s3.bucket(),
        "object_store_endpoint": s3.endpoint,
    }
    box = shapes.box()
    mesh = {"vertices": box.vertices.tolist(), "faces": box.faces.tolist(), "epsilon": 0.05}
    query = {
        "a": [0, 0],
        "b": [0, 0],
        "position_a": [[0.0, 0.0, 0.0], [0.0, 0.0, 0.0]],
        "orientation_a": [[1.0, 0.0, 0.0, 0.0]] * 2,
        "position_b": [[0.9, 0.1, 0.0], [0.0, 0.5, 0.95]],
        "orientation_b": [[1.0, 0.0, 0.0, 0.0], [0.9238795325, 0.3826834324, 0.0, 0.0]],
    }
    with (
        InProcessService(tmp_path / "a", **settings) as one,
        InProcessService(tmp_path / "b", **settings) as two,
        one.client(timeout=120) as first,
        two.client(timeout=120) as second,
    ):
        uploaded = first.post("/v1/meshes", json=mesh)
        assert uploaded.status_code in (200, 201), uploaded.text
        mesh_id = uploaded.json()["id"]
        assert second.get(f"/v1/meshes/{mesh_id}").json()["id"] == mesh_id
        query["meshes"] = [mesh_id]
        answers = [c.post("/v1/contacts", json=query) for c in (first, second)]
        assert [a.status_code for a in answers] == [200, 200], answers[0].text
        found = [a.json() for a in answers]
        for part in ("offsets", "points", "normals", "overlaps", "pairs"):
            assert found[0][part] == found[1][part]
        assert found[0]["offsets"][-1] > 0
        scene = first.post(
            "/v1/scenes",
            json={
                "bodies": [{"mesh": mesh_id, "position": [0, 0, 1.2]}],
                "planes": [{"point": [0, 0, 0], "normal": [0, 0, 1]}],
                "dt": 0.001,
            },
        )
        assert scene.status_code == 201, scene.text
        scene_id = scene.json()["id"]
        stepped = second.post(f"/v1/scenes/{scene_id}/step", json={"steps": 5})
        assert stepped.status_code == 200, stepped.text
        assert first.get(f"/v1/scenes/{scene_id}").json()["steps"] == 5
