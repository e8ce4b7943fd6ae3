"""Benchmark of surrogate trees and the multiresolution contact search (issue 3, baseline).

Run: ``.venv/bin/python benchmarks/trees.py``. Prints tables and writes
``bench-results/trees.json``.

* build time of icosphere trees, 80 … 5,120 triangles (ε = 0.01, N_surrogate = 8);
* two 1,280-triangle icospheres (radius 1, ε = 0.01) at gaps 1.0, 0.02, −0.01, −0.1:
  contact pairs, triangle comparisons and query time of the multiresolution search
  (hybrid) against the flat exact search, same poses, same run;
* two 1,224-triangle UV spheres approaching (gaps 0.5 → 0.0) and a UV sphere on a
  plane: comparisons summed over the approach, flat against hierarchy.
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from common import best_time  # noqa: E402

import engine  # noqa: E402
from engine import Pose, build_tree, find_contacts, shapes  # noqa: E402

OUT = ROOT / "bench-results"


def build_times() -> list[dict]:
    rows = []
    for k in range(1, 5):
        mesh = shapes.icosphere(k)
        start = time.perf_counter()
        tree = build_tree(mesh, 0.01)
        seconds = time.perf_counter() - start
        rows.append(
            {
                "triangles": mesh.n_faces,
                "seconds": seconds,
                "depth": tree.stats.depth,
                "nodes": len(tree),
                "root_epsilon": tree.stats.root_epsilon,
            }
        )
        print(f"build {mesh.n_faces:5d} triangles: {seconds:6.2f} s  depth {tree.stats.depth}")
    return rows


def gap_queries() -> list[dict]:
    tree = build_tree(shapes.icosphere(3), 0.01)
    rows = []
    for gap in (1.0, 0.02, -0.01, -0.1):
        pa, pb = Pose.identity(), Pose([2.0 + gap, 0, 0], [1, 0, 0, 0])
        hier = find_contacts(tree, pa, tree, pb, kernel="hybrid")
        sets = find_contacts(tree, pa, tree, pb, kernel="hybrid", traversal="sets")
        assert np.array_equal(sets.pairs, hier.pairs)
        flat = find_contacts(tree, pa, tree, pb, kernel="exact", hierarchy=False)
        assert np.array_equal(hier.pairs, flat.pairs)
        t_h = best_time(lambda pa=pa, pb=pb: find_contacts(tree, pa, tree, pb))
        t_f = best_time(
            lambda pa=pa, pb=pb: find_contacts(tree, pa, tree, pb, kernel="exact", hierarchy=False)
        )
        rows.append(
            {
                "gap": gap,
                "pairs": len(hier.pairs),
                "points": len(hier.points),
                "comparisons_hierarchy": hier.stats.comparisons,
                "comparisons_active_sets": sets.stats.comparisons,
                "comparisons_flat": flat.stats.comparisons,
                "us_hierarchy": t_h * 1e6,
                "us_flat": t_f * 1e6,
            }
        )
        r = rows[-1]
        print(
            f"gap {gap:+.2f}: pairs {r['pairs']:4d}  comparisons {r['comparisons_hierarchy']:6d}"
            f" (active sets {r['comparisons_active_sets']:6d})"
            f" vs {r['comparisons_flat']}  hierarchy {r['us_hierarchy']:8.0f} us"
            f"  flat {r['us_flat']:8.0f} us"
        )
    return rows


def approach() -> list[dict]:
    sphere = build_tree(shapes.paper_sphere(1224), 0.01)
    plane = build_tree(shapes.plane(size=(6.0, 6.0), divisions=8), 0.01)
    rows = []
    for name, other, base in (("sphere-sphere", sphere, 2.0), ("sphere-plane", plane, 1.0)):
        totals = {"hierarchy": 0, "flat": 0, "pairs": 0}
        for gap in np.linspace(0.5, 0.0, 11):
            pa, pb = Pose([0, 0, base + gap], [1, 0, 0, 0]), Pose.identity()
            hier = find_contacts(sphere, pa, other, pb)
            flat = find_contacts(sphere, pa, other, pb, kernel="exact", hierarchy=False)
            assert np.array_equal(hier.pairs, flat.pairs)
            totals["hierarchy"] += hier.stats.comparisons
            totals["flat"] += flat.stats.comparisons
            totals["pairs"] += len(hier.pairs)
        totals["reduction"] = totals["flat"] / totals["hierarchy"]
        rows.append({"scenario": name, **totals})
        print(
            f"{name}: comparisons over 11 gaps {totals['hierarchy']} vs {totals['flat']} "
            f"({totals['reduction']:.0f}x fewer), contact pairs {totals['pairs']}"
        )
    return rows


def main() -> None:
    OUT.mkdir(exist_ok=True)
    engine.warmup()
    results = {"build": build_times(), "gaps": gap_queries(), "approach": approach()}
    (OUT / "trees.json").write_text(json.dumps(results, indent=2))
    print(f"wrote {OUT / 'trees.json'}")


if __name__ == "__main__":
    main()
