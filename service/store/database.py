"""The store's SQL database behind one small interface: SQLite (embedded, one process) or
PostgreSQL (shared by every replica of a cluster), and the versioned migrations of its
schema.

Both speak the same SQL: ``?`` placeholders (turned into ``%s`` for psycopg), ``INSERT …
ON CONFLICT DO NOTHING`` with ``rowcount`` telling whether a row went in, and two column
types that differ (``{real}``, ``{blob}`` in the migrations). A :class:`Transaction` is a
cursor inside ``BEGIN`` … ``COMMIT`` (rolled back on any error); :meth:`Database.lock`
serialises the transactions that check and change what refers to one name (a tree file
and its references): SQLite's writers are serialised already (``BEGIN IMMEDIATE`` under
the process's lock), PostgreSQL takes a transaction-scoped advisory lock.
"""

from __future__ import annotations

import sqlite3
import threading
import time
from abc import ABC, abstractmethod
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any

__all__ = ["MIGRATIONS", "Database", "PostgresDatabase", "SqliteDatabase", "Transaction"]

_TABLES = """
CREATE TABLE IF NOT EXISTS meshes (
    owner   TEXT NOT NULL,
    id      TEXT NOT NULL,
    facts   TEXT NOT NULL,
    created {real} NOT NULL,
    PRIMARY KEY (owner, id)
);
CREATE TABLE IF NOT EXISTS scenes (
    owner   TEXT NOT NULL,
    id      TEXT NOT NULL,
    spec    TEXT NOT NULL,
    state   {blob} NOT NULL,
    steps   BIGINT NOT NULL,
    updated {real} NOT NULL,
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
    levels  BIGINT NOT NULL DEFAULT 0,
    nodes   BIGINT NOT NULL DEFAULT 0,
    seconds {real},
    cause   TEXT,
    error   TEXT,
    created {real} NOT NULL,
    updated {real} NOT NULL
);
CREATE INDEX IF NOT EXISTS jobs_mesh ON jobs (mesh, status);
CREATE TABLE IF NOT EXISTS idempotency (
    owner       TEXT NOT NULL,
    key         TEXT NOT NULL,
    fingerprint TEXT NOT NULL,
    status      INTEGER NOT NULL,
    response    {blob} NOT NULL,
    created     {real} NOT NULL,
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


def _add_attempts(tx: Transaction) -> None:
    if "attempts" not in tx.columns("jobs"):  # a store written before attempts were counted
        tx.execute("ALTER TABLE jobs ADD COLUMN attempts BIGINT NOT NULL DEFAULT 0")


#: ``(version, what it does, SQL script or a function of the transaction)``, applied in
#: order, each in its own transaction with its row in ``schema_migrations``. Version 1 is
#: written with ``IF NOT EXISTS``: a store from before migrations were versioned adopts it.
MIGRATIONS: tuple[tuple[int, str, str | Callable[[Transaction], None]], ...] = (
    (1, "meshes, scenes, build jobs, idempotency keys", _TABLES),
    (2, "build attempts counted", _add_attempts),
    (
        3,
        "one unfinished build job per content (replicas race to start it)",
        "CREATE UNIQUE INDEX IF NOT EXISTS jobs_one_active ON jobs (mesh)"
        " WHERE status IN ('queued', 'building')",
    ),
    (
        4,
        "a scene's version, counted up by every saved state (compare and set)",
        "ALTER TABLE scenes ADD COLUMN version BIGINT NOT NULL DEFAULT 0",
    ),
)


class Transaction:
    """A cursor inside a transaction: ``execute``/``executemany`` take ``?`` placeholders
    and return the cursor (``fetchone``, ``fetchall``, ``rowcount``)."""

    def __init__(self, cursor, placeholder: str, dialect: str) -> None:
        self._cursor = cursor
        self._placeholder = placeholder
        self.dialect = dialect

    def _sql(self, sql: str) -> str:
        return sql if self._placeholder == "?" else sql.replace("?", self._placeholder)

    def execute(self, sql: str, args: Sequence[Any] = ()):
        self._cursor.execute(self._sql(sql), tuple(args))
        return self._cursor

    def executemany(self, sql: str, rows: Sequence[Sequence[Any]]) -> None:
        if rows:
            self._cursor.executemany(self._sql(sql), [tuple(r) for r in rows])

    def script(self, sql: str) -> None:
        for statement in (s.strip() for s in sql.split(";")):
            if statement:
                self._cursor.execute(statement)

    def columns(self, table: str) -> set[str]:
        if self.dialect == "sqlite":
            return {row[1] for row in self._cursor.execute(f"PRAGMA table_info({table})")}
        self._cursor.execute(
            "SELECT column_name FROM information_schema.columns"
            " WHERE table_schema = current_schema() AND table_name = %s",
            (table,),
        )
        return {row[0] for row in self._cursor.fetchall()}


class Database(ABC):
    """What the store needs of a SQL database; see the module's docstring."""

    dialect: str
    types: dict[str, str]

    @abstractmethod
    def transaction(self) -> Any:
        """A context manager yielding a :class:`Transaction` (committed at its end)."""

    @abstractmethod
    def read(self) -> Any:
        """A context manager yielding a :class:`Transaction` for reads only."""

    @abstractmethod
    def lock(self, tx: Transaction, name: str) -> None:
        """Hold ``name`` until ``tx`` ends."""

    @abstractmethod
    def claim(self, name: str) -> Any:
        """A context manager yielding whether this process now holds ``name`` (until the
        block ends) — False while another holder has it. A holder that dies loses it."""

    def ping(self) -> bool:
        with self.read() as tx:
            return tuple(tx.execute("SELECT 1").fetchone()) == (1,)

    @abstractmethod
    def close(self) -> None:
        """Close the connections."""

    def migrate(self) -> list[int]:
        """Apply the migrations this database lacks, in one transaction under a lock (so
        replicas starting at once apply each exactly once, and a failed migration leaves
        the schema as it was); the versions applied."""
        applied = []
        with self.transaction() as tx:
            self.lock(tx, "schema_migrations")
            tx.execute(
                "CREATE TABLE IF NOT EXISTS schema_migrations (version INTEGER PRIMARY KEY,"
                f" description TEXT NOT NULL, applied {self.types['real']} NOT NULL)"
            )
            done = {r[0] for r in tx.execute("SELECT version FROM schema_migrations").fetchall()}
            for version, description, change in MIGRATIONS:
                if version in done:
                    continue
                if callable(change):
                    change(tx)
                else:
                    tx.script(change.format(**self.types))
                tx.execute(
                    "INSERT INTO schema_migrations (version, description, applied)"
                    " VALUES (?, ?, ?)",
                    (version, description, time.time()),
                )
                applied.append(version)
        return applied

    def versions(self) -> list[int]:
        """The schema versions applied, in order."""
        with self.read() as tx:
            rows = tx.execute("SELECT version FROM schema_migrations ORDER BY version")
            return [int(r[0]) for r in rows.fetchall()]


