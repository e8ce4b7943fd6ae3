"""Big contacts requests across the cluster: a request of at least ``MRDEM_SPLIT_PAIRS``
pairs is cut into runs of consecutive pairs (:func:`service.search.split`), at most
``MRDEM_SPLIT_CHUNKS``: the replica searches the first itself, with its engine threads and
its banks, while each other run goes to another alive node with CPUs as a Ray task; the
answers are merged in order (:func:`service.search.merge`): the same arrays as one process's
search. A run's length is in proportion to how fast its node has searched this replica's
runs, relative to the replica, from the moment the runs are sent to the moment its last
answer is in hand (:class:`service.search.RunSpeeds`: the hand-off counts; at first, the
engine threads that search it), so that the runs end together.

A task searches its run in ``MRDEM_SPLIT_PIECES`` pieces (2), front to back, and hands
each piece's answer over as it ends (a streaming generator task): the replica pulls each as
soon as it is ready, while it still searches its own run, and once its own run is searched
it takes back, from the back of the runs, the pieces a node has not begun — and the one it
is on, once it has been at it half as long again as the replica would be for the whole
piece (:class:`service.search.SentPieces`). So a request ends when its pieces do, whatever
happens to a node meanwhile (a neighbour busy on it, a cold worker, a stall), and a slow
node loses its share within the request, not only over the next ones. Each piece costs a
hand-over: on the 2-vCPU VM the split gave 1.33x and 1.44x with 8 pieces, 1.59x and 1.48x
with 2 (BENCHMARKS.md).
A task no longer needed is cancelled once it has handed a piece over (it stops at its next
one); one that has not may still be starting, and is left to end — its node gets no other
task of this replica's until it has (:meth:`RaySplitter._stop`). A node gets runs only
once a worker is readied there: each replica sends every alive node, when it starts and
when a node first appears, a task that opens the store and loads the kernels
(:meth:`RaySplitter.ready`); its worker goes back to the node's pool for the next task.

The nodes for a request's meshes are ranked by rendezvous hashing: every replica sends the
same meshes to the same nodes while they are alive (their trees on disk there, their banks
in the workers), a node's death moves only its runs, and other meshes rank the nodes
otherwise (the load spreads). A task loads the trees from the store's blobs (a node keeps a
bounded copy of those it read: ``data_dir/tree-cache``) and keeps their banks for the next
request in its worker process; its triangle pairs travel as int32 (half the bytes through
Ray's object store).

The pieces left of a task that fails (its node died, it raised: a node that cannot open the
store, say) are taken back and searched by the replica, with a warning in the log: the
answer is whole. Ray does not run such a task again (``max_retries=0``): its retry would
start a worker on another node, which loads Python, the kernels, the trees (seconds: 9 s
measured on the 2-vCPU VM), where the replica has them in memory."""

from __future__ import annotations

import functools
import hashlib
import logging
import os
import signal
import threading
import time
from collections.abc import Callable

import numpy as np
import ray
from ray.exceptions import RayError
from ray.util.scheduling_strategies import NodeAffinitySchedulingStrategy

import engine

from ..banks import BankCache
from ..search import RunSpeeds, SentPieces, find, merge, split
from ..settings import Settings
from ..store import Store, open_store

__all__ = [
    "IDLE_WORKERS",
    "IDLE_WORKERS_MS",
    "IDLE_WORKERS_VARIABLE",
    "RaySplitter",
    "idle_worker_warning",
    "ranked",
]

log = logging.getLogger("mrdem.cluster")

_WORKER: dict = {}  # per worker process: its store and banks, opened on first use
_WORKER_LOCK = threading.Lock()


def _worker_store(settings: Settings) -> tuple[Store, BankCache]:
    key = settings.model_dump_json()
    with _WORKER_LOCK:
        if key not in _WORKER:
            store = open_store(settings)
            _WORKER[key] = (store, BankCache(store))
        return _WORKER[key]


