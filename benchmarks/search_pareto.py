"""Contact search, run time against error (issue 6): kernel × precision × hierarchy against
the flat exact float64 search (the oracle), on pairs posed near contact.

Workloads: two 320-triangle icospheres (200 random poses near touching) and a 1,024-triangle
torus against η_r = 1.2 noisy spheres (100 poses). Per configuration: the best of 3 run times
over the workload; triangle pairs missed and invented against the oracle; and, matching each
oracle contact to the nearest reported one, the largest point distance, normal angle and
overlap difference. Prints the table and the Pareto front (time against point error, among
configurations that miss nothing); writes ``bench-results/search_pareto.json``. The iteration
count of the iterative kernel is swept at the triangle level in ``benchmarks/kernels.py``.

    .venv/bin/python benchmarks/search_pareto.py
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from common import pareto_front  # noqa: E402

import engine  # noqa: E402
from engine import Pose, build_tree, find_contacts, shapes  # noqa: E402

OUT = ROOT / "bench-results"


def poses(rng, n: int, near: tuple[float, float]) -> list[Pose]:
    out = []
    for _ in range(n):
        d = rng.normal(size=3)
        q = rng.normal(size=4)
        out.append(Pose(d / np.linalg.norm(d) * rng.uniform(*near), q / np.linalg.norm(q)))
    return out


def workloads() -> dict:
    rng = np.random.default_rng(5)
    ball = build_tree(shapes.icosphere(2, radius=0.5), 0.01)
    torus = build_tree(shapes.torus(1.0, 0.3, 32, 16), 0.026)
    rough = build_tree(shapes.noisy_sphere(2, eta_r=1.2, seed=3), 0.024)
    return {
        "spheres": [(ball, Pose.identity(), ball, p) for p in poses(rng, 200, (0.99, 1.02))],
        "torus-rough": [(torus, Pose.identity(), rough, p) for p in poses(rng, 100, (0.5, 1.7))],
    }


def run(queries, kernel: str, precision: str, hierarchy: bool) -> tuple[list, float]:
    best = float("inf")
    for _ in range(3):
        start = time.perf_counter()
        found = [
            find_contacts(a, pa, b, pb, kernel, hierarchy, precision) for a, pa, b, pb in queries
        ]
        best = min(best, time.perf_counter() - start)
    return found, best


def errors(found, oracle) -> dict:
    missed = invented = 0
    point = angle = overlap = 0.0
    for got, want in zip(found, oracle, strict=True):
        g, w = set(map(tuple, got.pairs.tolist())), set(map(tuple, want.pairs.tolist()))
        missed += len(w - g)
        invented += len(g - w)
        if len(want.points) and len(got.points):
            d = np.linalg.norm(want.points[:, None] - got.points[None], axis=2)
            nearest = d.argmin(axis=1)
            point = max(point, float(d.min(axis=1).max()))
            cos = np.clip(np.einsum("ij,ij->i", want.normals, got.normals[nearest]), -1, 1)
            angle = max(angle, float(np.degrees(np.arccos(cos)).max()))
            overlap = max(overlap, float(np.abs(want.overlaps - got.overlaps[nearest]).max()))
    return {
        "missed": missed,
        "invented": invented,
        "point": point,
        "angle_deg": angle,
        "overlap": overlap,
    }


def main() -> None:
    OUT.mkdir(exist_ok=True)
    engine.warmup()
    results = {}
    for name, queries in workloads().items():
        oracle, oracle_s = run(queries, "exact", "float64", False)
        print(
            f"\n== {name}: {len(queries)} pairs, {sum(len(o.pairs) for o in oracle):,} triangle"
            f" pairs in contact (oracle: flat exact float64, {oracle_s:.2f} s)"
        )
        print(
            f"{'kernel':10s}{'precision':>10s}{'hierarchy':>10s}{'seconds':>9s}{'missed':>8s}"
            f"{'invented':>9s}{'point err':>11s}{'angle°':>9s}{'overlap err':>12s}"
        )
        rows = []
        for hierarchy in (True, False):
            for kernel in ("exact", "iterative", "hybrid"):
                for precision in ("float64", "float32"):
                    found, seconds = run(queries, kernel, precision, hierarchy)
                    row = {
                        "kernel": kernel,
                        "precision": precision,
                        "hierarchy": hierarchy,
                        "seconds": seconds,
                        **errors(found, oracle),
                    }
                    rows.append(row)
                    print(
                        f"{kernel:10s}{precision:>10s}{str(hierarchy):>10s}{seconds:9.3f}"
                        f"{row['missed']:8d}{row['invented']:9d}{row['point']:11.2e}"
                        f"{row['angle_deg']:9.2e}{row['overlap']:12.2e}",
                        flush=True,
                    )
        complete = [r for r in rows if r["missed"] == 0]
        front = pareto_front(complete, "seconds", "point")
        print("Pareto front (time against point error, nothing missed):")
        for r in sorted(front, key=lambda r: r["seconds"]):
            print(
                f"  {r['kernel']} {r['precision']} hierarchy={r['hierarchy']}:"
                f" {r['seconds']:.3f} s, {r['point']:.2e}"
            )
        results[name] = {"oracle_seconds": oracle_s, "rows": rows, "pareto": front}
    (OUT / "search_pareto.json").write_text(json.dumps(results, indent=2))


if __name__ == "__main__":
    main()
