"""The service's store: one interface (:class:`Store`) over two back ends — SQLite and
tree files in a data directory (embedded, the default), or PostgreSQL and an
S3-compatible bucket shared by the replicas of a cluster — chosen by the settings
(:func:`open_store`)."""

from __future__ import annotations

from .blobs import Blobs, FileBlobs, S3Blobs
from .database import MIGRATIONS, Database, PostgresDatabase, SqliteDatabase
from .keys import Key
from .store import ACTIVE, CANCELLED, KeyTaken, Store

__all__ = [
    "ACTIVE",
    "CANCELLED",
    "MIGRATIONS",
    "Blobs",
    "Database",
    "FileBlobs",
    "Key",
    "KeyTaken",
    "PostgresDatabase",
    "S3Blobs",
    "SqliteDatabase",
    "Store",
    "open_store",
]


def open_store(settings) -> Store:
    """The store the settings name: ``MRDEM_STORE_URL`` (``postgresql://…``; unset: SQLite
    under ``MRDEM_DATA_DIR``) and ``MRDEM_OBJECT_STORE_URL`` (``s3://bucket/prefix`` with
    ``MRDEM_OBJECT_STORE_ENDPOINT``; unset: files under ``MRDEM_DATA_DIR``)."""
    database = None
    if settings.store_url:
        database = PostgresDatabase(settings.store_url, settings.store_pool)
    blobs = None
    if settings.object_store_url:
        blobs = S3Blobs(
            settings.object_store_url,
            settings.object_store_endpoint,
            settings.data_dir / "tree-cache",
            settings.tree_disk_cache,
        )
    try:
        return Store(
            settings.data_dir,
            settings.tree_cache,
            settings.idempotency_retention,
            database=database,
            blobs=blobs,
        )
    except BaseException:
        for part in (database, blobs):
            if part is not None:
                part.close()
        raise
