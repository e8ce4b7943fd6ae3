"""Tree builds as durable jobs, run by a bounded pool of background threads.

An upload whose tree is not stored yet becomes a **build job** (:meth:`BuildJobs.submit`):
the repaired mesh is written to ``jobs/<job>.npz`` (temporary file, fsync, rename) and the
job's row committed before the upload is acknowledged. ``MRDEM_BUILD_CONCURRENCY``
threads take jobs in order, build the tree (the kernels release the GIL), write the tree
file, then mark the job done and add every waiting owner's mesh row in one transaction.
The same content uploaded while its job is unfinished joins that job (one build, one
tree); each owner then gets its own mesh row. Nothing ties a build to the request that
started it: a client that disconnects does not stop it.

Crash safety: at start-up every job still ``queued`` or ``building`` is queued again from
its stored mesh, or marked ``failed``: cause ``lost`` when that file is gone or unreadable,
cause ``crashed`` when its build was already interrupted ``MAX_ATTEMPTS`` (3) times (the
attempt is counted, and committed, as the build starts: a build that kills the process —
out of memory, a crash — is not retried forever). Job files of finished jobs, tree files
nothing refers to and half-written temporaries are removed. A build that raises never takes
the server down: the job is marked ``failed`` with the reason — cause ``engine`` for an
:class:`engine.EngineError` (the mesh cannot be built), ``memory`` for an out-of-memory
error, ``storage`` when the tree file cannot be written, ``internal`` otherwise (logged
with its traceback; the answer names no server internals) — and its tree file is removed
unless something else uses it. Should the store fail to record a failure, the job reads
as failed from memory (and is recovered at the next start). A failed job is retried by
uploading the mesh again (a new job). Finished jobs older than the retention are
forgotten at start-up and after every finished build.

Cancellation: when every owner has left a job (``DELETE /v1/meshes/{id}`` while it is
unfinished), the build stops at its next level and the job is marked ``failed`` (cause
``cancelled``).
"""

from __future__ import annotations

import asyncio
import contextlib
import hashlib
import logging
import queue
import threading
import time
import uuid
from dataclasses import dataclass, field

import numpy as np

from engine import TREE_FORMAT, EngineError, Mesh, build_tree

from .store import ACTIVE, Store

__all__ = ["BuildJobs", "Submission", "content_id", "mesh_facts"]

log = logging.getLogger("mrdem.service")


def content_id(mesh: Mesh, epsilon: float, branching: int) -> str:
    """The mesh id: SHA-256 (32 hex digits) of the tree format, the (repaired) vertices
    and faces, ε and branching — a tree built by another format is never served."""
    digest = hashlib.sha256(f"mrdem-tree-{TREE_FORMAT}\0".encode())
    digest.update(np.ascontiguousarray(mesh.vertices, "<f8").tobytes())
    digest.update(np.ascontiguousarray(mesh.faces, "<i8").tobytes())
    digest.update(f"\0{epsilon!r}\0{branching}".encode())
    return digest.hexdigest()[:32]


def mesh_facts(mesh_id: str, mesh: Mesh, tree, epsilon: float, branching: int) -> dict:
    """The facts of a built mesh shared by all its owners (each owner's row adds the
    ``repair`` report and ``epsilon_given`` of its own upload)."""
    stats = tree.stats
    closed = bool(mesh.is_watertight)
    return {
        "id": mesh_id,
        "triangles": int(mesh.n_faces),
        "vertices": int(mesh.n_vertices),
        "epsilon": epsilon,
        "branching": branching,
        "levels": int(stats.depth) + 1,
        "nodes": len(tree),
        "nodes_per_level": list(stats.nodes_per_level),
        "bounds": mesh.bounds.tolist(),
        "watertight": closed,
        "volume": float(mesh.volume) if closed else None,
    }


STRAY_AGE = 600.0  # seconds before a job mesh without a job row is a stray on a shared store
MAX_ATTEMPTS = 3  # builds of one job interrupted by a crash before it is failed ("crashed")
CRASHED = (
    "the build was interrupted {attempts} times (the server stopped or crashed while building"
    " it, e.g. out of memory) and is not tried again: upload a smaller mesh, or ask the"
    " service's operator"
)
STORAGE = "the tree could not be stored (a storage error on the server, logged); try again later"


class _Cancelled(Exception):
    """Raised from the progress callback to stop a build nobody waits for any more."""


class _StorageError(Exception):
    """The built tree could not be written (disk full, permissions, a broken data dir)."""