#: The variable that sets how long a Ray node keeps an idle worker once it runs more workers
#: than it has CPUs (its actors count: replicas, scenes, spares): Ray's default is 1 s, after
#: which a split request's task on that node waits for a fresh worker (seconds: Python, the
#: kernels, the store) and the replica searches the whole run itself. Measured (BENCHMARKS.md,
#: issue 18, ninth session; ``benchmarks/cluster.py --only batch --pause 0.6``: 2 nodes of
#: 1 CPU, a replica on each, the other replica's request and 0.6 s between two splits): a
#: task searched in 4 of 9 rounds and the split gave 1.01x with Ray's 1 s; 9 of 9 and 1.60x
#: with 10 minutes. The README's ``ray start``, the compose file and ``mrdem cluster
#: serve``'s own local cluster set it.
IDLE_WORKERS_VARIABLE = "RAY_idle_worker_killing_time_threshold_ms"
IDLE_WORKERS_MS = 600_000
IDLE_WORKERS = f"{IDLE_WORKERS_VARIABLE}={IDLE_WORKERS_MS}"
_RAY_IDLE_WORKERS_MS = 1000  # Ray's default


def idle_worker_warning(idle_ms: int) -> str | None:
    """What to tell the operator of a node that ends an idle worker after ``idle_ms`` (None
    when that is at least a minute)."""
    if idle_ms >= 60_000:
        return None
    return (
        f"it ends an idle worker after {idle_ms / 1000:g} s once it runs more workers than"
        " CPUs (actors count): after a pause that long, a split request's task there waits"
        " seconds for a fresh worker and the replica searches the run itself; start the Ray"
        f" node with {IDLE_WORKERS} (ray start, or the containers' environment)"
    )


def _node_idle_ms() -> int:
    """This process's node's idle-worker time (ms): its raylet's environment, which the
    worker inherits, or Ray's default."""
    try:
        return int(os.environ.get(IDLE_WORKERS_VARIABLE, _RAY_IDLE_WORKERS_MS))
    except ValueError:
        return _RAY_IDLE_WORKERS_MS


def _ready_worker(settings: Settings) -> tuple[float, int]:
    """A task that readies a worker of its node for the contacts tasks: the engine imported,
    the store opened (first: it fails sooner), every kernel loaded (from the cache the
    cluster shares, or compiled); ``(its seconds, how long its node keeps an idle worker,
    ms)``. The worker goes back to its node's pool, where the next task takes it."""
    start = time.perf_counter()
    _worker_store(settings)
    engine.warmup(1)
    return time.perf_counter() - start, _node_idle_ms()


def _search_pieces(settings: Settings, meshes, run, pieces, kernel, hierarchy, precision, threads):
    """:func:`service.search.find` of each of ``pieces`` consecutive pieces of ``run``
    (:func:`service.search.split`, equal weights), front to back, in a Ray task: yields
    ``(answer, its seconds)`` per piece, and stops at the next piece once cancelled."""
    # arrays from the object store are read-only: Numba would compile read-only variants
    run = tuple(np.array(c) for c in run)
    store, banks = _worker_store(settings)
    with _Cancel() as cancel:
        for piece in split(run, [1.0] * pieces):
            if cancel.requested:
                return
            start = time.perf_counter()
            found = find(meshes, piece, kernel, hierarchy, precision, threads, store, banks)
            pairs = found["pairs"]
            if pairs.size == 0 or pairs.max() < 2**31:  # triangle indices: int32 in transit
                found["pairs"] = pairs.astype(np.int32)
            yield found, time.perf_counter() - start


