"""Big contacts requests across the cluster: a request of at least ``MRDEM_SPLIT_PAIRS``
pairs is cut into runs of consecutive pairs (:func:`service.search.split`), one per node
with CPUs (at most ``MRDEM_SPLIT_CHUNKS``), each run as a Ray task spread over the nodes;
the answers are merged in order (:func:`service.search.merge`): the same arrays as one
process's search. A task loads the trees from the store's blobs (a node keeps a bounded copy
of those it read: ``data_dir/tree-cache``) and keeps their banks for the next request in its
worker process."""

from __future__ import annotations

import threading
from collections import OrderedDict

import numpy as np
import ray

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
    # arrays from the object store are read-only: Numba would compile read-only variants
    columns = tuple(np.array(c) for c in columns)
    store, banks = _worker_store(settings)
    return find(meshes, columns, kernel, hierarchy, precision, threads, store, banks)


class RaySplitter:
    """The :class:`~service.search.BatchSplitter` of a Ray cluster."""

    def __init__(self, settings: Settings, threshold: int, chunks: int, cpus: float) -> None:
        self.settings, self.threshold, self.most, self.cpus = settings, threshold, chunks, cpus
        self._task = ray.remote(_search_chunk)
        self._nodes: OrderedDict = OrderedDict()

    def applies(self, pairs: int) -> bool:
        return pairs >= self.threshold and self.chunks(pairs) > 1

    def chunks(self, pairs: int) -> int:
        """Runs to cut ``pairs`` into: one per alive node with CPUs, at most the setting."""
        nodes = sum(1 for n in ray.nodes() if n["Alive"] and n["Resources"].get("CPU", 0) > 0)
        return max(1, min(self.most, nodes, pairs))

    def find(self, meshes, columns, kernel, hierarchy, precision) -> dict:
        threads = max(1, int(round(self.cpus)))
        settings = self.settings.model_copy(update={"engine_threads": threads})
        runs = split(columns, self.chunks(len(columns[0])))
        task = self._task.options(num_cpus=self.cpus, scheduling_strategy="SPREAD")
        parts = [
            task.remote(settings, meshes, run, kernel, hierarchy, precision, threads)
            for run in runs
        ]
        return merge(ray.get(parts))
