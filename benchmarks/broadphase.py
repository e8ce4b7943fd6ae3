"""Benchmark of the broad phase (:func:`engine.collision.broadphase.candidate_pairs`).

Run: ``.venv/bin/python benchmarks/broadphase.py``. Prints a table and writes
``bench-results/broadphase.json``.

Scenes (bounding spheres only; a plane-like body is the bounding sphere of a square
plane, centred on it with its half-diagonal as radius, so it overlaps every body above
it and is fixed):

* a cubic grid (32 × 32 × 24 = 24,576) of unit-diameter spheres at spacing 0.995, so face
  neighbours barely overlap; the same with uniform jitter of ±0.005 per coordinate
  (some contacts open); the grid on a plane; grids of 512 … 196,608 spheres (scaling);
* 1,000 spheres of radii uniform in [1, 8] on a plane;
* 4,000 spheres of radii 0.5, 1, 2, 4 (an 80-triangle sphere scaled 1, 2, 4, 8).

Each row: bodies, candidate pairs, pairs per body (k / n; a body has 2k / n partners on
average), levels of the grid, best time of the broad phase, and where feasible
(n ≤ 25,000) the time of an O(n²) brute force (compiled, same predicate) whose pairs must
be identical.
"""

from __future__ import annotations

import json
import os
import platform
import sys
from pathlib import Path

import numba
import numpy as np
from numba import njit

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from common import best_time, per_call  # noqa: E402

import engine.collision.broadphase as bp  # noqa: E402
from engine.collision.broadphase import _grid, candidate_pairs  # noqa: E402

OUT = ROOT / "bench-results"
BRUTE_LIMIT = 25_000


@njit(cache=False, nogil=True)
def _brute_count(centres, radii, fixed, out):
    """All pairs i < j, not both fixed, with dx² + dy² + dz² ≤ (r_i + r_j)²: writes up to
    ``len(out)`` of them to ``out (K, 2)`` and returns how many there are."""
    k = 0
    for i in range(centres.shape[0]):
        for j in range(i + 1, centres.shape[0]):
            if fixed[i] and fixed[j]:
                continue
            dx = centres[i, 0] - centres[j, 0]
            dy = centres[i, 1] - centres[j, 1]
            dz = centres[i, 2] - centres[j, 2]
            s = radii[i] + radii[j]
            if dx * dx + dy * dy + dz * dz <= s * s:
                if k < out.shape[0]:
                    out[k, 0], out[k, 1] = i, j
                k += 1
    return k


def brute_force(centres, radii, fixed) -> np.ndarray:
    out = np.empty((16 * len(radii), 2), np.int64)
    k = _brute_count(centres, radii, fixed, out)
    if k > len(out):
        out = np.empty((k, 2), np.int64)
        _brute_count(centres, radii, fixed, out)
    return out[:k]


def grid(shape, spacing=0.995) -> np.ndarray:
    axes = [np.arange(m, dtype=np.float64) for m in shape]
    return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3) * spacing


def with_plane(centres, radii, fixed=None):
    """Append a fixed plane-like body under the scene: the bounding sphere of a square
    plane 10% wider than the scene, at its lowest point."""
    low, high = (centres - radii[:, None]).min(axis=0), (centres + radii[:, None]).max(axis=0)
    half = 0.55 * float((high - low)[:2].max())
    plane = [(low[0] + high[0]) / 2, (low[1] + high[1]) / 2, low[2]]
    fixed = np.zeros(len(radii), bool) if fixed is None else fixed
    return np.vstack([centres, plane]), np.append(radii, half * np.sqrt(2)), np.append(fixed, True)


def scenes():
    rng = np.random.default_rng(2024)
    g = grid((32, 32, 24))
    half = np.full(len(g), 0.5)
    yield "grid 32x32x24, spacing 0.995", g, half, None
    jitter = g + rng.uniform(-0.005, 0.005, g.shape)
    yield "grid + jitter 0.005", jitter, half, None
    yield "grid on a plane", *with_plane(g, half)
    n = 1000
    radii = rng.uniform(1, 8, n)
    side = (n * 4.19 * np.mean(radii**3) / 0.3) ** (1 / 3)  # solid fraction about 0.3
    mixed = rng.uniform(0, side, (n, 3)) + [0, 0, 8]
    yield "1,000 radii 1..8 on a plane", *with_plane(mixed, radii)
    n = 4000
    radii = rng.choice([0.5, 1.0, 2.0, 4.0], n)
    side = (n * 4.19 * np.mean(radii**3) / 0.3) ** (1 / 3)
    yield "4,000 radii 0.5/1/2/4", rng.uniform(0, side, (n, 3)), radii, None
    for shape in ((8, 8, 8), (16, 16, 12), (64, 64, 48)):
        g = grid(shape)
        yield f"grid {'x'.join(map(str, shape))}", g, np.full(len(g), 0.5), None


