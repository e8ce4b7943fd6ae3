"""Contact search, run time against error (issue 6): kernel × iteration count × precision ×
hierarchy against the flat exact float64 search (the oracle), on pairs posed near contact.

Workloads: two 320-triangle icospheres (200 random poses near touching) and a 1,024-triangle
torus against η_r = 1.2 noisy spheres (100 poses). Per configuration: the best of 3 run times
over the workload; triangle pairs missed and invented against the oracle; and, matching each
oracle contact to the nearest reported one, the largest point distance, normal angle and
overlap difference. Prints the table and the Pareto front (time against the point, normal and
overlap errors together, among configurations that miss nothing); writes
``bench-results/search_pareto.json`` and, with matplotlib, ``bench-results/search_pareto.png``.
The iterative and hybrid kernels run with 1, 2, 4 and 8 sweeps (``iterations``; the exact
kernel has none). The defaults' close calls (hybrid
with the hierarchy, float64 against float32, 1 against 2 sweeps) are timed again, interleaved,
``--interleaved N`` times each: medians and quartiles decide them, not one noisy best-of-3.

    .venv/bin/python benchmarks/search_pareto.py [--interleaved 15]
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


ITERATIONS = (1, 2, 4, 8)
ERRORS = ("point", "angle_deg", "overlap")  # a configuration dominates only if no worse in all


def once(queries, kernel, precision, hierarchy, iterations=1) -> tuple[list, float]:
    start = time.perf_counter()
    found = [
        find_contacts(a, pa, b, pb, kernel, hierarchy, precision, iterations=iterations)
        for a, pa, b, pb in queries
    ]
    return found, time.perf_counter() - start


def run(queries, kernel, precision, hierarchy, iterations=1) -> tuple[list, float]:
    """The results and the best of 3 run times over ``queries``."""
    runs = [once(queries, kernel, precision, hierarchy, iterations) for _ in range(3)]
    return runs[0][0], min(t for _, t in runs)


def configurations():
    for hierarchy in (True, False):
        for kernel in ("exact", "iterative", "hybrid"):
            for precision in ("float64", "float32"):
                for iterations in (1,) if kernel == "exact" else ITERATIONS:
                    yield kernel, precision, hierarchy, iterations


CLOSE_CALLS = {  # the default and its neighbours on the front
    "hybrid float64 1 (default)": ("hybrid", "float64", True, 1),
    "hybrid float32 1": ("hybrid", "float32", True, 1),
    "hybrid float64 2": ("hybrid", "float64", True, 2),
    "exact float64": ("exact", "float64", True, 1),
}


def interleaved(queries, repeat: int) -> dict:
    """Run times of the close calls, taken in turn ``repeat`` times: quartiles (s)."""
    times = {name: [] for name in CLOSE_CALLS}
    for _ in range(repeat):
        for name, config in CLOSE_CALLS.items():
            times[name].append(once(queries, *config)[1])
    return {name: np.percentile(t, [25, 50, 75]).tolist() for name, t in times.items()}


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
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--interleaved", type=int, default=15, help="runs of each close call")
    repeat = parser.parse_args().interleaved
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
            f"{'kernel':10s}{'precision':>10s}{'hierarchy':>10s}{'iter':>5s}{'seconds':>9s}"
            f"{'fallbk':>8s}{'missed':>8s}"
            f"{'invented':>9s}{'point err':>11s}{'angle°':>9s}{'overlap err':>12s}"
        )
        rows = []
        for kernel, precision, hierarchy, iterations in configurations():
            found, seconds = run(queries, kernel, precision, hierarchy, iterations)
            row = {
                "kernel": kernel,
                "precision": precision,
                "hierarchy": hierarchy,
                "iterations": iterations,
                "seconds": seconds,
                "fallbacks": sum(f.stats.fallbacks for f in found),
                **errors(found, oracle),
            }
            rows.append(row)
            print(
                f"{kernel:10s}{precision:>10s}{str(hierarchy):>10s}{iterations:5d}{seconds:9.3f}"
                f"{row['fallbacks']:8d}{row['missed']:8d}{row['invented']:9d}{row['point']:11.2e}"
                f"{row['angle_deg']:9.2e}{row['overlap']:12.2e}",
                flush=True,
            )
        complete = [r for r in rows if r["missed"] == 0]
        front = pareto_front(complete, "seconds", ERRORS)
        print("Pareto front (time against point, normal and overlap errors, nothing missed):")
        for r in sorted(front, key=lambda r: r["seconds"]):
            print(f"  {label(r)}: {r['seconds']:.3f} s, {r['point']:.2e}")
        close = interleaved(queries, repeat)
        print(f"close calls, {repeat} interleaved runs each: quartiles (s)")
        for call, (q1, med, q3) in close.items():
            print(f"  {call:28s} {q1:.4f} {med:.4f} {q3:.4f}")
        results[name] = {
            "oracle_seconds": oracle_s,
            "rows": rows,
            "pareto": front,
            "interleaved": {"runs": repeat, "quartiles": close},
        }
    (OUT / "search_pareto.json").write_text(json.dumps(results, indent=2))
    plot(results, OUT / "search_pareto.png")


def label(r: dict) -> str:
    sweeps = "" if r["kernel"] == "exact" else f" x{r['iterations']}"
    flat = "" if r["hierarchy"] else " flat"
    return f"{r['kernel']}{sweeps} {r['precision']}{flat}"


def plot(results: dict, target: Path) -> None:
    """Time against point error per workload; the front joined (configurations missing
    contacts are left out; a zero error is drawn at 1e-9)."""
    try:
        import matplotlib
        import matplotlib.ticker

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        print("matplotlib missing: no PNG")
        return
    fig, axes = plt.subplots(1, len(results), figsize=(6 * len(results), 4.5))
    for ax, (name, result) in zip(np.atleast_1d(axes), results.items(), strict=True):
        for r in (r for r in result["rows"] if r["missed"] == 0):
            marker = "o" if r["hierarchy"] else "x"
            color = {"exact": "C0", "hybrid": "C1"}[r["kernel"]]
            ax.scatter(r["seconds"], max(r["point"], 1e-9), marker=marker, color=color)
        front = sorted(result["pareto"], key=lambda r: r["seconds"])
        ax.plot([r["seconds"] for r in front], [max(r["point"], 1e-9) for r in front], "k--")
        named = set()
        for r in front:  # the fastest of each error level is named
            level = f"{max(r['point'], 1e-9):.1e}"
            if level not in named:
                named.add(level)
                ax.annotate(label(r), (r["seconds"], max(r["point"], 1e-9)), fontsize=7)
        ax.set(xscale="log", yscale="log", xlabel="seconds", ylabel="largest point error")
        ax.xaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
        ax.set_title(f"{name} (o hierarchy, x flat; blue exact, orange hybrid)", fontsize=9)
    fig.tight_layout()
    fig.savefig(target, dpi=120)
    print(f"wrote {target}")


if __name__ == "__main__":
    main()
