"""Where the store keeps its files (tree files ``trees/<id>.npz``, build jobs' meshes
``jobs/<id>.npz``): a directory on local disk, or an S3-compatible bucket shared by every
replica, with a bounded local copy of the trees it read (content-addressed: a copy is
never stale).

A blob is durable when :meth:`Blobs.put` returns (a file: written to a temporary,
fsynced, renamed, the directory fsynced; S3: the ``PutObject`` acknowledged). A missing
blob raises :class:`FileNotFoundError`; any other failure an :class:`OSError`.
"""

from __future__ import annotations

import os
import threading
import time
import uuid
from abc import ABC, abstractmethod
from collections import OrderedDict
from pathlib import Path
from urllib.parse import urlsplit

__all__ = ["Blobs", "FileBlobs", "S3Blobs"]

FOLDERS = ("trees", "jobs")


class Blobs(ABC):
    """Named byte strings (``"trees/<id>.npz"``); see the module's docstring."""

    @abstractmethod
    def put(self, name: str, data: bytes) -> None:
        """Store ``data`` under ``name`` durably (replacing what was there)."""

    @abstractmethod
    def get(self, name: str) -> bytes:
        """The bytes stored under ``name``; :class:`FileNotFoundError` if none."""

    @abstractmethod
    def exists(self, name: str) -> bool:
        """Whether something is stored under ``name``."""

    @abstractmethod
    def delete(self, name: str) -> None:
        """Remove ``name`` (nothing happens when it is not there)."""

    @abstractmethod
    def names(self, folder: str, older_than: float = 0.0) -> list[str]:
        """The names in ``folder`` (``"trees"``), with their folder, last written at least
        ``older_than`` seconds ago."""

    def ping(self) -> bool:
        """The storage answers."""
        return True

    @abstractmethod
    def close(self) -> None:
        """Release connections."""


class FileBlobs(Blobs):
    """Blobs as files under ``root`` (``root/trees``, ``root/jobs``); temporaries a crash
    left are removed when it opens."""

    def __init__(self, root: str | os.PathLike) -> None:
        self.root = Path(root)
        for folder in FOLDERS:
            path = self.root / folder
            path.mkdir(parents=True, exist_ok=True)
            for stale in path.glob(".*.tmp"):  # half-written by a crash
                stale.unlink(missing_ok=True)

    def path(self, name: str) -> Path:
        return self.root / name

    def put(self, name: str, data: bytes) -> None:
        write_durably(self.path(name), data)

    def get(self, name: str) -> bytes:
        return self.path(name).read_bytes()

    def exists(self, name: str) -> bool:
        return self.path(name).exists()

    def delete(self, name: str) -> None:
        self.path(name).unlink(missing_ok=True)

    def names(self, folder: str, older_than: float = 0.0) -> list[str]:
        limit = time.time() - older_than
        found = []
        for path in (self.root / folder).glob("*.npz"):
            try:
                if older_than <= 0 or path.stat().st_mtime <= limit:
                    found.append(f"{folder}/{path.name}")
            except FileNotFoundError:  # removed meanwhile
                continue
        return sorted(found)

    def ping(self) -> bool:
        return self.root.is_dir()

    def close(self) -> None:
        """Nothing to release: every file is closed when written or read."""