class SqliteDatabase(Database):
    """One SQLite file (WAL, ``synchronous=FULL``: a committed row survives ``kill -9`` and
    power loss), one connection used under a lock."""

    dialect = "sqlite"
    types = {"real": "REAL", "blob": "BLOB"}

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self.connection = sqlite3.connect(self.path, check_same_thread=False, isolation_level=None)
        self.connection.execute("PRAGMA journal_mode=WAL")
        self.connection.execute("PRAGMA synchronous=FULL")
        self._lock = threading.RLock()
        self._claims: set[str] = set()

    @contextmanager
    def transaction(self) -> Iterator[Transaction]:
        with self._lock:
            cursor = self.connection.cursor()
            cursor.execute("BEGIN IMMEDIATE")
            try:
                yield Transaction(cursor, "?", self.dialect)
            except BaseException:
                cursor.execute("ROLLBACK")
                raise
            cursor.execute("COMMIT")

    @contextmanager
    def read(self) -> Iterator[Transaction]:
        with self._lock:
            yield Transaction(self.connection.cursor(), "?", self.dialect)

    def lock(self, tx: Transaction, name: str) -> None:
        """Nothing to take: the transaction holds the process's lock and SQLite's write
        lock (``BEGIN IMMEDIATE``) already."""

    @contextmanager
    def claim(self, name: str) -> Iterator[bool]:
        # one process writes a SQLite store: a claim is this process's
        with self._lock:
            mine = name not in self._claims
            self._claims.add(name)
        try:
            yield mine
        finally:
            if mine:
                with self._lock:
                    self._claims.discard(name)

    def close(self) -> None:
        with self._lock:
            self.connection.close()


class PostgresDatabase(Database):
    """A PostgreSQL database shared by replicas, reached through a psycopg 3 connection
    pool (``url``: ``postgresql://user:password@host:port/database``)."""

    dialect = "postgresql"
    types = {"real": "DOUBLE PRECISION", "blob": "BYTEA"}

    def __init__(self, url: str, pool_size: int = 8, timeout: float = 30.0) -> None:
        try:
            from psycopg_pool import ConnectionPool
        except ImportError as exc:  # pragma: no cover - the message is the point
            raise RuntimeError(
                "a PostgreSQL store needs psycopg: pip install 'mrdem[cluster]'"
            ) from exc
        self.pool = ConnectionPool(
            url,
            min_size=1,
            max_size=pool_size,
            kwargs={"autocommit": True},
            timeout=timeout,
            open=False,
            name="mrdem-store",
        )
        self.pool.open(wait=True, timeout=timeout)

    @contextmanager
    def transaction(self) -> Iterator[Transaction]:
        with (
            self.pool.connection() as connection,
            connection.transaction(),
            connection.cursor() as cursor,
        ):
            yield Transaction(cursor, "%s", self.dialect)

    @contextmanager
    def read(self) -> Iterator[Transaction]:
        with self.pool.connection() as connection, connection.cursor() as cursor:
            yield Transaction(cursor, "%s", self.dialect)

    def lock(self, tx: Transaction, name: str) -> None:
        tx.execute("SELECT pg_advisory_xact_lock(hashtextextended(?, 0))", (name,))

    @contextmanager
    def claim(self, name: str) -> Iterator[bool]:
        # a session advisory lock on a connection kept for the block: released when the
        # block ends, or by the server when this process's connection drops
        with self.pool.connection() as connection:
            mine = connection.execute(
                "SELECT pg_try_advisory_lock(hashtextextended(%s, 0))", (name,)
            ).fetchone()[0]
            try:
                yield bool(mine)
            finally:
                if mine:
                    connection.execute(
                        "SELECT pg_advisory_unlock(hashtextextended(%s, 0))", (name,)
                    )

    def close(self) -> None:
        self.pool.close()