class _Cancel:
    """While a task runs: Ray's cancel noted, not raised. Ray cancels a running task by
    simulating SIGINT in its worker's main thread (``_thread.interrupt_main``), which
    Python's own handler raises as ``KeyboardInterrupt`` wherever the thread is — in a
    kernel's dispatch, it crashed the worker (SIGSEGV, measured), and the next request's
    task waited seconds for a fresh one. This handler only sets :attr:`requested`; the
    previous handler is back when the task ends. Off the main thread nothing changes."""

    def __init__(self) -> None:
        self.requested = False
        self._installed = False
        self._previous = None

    def _note(self, signum, frame) -> None:
        self.requested = True

    def __enter__(self) -> _Cancel:
        if threading.current_thread() is threading.main_thread():
            self._previous = signal.signal(signal.SIGINT, self._note)
            self._installed = True
        return self

    def __exit__(self, *exc) -> None:
        if self._installed:  # the previous handler may be None (not set from Python)
            signal.signal(signal.SIGINT, self._previous or signal.SIG_DFL)


def _pull(board: SentPieces, run: int, pieces, seconds: list, ended: Callable[[], None]):
    """Run ``run``'s answers, pulled here as each is handed over (``ray.get`` pulls an
    object from another node only when called): into ``board``, their seconds in the task
    into ``seconds[run]``; how the task ended, if it failed, too; ``ended()`` at its end."""
    piece = 0
    try:
        for ref in pieces:  # the next piece's answer, or the error the task ended with
            answer, took = ray.get(ref)
            seconds[run] += took  # first: the request may end with the hand-over
            board.handed(run, piece, answer, time.perf_counter())
            piece += 1
    except BaseException as error:  # noqa: BLE001 - the pieces left are the replica's
        board.failed(run, error)  # (SystemExit: Ray shut down under a cancelled task's end)
    finally:
        ended()


class _Task:
    """A task sent, as its request and its puller see it: its node, whether it has ended,
    whether it was left to end on its own."""

    __slots__ = ("ended", "left", "node")

    def __init__(self, node: str) -> None:
        self.node, self.ended, self.left = node, False, False


def _take_back(board: SentPieces, pieces, here, per_pair: float) -> tuple[float, float]:
    """Pieces taken back from the runs sent (``pieces[run][piece]``) and searched here
    (``here``, ``per_pair`` seconds a pair) until every piece has its answer: ``(their
    seconds, when the last ended)``."""
    busy, ended = 0.0, 0.0
    while True:
        now = time.perf_counter()
        picked = board.take(now, per_pair)
        if picked is None:
            if board.done():
                return busy, ended
            board.wait(now, per_pair)
            continue
        run, piece = picked
        answer = here(pieces[run][piece])
        ended = time.perf_counter()
        busy += ended - now
        board.give(run, piece, answer, ended)


def ranked(meshes, nodes) -> list[str]:
    """``nodes`` (ids) in the order of preference for a request of ``meshes`` (ids):
    highest random weight first (rendezvous hashing), the same order in every process."""
    key = "\0".join(sorted(set(meshes)))

    def weight(node: str) -> bytes:
        return hashlib.blake2b(f"{key}\0{node}".encode(), digest_size=8).digest()

    return sorted(nodes, key=weight, reverse=True)


