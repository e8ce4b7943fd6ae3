"""Tree banks (the batched search's concatenated trees) kept per set of meshes, so that a
contacts request over meshes seen before pays no concatenation."""

from __future__ import annotations

import threading
from collections import OrderedDict

from engine import TreeBank

__all__ = ["BankCache"]


class BankCache:
    def __init__(self, store, capacity: int = 32) -> None:
        self.store, self.capacity = store, capacity
        self._banks: OrderedDict[tuple, TreeBank] = OrderedDict()
        self._lock = threading.Lock()

    def get(self, mesh_ids: tuple[str, ...], precision: str) -> TreeBank:
        """The bank of these trees, in this order (built on first use)."""
        key = (mesh_ids, precision)
        with self._lock:
            if key in self._banks:
                self._banks.move_to_end(key)
                return self._banks[key]
        bank = TreeBank([self.store.tree(m) for m in mesh_ids], precision)
        with self._lock:
            self._banks[key] = bank
            while len(self._banks) > self.capacity:
                self._banks.popitem(last=False)
        return bank

    def forget(self, mesh_id: str) -> None:
        """Drop the banks that hold ``mesh_id`` (its tree file may go)."""
        with self._lock:
            for key in [k for k in self._banks if mesh_id in k[0]]:
                del self._banks[key]
