"""The store: meshes per owner, scenes and their states, build jobs and idempotency keys
in a SQL database (:mod:`.database`: SQLite embedded, PostgreSQL shared by replicas), tree
files and build jobs' meshes as blobs (:mod:`.blobs`: a directory, or an S3-compatible
bucket with a bounded local copy per replica).

A blob is written before the row that refers to it, so an acknowledged mesh always has its
tree and an acknowledged build job its mesh, and a crash leaves at most an unreferenced
blob: job meshes without a live job and trees nothing refers to are removed at start-up.
Meshes belong to an owner (the API key's digest; "" when the service runs without keys); a
tree is shared by every owner of the same content and kept while a mesh, a scene or an
unfinished build job refers to it. Checking that a tree exists and adding a reference to
it, or checking that nothing refers to it and removing it, happen under the database's lock
on that tree (:meth:`.Database.lock`), so no replica records a mesh whose tree another is
removing. A scene's row holds its specification and its latest state, replaced in one
transaction per acknowledged step; a request sent with an ``Idempotency-Key``
(:mod:`service.idempotency`) stores its answer with the key in the same transaction.

Build jobs (:mod:`service.builds`): a row per build of one content (``queued``,
``building``, ``done`` or ``failed``; at most one unfinished per content) with the
uploaders waiting for it in ``job_owners`` (each with the facts of its own upload).
Finishing a job writes the tree, then marks the job done and adds every waiting owner's
mesh row in one transaction.
"""

from __future__ import annotations

import io
import json
import os
import threading
import time
from collections import OrderedDict

import numpy as np

from engine import SurrogateTree

from .blobs import Blobs, FileBlobs
from .database import Database, SqliteDatabase

__all__ = ["KeyTaken", "Store"]

ACTIVE = ("queued", "building")
_JOB_COLUMNS = (
    "id, mesh, status, spec, levels, nodes, seconds, cause, error, created, updated, attempts"
)
CANCELLED = "cancelled: every uploader deleted the mesh before its tree was built"


class KeyTaken(Exception):
    """An idempotency key stored by another request while this one ran."""


