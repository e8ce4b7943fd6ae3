"""Real servers on loopback for the shared store's tests and the cluster benchmark:
PostgreSQL started from the machine's binaries in a temporary directory (as the
``postgres`` user when run as root: ``initdb`` refuses root) and an S3-compatible server
(moto in server mode, from the dev extra).

Imports neither engine nor service; psycopg and moto only when a server is asked for."""

from __future__ import annotations

import glob
import os
import pwd
import shutil
import socket
import subprocess
import tempfile
import time
import uuid
from pathlib import Path

from .serving import free_port

__all__ = ["PostgresServer", "S3Server", "free_port", "postgres_bin"]


def postgres_bin() -> Path | None:
    """The folder of ``initdb`` and ``pg_ctl`` (``MRDEM_TEST_PG_BIN``, the ``PATH``, or
    Debian's ``/usr/lib/postgresql/<version>/bin``)."""
    candidates = [os.environ.get("MRDEM_TEST_PG_BIN", "")]
    found = shutil.which("initdb")
    candidates.append(os.path.dirname(found) if found else "")
    candidates += sorted(glob.glob("/usr/lib/postgresql/*/bin"), reverse=True)
    for folder in candidates:
        if folder and os.path.exists(os.path.join(folder, "initdb")):
            return Path(folder)
    return None


class PostgresServer:
    """A PostgreSQL server of its own (``initdb`` in a temporary directory, ``pg_ctl
    start`` on a free loopback port, trust authentication); :meth:`database` creates a
    fresh database and gives its URL."""

    def __init__(self) -> None:
        folder = postgres_bin()
        if folder is None:
            raise FileNotFoundError("PostgreSQL's initdb and pg_ctl are not on this machine")
        self.bin = folder
        self.root = Path(tempfile.mkdtemp(prefix="mrdem-pg-"))
        self.data = self.root / "data"
        self.port = free_port()
        self.user = None
        if os.geteuid() == 0:  # initdb refuses root: the server runs as postgres
            self.user = pwd.getpwnam("postgres")
            os.chown(self.root, self.user.pw_uid, self.user.pw_gid)
        self._run("initdb", "-D", str(self.data), "-U", "mrdem", "-A", "trust", "-E", "UTF8")
        options = f"-p {self.port} -k {self.root} -c listen_addresses=127.0.0.1 -c fsync=on"
        self._run(
            "pg_ctl", "-D", str(self.data), "-l", str(self.root / "log"), "-o", options, "-w",
            "start",
        )  # fmt: skip
        self.url = f"postgresql://mrdem@127.0.0.1:{self.port}/postgres"

    def _run(self, program: str, *args: str) -> None:
        command = [str(self.bin / program), *args]
        kwargs = {}
        if self.user is not None:
            kwargs = {"user": self.user.pw_uid, "group": self.user.pw_gid, "extra_groups": []}
        done = subprocess.run(
            command, capture_output=True, text=True, timeout=120, cwd=self.root, **kwargs
        )
        if done.returncode != 0:
            raise RuntimeError(f"{program} failed: {done.stdout}\n{done.stderr}")

    def database(self) -> str:
        """A new, empty database's URL."""
        import psycopg

        name = "t" + uuid.uuid4().hex[:12]
        with psycopg.connect(self.url, autocommit=True) as connection:
            connection.execute(f'CREATE DATABASE "{name}"')
        return f"postgresql://mrdem@127.0.0.1:{self.port}/{name}"

    def stop(self) -> None:
        try:
            self._run("pg_ctl", "-D", str(self.data), "-m", "immediate", "-w", "stop")
        finally:
            shutil.rmtree(self.root, ignore_errors=True)


class S3Server:
    """moto's S3 server on a free loopback port (credentials set for boto3 in this
    process's environment); :meth:`bucket` gives a fresh bucket's URL."""

    def __init__(self) -> None:
        from moto.server import ThreadedMotoServer

        for name, value in (
            ("AWS_ACCESS_KEY_ID", "mrdem-test"),
            ("AWS_SECRET_ACCESS_KEY", "mrdem-test-secret"),
            ("AWS_DEFAULT_REGION", "us-east-1"),
        ):
            os.environ.setdefault(name, value)
        self.port = free_port()
        self.server = ThreadedMotoServer(ip_address="127.0.0.1", port=self.port, verbose=False)
        self.server.start()
        self.endpoint = f"http://127.0.0.1:{self.port}"
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline:
            try:
                socket.create_connection(("127.0.0.1", self.port), timeout=1).close()
                break
            except OSError:
                time.sleep(0.05)

    def bucket(self) -> str:
        """A fresh bucket's URL (created by the store on first use)."""
        return f"s3://b{uuid.uuid4().hex[:12]}/trees-of-test"

    def stop(self) -> None:
        self.server.stop()