class S3Blobs(Blobs):
    """Blobs in an S3-compatible bucket: ``url`` ``s3://bucket/prefix`` (the prefix may be
    empty), ``endpoint_url`` for a store other than AWS (MinIO, moto, Ceph …); the
    credentials and region come from boto3's usual sources (``AWS_ACCESS_KEY_ID`` …). The
    bucket is created if it does not exist. Tree files read are copied under
    ``cache_dir`` (at most ``cache_bytes``, least recently used removed first)."""

    def __init__(
        self,
        url: str,
        endpoint_url: str | None = None,
        cache_dir: str | os.PathLike | None = None,
        cache_bytes: int = 2 * 2**30,
    ) -> None:
        try:
            import boto3
            from botocore.config import Config
            from botocore.exceptions import BotoCoreError, ClientError
        except ImportError as exc:  # pragma: no cover - the message is the point
            raise RuntimeError(
                "an S3 object store needs boto3: pip install 'mrdem[cluster]'"
            ) from exc
        parts = urlsplit(url)
        if parts.scheme != "s3" or not parts.netloc:
            raise ValueError(f"an object store URL looks like s3://bucket/prefix, not {url!r}")
        self.bucket = parts.netloc
        self.prefix = parts.path.strip("/") + "/" if parts.path.strip("/") else ""
        self._errors = (BotoCoreError, ClientError)
        self._client_error = ClientError
        self.client = boto3.client(
            "s3",
            endpoint_url=endpoint_url,
            config=Config(retries={"max_attempts": 5, "mode": "standard"}),
        )
        self.cache = None if cache_dir is None else _DiskCache(Path(cache_dir), cache_bytes)
        try:
            self.client.head_bucket(Bucket=self.bucket)
        except ClientError as exc:
            if _status(exc) != 404:
                raise OSError(f"the bucket {self.bucket!r} cannot be reached: {exc}") from exc
            self.client.create_bucket(Bucket=self.bucket)

    def _key(self, name: str) -> str:
        return self.prefix + name

    def put(self, name: str, data: bytes) -> None:
        try:
            self.client.put_object(Bucket=self.bucket, Key=self._key(name), Body=data)
        except self._errors as exc:
            raise OSError(f"storing {name} failed: {exc}") from exc
        if self.cache is not None and name.startswith("trees/"):
            self.cache.put(name, data)

    def get(self, name: str) -> bytes:
        cached = name.startswith("trees/") and self.cache is not None
        if cached:
            data = self.cache.get(name)
            if data is not None:
                return data
        try:
            answer = self.client.get_object(Bucket=self.bucket, Key=self._key(name))
            data = answer["Body"].read()
        except self._client_error as exc:
            if _status(exc) == 404:
                raise FileNotFoundError(name) from None
            raise OSError(f"reading {name} failed: {exc}") from exc
        except self._errors as exc:
            raise OSError(f"reading {name} failed: {exc}") from exc
        if cached:
            self.cache.put(name, data)
        return data

    def exists(self, name: str) -> bool:
        try:
            self.client.head_object(Bucket=self.bucket, Key=self._key(name))
        except self._client_error as exc:
            if _status(exc) == 404:
                return False
            raise OSError(f"looking up {name} failed: {exc}") from exc
        except self._errors as exc:
            raise OSError(f"looking up {name} failed: {exc}") from exc
        return True

    def delete(self, name: str) -> None:
        if self.cache is not None:
            self.cache.drop(name)
        try:
            self.client.delete_object(Bucket=self.bucket, Key=self._key(name))
        except self._errors as exc:
            raise OSError(f"removing {name} failed: {exc}") from exc

    def names(self, folder: str, older_than: float = 0.0) -> list[str]:
        limit = time.time() - older_than
        found = []
        try:
            pages = self.client.get_paginator("list_objects_v2").paginate(
                Bucket=self.bucket, Prefix=self._key(folder + "/")
            )
            for page in pages:
                for item in page.get("Contents", ()):
                    if older_than <= 0 or item["LastModified"].timestamp() <= limit:
                        found.append(item["Key"][len(self.prefix) :])
        except self._errors as exc:
            raise OSError(f"listing {folder} failed: {exc}") from exc
        return sorted(n for n in found if n.endswith(".npz"))

    def ping(self) -> bool:
        try:
            self.client.head_bucket(Bucket=self.bucket)
        except self._errors:
            return False
        return True

    def close(self) -> None:
        self.client.close()


class _DiskCache:
    """Copies of blobs under ``root`` (at most ``limit`` bytes, least recently used removed
    first); safe to share between processes (files written atomically, a vanished copy is
    a miss)."""

    def __init__(self, root: Path, limit: int) -> None:
        self.root = root
        self.limit = int(limit)
        self._lock = threading.Lock()
        self._sizes: OrderedDict[str, int] = OrderedDict()
        self._total = 0
        for folder in FOLDERS:
            (root / folder).mkdir(parents=True, exist_ok=True)
            for stale in (root / folder).glob(".*.tmp"):
                stale.unlink(missing_ok=True)
        found = sorted(
            (p.stat().st_atime, f"{p.parent.name}/{p.name}", p.stat().st_size)
            for folder in FOLDERS
            for p in (root / folder).glob("*.npz")
        )
        for _, name, size in found:
            self._sizes[name] = size
            self._total += size
        self._evict()

    def get(self, name: str) -> bytes | None:
        try:
            data = (self.root / name).read_bytes()
        except OSError:
            return None
        with self._lock:
            self._note(name, len(data))
        return data

    def put(self, name: str, data: bytes) -> None:
        if len(data) > self.limit:
            return
        try:
            write_durably(self.root / name, data, sync=False)
        except OSError:  # a full disk costs a later download, nothing more
            return
        with self._lock:
            self._note(name, len(data))
        self._evict()

    def _note(self, name: str, size: int) -> None:  # lock held
        self._total += size - self._sizes.get(name, 0)
        self._sizes[name] = size
        self._sizes.move_to_end(name)

    def drop(self, name: str) -> None:
        with self._lock:
            self._total -= self._sizes.pop(name, 0)
        (self.root / name).unlink(missing_ok=True)

    def _evict(self) -> None:
        with self._lock:
            while self._sizes and self._total > self.limit:
                name, size = self._sizes.popitem(last=False)
                self._total -= size
                (self.root / name).unlink(missing_ok=True)

    def bytes(self) -> int:
        with self._lock:
            return self._total


def _status(exc) -> int:
    return int(exc.response.get("ResponseMetadata", {}).get("HTTPStatusCode", 0))


def write_durably(path: Path, data: bytes, sync: bool = True) -> None:
    """``data`` into ``path``: a temporary file, fsynced, renamed, the directory fsynced
    (``sync=False``: only the rename, for copies that can be fetched again)."""
    tmp = path.parent / f".{path.stem}.{uuid.uuid4().hex}.tmp"
    try:
        with open(tmp, "wb") as f:
            f.write(data)
            if sync:
                f.flush()
                os.fsync(f.fileno())
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)
    if sync:
        fd = os.open(path.parent, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)
