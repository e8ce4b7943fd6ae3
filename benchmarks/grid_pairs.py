"""One body pair of the paper's sphere grid, searched many times: the cost of a traversal that
makes the pair cache's list, of a search served by that list, and of a plain traversal.

Run: ``.venv/bin/python benchmarks/grid_pairs.py [--copies 2000] [--threads 1] [--skin S]``.
Prints a table and writes ``bench-results/grid_pairs.json``.

The pairs are neighbours of :func:`engine.scenarios.sphere_grid` (1,224-triangle UV spheres,
centres 1.0195 apart): along z and along x, for the ``"aligned"`` and the ``"vertices"``
orientations (the "aligned" z pair touches pole to pole: 1,296 touching leaf pairs). Each is
queried as ``--copies`` identical body pairs in one :meth:`engine.TreeBank.run` call (hybrid,
the scene's precision): with a fresh :class:`engine.PairCache` of the default skin (every
list made; ``--skin`` for another), again with that cache (every list serving), and without
a cache. Times are per body pair, best of ``REPEAT`` calls (a fresh cache for each call
that makes lists).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from engine import PairCache, scenarios  # noqa: E402
from engine.collision.pair_cache import DEFAULT_SKIN  # noqa: E402

OUT = ROOT / "bench-results"
REPEAT = 5
SHAPES = {"z": (1, 1, 2), "x": (2, 1, 1)}


def _queries(scene, copies: int) -> tuple:
    """``copies`` times the scene's one candidate body pair, as the bank's query arrays."""
    origins, pairs = scene.configuration(scene.positions, scene.orientations)
    (a, b), q = pairs[0], scene.orientations
    index = np.zeros(copies, np.int64)
    tile = lambda row: np.tile(row, (copies, 1))  # noqa: E731
    return index, index, tile(origins[a]), tile(q[a]), tile(origins[b]), tile(q[b])


def _making(bank, queries: tuple, threads: int, skin: float, keys) -> None:
    """One search with a fresh cache: every list made."""
    bank.run(queries, "hybrid", threads, PairCache(skin), keys)


def _best(run, arguments: tuple) -> float:
    """The least time of ``REPEAT`` calls ``run(*arguments)``, in seconds."""
    best = np.inf
    for _ in range(REPEAT):
        start = time.perf_counter()
        run(*arguments)
        best = min(best, time.perf_counter() - start)
    return best


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--copies", type=int, default=2000)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--skin", type=float, default=DEFAULT_SKIN)
    args = parser.parse_args()
    k, threads = args.copies, args.threads
    rows = []
    header = f"{'pair':>12} {'listed':>6} {'contacts':>8} {'makes list':>11}"
    print(header + f" {'served':>8} {'plain':>8}")
    for orientation in ("aligned", "vertices"):
        for axis, shape in SHAPES.items():
            scene = scenarios.sphere_grid(shape=shape, orientations=orientation)
            bank, queries = scene.bank, _queries(scene, k)
            keys = np.arange(k, dtype=np.int64)
            few = tuple(column[:2] for column in queries)
            bank.run(few, "hybrid", threads, PairCache(args.skin), keys[:2])  # compiled or loaded
            cache = PairCache(args.skin)
            made = bank.run(queries, "hybrid", threads, cache, keys)
            making = _best(_making, (bank, queries, threads, args.skin, keys))
            served = _best(bank.run, (queries, "hybrid", threads, cache, keys))
            plain = _best(bank.run, (queries, "hybrid", threads))
            row = {
                "orientation": orientation,
                "axis": axis,
                "listed": int(np.diff(cache.offsets)[0]),
                "leaf_pairs_in_contact": int(made.pair_offsets[1]),
                "contacts": int(made.contact_offsets[1]),
                "makes_list_us": making / k * 1e6,
                "served_us": served / k * 1e6,
                "plain_us": plain / k * 1e6,
            }
            rows.append(row)
            print(
                f"{orientation + ' ' + axis:>12} {row['listed']:6d} {row['contacts']:8d}"
                f" {row['makes_list_us']:8.1f} µs {row['served_us']:5.1f} µs"
                f" {row['plain_us']:5.1f} µs"
            )
    OUT.mkdir(exist_ok=True)
    target = OUT / "grid_pairs.json"
    setup = {"copies": k, "threads": threads, "repeat": REPEAT, "skin": args.skin}
    target.write_text(json.dumps({"setup": setup, "pairs": rows}, indent=2))
    print(f"wrote {target}")


if __name__ == "__main__":
    main()
