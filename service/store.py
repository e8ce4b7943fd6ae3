"""The embedded store: SQLite for metadata, content-addressed tree files beside it.

Layout under the data directory: ``mrdem.sqlite3`` (WAL, ``synchronous=FULL``: a committed
row survives ``kill -9`` and power loss), ``trees/<id>.npz`` and ``jobs/<job>.npz``. A
file is written before the row that refers to it — to a temporary file, fsynced, renamed
into place, the directory fsynced — so an acknowledged mesh always has its tree and an
acknowledged build job its mesh, and a crash leaves at most an unreferenced file:
temporaries, job files without a live job and tree files nothing refers to are removed at
start-up. Meshes belong to an owner (the API key's digest; "" when the service runs
without keys); a tree file is shared by every owner of the same content and kept while a
mesh, a scene or an unfinished build job refers to it. A scene's row holds its
specification and its latest state, replaced in one transaction per acknowledged step;
a request sent with an ``Idempotency-Key`` (:mod:`service.idempotency`) stores its answer
with the key in the same transaction.

Build jobs (:mod:`service.builds`): a row per build of one content (``queued``,
``building``, ``done`` or ``failed``) with the uploaders waiting for it in
``job_owners`` (each with the facts of its own upload). Finishing a job writes the tree
file, then marks the job done and adds every waiting owner's mesh row in one transaction.
"""

from __future__ import annotations

import io
import json
import os
import sqlite3
import threading
import time
import uuid
from collections import OrderedDict
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from engine import SurrogateTree

__all__ = ["KeyTaken", "Store"]

_SCHEMA = """
CREATE TABLE IF NOT EXISTS meshes (
    owner   TEXT NOT NULL,
    id      TEXT NOT NULL,
    facts   TEXT NOT NULL,
    created REAL NOT NULL,
    PRIMARY KEY (owner, id)
);
CREATE TABLE IF NOT EXISTS scenes (
    owner   TEXT NOT NULL,
    id      TEXT NOT NULL,
    spec    TEXT NOT NULL,
    state   BLOB NOT NULL,
    steps   INTEGER NOT NULL,
    updated REAL NOT NULL,
    PRIMARY KEY (owner, id)
);
CREATE TABLE IF NOT EXISTS scene_trees (
    owner TEXT NOT NULL,
    scene TEXT NOT NULL,
    tree  TEXT NOT NULL
);
CREATE INDEX IF NOT EXISTS scene_trees_tree ON scene_trees (tree);
CREATE TABLE IF NOT EXISTS jobs (
    id      TEXT PRIMARY KEY,
    mesh    TEXT NOT NULL,
    status  TEXT NOT NULL,
    spec    TEXT NOT NULL,
    levels  INTEGER NOT NULL DEFAULT 0,
    nodes   INTEGER NOT NULL DEFAULT 0,
    seconds REAL,
    cause   TEXT,
    error   TEXT,
    created REAL NOT NULL,
    updated REAL NOT NULL,
    attempts INTEGER NOT NULL DEFAULT 0
);
CREATE INDEX IF NOT EXISTS jobs_mesh ON jobs (mesh, status);
CREATE TABLE IF NOT EXISTS idempotency (
    owner       TEXT NOT NULL,
    key         TEXT NOT NULL,
    fingerprint TEXT NOT NULL,
    status      INTEGER NOT NULL,
    response    BLOB NOT NULL,
    created     REAL NOT NULL,
    PRIMARY KEY (owner, key)
);
CREATE INDEX IF NOT EXISTS idempotency_created ON idempotency (created);
CREATE TABLE IF NOT EXISTS job_owners (
    job   TEXT NOT NULL,
    owner TEXT NOT NULL,
    extra TEXT NOT NULL,
    PRIMARY KEY (job, owner)
);
"""

ACTIVE = ("queued", "building")
_JOB_COLUMNS = (
    "id, mesh, status, spec, levels, nodes, seconds, cause, error, created, updated, attempts"
)


class KeyTaken(Exception):
    """An idempotency key stored by another request while this one ran."""


