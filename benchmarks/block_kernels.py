"""The block kernels' cost against the block's size: one call of the iterative kernel
(``iterate_paired``) and of the centroid-axis cull (``bound_paired``) on the first ``m``
pairs of a gathered block, float64, in a compiled loop (no dispatch).

Run: ``.venv/bin/python benchmarks/block_kernels.py [--repeat 20000]``. Prints a table and
writes ``bench-results/block_kernels.json``.

A traversal calls these kernels once per level on every pair of that level, often a
handful: the time of a small block is what a near query pays (BENCHMARKS.md, issue 15,
tenth step: runtime alias checks and scalar remainders before ``DISTINCT``).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
from numba import njit

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from common import machine  # noqa: E402

from engine import build_tree, shapes  # noqa: E402
from engine.kernels.geometry import triangle_batch as tb  # noqa: E402
from engine.kernels.geometry.triangle_points import BLOCK  # noqa: E402

OUT = ROOT / "bench-results"
SIZES = (1, 2, 4, 8, 16, 32, 64, 256)


@njit(nogil=True)
def _iterate(ga, gfa, gb, gfb, m, scratch, repeat):
    for _ in range(repeat):
        tb.iterate_paired(ga, gfa, gb, gfb, m, 1, 1.0, 1e-14, scratch)


@njit(nogil=True)
def _bound(ga, gb, m, eps, margin, repeat):
    for _ in range(repeat):
        tb.bound_paired(ga, gb, m, eps, 1.0, 1e-14, margin)


def _block() -> tuple:
    """A gathered block (coordinates (9, BLOCK), frames (14, BLOCK) of A and of B, float64):
    the nodes of a 1,280-triangle icosphere's tree against the next ones, shifted."""
    nodes = build_tree(shapes.icosphere(3), epsilon=0.01).views.geometry.node_set("float64", False)
    coords, frames = nodes.coords_rm, nodes.frames_rm
    ga, gfa = np.ascontiguousarray(coords[:BLOCK].T), np.ascontiguousarray(frames[:BLOCK].T)
    gb = np.ascontiguousarray(coords[BLOCK : 2 * BLOCK].T) + 0.3
    gfb = np.ascontiguousarray(frames[BLOCK : 2 * BLOCK].T)
    return ga, gfa, gb, gfb


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=20000)
    args = parser.parse_args()
    ga, gfa, gb, gfb = _block()
    scratch, margin, eps = np.empty((9, BLOCK)), np.empty(BLOCK), np.full(BLOCK, 0.02)
    rows = []
    print(f"{'pairs':>6} {'iterate ns':>11} {'/pair':>7} {'bound ns':>9} {'/pair':>7}")
    for m in SIZES:
        _iterate(ga, gfa, gb, gfb, m, scratch, 10)
        _bound(ga, gb, m, eps, margin, 10)
        start = time.perf_counter()
        _iterate(ga, gfa, gb, gfb, m, scratch, args.repeat)
        iterate = (time.perf_counter() - start) / args.repeat * 1e9
        start = time.perf_counter()
        _bound(ga, gb, m, eps, margin, args.repeat)
        bound = (time.perf_counter() - start) / args.repeat * 1e9
        rows.append({"pairs": m, "iterate_ns": iterate, "bound_ns": bound})
        print(f"{m:6d} {iterate:11.1f} {iterate / m:7.1f} {bound:9.1f} {bound / m:7.1f}")
    OUT.mkdir(exist_ok=True)
    target = OUT / "block_kernels.json"
    target.write_text(json.dumps({"machine": machine(), "repeat": args.repeat, "rows": rows}))
    print(f"wrote {target}")


if __name__ == "__main__":
    main()
