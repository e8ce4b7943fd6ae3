"""``python -m service`` as a child process on a free loopback port, waited for until ready:
the one way the tests, the demo (``clients/demo.py``) and the container check start a server.

Imports neither engine nor service (the service runs in its own process); httpx and the
standard library only.
"""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import IO

import httpx

__all__ = ["LOOPBACK", "ServiceProcess", "ServiceStartError", "free_port", "readyz"]

LOOPBACK = "127.0.0.1"
LOG_TAIL = 2000  # characters of the service's log quoted when it fails to start


class ServiceStartError(RuntimeError):
    """The service exited or did not get ready in time; the message ends with its log tail
    when its output went to a file."""


def free_port() -> int:
    """A TCP port on the loopback interface that nothing listens on now (int)."""
    with socket.socket() as s:
        s.bind((LOOPBACK, 0))
        return s.getsockname()[1]


def readyz(url: str) -> bool:
    """Whether the service at ``url`` answers 200 on ``/readyz`` (False when it cannot be
    reached yet)."""
    try:
        return httpx.get(f"{url}/readyz", timeout=2.0).status_code == 200
    except httpx.TransportError:
        return False


class ServiceProcess:
    """``python -m service`` on ``LOOPBACK`` with its store in ``data_dir``.

    Parameters
    ----------
    data_dir : the store (``MRDEM_DATA_DIR``; created by the service)
    settings : more ``MRDEM_*`` settings by field name (``{"build_wait": "0"}`` sets
        ``MRDEM_BUILD_WAIT=0``)
    port : the port (default: a free one, chosen anew at each :meth:`start`)
    env : the environment the settings are added to (default: this process's)
    cwd : the working directory (default: this process's)
    log_dir : where the output goes, as ``service-<port>.log`` (:attr:`log_path`; its tail
        is quoted when the start fails); None: this process's stdout and stderr
    ready_timeout : seconds :meth:`start` waits (a fresh kernel cache compiles everything
        first: minutes)

    A context manager: ``with ServiceProcess(...) as service:`` starts and stops it.
    """

    def __init__(
        self,
        data_dir: str | os.PathLike,
        *,
        settings: Mapping[str, object] | None = None,
        port: int | None = None,
        env: Mapping[str, str] | None = None,
        cwd: str | os.PathLike | None = None,
        log_dir: str | os.PathLike | None = None,
        ready_timeout: float = 600.0,
    ) -> None:
        self.data_dir = Path(data_dir)
        self.settings = dict(settings or {})
        self.requested_port, self.port = port, port or 0
        self.env = dict(os.environ if env is None else env)
        self.cwd, self.ready_timeout = cwd, ready_timeout
        self.log_dir = None if log_dir is None else Path(log_dir)
        self.log_path: Path | None = None
        self.log: IO[bytes] | None = None
        self.proc: subprocess.Popen | None = None

    @property
    def url(self) -> str:
        return f"http://{LOOPBACK}:{self.port}"

    def start(self, ready: Callable[[], bool] | None = None) -> ServiceProcess:
        """Start the process and wait until ``ready()`` (default: ``/readyz`` answers 200);
        :class:`ServiceStartError` (the process stopped) if it exits first or is not ready
        within ``ready_timeout`` seconds."""
        self.port = self.requested_port or free_port()
        env = {
            **self.env,
            "MRDEM_HOST": LOOPBACK,
            "MRDEM_PORT": str(self.port),
            "MRDEM_DATA_DIR": str(self.data_dir),
            **{f"MRDEM_{k.upper()}": str(v) for k, v in self.settings.items()},
        }
        output = None
        if self.log_dir is not None:
            self.log_path = self.log_dir / f"service-{self.port}.log"
            output = self.log = open(self.log_path, "wb")  # noqa: SIM115 -- open while it runs
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "service"], cwd=self.cwd, env=env, stdout=output, stderr=output
        )
        try:
            self._wait(ready or (lambda: readyz(self.url)))
        except BaseException:
            self.stop()
            raise
        return self

    def _wait(self, ready: Callable[[], bool]) -> None:
        deadline = time.monotonic() + self.ready_timeout
        while True:
            if self.proc.poll() is not None:
                raise ServiceStartError(
                    f"the service exited with {self.proc.returncode}{self._tail()}"
                )
            if ready():
                return
            if time.monotonic() > deadline:
                raise ServiceStartError(
                    f"the service on {self.url} was not ready in {self.ready_timeout:g} s"
                    f"{self._tail()}"
                )
            time.sleep(0.2)

    def _tail(self) -> str:
        if self.log_path is None:
            return " (its output is above)"
        text = self.log_path.read_text(errors="replace")[-LOG_TAIL:]
        return f"; the end of {self.log_path}:\n{text}"

    def kill(self) -> None:
        """SIGKILL: no shutdown, no flush."""
        self.proc.send_signal(signal.SIGKILL)
        self.proc.wait(10)
        self._close()

    def stop(self, grace: float = 20.0) -> None:
        """SIGTERM, then SIGKILL if it has not exited after ``grace`` seconds."""
        if self.proc and self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(grace)
            except subprocess.TimeoutExpired:
                self.kill()
        self._close()

    def _close(self) -> None:
        if self.log:
            self.log.close()
            self.log = None

    def __enter__(self) -> ServiceProcess:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()
