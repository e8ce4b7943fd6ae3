"""The embedded store: SQLite for metadata, content-addressed tree files beside it.

Layout under the data directory: ``mrdem.sqlite3`` (WAL, ``synchronous=FULL``: a committed
row survives ``kill -9`` and power loss) and ``trees/<id>.npz``. A tree file is written
before the row that refers to it — to a temporary file, fsynced, renamed into place, the
directory fsynced — so an acknowledged mesh always has its tree, and a crash leaves at
most an unreferenced file (reused by the next upload of the same content, or removed with
leftover temporaries at start-up). Meshes belong to an owner (the API key's digest; "" when
the service runs without keys); a tree file is shared by every owner of the same content
and kept while a mesh or a scene refers to it. A scene's row holds its specification and
its latest state, replaced in one transaction per acknowledged step.
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
from pathlib import Path

from engine import SurrogateTree

__all__ = ["Store"]

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
"""


class Store:
    """Meshes (and their surrogate trees) per owner, durable across restarts.

    Parameters
    ----------
    data_dir : path — created if missing
    tree_cache : int — trees kept in memory (least recently used dropped first)
    """

    def __init__(self, data_dir: str | os.PathLike, tree_cache: int = 256) -> None:
        self.root = Path(data_dir)
        self.trees_dir = self.root / "trees"
        self.trees_dir.mkdir(parents=True, exist_ok=True)
        for stale in self.trees_dir.glob(".*.tmp"):
            stale.unlink(missing_ok=True)
        self.db = sqlite3.connect(
            self.root / "mrdem.sqlite3", check_same_thread=False, isolation_level=None
        )
        self.db.execute("PRAGMA journal_mode=WAL")
        self.db.execute("PRAGMA synchronous=FULL")
        self.db.executescript(_SCHEMA)
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
        tmp = self.trees_dir / f".{tree_id}.{uuid.uuid4().hex}.tmp"
        try:
            with open(tmp, "wb") as f:
                f.write(buffer.getvalue())
                f.flush()
                os.fsync(f.fileno())
            os.replace(tmp, path)
        finally:
            tmp.unlink(missing_ok=True)
        _fsync_dir(self.trees_dir)
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
    def add_mesh(self, owner: str, mesh_id: str, facts: dict) -> bool:
        """Record the mesh for ``owner``; False when it was there already."""
        with self.lock:
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

    def _drop_unused(self, tree_ids) -> None:
        """Remove the tree files no mesh and no scene refers to (lock held)."""
        for tree_id in set(tree_ids):
            used = self.db.execute(
                "SELECT 1 FROM meshes WHERE id = ? UNION ALL"
                " SELECT 1 FROM scene_trees WHERE tree = ? LIMIT 1",
                (tree_id, tree_id),
            ).fetchone()
            if used is None:
                self._cache.pop(tree_id, None)
                self.tree_path(tree_id).unlink(missing_ok=True)

    # ----------------------------------------------------------------- scenes
    def add_scene(self, owner: str, scene_id: str, spec: dict, state: bytes, trees) -> None:
        """Record a new scene, its state and the trees it uses, in one transaction."""
        with self.lock:
            self.db.execute("BEGIN IMMEDIATE")
            try:
                self.db.execute(
                    "INSERT INTO scenes (owner, id, spec, state, steps, updated)"
                    " VALUES (?, ?, ?, ?, 0, ?)",
                    (owner, scene_id, json.dumps(spec), state, time.time()),
                )
                self.db.executemany(
                    "INSERT INTO scene_trees (owner, scene, tree) VALUES (?, ?, ?)",
                    [(owner, scene_id, t) for t in sorted(set(trees))],
                )
                self.db.execute("COMMIT")
            except BaseException:
                self.db.execute("ROLLBACK")
                raise

    def scene(self, owner: str, scene_id: str) -> tuple[dict, bytes, int] | None:
        """``(spec, state, steps)`` of ``owner``'s scene, or None."""
        with self.lock:
            row = self.db.execute(
                "SELECT spec, state, steps FROM scenes WHERE owner = ? AND id = ?",
                (owner, scene_id),
            ).fetchone()
        return None if row is None else (json.loads(row[0]), bytes(row[1]), int(row[2]))

    def save_state(self, owner: str, scene_id: str, state: bytes, steps: int) -> bool:
        """Replace the scene's state (committed before this returns); False if it is gone."""
        with self.lock:
            cursor = self.db.execute(
                "UPDATE scenes SET state = ?, steps = ?, updated = ? WHERE owner = ? AND id = ?",
                (state, steps, time.time(), owner, scene_id),
            )
            return cursor.rowcount == 1

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


def _fsync_dir(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)
