"""Benchmark of surrogate trees and the multiresolution contact search (issue 3).

Run: ``.venv/bin/python benchmarks/trees.py``. Prints tables and writes
``bench-results/trees.json``.

* build time of icosphere trees, 80 … 5,120 triangles (ε = 0.01, N_surrogate = 8);
* two 1,280-triangle icospheres (radius 1, ε = 0.01) at gaps 1.0, 0.02, −0.01, −0.1:
  contact pairs, triangle comparisons and query time of the multiresolution search
  (hybrid) against the flat exact search, same poses, same run;
* the paper's explicit comparison-count table: two 1,224-triangle UV spheres approaching,
  touching and separating, and a UV sphere rolling on a 512-triangle plane, 100 static
  configurations each: comparisons, iterative evaluations, fallbacks and time per step,
  flat vs hierarchy, exact vs hybrid, beside the paper's numbers.
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from common import best_time, per_call  # noqa: E402

import engine  # noqa: E402
from engine import Pose, build_tree, find_contacts, find_contacts_batch, shapes  # noqa: E402

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
        single = find_contacts(tree, pa, tree, pb, precision="float32")
        flat32 = find_contacts(tree, pa, tree, pb, "exact", hierarchy=False, precision="float32")
        assert np.array_equal(single.pairs, flat32.pairs)
        t_h = per_call(lambda pa=pa, pb=pb: find_contacts(tree, pa, tree, pb))
        t_32 = per_call(lambda pa=pa, pb=pb: find_contacts(tree, pa, tree, pb, precision="float32"))
        t_f = best_time(
            lambda pa=pa, pb=pb: find_contacts(tree, pa, tree, pb, kernel="exact", hierarchy=False)
        )
        rows.append(
            {
                "gap": gap,
                "pairs": len(hier.pairs),
                "points": len(hier.points),
                "comparisons_hierarchy": hier.stats.comparisons,
                "iterative": hier.stats.iterative,
                "fallbacks": hier.stats.fallbacks,
                "sphere_pruned": hier.stats.sphere_pruned,
                "comparisons_active_sets": sets.stats.comparisons,
                "comparisons_flat": flat.stats.comparisons,
                "us_hierarchy": t_h * 1e6,
                "us_hierarchy_float32": t_32 * 1e6,
                "us_flat": t_f * 1e6,
            }
        )
        r = rows[-1]
        print(
            f"gap {gap:+.2f}: pairs {r['pairs']:4d}  comparisons {r['comparisons_hierarchy']:6d}"
            f" (iterative {r['iterative']}, fallbacks {r['fallbacks']}, sphere-pruned node pairs"
            f" {r['sphere_pruned']}; active sets {r['comparisons_active_sets']:6d})"
            f" vs {r['comparisons_flat']}  hierarchy {r['us_hierarchy']:7.1f} us"
            f" (float32 {r['us_hierarchy_float32']:7.1f} us)  flat {r['us_flat']:8.0f} us"
        )
    return rows


def batch_throughput() -> dict:
    """1,000 random near-contact poses of two 1,280-triangle icospheres: µs per pair for
    single queries and for one batched call on 1 and 2 threads (same results)."""
    tree = build_tree(shapes.icosphere(3), 0.01)
    rng = np.random.default_rng(5)
    queries = []
    for _ in range(1000):
        q, d = rng.normal(size=4), rng.normal(size=3)
        queries.append(
            (
                tree,
                Pose.identity(),
                tree,
                Pose(d / np.linalg.norm(d) * rng.uniform(1.9, 2.05), q / np.linalg.norm(q)),
            )
        )
    singles = [find_contacts(*x) for x in queries]
    batched = find_contacts_batch(queries)
    assert all(np.array_equal(a.pairs, b.pairs) for a, b in zip(singles, batched, strict=True))
    row = {
        "pairs": len(queries),
        "contact_pairs": sum(len(s.pairs) for s in singles),
        "us_single": best_time(lambda: [find_contacts(*x) for x in queries], 3) * 1e3,
        "us_batch_1_thread": best_time(lambda: find_contacts_batch(queries, threads=1), 3) * 1e3,
        "us_batch_2_threads": best_time(lambda: find_contacts_batch(queries, threads=2), 3) * 1e3,
    }
    print(
        f"batch of {row['pairs']} near-contact pairs ({row['contact_pairs']} contact pairs), us per"
        f" pair: single {row['us_single']:.1f}, batch 1 thread {row['us_batch_1_thread']:.1f},"
        f" 2 threads {row['us_batch_2_threads']:.1f}"
    )
    return row


# The paper's Table "comparison count" (explicit Euler step, averaged over 100 steps,
# 1,224-triangle spheres of diameter 1, plane of 512 triangles): comparisons and seconds.
PAPER_EXPLICIT = {
    "particle-particle": {
        "flat exact": (1.50e6, 3.96),
        "flat hybrid": (1.50e6, 1.87, 1.66e3),
        "hierarchy exact": (8.20e3, 2.60e-2),
        "hierarchy hybrid": (7.64e3, 1.80e-2, 1.44e2),
    },
    "particle-plane": {
        "flat exact": (6.27e5, 1.68),
        "flat hybrid": (6.27e5, 8.00, 1.57e4),
        "hierarchy exact": (5.27e3, 7.68e-2),
        "hierarchy hybrid": (5.03e3, 4.00e-2, 4.96e2),
    },
}
STEPS = 100
VARIANTS = {  # name: (kernel, hierarchy)
    "flat exact": ("exact", False),
    "flat hybrid": ("hybrid", False),
    "hierarchy exact": ("exact", True),
    "hierarchy hybrid": ("hybrid", True),
}


def paper_poses(scenario: str) -> list[tuple[Pose, Pose]]:
    """100 static configurations along the paper's two explicit scenarios (unit diameter).

    particle-particle: B approaches A head-on from 0.25 apart, touches (down to an overlap
    of half the contact distance), and separates again, both spinning slowly;
    particle-plane: the sphere rolls along the plane at a gap inside the contact distance.
    """
    poses = []
    for step in range(STEPS):
        phase = step / (STEPS - 1)
        angle = 2 * np.pi * phase
        spin = [np.cos(angle / 2), 0.0, np.sin(angle / 2), 0.0]  # about y
        if scenario == "particle-particle":
            gap = 0.25 * abs(2 * phase - 1) ** 1.5 - 0.01
            other = [np.cos(angle / 3), np.sin(angle / 3), 0.0, 0.0]
            poses.append((Pose([0, 0, 0], spin), Pose([1.0 + gap, 0.1, 0.05], other)))
        else:  # rolls 1.5 along x (≈ one turn of a unit-diameter sphere), gap 0.005
            poses.append((Pose([-0.75 + 1.5 * phase, 0.2, 0.505], spin), Pose.identity()))
    return poses


def paper_table() -> list[dict]:
    sphere = build_tree(shapes.paper_sphere(1224, radius=0.5), 0.01)
    plane = build_tree(shapes.plane(size=(3.0, 3.0), divisions=16), 0.01)  # 512 triangles
    rows = []
    for scenario, other in (("particle-particle", sphere), ("particle-plane", plane)):
        poses = paper_poses(scenario)
        reference = None
        for name, (kernel, hierarchy) in VARIANTS.items():
            total = {
                "comparisons": 0,
                "iterative": 0,
                "fallbacks": 0,
                "sphere_pruned": 0,
                "seconds": 0.0,
                "pairs": 0,
            }
            results = []
            for pa, pb in poses:
                start = time.perf_counter()
                res = find_contacts(sphere, pa, other, pb, kernel=kernel, hierarchy=hierarchy)
                total["seconds"] += time.perf_counter() - start
                results.append(res.pairs)
                total["comparisons"] += res.stats.comparisons
                total["iterative"] += res.stats.iterative
                total["fallbacks"] += res.stats.fallbacks
                total["sphere_pruned"] += res.stats.sphere_pruned
                total["pairs"] += len(res.pairs)
            if reference is None:
                reference = results
            assert all(np.array_equal(x, y) for x, y in zip(results, reference, strict=True))
            row = {
                "scenario": scenario,
                "variant": name,
                **{k: v / STEPS for k, v in total.items()},
            }
            paper = PAPER_EXPLICIT[scenario][name]
            row["paper_comparisons"], row["paper_seconds"] = paper[0], paper[1]
            row["paper_fallbacks"] = paper[2] if len(paper) > 2 else None
            rows.append(row)
            print(
                f"{scenario:17s} {name:16s} comparisons {row['comparisons']:10.4g}"
                f" (paper {paper[0]:.3g})  iterative {row['iterative']:10.4g}"
                f"  fallbacks {row['fallbacks']:8.4g}  sphere-pruned {row['sphere_pruned']:8.4g}"
                f"  time {row['seconds'] * 1e3:9.3f} ms"
                f" (paper {paper[1] * 1e3:.3g} ms)  contact pairs {row['pairs']:.1f}"
            )
        flat, tree = rows[-4]["comparisons"], rows[-1]["comparisons"]
        print(f"{scenario}: comparisons reduced {flat / tree:.0f}x (flat exact / hierarchy hybrid)")
    return rows


def main() -> None:
    OUT.mkdir(exist_ok=True)
    engine.warmup()
    results = {
        "build": build_times(),
        "gaps": gap_queries(),
        "batch": batch_throughput(),
        "paper_table": paper_table(),
    }
    (OUT / "trees.json").write_text(json.dumps(results, indent=2))
    print(f"wrote {OUT / 'trees.json'}")


if __name__ == "__main__":
    main()