def run_scene(name, centres, radii, fixed) -> dict:
    n = len(radii)
    f = np.zeros(n, bool) if fixed is None else fixed
    pairs = candidate_pairs(centres, radii, f)
    seconds = best_time(lambda: candidate_pairs(centres, radii, f), 10)
    row = {
        "scene": name,
        "bodies": n,
        "pairs": len(pairs),
        "pairs_per_body": len(pairs) / n,
        "levels": len(_grid(centres, radii)[1]),
        "ms": seconds * 1e3,
        "ns_per_body": seconds / n * 1e9,
        "brute_ms": None,
    }
    if n <= BRUTE_LIMIT:
        brute = brute_force(centres, radii, f)
        assert np.array_equal(brute, pairs), name
        row["brute_ms"] = best_time(lambda: brute_force(centres, radii, f), 1) * 1e3
    return row


def main() -> None:
    OUT.mkdir(exist_ok=True)
    info = {
        "python": platform.python_version(),
        "numpy": np.__version__,
        "numba": numba.__version__,
        "cores": os.cpu_count(),
    }
    print(json.dumps(info))
    candidate_pairs(np.zeros((2, 3)), np.ones(2))  # compile or load the kernels
    header = (
        f"{'scene':30s} {'bodies':>8s} {'pairs':>8s} {'pairs/body':>10s} {'levels':>6s}"
        f" {'ms':>8s} {'ns/body':>8s} {'brute ms':>9s} {'speed-up':>8s}"
    )
    print(header)
    print("-" * len(header))
    rows = []
    for scene in scenes():
        row = run_scene(*scene)
        rows.append(row)
        brute = row["brute_ms"]
        print(
            f"{row['scene']:30s} {row['bodies']:8d} {row['pairs']:8d}"
            f" {row['pairs_per_body']:10.3f} {row['levels']:6d} {row['ms']:8.2f}"
            f" {row['ns_per_body']:8.0f}"
            + (f" {brute:9.1f} {brute / row['ms']:7.0f}x" if brute else f" {'-':>9s} {'-':>8s}")
        )
    small = small_scenes()
    result = {"machine": info, "scenes": rows, "small": small}
    (OUT / "broadphase.json").write_text(json.dumps(result, indent=2))
    print(f"wrote {OUT / 'broadphase.json'}")


def small_scenes() -> list[dict]:
    """A few bodies (the paper's two-body scenes, small piles): the whole call through the
    grid and through the brute force (``SMALL_SCENE`` chooses; same pairs)."""
    rng = np.random.default_rng(3)
    print(f"\n{'bodies':>8s} {'pairs':>6s} {'grid us':>8s} {'brute us':>9s}  (whole call)")
    rows = []
    default = bp.SMALL_SCENE
    for n in (2, 4, 8, 16, 32, 64, 128, 256):
        centres = rng.uniform(0, (n / 0.3) ** (1 / 3), (n, 3))  # a few neighbours each
        radii, fixed = np.full(n, 0.5), np.zeros(n, bool)
        times = {}
        for path, limit in (("grid", 0), ("brute", 10**9)):
            bp.SMALL_SCENE = limit
            times[path] = per_call(lambda c=centres, r=radii, f=fixed: candidate_pairs(c, r, f))
            pairs = candidate_pairs(centres, radii, fixed)
        bp.SMALL_SCENE = default
        assert np.array_equal(pairs, candidate_pairs(centres, radii, fixed))
        row = {"bodies": n, "pairs": len(pairs), **{f"{k}_us": v * 1e6 for k, v in times.items()}}
        rows.append(row)
        print(f"{n:8d} {len(pairs):6d} {row['grid_us']:8.1f} {row['brute_us']:9.1f}")
    print(f"SMALL_SCENE = {default}: the brute force up to that many bodies")
    return rows


if __name__ == "__main__":
    main()
