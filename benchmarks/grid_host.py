"""Where the host time of a steady step of the paper's sphere grid goes (issue 15, point 4).

Run: ``.venv/bin/python benchmarks/grid_host.py [--threads 2] [--orientations vertices]
[--steps 5]``. Prints a table, writes ``bench-results/grid_host.json``.

The grid of ``benchmarks/grid_threads.py`` (32 × 32 × 24 UV spheres, implicit-surrogate,
dt = 1e-3) is stepped twice, then ``--steps`` more times with a wall-clock timer around
each of the host functions below (wrapped in this process only; nested calls count in both,
so the rows do not add up): the milliseconds each takes per step, next to the step's.
``bank.run`` is the batched search, its kernel chunks on the worker threads included.
"""

from __future__ import annotations

import argparse
import collections
import functools
import json
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from common import machine  # noqa: E402
from grid_threads import DT, grid  # noqa: E402

import engine.collision.batch as batch  # noqa: E402
import engine.collision.broadphase as broadphase  # noqa: E402
import engine.collision.configuration as configuration  # noqa: E402
import engine.dynamics.evaluation as evaluation  # noqa: E402
import engine.dynamics.picard as picard  # noqa: E402
from engine.scene import Scene  # noqa: E402

OUT = ROOT / "bench-results"
TIMED = [
    (picard, "evaluate", "evaluate (all of it)"),
    (batch.TreeBank, "run", "bank.run (the batched search)"),
    (evaluation, "contact_forces", "contact_forces"),
    (picard, "_advance", "_advance (the motion update)"),
    (batch, "_join", "_join (the chunks' contacts joined)"),
    (Scene, "configuration", "Scene.configuration (with the broad phase)"),
    (broadphase.CandidateList, "pairs", "broad phase"),
    (configuration, "gathered_queries", "gathered_queries"),
    (picard, "reused", "reused (the warm start's check)"),
    (picard, "_settled", "_settled"),
    (picard, "_flat", "_flat"),
    (picard, "_aitken", "_aitken"),
    (picard, "_first_weights", "_first_weights"),
    (picard, "_summary", "_summary"),
    (picard, "travel", "travel"),
    (picard, "_state", "_state"),
    (picard, "_restore", "_restore"),
]


def timed(owner, name: str, label: str, spent: collections.Counter) -> None:
    """Replace ``owner.name`` with a wrapper that adds its wall time to ``spent[label]``."""
    function = getattr(owner, name)

    @functools.wraps(function)
    def wrapper(*args, **kwargs):
        start = time.perf_counter()
        try:
            return function(*args, **kwargs)
        finally:
            spent[label] += time.perf_counter() - start

    setattr(owner, name, wrapper)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--orientations", default="vertices")
    parser.add_argument("--steps", type=int, default=5)
    args = parser.parse_args()
    host = machine()
    scene = grid((32, 32, 24), args.orientations, args.threads)
    for _ in range(2):
        scene.step(DT)
    spent: collections.Counter = collections.Counter()
    for owner, name, label in TIMED:
        timed(owner, name, label, spent)
    start = time.perf_counter()
    for _ in range(args.steps):
        scene.step(DT)
    step_ms = (time.perf_counter() - start) / args.steps * 1e3
    rows = {label: seconds / args.steps * 1e3 for label, seconds in spent.most_common()}
    print(
        f"{host.get('cpu', '?')}, {host['cores']} cores; {args.orientations} grid,"
        f" {args.threads} threads: {step_ms:.1f} ms a steady step"
    )
    for label, ms in rows.items():
        print(f"  {ms:8.2f} ms  {label}")
    OUT.mkdir(exist_ok=True)
    target = OUT / "grid_host.json"
    setup = vars(args) | {"dt": DT, "machine": host}
    target.write_text(json.dumps({"setup": setup, "step_ms": step_ms, "ms": rows}, indent=2))
    print(f"wrote {target}")


if __name__ == "__main__":
    main()