class RaySplitter:
    """The :class:`~service.search.BatchSplitter` of a Ray cluster: the first run here, the
    others on the other alive nodes with CPUs that rank first for the request's meshes
    (soft node affinity: a node without room passes its run on)."""

    def __init__(self, settings: Settings, threshold: int, chunks: int, cpus: float) -> None:
        self.settings, self.threshold, self.most, self.cpus = settings, threshold, chunks, cpus
        self._task = ray.remote(_search_pieces)
        self._threads = max(1, int(round(cpus)))  # a task's engine threads, and its settings
        self._task_settings = settings.model_copy(update={"engine_threads": self._threads})
        self._node = ray.get_runtime_context().get_node_id()  # this process's
        self._prior = self._threads / settings.engine_threads  # a node's speed, unmeasured
        self.speeds = RunSpeeds()  # each node's, measured on this replica's requests
        self._left: dict[str, set[_Task]] = {}  # node → this replica's tasks left to end there
        self._lock = threading.Lock()
        self._readier = ray.remote(_ready_worker)
        self._readying: dict[str, ray.ObjectRef] = {}  # node → its readying task, running
        self._ready: set[str] = set()  # nodes with a worker readied (or whose readying failed)
        if self.most > 1:  # from the start, where it splits: the first requests find them ready
            self.ready(self.others())

    def applies(self, pairs: int) -> bool:
        return pairs >= self.threshold and self.most > 1

    def others(self) -> list[str]:
        """The alive nodes with CPUs, this process's node excepted."""
        return [
            n["NodeID"]
            for n in ray.nodes()
            if n["Alive"] and n["Resources"].get("CPU", 0) > 0 and n["NodeID"] != self._node
        ]

    def ready(self, nodes: list[str], timeout: float = 0.0) -> list[str]:
        """Of ``nodes`` (the alive ones, ids), those with a worker readied for this
        replica's tasks (:func:`_ready_worker`), after at most ``timeout`` seconds; each
        other node is sent a task that readies one (once). A fresh worker takes seconds to
        start (imports, kernels, the store; a node without the kernels' cache compiles
        them), in which a request's run sent there would be taken back: a node gets runs
        once it is ready. A node whose readying failed is logged and counted as ready: its
        tasks fail too, and their pieces are searched here, with a warning each."""
        with self._lock:
            alive = set(nodes)
            self._ready &= alive  # nodes gone: a node joining again has a new id
            for node in [m for m in self._readying if m not in alive]:
                del self._readying[node]
            for node in nodes:
                if node not in self._ready and node not in self._readying:
                    self._readying[node] = self._send_ready(node)
            waiting = {ref: node for node, ref in self._readying.items()}
        ended = []
        if waiting:
            done, _ = ray.wait(list(waiting), num_returns=len(waiting), timeout=timeout)
            with self._lock:  # each readying's end taken once (requests call this at once)
                for ref in done:
                    node = waiting[ref]
                    if self._readying.get(node) == ref:
                        del self._readying[node]
                        self._ready.add(node)
                        ended.append((node, ref))
        for node, ref in ended:
            try:
                seconds, idle_ms = ray.get(ref)
            except RayError as error:
                log.warning(
                    "readying a worker on node %s failed; its runs are sent still (and"
                    " searched here when they fail): %s",
                    node,
                    error,
                )
                continue
            log.info("node %s ready in %.1f s", node, seconds)
            if warning := idle_worker_warning(idle_ms):
                log.warning("node %s: %s", node, warning)
        with self._lock:
            return [node for node in nodes if node in self._ready]

    def find(
        self, meshes, columns, kernel, hierarchy, precision, here: Callable[[tuple], dict]
    ) -> dict:
        """The merged answer, with ``timing`` (seconds): ``submit`` (the nodes chosen, the
        runs cut and sent), ``here`` (this process's run), ``taken`` (pieces taken back and
        searched here), ``task`` (the busiest node's search, in its worker), ``wait``
        (from the end of this process's last search to every answer here), ``merge``. The
        pieces left of a task that failed (its node or worker died, it raised) are taken
        back too, with a warning in the log."""
        start = time.perf_counter()
        n = len(columns[0])
        alive = self.others()
        self.speeds.keep(alive)
        ready = set(self.ready(alive))
        nodes = ranked(meshes, alive)[: min(self.most, n) - 1]
        # a node not ready yet, or still on a task of ours left to end, gets no run (nor
        with self._lock:  # does another node take it: the trees stay where they ranked)
            nodes = [m for m in nodes if m in ready and m not in self._left]
        if not nodes:
            return here(columns)
        mine, *runs = split(columns, [1.0, *self.speeds.weights(nodes, self._prior)])
        sent = [(node, run) for node, run in zip(nodes, runs, strict=True) if len(run[0])]
        most = self.settings.split_pieces
        pieces = [split(run, [1.0] * min(most, len(run[0]))) for _, run in sent]
        submitted = time.perf_counter()
        board = SentPieces([[len(p[0]) for p in run] for run in pieces], submitted)
        generators = [
            self._send(node, run, len(cut), meshes, kernel, hierarchy, precision)
            for (node, run), cut in zip(sent, pieces, strict=True)
        ]
        seconds = [0.0] * len(sent)  # each task's, in its worker
        tasks = [_Task(node) for node, _ in sent]
        for k, generator in enumerate(generators):
            pull = (board, k, generator, seconds, functools.partial(self._end, tasks[k]))
            threading.Thread(target=_pull, args=pull, daemon=True).start()
        try:
            found = [here(mine)] if len(mine[0]) else []  # while the tasks run
            searched = time.perf_counter()
            per_pair = (searched - submitted) / max(len(mine[0]), 1)
            taken, ended = _take_back(board, pieces, here, per_pair)
        finally:  # every piece answered, or a failure here
            for run, generator in enumerate(generators):
                self._stop(tasks[run], generator, board.handed_over(run), len(pieces[run]))
        last = max(searched, ended)  # this process's last search
        arrived = max([last, *board.completed])
        measured = {}
        for run, (node, cut) in enumerate(sent):
            error = board.errors[run]
            if error is None:
                measured[node] = (board.handed_pairs[run], board.completed[run] - submitted)
            else:
                log.warning(
                    "a contacts task of %d pairs sent to node %s failed; its pieces left "
                    "were searched here: %s",
                    len(cut[0]),
                    node,
                    error,
                    exc_info=None if isinstance(error, RayError) else error,
                )
        self.speeds.update((len(mine[0]), searched - submitted), measured, self._prior)
        found += [answer for run in board.answers for answer in run]
        merged = merge(found)
        merged["timing"] = {
            "submit": submitted - start,
            "here": searched - submitted,
            "taken": taken,
            "task": max(seconds, default=0.0),
            "wait": arrived - last,
            "merge": time.perf_counter() - arrived,
        }
        return merged

    def _stop(self, task: _Task, generator, begun: int, pieces: int) -> None:
        """A task whose answers are no longer needed: cancelled once it has handed a piece
        over (it runs its pieces then: it ends at the next one, see :class:`_Cancel`);
        before that it may still be starting — Ray's cancel would interrupt the worker's
        imports, and a node would stay cold while requests are shorter than its start — so
        it is left to end on its own, and its node gets no other task of this replica's
        meanwhile (a stalled node's work cannot pile up)."""
        if begun == pieces:  # handed everything: it has ended, or is ending
            return
        if begun > 0:
            ray.cancel(generator)
            return
        with self._lock:
            if not task.ended:
                task.left = True
                self._left.setdefault(task.node, set()).add(task)

    def _end(self, task: _Task) -> None:
        """``task`` ended (its puller saw the last of it): its node is free again."""
        with self._lock:
            task.ended = True
            if task.left:
                left = self._left[task.node]
                left.discard(task)
                if not left:
                    del self._left[task.node]

    def _send_ready(self, node: str) -> ray.ObjectRef:
        """A task readying a worker on ``node`` (there only: a node without room queues it)."""
        strategy = NodeAffinitySchedulingStrategy(node, soft=False)
        task = self._readier.options(
            num_cpus=self.cpus, scheduling_strategy=strategy, max_retries=0
        )
        return task.remote(self._task_settings)

    def _send(self, node: str, run, pieces: int, meshes, kernel, hierarchy, precision):
        """Run ``run`` as ``pieces`` pieces in a task on ``node``: its answers' refs."""
        strategy = NodeAffinitySchedulingStrategy(node, soft=True, _spill_on_unavailable=True)
        task = self._task.options(
            num_cpus=self.cpus,
            scheduling_strategy=strategy,
            max_retries=0,
            num_returns="streaming",
        )
        settings, threads = self._task_settings, self._threads
        return task.remote(settings, meshes, run, pieces, kernel, hierarchy, precision, threads)
