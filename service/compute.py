"""Engine calls off the event loop, at most ``engine_concurrency`` at a time; store calls,
body parsing and answer encoding off the loop too, in their own threads (``io``), so that
they never queue behind long engine calls and never hold up ``/healthz``.

The kernels release the GIL (``nogil``) and none uses Numba's ``parallel=True`` threading
layer (which aborts the process when parallel kernels are entered from several threads):
a batched call spreads its pairs over a Python thread pool instead. So engine calls may run
in any number of request threads; the limiter only bounds how many run at once.
"""

from __future__ import annotations

import functools
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import anyio
import anyio.to_thread

__all__ = ["EngineRunner", "Warmup"]


@dataclass
class Warmup:
    """The kernel warm-up's outcome: ``ready`` once done, ``error`` if it failed."""

    ready: threading.Event = field(default_factory=threading.Event)
    error: str | None = None
    seconds: float | None = None


class EngineRunner:
    def __init__(self, concurrency: int, metrics=None, io_concurrency: int = 16) -> None:
        self.limiter = anyio.CapacityLimiter(concurrency)
        self.io_limiter = anyio.CapacityLimiter(io_concurrency)
        self.metrics = metrics

    async def io(self, fn: Callable, *args: Any, **kwargs: Any) -> Any:
        """``fn(*args, **kwargs)`` in a worker thread of its own pool: store calls,
        decoding and encoding bodies (short, blocking work that must not run on the loop)."""
        return await anyio.to_thread.run_sync(
            functools.partial(fn, *args, **kwargs), limiter=self.io_limiter
        )

    async def run(self, name: str, fn: Callable, *args: Any, **kwargs: Any) -> Any:
        """``fn(*args, **kwargs)`` in a worker thread; its seconds go to the metrics."""
        start = time.perf_counter()
        try:
            return await anyio.to_thread.run_sync(
                functools.partial(fn, *args, **kwargs), limiter=self.limiter
            )
        finally:
            if self.metrics is not None:
                self.metrics.engine_seconds.labels(name).observe(time.perf_counter() - start)
