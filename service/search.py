"""The contacts of a columnar batch of posed pairs, as arrays (the answer's columns), and
the merge of batches searched apart (the chunks of a big request run on a cluster's nodes:
:mod:`service.cluster.batches`)."""

from __future__ import annotations

import threading
from collections.abc import Callable, Collection, Mapping, Sequence
from typing import Protocol

import numpy as np

from engine import Pose, find_contacts_batch

__all__ = ["BatchSplitter", "RunSpeeds", "SentPieces", "find", "merge", "split"]


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
        each place's ``(pairs it answered, seconds from sent to its run's last answer
        here)``. A place that answered none in that time is at its lower bound; runs
        without time, and a request whose own run is empty or instant, teach nothing."""
        pairs, seconds = here
        if pairs <= 0 or seconds <= 0:
            return
        with self._lock:
            for place, (n, elapsed) in runs.items():
                if n < 0 or elapsed <= 0:
                    continue
                speed = (n * seconds) / (elapsed * pairs)  # its pairs/s over this process's
                sample = min(max(speed, prior / self.bound), prior * self.bound)
                old = self._speeds.get(place, prior)
                self._speeds[place] = old + self.smoothing * (sample - old)

    def keep(self, places: Collection[str]) -> None:
        """Forget every place but ``places`` (those alive)."""
        with self._lock:
            self._speeds = {p: v for p, v in self._speeds.items() if p in places}


class SentPieces:
    """The runs sent to other places, each cut into pieces that its place searches front
    to back, handing each piece's answer over as it ends; this process, once its own run
    is searched, takes pieces back from the back of the runs: those not begun (while a
    place has at least two left), and the one a place is on once it has been at it
    ``patience`` times as long as this process would take for the whole piece (a stalled
    or slowed place), or every piece left of a place that failed. The first answer of each
    piece is kept. Thread-safe: the threads pulling the places' answers call
    :meth:`handed` and :meth:`failed`, the request's thread :meth:`take` and :meth:`give`.

    Parameters
    ----------
    sizes : per run, the pairs of each of its pieces (each > 0)
    started : when the runs were sent (``time.perf_counter``)
    patience : how much longer than this process a place may take for a piece it is on
    """

    def __init__(self, sizes: Sequence[Sequence[int]], started: float, patience: float = 1.5):
        self.sizes = [list(run) for run in sizes]
        self.patience = patience
        self.answers: list[list] = [[None] * len(run) for run in self.sizes]
        self.handed_pairs = [0] * len(self.sizes)  # pairs each place answered first
        self.completed = [0.0] * len(self.sizes)  # when each run's last answer was here
        self._unanswered = [len(run) for run in self.sizes]
        self.errors: list[BaseException | None] = [None] * len(self.sizes)
        self._front = [0] * len(self.sizes)  # pieces handed over: the place is on this one
        self._back = [len(run) for run in self.sizes]  # from this piece on, taken back
        self._since = [started] * len(self.sizes)  # when the place began its current piece
        self._changed = threading.Condition()

    def handed(self, run: int, piece: int, answer, at: float) -> None:
        """Piece ``piece`` of run ``run`` (the place's next) answered there, here at ``at``."""
        with self._changed:
            self._front[run] = piece + 1
            self._since[run] = at
            if self._keep(run, piece, answer, at):
                self.handed_pairs[run] += self.sizes[run][piece]
            self._changed.notify_all()

    def failed(self, run: int, error: BaseException) -> bool:
        """Run ``run``'s place ended with ``error`` before handing every piece over: the
        pieces left are this process's to take. Whether any was left (else the error
        cost nothing: a place cancelled once its run was answered, say)."""
        with self._changed:
            if self.complete(run):
                return False
            self.errors[run] = error
            self._changed.notify_all()
            return True

    def take(self, now: float, seconds_per_pair: float) -> tuple[int, int] | None:
        """``(run, piece)`` for this process to search next (of the run with the most
        pieces left), or None: nothing to take now (see :meth:`wait`)."""
        with self._changed:
            best, most = None, 0
            for run in range(len(self.sizes)):
                front, back = self._front[run], self._back[run]
                left = back - front
                if left <= 0 or self.complete(run):
                    continue
                if left == 1 and self.errors[run] is None:
                    begun = now - self._since[run]  # the place is on it: is it stalled?
                    if begun <= self.patience * self.sizes[run][front] * seconds_per_pair:
                        continue
                if left > most:
                    best, most = run, left
            if best is None:
                return None
            self._back[best] -= 1
            return best, self._back[best]

    def give(self, run: int, piece: int, answer, at: float) -> None:
        """The answer of a piece this process took (kept unless its place's came first)."""
        with self._changed:
            self._keep(run, piece, answer, at)

    def wait(self, now: float, seconds_per_pair: float) -> None:
        """Until a place hands a piece over or fails, or one it is on may be taken."""
        with self._changed:
            due = [
                self._since[run]
                + self.patience * self.sizes[run][self._front[run]] * seconds_per_pair
                for run in range(len(self.sizes))
                if self._back[run] - self._front[run] == 1 and not self.complete(run)
            ]
            timeout = min(due, default=now + 1.0) - now
            if sum(self._unanswered) and timeout > 0:
                self._changed.wait(min(timeout, 1.0))

    def handed_over(self, run: int) -> int:
        """Pieces of run ``run`` its place has handed over (so far: it goes front to back)."""
        return self._front[run]

    def complete(self, run: int) -> bool:
        """Whether every piece of run ``run`` has its answer."""
        return self._unanswered[run] == 0

    def done(self) -> bool:
        """Whether every piece has its answer."""
        with self._changed:
            return not any(self._unanswered)

    def _keep(self, run: int, piece: int, answer, at: float) -> bool:
        if self.answers[run][piece] is not None:
            return False
        self.answers[run][piece] = answer
        self._unanswered[run] -= 1
        if self._unanswered[run] == 0:
            self.completed[run] = at
        return True


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