class Store:
    """Meshes (and their surrogate trees) per owner, durable across restarts.

    Parameters
    ----------
    data_dir : path — created if missing; the embedded database ``mrdem.sqlite3`` and the
        tree files live there unless ``database``/``blobs`` say otherwise
    tree_cache : int — trees kept in memory (least recently used dropped first)
    key_retention : float — seconds an idempotency key's answer is kept (0: forever);
        older keys are dropped whenever a key is stored
    database : Database — the SQL database (default: SQLite in ``data_dir``); migrated to
        the current schema when the store opens
    blobs : Blobs — where tree files and job meshes go (default: files in ``data_dir``)
    """

    def __init__(
        self,
        data_dir: str | os.PathLike,
        tree_cache: int = 256,
        key_retention: float = 0.0,
        *,
        database: Database | None = None,
        blobs: Blobs | None = None,
    ) -> None:
        self.key_retention = float(key_retention)
        self.blobs = blobs if blobs is not None else FileBlobs(data_dir)
        if database is None:
            os.makedirs(data_dir, exist_ok=True)
            database = SqliteDatabase(os.path.join(data_dir, "mrdem.sqlite3"))
        self.db = database
        self.db.migrate()
        self._lock = threading.Lock()  # the memory cache
        self._cache: OrderedDict[str, SurrogateTree] = OrderedDict()
        self._cache_size = tree_cache

    def close(self) -> None:
        self.db.close()
        self.blobs.close()

    def ping(self) -> bool:
        """The database and the blob storage answer."""
        return self.db.ping() and self.blobs.ping()

    @property
    def shared(self) -> bool:
        """Whether other processes (replicas) use this store too."""
        return self.db.dialect != "sqlite"

    def claim(self, name: str):
        """A context manager yielding whether this process holds ``name`` for the block
        (:meth:`.Database.claim`): a build job is built by the replica that claims it."""
        return self.db.claim(name)

    # ------------------------------------------------------------------ trees
    def has_tree(self, tree_id: str) -> bool:
        """Whether the tree's file is stored."""
        return self.blobs.exists(_tree(tree_id))

    def put_tree(self, tree_id: str, tree: SurrogateTree) -> None:
        """Store the tree's file durably (no-op when it exists: content-addressed)."""
        if self.blobs.exists(_tree(tree_id)):
            return
        buffer = io.BytesIO()
        tree.save(buffer)
        self.blobs.put(_tree(tree_id), buffer.getvalue())
        self._remember(tree_id, tree)

    def tree(self, tree_id: str) -> SurrogateTree:
        """The stored tree (from memory when recently used); :class:`FileNotFoundError` when
        it is not stored, ``ValueError`` when its file is damaged."""
        with self._lock:
            if tree_id in self._cache:
                self._cache.move_to_end(tree_id)
                return self._cache[tree_id]
        tree = SurrogateTree.load(io.BytesIO(self.blobs.get(_tree(tree_id))))
        self._remember(tree_id, tree)
        return tree

    def _remember(self, tree_id: str, tree: SurrogateTree) -> None:
        with self._lock:
            self._cache[tree_id] = tree
            self._cache.move_to_end(tree_id)
            while len(self._cache) > self._cache_size:
                self._cache.popitem(last=False)

    def sweep_trees(self) -> int:
        """Remove the tree files no mesh, scene or unfinished job refers to (left by a
        crash between writing a tree and recording it); how many were removed."""
        names = self.blobs.names("trees")
        return self._drop_unused(n[len("trees/") : -len(".npz")] for n in names)

    def _drop_unused(self, tree_ids) -> int:
        """Remove the tree files no mesh, scene or unfinished job refers to, each checked
        and removed under the tree's lock; how many files were removed."""
        dropped = 0
        for tree_id in sorted(set(tree_ids)):
            with self.db.transaction() as tx:
                self.db.lock(tx, f"tree:{tree_id}")
                used = tx.execute(
                    "SELECT 1 FROM meshes WHERE id = ? UNION ALL"
                    " SELECT 1 FROM scene_trees WHERE tree = ? UNION ALL"
                    " SELECT 1 FROM jobs WHERE mesh = ? AND status IN (?, ?)",
                    (tree_id, tree_id, tree_id, *ACTIVE),
                ).fetchone()
                if used is not None:
                    continue
                with self._lock:
                    self._cache.pop(tree_id, None)
                if self.blobs.exists(_tree(tree_id)):
                    self.blobs.delete(_tree(tree_id))
                    dropped += 1
        return dropped

    # ----------------------------------------------------------------- meshes
    def add_mesh(self, owner: str, mesh_id: str, facts: dict) -> bool | None:
        """Record the mesh for ``owner`` if its tree file is stored: True when added, False
        when it was there already, None when the tree file is gone (the last mesh using it
        was deleted meanwhile: build it again). Checked under the tree's lock, so a
        recorded mesh always has its tree."""
        with self.db.transaction() as tx:
            self.db.lock(tx, f"tree:{mesh_id}")
            if not self.blobs.exists(_tree(mesh_id)):
                return None
            cursor = tx.execute(
                "INSERT INTO meshes (owner, id, facts, created) VALUES (?, ?, ?, ?)"
                " ON CONFLICT DO NOTHING",
                (owner, mesh_id, json.dumps(facts), time.time()),
            )
            return cursor.rowcount == 1

    def mesh(self, owner: str, mesh_id: str) -> dict | None:
        with self.db.read() as tx:
            row = tx.execute(
                "SELECT facts FROM meshes WHERE owner = ? AND id = ?", (owner, mesh_id)
            ).fetchone()
        return None if row is None else json.loads(row[0])

    def meshes(self, owner: str) -> list[dict]:
        with self.db.read() as tx:
            rows = tx.execute(
                "SELECT facts FROM meshes WHERE owner = ? ORDER BY created, id", (owner,)
            ).fetchall()
        return [json.loads(r[0]) for r in rows]

    def delete_mesh(self, owner: str, mesh_id: str) -> bool:
        """Forget ``owner``'s mesh; its tree file goes when nothing refers to it."""
        with self.db.transaction() as tx:
            cursor = tx.execute("DELETE FROM meshes WHERE owner = ? AND id = ?", (owner, mesh_id))
            if cursor.rowcount == 0:
                return False
        self._drop_unused([mesh_id])
        return True

    # ----------------------------------------------------------------- scenes
    def add_scene(
        self, owner: str, scene_id: str, spec: dict, state: bytes, trees, remember=None
    ) -> list:
        """Record a new scene, its state and the trees it uses, in one transaction (with
        ``remember``, an idempotency key's row: :meth:`Key.remember
        <service.store.Key.remember>`). Returns the trees whose files are gone (their
        meshes deleted meanwhile): then nothing is recorded. :class:`KeyTaken` if the key
        was stored meanwhile: then nothing is recorded either."""
        trees = sorted(set(trees))
        with self.db.transaction() as tx:
            for tree_id in trees:  # in order: two scenes never wait for each other
                self.db.lock(tx, f"tree:{tree_id}")
            missing = [t for t in trees if not self.blobs.exists(_tree(t))]
            if missing:
                return missing
            tx.execute(
                "INSERT INTO scenes (owner, id, spec, state, steps, updated)"
                " VALUES (?, ?, ?, ?, 0, ?)",
                (owner, scene_id, json.dumps(spec), state, time.time()),
            )
            tx.executemany(
                "INSERT INTO scene_trees (owner, scene, tree) VALUES (?, ?, ?)",
                [(owner, scene_id, t) for t in trees],
            )
            self._store_key(tx, owner, remember)
        return []

    def scene(self, owner: str, scene_id: str) -> tuple[dict, bytes, int] | None:
        """``(spec, state, steps)`` of ``owner``'s scene, or None."""
        found = self.scene_row(owner, scene_id)
        return None if found is None else found[:3]

    def scene_row(self, owner: str, scene_id: str) -> tuple[dict, bytes, int, int] | None:
        """``(spec, state, steps, version)`` of ``owner``'s scene, or None: the version
        counts the states saved (:meth:`save_state`)."""
        with self.db.read() as tx:
            row = tx.execute(
                "SELECT spec, state, steps, version FROM scenes WHERE owner = ? AND id = ?",
                (owner, scene_id),
            ).fetchone()
        if row is None:
            return None
        return json.loads(row[0]), bytes(row[1]), int(row[2]), int(row[3])

    def scene_version(self, owner: str, scene_id: str) -> int | None:
        """The version of ``owner``'s scene's stored state, or None when there is no such
        scene."""
        with self.db.read() as tx:
            row = tx.execute(
                "SELECT version FROM scenes WHERE owner = ? AND id = ?", (owner, scene_id)
            ).fetchone()
        return None if row is None else int(row[0])

    def save_state(
        self,
        owner: str,
        scene_id: str,
        state: bytes,
        steps: int,
        remember=None,
        after: int | None = None,
    ) -> bool:
        """Replace the scene's state (committed before this returns; with ``remember``,
        an idempotency key's row in the same transaction, as :meth:`add_scene`) and count
        its version up; with ``after``, only if the stored state is still version
        ``after`` (compare and set: a replica stepping a stale copy records nothing).
        False if the scene is gone or moved on (nothing recorded). :class:`KeyTaken` if
        the key was stored meanwhile (nothing recorded)."""
        sql = (
            "UPDATE scenes SET state = ?, steps = ?, updated = ?, version = version + 1"
            " WHERE owner = ? AND id = ?"
        )
        args: tuple = (state, steps, time.time(), owner, scene_id)
        if after is not None:
            sql, args = sql + " AND version = ?", (*args, after)
        with self.db.transaction() as tx:
            if tx.execute(sql, args).rowcount != 1:
                return False
            self._store_key(tx, owner, remember)
            return True

    def delete_scene(self, owner: str, scene_id: str) -> bool:
        with self.db.transaction() as tx:
            cursor = tx.execute("DELETE FROM scenes WHERE owner = ? AND id = ?", (owner, scene_id))
            if cursor.rowcount == 0:
                return False
            trees = [
                r[0]
                for r in tx.execute(
                    "SELECT tree FROM scene_trees WHERE owner = ? AND scene = ?", (owner, scene_id)
                ).fetchall()
            ]
            tx.execute("DELETE FROM scene_trees WHERE owner = ? AND scene = ?", (owner, scene_id))
        self._drop_unused(trees)
        return True

    # ------------------------------------------------------- idempotency keys
    def _store_key(self, tx, owner: str, remember) -> None:
        """Insert an idempotency key's row (inside ``tx``); :class:`KeyTaken` if the owner
        has that key already."""
        if remember is None:
            return
        key, fingerprint, status, response = remember
        now = time.time()
        if self.key_retention > 0:
            tx.execute("DELETE FROM idempotency WHERE created < ?", (now - self.key_retention,))
        cursor = tx.execute(
            "INSERT INTO idempotency (owner, key, fingerprint, status, response, created)"
            " VALUES (?, ?, ?, ?, ?, ?) ON CONFLICT DO NOTHING",
            (owner, key, fingerprint, status, response, now),
        )
        if cursor.rowcount != 1:
            raise KeyTaken(key)

    def remembered(self, owner: str, key: str) -> tuple[str, int, bytes] | None:
        """``(fingerprint, status, response)`` stored with ``owner``'s idempotency
        ``key``, or None."""
        with self.db.read() as tx:
            row = tx.execute(
                "SELECT fingerprint, status, response FROM idempotency WHERE owner = ? AND key = ?",
                (owner, key),
            ).fetchone()
        return None if row is None else (row[0], int(row[1]), bytes(row[2]))

    # ------------------------------------------------------------------- jobs
    def put_job_mesh(self, job_id: str, vertices: np.ndarray, faces: np.ndarray) -> None:
        """Store a job's mesh (``vertices (V, 3) float64``, ``faces (F, 3) int32``)
        durably."""
        buffer = io.BytesIO()
        np.savez(buffer, vertices=vertices, faces=faces)
        self.blobs.put(_job(job_id), buffer.getvalue())

    def job_mesh(self, job_id: str) -> tuple[np.ndarray, np.ndarray]:
        """The job's ``(vertices (V, 3) float64, faces (F, 3) int32)``; raises (OSError,
        ValueError, EOFError, zipfile.BadZipFile, …) when its file is missing or
        unreadable."""
        with np.load(io.BytesIO(self.blobs.get(_job(job_id))), allow_pickle=False) as data:
            return np.array(data["vertices"]), np.array(data["faces"])

    def drop_job_mesh(self, job_id: str) -> None:
        self.blobs.delete(_job(job_id))

    def job_meshes(self, older_than: float = 0.0) -> list[str]:
        """The ids of the jobs whose meshes are stored (written at least ``older_than``
        seconds ago)."""
        return [n[len("jobs/") : -len(".npz")] for n in self.blobs.names("jobs", older_than)]

    def active_job(self, mesh_id: str) -> str | None:
        """The id of the unfinished job building ``mesh_id``, or None."""
        with self.db.read() as tx:
            row = tx.execute(
                "SELECT id FROM jobs WHERE mesh = ? AND status IN (?, ?)", (mesh_id, *ACTIVE)
            ).fetchone()
        return None if row is None else row[0]

    def add_job(self, job_id: str, mesh_id: str, spec: dict, owner: str, extra: dict) -> bool:
        """Record a queued job and its first owner (its mesh file is written already);
        False (nothing recorded) when another unfinished job builds ``mesh_id``."""
        now = time.time()
        with self.db.transaction() as tx:
            cursor = tx.execute(
                f"INSERT INTO jobs ({_JOB_COLUMNS}) VALUES (?, ?, 'queued', ?, 0, 0, NULL,"
                " NULL, NULL, ?, ?, 0) ON CONFLICT DO NOTHING",
                (job_id, mesh_id, json.dumps(spec), now, now),
            )
            if cursor.rowcount != 1:
                return False
            tx.execute(
                "INSERT INTO job_owners (job, owner, extra) VALUES (?, ?, ?)",
                (job_id, owner, json.dumps(extra)),
            )
        return True

    def join_job(self, job_id: str, owner: str, extra: dict) -> bool | None:
        """Add ``owner`` to the unfinished job: True if added, False if it was an owner
        already, None if the job is no longer unfinished."""
        with self.db.transaction() as tx:
            self.db.lock(tx, f"job:{job_id}")
            row = tx.execute("SELECT status FROM jobs WHERE id = ?", (job_id,)).fetchone()
            if row is None or row[0] not in ACTIVE:
                return None
            cursor = tx.execute(
                "INSERT INTO job_owners (job, owner, extra) VALUES (?, ?, ?)"
                " ON CONFLICT DO NOTHING",
                (job_id, owner, json.dumps(extra)),
            )
            return cursor.rowcount == 1

    def job(self, job_id: str, owner: str | None = None) -> dict | None:
        """The job's row as a dict (``spec`` decoded); with ``owner``, only if that owner
        waits for it, and with its ``extra`` (the facts of that owner's upload)."""
        with self.db.read() as tx:
            row = tx.execute(f"SELECT {_JOB_COLUMNS} FROM jobs WHERE id = ?", (job_id,)).fetchone()
            extra = None
            if row is not None and owner is not None:
                extra = tx.execute(
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
            query = f"SELECT * FROM ({query} ORDER BY created DESC, id DESC LIMIT ?) AS newest"
            args.append(int(limit))
        with self.db.read() as tx:
            rows = tx.execute(query + " ORDER BY created, id", args).fetchall()
        return [_job_row(r) for r in rows]

    def owners(self, job_id: str) -> int:
        """How many owners wait for the job."""
        with self.db.read() as tx:
            return tx.execute(
                "SELECT COUNT(*) FROM job_owners WHERE job = ?", (job_id,)
            ).fetchone()[0]

    def set_job(self, job_id: str, status: str, **columns) -> None:
        """Set the job's status and any of ``levels``, ``nodes``, ``seconds``, ``cause``,
        ``error``, ``attempts``."""
        sets = ", ".join(f"{k} = ?" for k in columns)
        with self.db.transaction() as tx:
            tx.execute(
                f"UPDATE jobs SET status = ?, updated = ?{', ' + sets if sets else ''}"
                " WHERE id = ?",
                (status, time.time(), *columns.values(), job_id),
            )

    def start_job(self, job_id: str) -> int:
        """Mark the job ``building`` and count the attempt (committed before the build
        starts, so a build that kills the process is counted); the attempts so far."""
        with self.db.transaction() as tx:
            tx.execute(
                "UPDATE jobs SET status = 'building', attempts = attempts + 1, updated = ?"
                " WHERE id = ?",
                (time.time(), job_id),
            )
            row = tx.execute("SELECT attempts FROM jobs WHERE id = ?", (job_id,)).fetchone()
        return 0 if row is None else int(row[0])

    def fail_job(self, job_id: str, cause: str, error: str) -> None:
        """Mark the job ``failed`` with its ``cause`` and ``error``; then its tree file goes
        if nothing else refers to it."""
        with self.db.transaction() as tx:
            tx.execute(
                "UPDATE jobs SET status = 'failed', cause = ?, error = ?, updated = ? WHERE id = ?",
                (cause, error, time.time(), job_id),
            )
            row = tx.execute("SELECT mesh FROM jobs WHERE id = ?", (job_id,)).fetchone()
        if row is not None:
            self._drop_unused([row[0]])

    def cancel_job(self, job_id: str) -> bool:
        """Mark the unfinished job ``failed`` (cancelled) **if** nobody waits for it — one
        conditional statement under the job's lock, so an upload joining at that moment
        either joins before (and the job goes on: False) or finds the job failed (and
        starts a new one)."""
        with self.db.transaction() as tx:
            self.db.lock(tx, f"job:{job_id}")
            cursor = tx.execute(
                "UPDATE jobs SET status = 'failed', cause = 'cancelled', error = ?, updated = ?"
                " WHERE id = ? AND status IN (?, ?)"
                " AND NOT EXISTS (SELECT 1 FROM job_owners WHERE job = ?)",
                (CANCELLED, time.time(), job_id, *ACTIVE, job_id),
            )
            if cursor.rowcount == 0:
                return False
            row = tx.execute("SELECT mesh FROM jobs WHERE id = ?", (job_id,)).fetchone()
        self._drop_unused([row[0]])
        return True

    def finish_job(self, job_id: str, facts: dict, levels: int, nodes: int, seconds: float):
        """In one transaction: the job done and a mesh row (``facts`` plus the owner's
        ``extra``) for every owner waiting for it. Returns those owners; with none left,
        the job is marked failed (cancelled) and its unused tree file removed."""
        mesh_id, now = facts["id"], time.time()
        with self.db.transaction() as tx:
            self.db.lock(tx, f"job:{job_id}")
            rows = tx.execute(
                "SELECT owner, extra FROM job_owners WHERE job = ?", (job_id,)
            ).fetchall()
            if rows:
                tx.executemany(
                    "INSERT INTO meshes (owner, id, facts, created) VALUES (?, ?, ?, ?)"
                    " ON CONFLICT DO NOTHING",
                    [(o, mesh_id, json.dumps({**facts, **json.loads(e)}), now) for o, e in rows],
                )
                tx.execute(
                    "UPDATE jobs SET status = 'done', levels = ?, nodes = ?, seconds = ?,"
                    " updated = ? WHERE id = ?",
                    (levels, nodes, seconds, now, job_id),
                )
            else:
                tx.execute(
                    "UPDATE jobs SET status = 'failed', cause = 'cancelled', error = ?,"
                    " updated = ? WHERE id = ?",
                    (CANCELLED, now, job_id),
                )
        if not rows:
            self._drop_unused([mesh_id])
        return [o for o, _ in rows]

    def leave_job(self, owner: str, mesh_id: str) -> tuple[str, int] | None:
        """Take ``owner`` off the unfinished job building ``mesh_id``: ``(job id, owners
        left)``, or None when the owner waits for no such job."""
        job_id = self.active_job(mesh_id)
        if job_id is None:
            return None
        with self.db.transaction() as tx:
            self.db.lock(tx, f"job:{job_id}")
            row = tx.execute(
                "SELECT id FROM jobs WHERE id = ? AND status IN (?, ?)"
                " AND id IN (SELECT job FROM job_owners WHERE owner = ?)",
                (job_id, *ACTIVE, owner),
            ).fetchone()
            if row is None:
                return None
            tx.execute("DELETE FROM job_owners WHERE job = ? AND owner = ?", (job_id, owner))
            left = tx.execute(
                "SELECT COUNT(*) FROM job_owners WHERE job = ?", (job_id,)
            ).fetchone()[0]
        return job_id, int(left)

    def prune_jobs(self, before: float) -> int:
        """Forget finished jobs last updated before ``before`` (epoch seconds)."""
        with self.db.transaction() as tx:
            old = "SELECT id FROM jobs WHERE status IN ('done', 'failed') AND updated < ?"
            tx.execute(f"DELETE FROM job_owners WHERE job IN ({old})", (before,))
            return tx.execute(
                "DELETE FROM jobs WHERE status IN ('done', 'failed') AND updated < ?", (before,)
            ).rowcount


def _tree(tree_id: str) -> str:
    return f"trees/{tree_id}.npz"


def _job(job_id: str) -> str:
    return f"jobs/{job_id}.npz"


def _job_row(row) -> dict:
    job = dict(zip(_JOB_COLUMNS.split(", "), row, strict=True))
    job["spec"] = json.loads(job["spec"])
    return job
