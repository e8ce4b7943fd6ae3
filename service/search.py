"""The contacts of a columnar batch of posed pairs, as arrays (the answer's columns), and
the merge of batches searched apart (the chunks of a big request run on a cluster's nodes:
:mod:`service.cluster.batches`)."""

from __future__ import annotations

import threading
from collections.abc import Callable, Collection, Mapping, Sequence
from typing import Protocol

import numpy as np

from engine import Pose, find_contacts_batch

__all__ = ["BatchSplitter", "RunSpeeds", "find", "merge", "split"]


class BatchSplitter(Protocol):
    """Runs a big contacts request as runs of pairs: one here, the others elsewhere (a
    cluster's nodes)."""

    def applies(self, pairs: int) -> bool:
        """Whether a request of ``pairs`` pairs is split."""

    def find(
        self, meshes, columns, kernel, hierarchy, precision, here: Callable[[tuple], dict]
    ) -> dict:
        """What :func:`find` answers for the whole request, and optionally ``timing``
        (name → seconds: parts of the work, for the ``Server-Timing`` header); ``here(run)``
        is :func:`find` of a run of the columns in this process (its engine threads, its
        banks)."""


_ROWS = ("points", "normals", "overlaps")
_STATS = ("pairs", "contacts", "comparisons", "iterative", "fallbacks", "sphere_pruned")


def find(meshes, columns, kernel, hierarchy, precision, threads, store, banks) -> dict:
    """The contacts of ``columns`` ``(a (n,) int64, position_a (n, 3), orientation_a (n, 4),
    b, position_b, orientation_b)`` (``a``/``b`` index ``meshes``): ``offsets (n + 1,)``,
    ``points (c, 3)``, ``normals (c, 3)``, ``overlaps (c,)``, ``pair_offsets (n + 1,)``,
    ``pairs (m, 2)`` and ``stats``; trees from ``store``, multiresolution banks from
    ``banks`` (:class:`~service.banks.BankCache`)."""
    if hierarchy:
        bank = banks.get(tuple(meshes), precision)
        return _from_batch(bank.find_contacts(*columns, kernel=kernel, threads=threads))
    return _flat([store.tree(m) for m in meshes], columns, kernel, precision)


def split(columns, weights: Sequence[float]) -> list[tuple]:
    """``columns`` cut into one run of consecutive pairs per weight (> 0), their lengths in
    proportion to the weights as near as whole pairs allow (a run may be empty when there
    are fewer pairs than weights)."""
    n, shares = len(columns[0]), np.asarray(weights, np.float64)
    cuts = np.concatenate([[0.0], np.cumsum(shares) / shares.sum() * n]).round().astype(np.int64)
    cuts[-1] = n
    return [tuple(c[cuts[k] : cuts[k + 1]] for c in columns) for k in range(len(shares))]


class RunSpeeds:
    """How fast each place (a cluster's node) searches a run of this process's split
    requests, relative to this process: its pairs per second counted from the moment the
    runs were sent to the moment its answer is here (the hand-off counts), over this
    process's own pairs per second in the same request; exponentially weighted
    (``smoothing``), each sample clamped to ``[prior / bound, prior * bound]`` (a cold
    worker's first run weighs little, and no place is ever left without pairs, so each is
    measured again). Runs cut in proportion to these speeds end together: a share equal to
    its place's measured speed is the fixed point. Thread-safe."""

    def __init__(self, smoothing: float = 0.3, bound: float = 4.0) -> None:
        self.smoothing, self.bound = smoothing, bound
        self._speeds: dict[str, float] = {}
        self._lock = threading.Lock()

    def weights(self, places: Sequence[str], prior: float) -> list[float]:
        """The speed of each of ``places`` (> 0): ``prior`` (its engine threads over this
        process's, say) where none was measured yet."""
        with self._lock:
            return [self._speeds.get(place, prior) for place in places]

    def update(
        self, here: tuple[int, float], runs: Mapping[str, tuple[int, float]], prior: float
    ) -> None:
        """One split request: ``here`` this process's run ``(pairs, seconds)``, ``runs``
        each place's ``(pairs, seconds from sent to answer here)``. Runs without pairs or
        time teach nothing."""
        pairs, seconds = here
        if pairs <= 0 or seconds <= 0:
            return
        with self._lock:
            for place, (n, elapsed) in runs.items():
                if n <= 0 or elapsed <= 0:
                    continue
                speed = (n * seconds) / (elapsed * pairs)  # its pairs/s over this process's
                sample = min(max(speed, prior / self.bound), prior * self.bound)
                old = self._speeds.get(place, prior)
                self._speeds[place] = old + self.smoothing * (sample - old)

    def keep(self, places: Collection[str]) -> None:
        """Forget every place but ``places`` (those alive)."""
        with self._lock:
            self._speeds = {p: v for p, v in self._speeds.items() if p in places}


def merge(parts: list[dict]) -> dict:
    """One answer of the answers of consecutive runs of pairs, in order: rows
    concatenated, offsets shifted, statistics summed; triangle pairs int64."""
    # triangle pairs may arrive as int32 (half the bytes through a cluster's object store)
    if len(parts) == 1:
        return {**parts[0], "pairs": parts[0]["pairs"].astype(np.int64, copy=False)}
    merged = {name: np.concatenate([p[name] for p in parts]) for name in _ROWS}
    merged["pairs"] = np.concatenate([p["pairs"] for p in parts], dtype=np.int64)
    for name in ("offsets", "pair_offsets"):
        pieces, base = [np.zeros(1, np.int64)], 0
        for part in parts:
            pieces.append(part[name][1:] + base)
            base += int(part[name][-1])
        merged[name] = np.concatenate(pieces)
    merged["stats"] = {k: sum(p["stats"][k] for p in parts) for k in _STATS}
    return merged


def _from_batch(batch) -> dict:
    return {
        "offsets": batch.contact_offsets,
        "points": batch.points,
        "normals": batch.normals,
        "overlaps": batch.overlaps,
        "pair_offsets": batch.pair_offsets,
        "pairs": batch.pairs,
        "stats": {
            "pairs": len(batch),
            "contacts": len(batch.points),
            "comparisons": batch.comparisons,
            "iterative": batch.iterative,
            "fallbacks": batch.fallbacks,
            "sphere_pruned": batch.sphere_pruned,
        },
    }


def _flat(trees, query, kernel: str, precision: str) -> dict:
    a, pa, qa, b, pb, qb = query
    found = find_contacts_batch(
        [(trees[a[i]], Pose(pa[i], qa[i]), trees[b[i]], Pose(pb[i], qb[i])) for i in range(len(a))],
        kernel=kernel,
        hierarchy=False,
        precision=precision,
    )

    def offsets(sizes):
        return np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64)

    return {
        "offsets": offsets([len(c.points) for c in found]),
        "points": np.concatenate([c.points for c in found]).reshape(-1, 3),
        "normals": np.concatenate([c.normals for c in found]).reshape(-1, 3),
        "overlaps": np.concatenate([c.overlaps for c in found]),
        "pair_offsets": offsets([len(c.pairs) for c in found]),
        "pairs": np.concatenate([c.pairs for c in found]).reshape(-1, 2),
        "stats": {
            "pairs": len(found),
            "contacts": int(sum(len(c.points) for c in found)),
            "comparisons": sum(c.stats.comparisons for c in found),
            "iterative": sum(c.stats.iterative for c in found),
            "fallbacks": sum(c.stats.fallbacks for c in found),
            "sphere_pruned": sum(c.stats.sphere_pruned for c in found),
        },
    }