@dataclass
class _Live:
    """What only the running process knows about an unfinished job."""

    id: str
    status: str = "queued"
    levels: int = 0
    nodes: int = 0
    cancelled: bool = False
    finished: threading.Event = field(default_factory=threading.Event)
    waiters: list = field(default_factory=list)  # (loop, asyncio.Event)


@dataclass(frozen=True)
class Submission:
    """The outcome of :meth:`BuildJobs.submit`: the job's id, whether this upload started
    it (False: joined an unfinished one) and whether it made ``owner`` one of its owners
    (False: the owner waited for it already)."""

    job_id: str
    started: bool
    added: bool


class BuildJobs:
    """The build queue and its worker threads.

    Parameters
    ----------
    store : Store
    concurrency : int — builds running at once (worker threads)
    metrics : service.metrics.Metrics or None
    retention : float — seconds a finished job stays readable (0: forever)
    threads : int or None — worker threads of one build (None: the engine's default)
    """

    def __init__(
        self,
        store: Store,
        concurrency: int,
        metrics=None,
        retention: float = 0,
        threads: int | None = None,
    ) -> None:
        self.store, self.metrics, self.retention = store, metrics, retention
        self.threads = threads
        self._queue: queue.Queue[str | None] = queue.Queue()
        self._live: dict[str, _Live] = {}
        self._lock = threading.Lock()  # _live and the waiters: never held across I/O
        self._submitting = threading.Lock()  # one new job at a time (DB check + insert)
        self._unrecorded: dict[str, dict] = {}  # failures the store could not record
        self._closed = False
        self._threads = [
            threading.Thread(target=self._work, name=f"build-{i}", daemon=True)
            for i in range(concurrency)
        ]

    # --------------------------------------------------------------- life cycle
    def start(self) -> None:
        """Recover the unfinished jobs of an earlier run (queued again; failed when their
        mesh is lost or when their builds were interrupted ``MAX_ATTEMPTS`` times), remove
        stray job files, unreferenced tree files and old finished jobs, then start the
        workers."""
        for job in self.store.jobs(statuses=ACTIVE):
            with self.store.claim(f"build:{job['id']}") as mine:
                if not mine:  # another replica builds it now
                    continue
            if job["attempts"] >= MAX_ATTEMPTS:
                self._fail(job["id"], "crashed", CRASHED.format(attempts=job["attempts"]))
                self._count("failed")
                continue
            try:
                self.store.job_mesh(job["id"])
            except Exception as exc:  # missing, truncated, not a zip, not our arrays …
                log.error("build job %s: its mesh is unreadable: %r", job["id"], exc)
                reason = (
                    f"the uploaded mesh was lost across a restart ({type(exc).__name__});"
                    " upload it again"
                )
                self._fail(job["id"], "lost", reason)
                self._count("failed")
                continue
            self.store.set_job(job["id"], "queued", levels=0, nodes=0)
            self._enqueue(job["id"])
            log.info("build job %s queued again after a restart", job["id"])
        # a replica's upload writes its job's mesh a moment before the job's row: on a
        # shared store, only meshes older than that moment can be strays
        age = STRAY_AGE if self.store.shared else 0.0
        strays = set(self.store.job_meshes(older_than=age))
        for job_id in strays - {job["id"] for job in self.store.jobs(statuses=ACTIVE)}:
            self.store.drop_job_mesh(job_id)
        swept = self.store.sweep_trees()
        if swept:
            log.info("removed %d tree files nothing refers to", swept)
        self._prune()
        for thread in self._threads:
            thread.start()

    def close(self) -> None:
        """Stop taking jobs; running builds are abandoned (their jobs stay unfinished in
        the store and are queued again at the next start)."""
        self._closed = True
        for _ in self._threads:
            self._queue.put(None)

    # ------------------------------------------------------------- submission
    def submit(self, owner: str, mesh: Mesh, mesh_id: str, spec: dict, extra: dict) -> Submission:
        """Join the unfinished job building ``mesh_id`` or start one: the mesh file and
        the job row are durable when this returns (blocking: call it in a worker
        thread). ``spec``: ``epsilon``, ``branching``, … of the build; ``extra``: the
        facts of this owner's upload (``repair``, ``epsilon_given``)."""
        joined = self._join(owner, mesh_id, extra)
        if joined is not None:
            return joined
        job_id = uuid.uuid4().hex
        self.store.put_job_mesh(job_id, mesh.vertices, mesh.faces)  # no lock held: slow
        try:
            with self._submitting:  # another upload of the same content may have won
                while True:  # … here, or on another replica (add_job is then refused)
                    joined = self._join(owner, mesh_id, extra)
                    if joined is not None:
                        break
                    if self.store.add_job(job_id, mesh_id, spec, owner, extra):
                        self._enqueue(job_id)
                        return Submission(job_id, True, True)
        except BaseException:
            self.store.drop_job_mesh(job_id)
            raise
        self.store.drop_job_mesh(job_id)
        return joined

    def _join(self, owner: str, mesh_id: str, extra: dict) -> Submission | None:
        """Make ``owner`` an owner of the unfinished job of ``mesh_id``, if there is one."""
        job_id = self.store.active_job(mesh_id)
        if job_id is None:
            return None
        added = self.store.join_job(job_id, owner, extra)  # None: it finished meanwhile
        if added is None:
            return None
        with self._lock:
            live = self._live.get(job_id)
            if live is not None:
                live.cancelled = False
        return Submission(job_id, False, added)

    def _enqueue(self, job_id: str) -> None:
        with self._lock:
            self._live[job_id] = _Live(job_id)
        self._queue.put(job_id)
        self._gauges()

    async def wait(self, job_id: str, timeout: float) -> bool:
        """Wait up to ``timeout`` seconds for the job to finish; whether it has."""
        with self._lock:
            live = self._live.get(job_id)
            if live is None or live.finished.is_set():
                return True
            waiter = (asyncio.get_running_loop(), asyncio.Event())
            live.waiters.append(waiter)
        try:
            with contextlib.suppress(asyncio.TimeoutError):  # not TimeoutError before 3.11
                await asyncio.wait_for(waiter[1].wait(), timeout)
        finally:
            with self._lock, contextlib.suppress(ValueError):
                live.waiters.remove(waiter)
        return live.finished.is_set()

    def progress(self, job_id: str) -> tuple[int, int] | None:
        """``(levels, nodes)`` built so far of an unfinished job of this process."""
        live = self._live.get(job_id)
        return None if live is None else (live.levels, live.nodes)

    def job(self, job_id: str, owner: str | None = None) -> dict | None:
        """:meth:`Store.job`, failed when its failure could not be written to the store."""
        job = self.store.job(job_id, owner)
        if job is not None and job["status"] in ACTIVE and job_id in self._unrecorded:
            job.update(self._unrecorded[job_id])
        return job

    def leave(self, owner: str, mesh_id: str) -> bool:
        """``owner`` no longer waits for the unfinished build of ``mesh_id`` (False if it
        did not); with nobody left, the build stops at its next level (blocking: call it
        in a worker thread)."""
        left = self.store.leave_job(owner, mesh_id)
        if left is None:
            return False
        job_id, remaining = left
        if remaining == 0:
            with self._lock:
                live = self._live.get(job_id)
                if live is not None:
                    live.cancelled = True
        return True

    # ---------------------------------------------------------------- workers
    def _work(self) -> None:
        while True:
            job_id = self._queue.get()
            if job_id is None or self._closed:
                return
            try:
                self._run(job_id)
            except Exception:  # the store is closed under us (shutdown), or worse
                log.exception("build job %s: not finished", job_id)

    def _run(self, job_id: str) -> None:
        """Build the job; whatever happens, a finished job (done or failed) releases its
        waiters. A job queued again (joined after a cancellation) or abandoned at
        shutdown stays unfinished."""
        live = self._live[job_id]
        status = None
        try:
            with self.store.claim(f"build:{job_id}") as mine:
                job = self.store.job(job_id) if mine else None
                if job is None or job["status"] not in ACTIVE:
                    # built by another replica (or finished by it meanwhile): its waiters
                    # read the outcome from the store
                    self._finish(live)
                    return
                status = self._build(job_id, live)
        except Exception as exc:  # recording the outcome failed (the store is broken)
            if self._closed:
                return
            log.exception("build job %s: its outcome could not be recorded", job_id)
            status = "failed"
            self._unrecorded[job_id] = {
                "status": "failed",
                "cause": "internal",
                "error": f"build failed: internal error (logged): {type(exc).__name__}",
            }
        finally:
            if status is not None:
                with contextlib.suppress(OSError):
                    self.store.drop_job_mesh(job_id)
                self._count(status)
                self._finish(live)
                with contextlib.suppress(Exception):
                    self._prune()

    def _build(self, job_id: str, live: _Live) -> str | None:
        """Run one job: ``"done"``, ``"failed"`` (recorded in the store), or None when the
        job stays unfinished (queued again, or abandoned at shutdown)."""
        job = self.store.job(job_id)
        start = time.perf_counter()
        started = False
        try:
            if self.store.owners(job_id) == 0:
                raise _Cancelled
            self.store.start_job(job_id)  # attempts + 1, committed before the build
            started = True
            live.status = "building"
            self._gauges()
            spec = job["spec"]
            vertices, faces = self.store.job_mesh(job_id)
            mesh = Mesh(vertices, faces, strict=True)  # repaired already: kept bit for bit
            if content_id(mesh, spec["epsilon"], spec["branching"]) != job["mesh"]:
                raise RuntimeError("the stored mesh does not match its id (corrupted file)")

            def progress(levels: int, nodes: int) -> None:
                live.levels, live.nodes = levels, nodes
                if live.cancelled or self._closed:
                    raise _Cancelled

            if self.store.has_tree(job["mesh"]):  # built before a crash
                tree = self.store.tree(job["mesh"])
            else:
                tree = build_tree(
                    mesh,
                    spec["epsilon"],
                    spec["branching"],
                    progress=progress,
                    threads=self.threads,
                )
                if self._closed:
                    raise _Cancelled
                try:
                    self.store.put_tree(job["mesh"], tree)
                except OSError as exc:
                    raise _StorageError(f"the tree could not be stored: {exc!r}") from exc
                if self.metrics is not None:
                    self.metrics.meshes_built.inc()
            seconds = time.perf_counter() - start
            facts = mesh_facts(job["mesh"], mesh, tree, spec["epsilon"], spec["branching"])
            levels, nodes = facts["levels"], facts["nodes"]
            live.levels, live.nodes = levels, nodes
            owners = self.store.finish_job(job_id, facts, levels, nodes, seconds)
            if not owners:  # all left during the last level: marked cancelled
                return "failed"
            if self.metrics is not None:
                self.metrics.build_seconds.observe(seconds)
            return "done"
        except _Cancelled:
            if self._closed:  # shutting down: queued again at the next start, not counted
                if started:
                    with contextlib.suppress(Exception):
                        self.store.set_job(job_id, "queued", attempts=job["attempts"])
                return None
            if self.store.cancel_job(job_id):
                return "failed"
            # someone joined after the last one left: build it for them
            live.cancelled, live.status, live.levels, live.nodes = False, "queued", 0, 0
            self.store.set_job(
                job_id,
                "queued",
                levels=0,
                nodes=0,
                **({"attempts": job["attempts"]} if started else {}),
            )
            self._queue.put(job_id)
            return None
        except EngineError as exc:
            return self._fail(job_id, "engine", f"the tree cannot be built: {exc}")
        except _StorageError as exc:
            log.error("build job %s: %s", job_id, exc)
            return self._fail(job_id, "storage", STORAGE)
        except MemoryError:
            triangles = job["spec"].get("triangles") if job else None
            error = f"out of memory while building the tree of {triangles} triangles"
            return self._fail(job_id, "memory", error + "; try again later")
        except Exception:
            if self._closed:
                return None
            log.exception("build job %s failed", job_id)
            return self._fail(job_id, "internal", "build failed: internal error (logged)")

    def _fail(self, job_id: str, cause: str, error: str) -> str:
        """Record the failure (and drop a tree file nothing else uses); when the store
        cannot, keep it in memory so that the job still reads as failed. ``"failed"``."""
        try:
            self.store.fail_job(job_id, cause, error)
        except Exception:
            log.exception("build job %s: failure (%s) not recorded in the store", job_id, cause)
            self._unrecorded[job_id] = {"status": "failed", "cause": cause, "error": error}
        log.error("build job %s failed (%s): %s", job_id, cause, error)
        return "failed"

    def _prune(self) -> None:
        """Forget the finished jobs older than the retention."""
        if self.retention > 0:
            self.store.prune_jobs(time.time() - self.retention)

    def _finish(self, live: _Live) -> None:
        with self._lock:
            live.finished.set()
            self._live.pop(live.id, None)
            waiters, live.waiters = live.waiters, []
        for loop, event in waiters:
            with contextlib.suppress(RuntimeError):  # that loop is closed
                loop.call_soon_threadsafe(event.set)
        self._gauges()

    # ---------------------------------------------------------------- metrics
    def _count(self, status: str) -> None:
        if self.metrics is not None:
            self.metrics.jobs_finished.labels(status).inc()

    def _gauges(self) -> None:
        if self.metrics is None:
            return
        with self._lock:
            building = sum(1 for live in self._live.values() if live.status == "building")
            total = len(self._live)
        self.metrics.jobs.labels("queued").set(total - building)
        self.metrics.jobs.labels("building").set(building)
