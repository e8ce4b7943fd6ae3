"""Big contacts requests across the cluster: a request of at least ``MRDEM_SPLIT_PAIRS``
pairs is cut into runs of consecutive pairs (:func:`service.search.split`), at most
``MRDEM_SPLIT_CHUNKS``: the replica searches the first itself, with its engine threads and
its banks, while each other run goes to another alive node with CPUs as a Ray task; the
answers are merged in order (:func:`service.search.merge`): the same arrays as one process's
search. A run's length is in proportion to how fast its node has searched this replica's
runs, relative to the replica, from the moment the runs are sent to the moment the answer is
in hand (:class:`service.search.RunSpeeds`: the hand-off counts; at first, the engine
threads that search it), so that the runs end together.

The nodes for a request's meshes are ranked by rendezvous hashing: every replica sends the
same meshes to the same nodes while they are alive (their trees on disk there, their banks
in the workers), a node's death moves only its runs, and other meshes rank the nodes
otherwise (the load spreads). A task loads the trees from the store's blobs (a node keeps a
bounded copy of those it read: ``data_dir/tree-cache``) and keeps their banks for the next
request in its worker process; its triangle pairs travel as int32 (half the bytes through
Ray's object store), pulled to the replica as soon as they are ready, while the replica
still searches its own run.

A run whose task fails (its node died, it raised: a node that cannot open the store, say)
is searched by the replica after the others, with a warning in the log: the answer is
whole. Ray does not run such a task again (``max_retries=0``): its retry would start a
worker on another node, which loads Python, the kernels, the trees (seconds: 9 s measured
on the 2-vCPU VM), where the replica has them in memory."""

from __future__ import annotations

import hashlib
import logging
import threading
import time
from collections.abc import Callable

import numpy as np
import ray
from ray.exceptions import RayError
from ray.util.scheduling_strategies import NodeAffinitySchedulingStrategy

from ..banks import BankCache
from ..search import RunSpeeds, find, merge, split
from ..settings import Settings
from ..store import Store, open_store

__all__ = ["RaySplitter", "ranked"]

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


def _search_chunk(settings: Settings, meshes, columns, kernel, hierarchy, precision, threads):
    """:func:`service.search.find` of a run, in a Ray task: ``(answer, its seconds)``."""
    start = time.perf_counter()
    # arrays from the object store are read-only: Numba would compile read-only variants
    columns = tuple(np.array(c) for c in columns)
    store, banks = _worker_store(settings)
    found = find(meshes, columns, kernel, hierarchy, precision, threads, store, banks)
    pairs = found["pairs"]
    if pairs.size == 0 or pairs.max() < 2**31:  # triangle indices: int32 in transit
        found["pairs"] = pairs.astype(np.int32)
    return found, time.perf_counter() - start


class _Fetch:
    """The tasks' answers pulled here as each is ready, by a thread of its own from now
    on: a task's answer crosses from its node's object store while this process still
    searches its own run (``ray.get`` pulls an object only when called); ``arrived[k]``
    is when part k's answer was here (``time.perf_counter``)."""

    def __init__(self, parts: list) -> None:
        self._answers: list = [None] * len(parts)
        self.arrived = [0.0] * len(parts)
        self._thread = threading.Thread(target=self._get, args=(parts,), daemon=True)
        self._thread.start()

    def _get(self, parts: list) -> None:
        index = {part: k for k, part in enumerate(parts)}
        pending = list(parts)
        while pending:
            try:
                ready, pending = ray.wait(pending, num_returns=1)  # here: fetch_local
            except Exception as error:  # Ray itself failing: every answer left failed so
                for part in pending:
                    self._answers[index[part]] = error
                return
            for part in ready:
                k = index[part]
                try:
                    self._answers[k] = ray.get(part)
                except Exception as error:  # handed to the request's thread by result()
                    self._answers[k] = error
                self.arrived[k] = time.perf_counter()

    def result(self) -> list:
        """Each task's answer, in order, or the :class:`ray.exceptions.RayError` it ended
        with (its node or worker died, it raised, it was cancelled); any other error raised
        here."""
        self._thread.join()
        for answer in self._answers:
            if isinstance(answer, Exception) and not isinstance(answer, RayError):
                raise answer
        return self._answers


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
        self._task = ray.remote(_search_chunk)
        self._threads = max(1, int(round(cpus)))  # a task's engine threads, and its settings
        self._task_settings = settings.model_copy(update={"engine_threads": self._threads})
        self._node = ray.get_runtime_context().get_node_id()  # this process's
        self._prior = self._threads / settings.engine_threads  # a node's speed, unmeasured
        self.speeds = RunSpeeds()  # each node's, measured on this replica's requests

    def applies(self, pairs: int) -> bool:
        return pairs >= self.threshold and self.most > 1

    def others(self) -> list[str]:
        """The alive nodes with CPUs, this process's node excepted."""
        return [
            n["NodeID"]
            for n in ray.nodes()
            if n["Alive"] and n["Resources"].get("CPU", 0) > 0 and n["NodeID"] != self._node
        ]

    def find(
        self, meshes, columns, kernel, hierarchy, precision, here: Callable[[tuple], dict]
    ) -> dict:
        """The merged answer, with ``timing`` (seconds): ``submit`` (the nodes chosen, the
        runs cut and sent), ``here`` (this process's run), ``task`` (the slowest task, in
        its worker), ``wait`` (from the end of this process's run to every answer here),
        ``merge``. A run whose task failed (its node or worker died, it raised) is searched
        here after the others, with a warning in the log."""
        start = time.perf_counter()
        n = len(columns[0])
        alive = self.others()
        self.speeds.keep(alive)
        nodes = ranked(meshes, alive)[: min(self.most, n) - 1]
        if not nodes:
            return here(columns)
        threads, settings = self._threads, self._task_settings
        mine, *runs = split(columns, [1.0, *self.speeds.weights(nodes, self._prior)])
        sent, parts = [], []
        for node, run in zip(nodes, runs, strict=True):
            if len(run[0]) == 0:  # more weight elsewhere than pairs to go round
                continue
            strategy = NodeAffinitySchedulingStrategy(node, soft=True, _spill_on_unavailable=True)
            task = self._task.options(
                num_cpus=self.cpus, scheduling_strategy=strategy, max_retries=0
            )
            parts.append(task.remote(settings, meshes, run, kernel, hierarchy, precision, threads))
            sent.append((node, run))
        submitted = time.perf_counter()
        fetch = _Fetch(parts)  # each answer pulled here as soon as it is ready
        try:
            found = [here(mine)] if len(mine[0]) else []  # while the tasks run
        except BaseException:
            for part in parts:
                ray.cancel(part)
            raise
        searched = time.perf_counter()
        answers = fetch.result()
        seconds, measured = [], {}
        for (node, run), answer, at in zip(sent, answers, fetch.arrived, strict=True):
            if isinstance(answer, RayError):
                log.warning(
                    "a contacts task of %d pairs sent to node %s failed; searched here: %s",
                    len(run[0]),
                    node,
                    answer,
                )
                answer = here(run), 0.0
            else:
                measured[node] = (len(run[0]), at - submitted)
            found.append(answer[0])
            seconds.append(answer[1])
        arrived = time.perf_counter()
        self.speeds.update((len(mine[0]), searched - submitted), measured, self._prior)
        merged = merge(found)
        merged["timing"] = {
            "submit": submitted - start,
            "here": searched - submitted,
            "task": max(seconds, default=0.0),
            "wait": arrived - searched,
            "merge": time.perf_counter() - arrived,
        }
        return merged