class Store:
    """Meshes (and their surrogate trees) per owner, durable across restarts.

    Parameters
    ----------
    data_dir : path — created if missing
    tree_cache : int — trees kept in memory (least recently used dropped first)
    key_retention : float — seconds an idempotency key's answer is kept (0: forever);
        older keys are dropped whenever a key is stored
    """

    def __init__(
        self, data_dir: str | os.PathLike, tree_cache: int = 256, key_retention: float = 0.0
    ) -> None:
        self.key_retention = float(key_retention)
        self.root = Path(data_dir)
        self.trees_dir = self.root / "trees"
        self.jobs_dir = self.root / "jobs"
        for folder in (self.trees_dir, self.jobs_dir):
            folder.mkdir(parents=True, exist_ok=True)
            for stale in folder.glob(".*.tmp"):  # half-written by a crash
                stale.unlink(missing_ok=True)
        self.db = sqlite3.connect(
            self.root / "mrdem.sqlite3", check_same_thread=False, isolation_level=None
        )
        self.db.execute("PRAGMA journal_mode=WAL")
        self.db.execute("PRAGMA synchronous=FULL")
        self.db.executescript(_SCHEMA)
        columns = {row[1] for row in self.db.execute("PRAGMA table_info(jobs)")}
        if "attempts" not in columns:  # a store written before build attempts were counted
            self.db.execute("ALTER TABLE jobs ADD COLUMN attempts INTEGER NOT NULL DEFAULT 0")
        self.lock = threading.Lock()
        self._cache: OrderedDict[str, SurrogateTree] = OrderedDict()
        self._cache_size = tree_cache

    def close(self) -> None:
        with self.lock:
            self.db.close()

    def ping(self) -> bool:
        """The database answers."""
        with self.lock:
            return self.db.execute("SELECT 1").fetchone() == (1,)

    # ------------------------------------------------------------------ trees
    def tree_path(self, tree_id: str) -> Path:
        return self.trees_dir / f"{tree_id}.npz"

    def put_tree(self, tree_id: str, tree: SurrogateTree) -> None:
        """Write the tree file atomically (no-op when it exists: content-addressed)."""
        path = self.tree_path(tree_id)
        if path.exists():
            return
        buffer = io.BytesIO()
        tree.save(buffer)
        _write_durably(path, buffer.getvalue())
        self._remember(tree_id, tree)

    def tree(self, tree_id: str) -> SurrogateTree:
        """The stored tree (from memory when recently used)."""
        with self.lock:
            if tree_id in self._cache:
                self._cache.move_to_end(tree_id)
                return self._cache[tree_id]
        tree = SurrogateTree.load(self.tree_path(tree_id))
        self._remember(tree_id, tree)
        return tree

    def _remember(self, tree_id: str, tree: SurrogateTree) -> None:
        with self.lock:
            self._cache[tree_id] = tree
            self._cache.move_to_end(tree_id)
            while len(self._cache) > self._cache_size:
                self._cache.popitem(last=False)

    # ----------------------------------------------------------------- meshes
    def add_mesh(self, owner: str, mesh_id: str, facts: dict) -> bool | None:
        """Record the mesh for ``owner`` if its tree file is stored: True when added, False
        when it was there already, None when the tree file is gone (the last mesh using it
        was deleted meanwhile: build it again). Checked under the lock that deletions take,
        so a recorded mesh always has its tree."""
        with self.lock:
            if not self.tree_path(mesh_id).exists():
                return None
            cursor = self.db.execute(
                "INSERT OR IGNORE INTO meshes (owner, id, facts, created) VALUES (?, ?, ?, ?)",
                (owner, mesh_id, json.dumps(facts), time.time()),
            )
            return cursor.rowcount == 1

    def mesh(self, owner: str, mesh_id: str) -> dict | None:
        with self.lock:
            row = self.db.execute(
                "SELECT facts FROM meshes WHERE owner = ? AND id = ?", (owner, mesh_id)
            ).fetchone()
        return None if row is None else json.loads(row[0])

    def meshes(self, owner: str) -> list[dict]:
        with self.lock:
            rows = self.db.execute(
                "SELECT facts FROM meshes WHERE owner = ? ORDER BY created, id", (owner,)
            ).fetchall()
        return [json.loads(r[0]) for r in rows]

    def delete_mesh(self, owner: str, mesh_id: str) -> bool:
        """Forget ``owner``'s mesh; its tree file goes when nothing refers to it."""
        with self.lock:
            cursor = self.db.execute(
                "DELETE FROM meshes WHERE owner = ? AND id = ?", (owner, mesh_id)
            )
            if cursor.rowcount == 0:
                return False
            self._drop_unused([mesh_id])
        return True

    def sweep_trees(self) -> int:
        """Remove the tree files no mesh, scene or unfinished job refers to (left by a
        crash between writing a tree and recording it); how many were removed."""
        with self.lock:
            return self._drop_unused(p.stem for p in self.trees_dir.glob("*.npz"))

    def _drop_unused(self, tree_ids) -> int:
        """Remove the tree files no mesh, scene or unfinished job refers to (lock held);
        how many files were removed."""
        dropped = 0
        for tree_id in set(tree_ids):
            used = self.db.execute(
                "SELECT 1 FROM meshes WHERE id = ? UNION ALL"
                " SELECT 1 FROM scene_trees WHERE tree = ? UNION ALL"
                " SELECT 1 FROM jobs WHERE mesh = ? AND status IN (?, ?) LIMIT 1",
                (tree_id, tree_id, tree_id, *ACTIVE),
            ).fetchone()
            if used is None:
                self._cache.pop(tree_id, None)
                path = self.tree_path(tree_id)
                if path.exists():
                    path.unlink(missing_ok=True)
                    dropped += 1
        return dropped

    # ----------------------------------------------------------------- scenes
    def add_scene(
        self, owner: str, scene_id: str, spec: dict, state: bytes, trees, remember=None
    ) -> list:
        """Record a new scene, its state and the trees it uses, in one transaction (with
        ``remember``, an idempotency key's row: :meth:`Key.remember
        <service.idempotency.Key.remember>`). Returns the trees whose files are gone (their
        meshes deleted meanwhile): then nothing is recorded. :class:`KeyTaken` if the key
        was stored meanwhile: then nothing is recorded either."""
        with self.lock:
            missing = sorted(t for t in set(trees) if not self.tree_path(t).exists())
            if missing:
                return missing
            with self._transaction():
                self.db.execute(
                    "INSERT INTO scenes (owner, id, spec, state, steps, updated)"
                    " VALUES (?, ?, ?, ?, 0, ?)",
                    (owner, scene_id, json.dumps(spec), state, time.time()),
                )
                self.db.executemany(
                    "INSERT INTO scene_trees (owner, scene, tree) VALUES (?, ?, ?)",
                    [(owner, scene_id, t) for t in sorted(set(trees))],
                )
                self._store_key(owner, remember)
        return []

    def scene(self, owner: str, scene_id: str) -> tuple[dict, bytes, int] | None:
        """``(spec, state, steps)`` of ``owner``'s scene, or None."""
        with self.lock:
            row = self.db.execute(
                "SELECT spec, state, steps FROM scenes WHERE owner = ? AND id = ?",
                (owner, scene_id),
            ).fetchone()
        return None if row is None else (json.loads(row[0]), bytes(row[1]), int(row[2]))

    def save_state(
        self, owner: str, scene_id: str, state: bytes, steps: int, remember=None
    ) -> bool:
        """Replace the scene's state (committed before this returns; with ``remember``,
        an idempotency key's row in the same transaction, as :meth:`add_scene`); False if
        the scene is gone (nothing recorded). :class:`KeyTaken` if the key was stored
        meanwhile (nothing recorded)."""
        with self.lock, self._transaction():
            cursor = self.db.execute(
                "UPDATE scenes SET state = ?, steps = ?, updated = ? WHERE owner = ? AND id = ?",
                (state, steps, time.time(), owner, scene_id),
            )
            if cursor.rowcount != 1:
                return False
            self._store_key(owner, remember)
            return True

    # ------------------------------------------------------- idempotency keys
    def _store_key(self, owner: str, remember) -> None:
        """Insert an idempotency key's row (inside a transaction); :class:`KeyTaken` if the
        owner has that key already."""
        if remember is None:
            return
        key, fingerprint, status, response = remember
        now = time.time()
        if self.key_retention > 0:
            self.db.execute(
                "DELETE FROM idempotency WHERE created < ?", (now - self.key_retention,)
            )
        try:
            self.db.execute(
                "INSERT INTO idempotency (owner, key, fingerprint, status, response, created)"
                " VALUES (?, ?, ?, ?, ?, ?)",
                (owner, key, fingerprint, status, response, now),
            )
        except sqlite3.IntegrityError:
            raise KeyTaken(key) from None

    def remembered(self, owner: str, key: str) -> tuple[str, int, bytes] | None:
        """``(fingerprint, status, response)`` stored with ``owner``'s idempotency
        ``key``, or None."""
        with self.lock:
            row = self.db.execute(
                "SELECT fingerprint, status, response FROM idempotency WHERE owner = ? AND key = ?",
                (owner, key),
            ).fetchone()
        return None if row is None else (row[0], int(row[1]), bytes(row[2]))

    def delete_scene(self, owner: str, scene_id: str) -> bool:
        with self.lock:
            cursor = self.db.execute(
                "DELETE FROM scenes WHERE owner = ? AND id = ?", (owner, scene_id)
            )
            if cursor.rowcount == 0:
                return False
            trees = [
                r[0]
                for r in self.db.execute(
                    "SELECT tree FROM scene_trees WHERE owner = ? AND scene = ?", (owner, scene_id)
                )
            ]
            self.db.execute(
                "DELETE FROM scene_trees WHERE owner = ? AND scene = ?", (owner, scene_id)
            )
            self._drop_unused(trees)
        return True

    # ------------------------------------------------------------------- jobs
    def job_path(self, job_id: str) -> Path:
        return self.jobs_dir / f"{job_id}.npz"

    def put_job_mesh(self, job_id: str, vertices: np.ndarray, faces: np.ndarray) -> None:
        """Write a job's mesh (``vertices (V, 3) float64``, ``faces (F, 3) int32``) durably."""
        buffer = io.BytesIO()
        np.savez(buffer, vertices=vertices, faces=faces)
        _write_durably(self.job_path(job_id), buffer.getvalue())

    def job_mesh(self, job_id: str) -> tuple[np.ndarray, np.ndarray]:
        """The job's ``(vertices (V, 3) float64, faces (F, 3) int32)``; raises (OSError,
        ValueError, EOFError, zipfile.BadZipFile, …) when its file is missing or
        unreadable."""
        with np.load(self.job_path(job_id), allow_pickle=False) as data:
            return np.array(data["vertices"]), np.array(data["faces"])

    def drop_job_mesh(self, job_id: str) -> None:
        self.job_path(job_id).unlink(missing_ok=True)

    def active_job(self, mesh_id: str) -> str | None:
        """The id of the unfinished job building ``mesh_id``, or None."""
        with self.lock:
            row = self.db.execute(
                "SELECT id FROM jobs WHERE mesh = ? AND status IN (?, ?)", (mesh_id, *ACTIVE)
            ).fetchone()
        return None if row is None else row[0]

    def add_job(self, job_id: str, mesh_id: str, spec: dict, owner: str, extra: dict) -> None:
        """Record a queued job and its first owner (its mesh file is written already)."""
        now = time.time()
        with self.lock, self._transaction():
            self.db.execute(
                f"INSERT INTO jobs ({_JOB_COLUMNS}) VALUES (?, ?, 'queued', ?, 0, 0, NULL,"
                " NULL, NULL, ?, ?, 0)",
                (job_id, mesh_id, json.dumps(spec), now, now),
            )
            self.db.execute(
                "INSERT INTO job_owners (job, owner, extra) VALUES (?, ?, ?)",
                (job_id, owner, json.dumps(extra)),
            )

    def join_job(self, job_id: str, owner: str, extra: dict) -> bool | None:
        """Add ``owner`` to the unfinished job: True if added, False if it was an owner
        already, None if the job is no longer unfinished."""
        with self.lock, self._transaction():
            row = self.db.execute("SELECT status FROM jobs WHERE id = ?", (job_id,)).fetchone()
            if row is None or row[0] not in ACTIVE:
                return None
            cursor = self.db.execute(
                "INSERT OR IGNORE INTO job_owners (job, owner, extra) VALUES (?, ?, ?)",
                (job_id, owner, json.dumps(extra)),
            )
            return cursor.rowcount == 1

    def job(self, job_id: str, owner: str | None = None) -> dict | None:
        """The job's row as a dict (``spec`` decoded); with ``owner``, only if that owner
        waits for it, and with its ``extra`` (the facts of that owner's upload)."""
        with self.lock:
            row = self.db.execute(
                f"SELECT {_JOB_COLUMNS} FROM jobs WHERE id = ?", (job_id,)
            ).fetchone()
            extra = None
            if row is not None and owner is not None:
                extra = self.db.execute(
                    "SELECT extra FROM job_owners WHERE job = ? AND owner = ?", (job_id, owner)
                ).fetchone()
                if extra is None:
                    return None
        if row is None:
            return None
        job = _job_row(row)
        if extra is not None:
            job["extra"] = json.loads(extra[0])
        return job

    def jobs(self, owner: str | None = None, statuses=None, limit: int | None = None) -> list[dict]:
        """Jobs (oldest first): those ``owner`` waits for (None: all), of ``statuses``;
        with ``limit``, only the newest ``limit`` of them."""
        query = f"SELECT {_JOB_COLUMNS} FROM jobs"
        args: list = []
        where = []
        if owner is not None:
            where.append("id IN (SELECT job FROM job_owners WHERE owner = ?)")
            args.append(owner)
        if statuses:
            where.append(f"status IN ({', '.join('?' * len(statuses))})")
            args.extend(statuses)
        if where:
            query += " WHERE " + " AND ".join(where)
        if limit is not None:
            query = f"SELECT * FROM ({query} ORDER BY created DESC, id DESC LIMIT ?)"
            args.append(int(limit))
        with self.lock:
            rows = self.db.execute(query + " ORDER BY created, id", args).fetchall()
        return [_job_row(r) for r in rows]

    def owners(self, job_id: str) -> int:
        """How many owners wait for the job."""
        with self.lock:
            return self.db.execute(
                "SELECT COUNT(*) FROM job_owners WHERE job = ?", (job_id,)
            ).fetchone()[0]

    def set_job(self, job_id: str, status: str, **columns) -> None:
        """Set the job's status and any of ``levels``, ``nodes``, ``seconds``, ``cause``,
        ``error``, ``attempts``."""
        sets = ", ".join(f"{k} = ?" for k in columns)
        with self.lock:
            self.db.execute(
                f"UPDATE jobs SET status = ?, updated = ?{', ' + sets if sets else ''}"
                " WHERE id = ?",
                (status, time.time(), *columns.values(), job_id),
            )

    def start_job(self, job_id: str) -> int:
        """Mark the job ``building`` and count the attempt (committed before the build
        starts, so a build that kills the process is counted); the attempts so far."""
        with self.lock, self._transaction():
            self.db.execute(
                "UPDATE jobs SET status = 'building', attempts = attempts + 1, updated = ?"
                " WHERE id = ?",
                (time.time(), job_id),
            )
            row = self.db.execute("SELECT attempts FROM jobs WHERE id = ?", (job_id,)).fetchone()
        return 0 if row is None else int(row[0])

    def fail_job(self, job_id: str, cause: str, error: str) -> None:
        """Mark the job ``failed`` with its ``cause`` and ``error``, and remove its tree
        file if nothing else refers to it (one transaction)."""
        with self.lock, self._transaction():
            self.db.execute(
                "UPDATE jobs SET status = 'failed', cause = ?, error = ?, updated = ? WHERE id = ?",
                (cause, error, time.time(), job_id),
            )
            row = self.db.execute("SELECT mesh FROM jobs WHERE id = ?", (job_id,)).fetchone()
            if row is not None:
                self._drop_unused([row[0]])

    def cancel_job(self, job_id: str) -> bool:
        """Mark the unfinished job ``failed`` (cancelled) **if** nobody waits for it — one
        conditional statement, so an upload joining at that moment either joins before
        (and the job goes on: False) or finds the job failed (and starts a new one)."""
        with self.lock, self._transaction():
            cursor = self.db.execute(
                "UPDATE jobs SET status = 'failed', cause = 'cancelled', error = ?, updated = ?"
                " WHERE id = ? AND status IN (?, ?)"
                " AND NOT EXISTS (SELECT 1 FROM job_owners WHERE job = ?)",
                (CANCELLED, time.time(), job_id, *ACTIVE, job_id),
            )
            if cursor.rowcount == 0:
                return False
            row = self.db.execute("SELECT mesh FROM jobs WHERE id = ?", (job_id,)).fetchone()
            self._drop_unused([row[0]])
        return True

    def finish_job(self, job_id: str, facts: dict, levels: int, nodes: int, seconds: float):
        """In one transaction: the job done and a mesh row (``facts`` plus the owner's
        ``extra``) for every owner waiting for it. Returns those owners; with none left,
        the job is marked failed (cancelled) and its unused tree file removed."""
        with self.lock, self._transaction():
            rows = self.db.execute(
                "SELECT owner, extra FROM job_owners WHERE job = ?", (job_id,)
            ).fetchall()
            mesh_id, now = facts["id"], time.time()
            if not rows:
                self.db.execute(
                    "UPDATE jobs SET status = 'failed', cause = 'cancelled', error = ?,"
                    " updated = ? WHERE id = ?",
                    (CANCELLED, now, job_id),
                )
                self._drop_unused([mesh_id])
                return []
            self.db.executemany(
                "INSERT OR IGNORE INTO meshes (owner, id, facts, created) VALUES (?, ?, ?, ?)",
                [(o, mesh_id, json.dumps({**facts, **json.loads(e)}), now) for o, e in rows],
            )
            self.db.execute(
                "UPDATE jobs SET status = 'done', levels = ?, nodes = ?, seconds = ?,"
                " updated = ? WHERE id = ?",
                (levels, nodes, seconds, now, job_id),
            )
        return [o for o, _ in rows]

    def leave_job(self, owner: str, mesh_id: str) -> tuple[str, int] | None:
        """Take ``owner`` off the unfinished job building ``mesh_id``: ``(job id, owners
        left)``, or None when the owner waits for no such job."""
        with self.lock, self._transaction():
            row = self.db.execute(
                "SELECT id FROM jobs WHERE mesh = ? AND status IN (?, ?)"
                " AND id IN (SELECT job FROM job_owners WHERE owner = ?)",
                (mesh_id, *ACTIVE, owner),
            ).fetchone()
            if row is None:
                return None
            self.db.execute("DELETE FROM job_owners WHERE job = ? AND owner = ?", (row[0], owner))
            left = self.db.execute(
                "SELECT COUNT(*) FROM job_owners WHERE job = ?", (row[0],)
            ).fetchone()[0]
        return row[0], left

    def prune_jobs(self, before: float) -> int:
        """Forget finished jobs last updated before ``before`` (epoch seconds)."""
        with self.lock, self._transaction():
            old = "SELECT id FROM jobs WHERE status IN ('done', 'failed') AND updated < ?"
            self.db.execute(f"DELETE FROM job_owners WHERE job IN ({old})", (before,))
            return self.db.execute(
                "DELETE FROM jobs WHERE status IN ('done', 'failed') AND updated < ?", (before,)
            ).rowcount

    @contextmanager
    def _transaction(self):
        """``BEGIN IMMEDIATE`` … ``COMMIT`` (rolled back on any error; lock held)."""
        self.db.execute("BEGIN IMMEDIATE")
        try:
            yield
        except BaseException:
            self.db.execute("ROLLBACK")
            raise
        self.db.execute("COMMIT")


CANCELLED = "cancelled: every uploader deleted the mesh before its tree was built"


def _job_row(row) -> dict:
    job = dict(zip(_JOB_COLUMNS.split(", "), row, strict=True))
    job["spec"] = json.loads(job["spec"])
    return job


def _write_durably(path: Path, data: bytes) -> None:
    """``data`` into ``path``: a temporary file, fsynced, renamed, the directory fsynced."""
    tmp = path.parent / f".{path.stem}.{uuid.uuid4().hex}.tmp"
    try:
        with open(tmp, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)
    _fsync_dir(path.parent)


def _fsync_dir(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)
