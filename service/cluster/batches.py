"""Big contacts requests across the cluster: a request of at least ``MRDEM_SPLIT_PAIRS``
pairs is cut into runs of consecutive pairs (:func:`service.search.split`), one per node
with CPUs (at most ``MRDEM_SPLIT_CHUNKS``), each run as a Ray task — on the nodes that ran
the last request of the same meshes, while they are alive, the others spread; the answers
are merged in order (:func:`service.search.merge`): the same arrays as one
process's search. A task loads the trees from the store's blobs (a node keeps a bounded copy
of those it read: ``data_dir/tree-cache``) and keeps their banks for the next request in its
worker process."""

from __future__ import annotations

import threading
from collections import OrderedDict

import numpy as np
import ray
from ray.util.scheduling_strategies import NodeAffinitySchedulingStrategy

from ..banks import BankCache
from ..search import find, merge, split
from ..settings import Settings
from ..store import Store, open_store

__all__ = ["RaySplitter"]

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
    """``(answer, the id of the node it ran on)``."""
    # arrays from the object store are read-only: Numba would compile read-only variants
    columns = tuple(np.array(c) for c in columns)
    store, banks = _worker_store(settings)
    found = find(meshes, columns, kernel, hierarchy, precision, threads, store, banks)
    return found, ray.get_runtime_context().get_node_id()


class RaySplitter:
    """The :class:`~service.search.BatchSplitter` of a Ray cluster. The runs of a request go
    to the nodes that ran the last request of the same meshes (their trees on disk there,
    their banks in the workers), as far as those nodes are alive and have room; the others
    are spread."""

    REMEMBERED = 256  # mesh sets whose nodes are remembered

    def __init__(self, settings: Settings, threshold: int, chunks: int, cpus: float) -> None:
        self.settings, self.threshold, self.most, self.cpus = settings, threshold, chunks, cpus
        self._task = ray.remote(_search_chunk)
        self._nodes: OrderedDict[tuple, list[str]] = OrderedDict()  # mesh ids → nodes
        self._lock = threading.Lock()

    def applies(self, pairs: int) -> bool:
        return pairs >= self.threshold and self.chunks(pairs) > 1

    def _alive(self) -> set[str]:
        return {n["NodeID"] for n in ray.nodes() if n["Alive"] and n["Resources"].get("CPU", 0) > 0}

    def chunks(self, pairs: int, alive: set[str] | None = None) -> int:
        """Runs to cut ``pairs`` into: one per alive node with CPUs (``alive``, asked of
        Ray when not given), at most the setting."""
        alive = self._alive() if alive is None else alive
        return max(1, min(self.most, len(alive), pairs))

    def find(self, meshes, columns, kernel, hierarchy, precision) -> dict:
        threads = max(1, int(round(self.cpus)))
        settings = self.settings.model_copy(update={"engine_threads": threads})
        alive = self._alive()
        runs = split(columns, self.chunks(len(columns[0]), alive))
        key = tuple(meshes)
        with self._lock:
            before = self._nodes.get(key, [])
        warm = [node for node in dict.fromkeys(before) if node in alive]
        parts = []
        for k, run in enumerate(runs):
            strategy = "SPREAD"
            if k < len(warm):  # back to a node that has the trees
                strategy = NodeAffinitySchedulingStrategy(
                    warm[k], soft=True, _spill_on_unavailable=True
                )
            task = self._task.options(num_cpus=self.cpus, scheduling_strategy=strategy)
            parts.append(task.remote(settings, meshes, run, kernel, hierarchy, precision, threads))
        answers = ray.get(parts)
        with self._lock:
            self._nodes[key] = [node for _, node in answers]
            self._nodes.move_to_end(key)
            while len(self._nodes) > self.REMEMBERED:
                self._nodes.popitem(last=False)
        return merge([found for found, _ in answers])
