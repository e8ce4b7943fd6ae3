"""Benchmark of the triangle-distance kernels: throughput, run time against error, JIT.

Run: ``make bench`` or ``.venv/bin/python benchmarks/kernels.py [--quick]``.
Prints tables and writes ``bench-results/kernels.json`` (``kernels_paired.json`` with
``--paired-only``; and
``bench-results/kernels_iterations.png`` when matplotlib is installed).

Workloads (all real meshes, radius-1 icospheres of 1,280 triangles):

* **streamed** — all 1,280 × 1,280 pairs between two spheres 0.01 apart,
  ε = 0.01 per triangle (contacts exist where the spheres nearly touch);
* **listed, near** — the pairs of those spheres whose centroids lie within 0.5
  of each other: the hard case, what a tree traversal hands to the finest level;
* **listed, random** — uniformly random index pairs of the same spheres;
* **iterations** — near pairs of two randomly rotated noisy spheres at gaps
  from overlapping to 0.05: fallback rate and distance error of the iterative
  kernel against the exact kernel, per iteration count;
* **paired API** — what a user calls: ``triangle_distances(a, b)`` on numpy
  ``(n, 3, 3)`` arrays of 200,000 pairs (the listed near and random pairs above,
  gathered into arrays), preparation included, and ``TriangleSet(a)`` alone
  (``--paired-only`` runs just this section).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from functools import partial
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from common import best_time, machine  # noqa: E402

import engine  # noqa: E402
from engine import TriangleSet, shapes, triangle_contacts, triangle_distances  # noqa: E402

OUT = ROOT / "bench-results"
KERNELS = ("exact", "iterative", "hybrid")
PRECISIONS = ("float32", "float64")


def sphere_pair(gap: float) -> tuple[np.ndarray, np.ndarray]:
    tri = shapes.icosphere(3).triangles
    return tri, tri + np.array([2.0 + gap, 0.0, 0.0])


def throughput(repeat: int) -> list[dict]:
    """Pairs per second for every kernel × precision × threads × form."""
    a, b = sphere_pair(0.01)
    centroids_a, centroids_b = a.mean(axis=1), b.mean(axis=1)
    near = np.argwhere(
        np.linalg.norm(centroids_a[:, None] - centroids_b[None], axis=2) < 0.5
    ).astype(np.int64)
    rng = np.random.default_rng(0)
    random_pairs = np.stack([rng.integers(0, len(a), 400_000), rng.integers(0, len(b), 400_000)], 1)
    near = np.repeat(near, max(1, 200_000 // len(near)), axis=0)  # enough work to time
    rows = []
    for precision in PRECISIONS:
        sa, sb = TriangleSet(a, precision), TriangleSet(b, precision)
        forms = {
            "streamed": (None, len(a) * len(b)),
            "listed near": (near, len(near)),
            "listed random": (random_pairs, len(random_pairs)),
        }
        for form, (pairs, n_pairs) in forms.items():
            for kernel in KERNELS:
                for threads in (1, 2):
                    run = partial(
                        triangle_contacts,
                        sa,
                        sb,
                        0.01,
                        0.01,
                        pairs=pairs,
                        kernel=kernel,
                        precision=precision,
                        threads=threads,
                    )
                    seconds = best_time(run, repeat)
                    result = run()
                    rows.append(
                        {
                            "form": form,
                            "kernel": kernel,
                            "precision": precision,
                            "threads": threads,
                            "pairs": n_pairs,
                            "seconds": seconds,
                            "mpairs_per_s": n_pairs / seconds / 1e6,
                            "contacts": int((result.status == engine.PairStatus.CONTACT).sum()),
                            "culled": result.stats.culled,
                            "iterative": result.stats.iterative,
                            "fallbacks": result.stats.fallbacks,
                        }
                    )
                    r = rows[-1]
                    print(
                        f"{form:14s} {kernel:9s} {precision:7s} {threads}t "
                        f"{r['mpairs_per_s']:9.1f} Mpairs/s  contacts {r['contacts']:5d}  "
                        f"culled {r['culled'] / n_pairs:6.1%}  fallbacks {r['fallbacks']}"
                    )
    return rows


def best_cpu_time(fn, repeat: int) -> float:
    """Minimum process CPU time of ``repeat`` calls of ``fn`` (after one warm-up call): on a
    shared machine, a 1-thread figure that does not count time spent waiting for a core."""
    fn()
    times = []
    for _ in range(repeat):
        start = time.process_time()
        fn()
        times.append(time.process_time() - start)
    return min(times)


def paired_api(repeat: int, precisions: tuple[str, ...] = PRECISIONS) -> list[dict]:
    """Pairs per second of the public paired form from numpy arrays (preparation included);
    wall time, and process CPU time (at 2 threads it sums both threads: on a shared machine
    a 2-thread wall figure near the 1-thread one with the same rate per CPU-second means the
    second core was busy, not that the kernels do not scale)."""
    a, b = sphere_pair(0.01)
    centroids_a, centroids_b = a.mean(axis=1), b.mean(axis=1)
    near = np.argwhere(np.linalg.norm(centroids_a[:, None] - centroids_b[None], axis=2) < 0.5)
    n = 200_000
    near = np.repeat(near, n // len(near) + 1, axis=0)[:n]
    rng = np.random.default_rng(0)
    random_pairs = np.stack([rng.integers(0, len(a), n), rng.integers(0, len(b), n)], 1)
    rows = []
    for precision in precisions:
        for workload, idx in (("near", near), ("random", random_pairs)):
            x = np.ascontiguousarray(a[idx[:, 0]], dtype=precision)
            y = np.ascontiguousarray(b[idx[:, 1]], dtype=precision)
            for threads in (1, 2):
                prepare = best_time(partial(TriangleSet, x, precision, threads=threads), repeat)
                for kernel in KERNELS:
                    run = partial(
                        triangle_distances, x, y, kernel, precision, 0.02, threads=threads
                    )
                    seconds = best_time(run, repeat)
                    cpu = best_cpu_time(run, repeat)
                    result = run()
                    rows.append(
                        {
                            "workload": workload,
                            "kernel": kernel,
                            "precision": precision,
                            "threads": threads,
                            "pairs": n,
                            "seconds": seconds,
                            "mpairs_per_s": n / seconds / 1e6,
                            "cpu_seconds": cpu,
                            "mpairs_per_cpu_s": n / cpu / 1e6,
                            "triangle_set_ns_per_triangle": prepare / n * 1e9,
                            "contacts": int((result.distance <= 0.02).sum()),
                            "fallbacks": result.stats.fallbacks,
                        }
                    )
                    r = rows[-1]
                    print(
                        f"paired {workload:6s} {kernel:9s} {precision:7s} {threads}t "
                        f"{r['mpairs_per_s']:8.1f} Mpairs/s ({r['mpairs_per_cpu_s']:5.1f}/CPU-s)  "
                        f"fallbacks {r['fallbacks']:5d}  "
                        f"TriangleSet {r['triangle_set_ns_per_triangle']:5.1f} ns/triangle"
                    )
    return rows


def iteration_study(repeat: int, quick: bool) -> list[dict]:
    """Fallback rate, distance error and time of the iterative kernel per iteration count."""
    rng = np.random.default_rng(1)
    base = shapes.noisy_sphere(subdivisions=3, eta_r=1.2, seed=3).triangles
    a_list, b_list = [], []
    for gap in (-0.05, -0.01, 0.0, 0.01, 0.02, 0.05):
        q = rng.normal(size=4)
        q /= np.linalg.norm(q)
        w, x, y, z = q
        rot = np.array(
            [
                [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
            ]
        )
        b = base @ rot.T
        # place B along +x so that its support meets A's support at the given gap
        shift = base[..., 0].max() - b[..., 0].min() + gap
        b = b + np.array([shift, 0.0, 0.0])
        ca, cb = base.mean(axis=1), b.mean(axis=1)
        pairs = np.argwhere(np.linalg.norm(ca[:, None] - cb[None], axis=2) < 0.4)
        a_list.append(base[pairs[:, 0]])
        b_list.append(b[pairs[:, 1]])
    a, b = np.concatenate(a_list), np.concatenate(b_list)
    eps = 0.02  # contact distance ε_a + ε_b
    rows = []
    for precision in PRECISIONS:
        sa, sb = TriangleSet(a, precision), TriangleSet(b, precision)
        exact = triangle_distances(sa, sb, "exact", precision, eps).distance.astype(np.float64)
        distances = partial(triangle_distances, sa, sb, precision=precision, epsilon=eps, threads=1)
        t_exact = best_time(partial(distances, kernel="exact"), repeat)
        for iterations in range(1, 5 if quick else 9):
            res = triangle_distances(sa, sb, "iterative", precision, eps, iterations=iterations)
            status = res.status
            contact = status == engine.PairStatus.CONTACT
            err = np.abs(res.distance.astype(np.float64) - exact)[contact]
            wrong = ((exact <= eps) != contact) & (status != engine.PairStatus.NOT_CONVERGED)
            t_iter = best_time(
                partial(distances, kernel="iterative", iterations=iterations), repeat
            )
            t_hyb = best_time(partial(distances, kernel="hybrid", iterations=iterations), repeat)
            rows.append(
                {
                    "precision": precision,
                    "iterations": iterations,
                    "pairs": len(a),
                    "fallback_rate": float((status == engine.PairStatus.NOT_CONVERGED).mean()),
                    "contacts_exact": int((exact <= eps).sum()),
                    "contacts_converged": int(contact.sum()),
                    "max_contact_error": float(err.max()) if err.size else 0.0,
                    "median_contact_error": float(np.median(err)) if err.size else 0.0,
                    "misclassified": int(wrong.sum()),
                    "ns_per_pair_iterative": t_iter / len(a) * 1e9,
                    "ns_per_pair_hybrid": t_hyb / len(a) * 1e9,
                    "ns_per_pair_exact": t_exact / len(a) * 1e9,
                }
            )
            r = rows[-1]
            print(
                f"{precision:7s} it={iterations}  fallback {r['fallback_rate']:6.1%}  "
                f"max err {r['max_contact_error']:.2e}  misclassified {r['misclassified']}  "
                f"iterative {r['ns_per_pair_iterative']:6.1f} ns  hybrid "
                f"{r['ns_per_pair_hybrid']:6.1f} ns  exact {r['ns_per_pair_exact']:6.1f} ns"
            )
    return rows


def jit_times() -> dict:
    """Cold compile of every kernel, and a second process with the cache warm."""
    code = (
        "import time; t0 = time.perf_counter(); import engine; engine.warmup(); "
        "print(time.perf_counter() - t0)"
    )
    with tempfile.TemporaryDirectory() as cache:
        env = {**os.environ, "NUMBA_CACHE_DIR": cache, "PYTHONPATH": str(ROOT)}
        out = {}
        for label in ("cold", "warm"):
            start = time.perf_counter()
            proc = subprocess.run(
                [sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True
            )
            out[f"{label}_process_s"] = time.perf_counter() - start
            out[f"{label}_import_and_warmup_s"] = float(proc.stdout.strip().splitlines()[-1])
    print(
        f"JIT: cold {out['cold_process_s']:.1f} s (process), warm "
        f"{out['warm_process_s']:.2f} s (process, to first result)"
    )
    return out


def plot(rows: list[dict], path: Path) -> bool:
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return False
    fig, axes = plt.subplots(1, 2, figsize=(10, 4))
    for precision in PRECISIONS:
        sub = [r for r in rows if r["precision"] == precision]
        its = [r["iterations"] for r in sub]
        axes[0].plot(its, [r["fallback_rate"] for r in sub], "o-", label=precision)
        axes[1].plot(its, [r["ns_per_pair_hybrid"] for r in sub], "o-", label=f"hybrid {precision}")
        axes[1].axhline(sub[0]["ns_per_pair_exact"], ls="--", color="gray")
    axes[0].set(xlabel="iterations", ylabel="fallback rate (not converged)", yscale="log")
    axes[1].set(xlabel="iterations", ylabel="ns per pair, 1 thread (dashed: exact)")
    for ax in axes:
        ax.legend()
        ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    return True


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="fewer repeats and iterations")
    parser.add_argument("--skip-jit", action="store_true", help="skip the JIT subprocess timing")
    parser.add_argument(
        "--paired-only", action="store_true", help="time the public paired API only"
    )
    parser.add_argument(
        "--precision",
        choices=PRECISIONS,
        action="append",
        help="with --paired-only: time this precision only (repeatable; default both)",
    )
    args = parser.parse_args()
    repeat = 2 if args.quick else 5
    OUT.mkdir(exist_ok=True)
    info = machine()
    print(json.dumps(info))
    results = {"machine": info}
    if args.paired_only:  # (every timing is taken after a warm-up call: no engine.warmup())
        results["paired_api"] = paired_api(repeat, tuple(args.precision or PRECISIONS))
        (OUT / "kernels_paired.json").write_text(json.dumps(results, indent=2))
        print(f"wrote {OUT / 'kernels_paired.json'}")
        return
    engine.warmup()
    results["jit"] = None if args.skip_jit else jit_times()
    results["throughput"] = throughput(repeat)
    results["paired_api"] = paired_api(repeat)
    results["iterations"] = iteration_study(repeat, args.quick)
    (OUT / "kernels.json").write_text(json.dumps(results, indent=2))
    if plot(results["iterations"], OUT / "kernels_iterations.png"):
        print(f"wrote {OUT / 'kernels_iterations.png'}")
    print(f"wrote {OUT / 'kernels.json'}")


if __name__ == "__main__":
    main()
