"""What the engine skips and what that saves (issue 6, "skip what a scene doesn't need").

Measured here, A/B in one process (the engine with and without the skip):

* **broad-phase culling** — the paper's sphere grid (8 × 8 × 4 = 256 spheres of 1,224
  triangles, ``orientations="vertices"``, at rest, implicit-surrogate, dt 1e-3): body pairs
  sent to the narrow phase per step, against every pair n(n − 1)/2 (the broad phase replaced
  by all pairs; the narrow phase's own root-sphere test then prunes the far ones);
* **fixed–fixed pairs** — the same grid with its bottom layer fixed (a floor of 64 spheres):
  the default against a broad phase that keeps fixed–fixed pairs;
* **surrogate levels** — for each paper scenario's trees, posed near contact: the node pairs
  that reach each level of the multiresolution search, how many of them the level's
  surrogate test passes (a level whose test passes every pair cannot change the answer and
  could be skipped), and the comparisons if a whole level were skipped (its pairs unfolded
  untested). Replayed level by level with the exact kernel; the totals match the engine's
  own comparison counts for ``kernel="exact"`` (asserted).

Sleeping bodies (``benchmarks/sleep.py``) and warm-started fronts
(``benchmarks/warmstart.py``) are measured by their own scripts. Writes
``bench-results/skipping.json``.

    .venv/bin/python benchmarks/skipping.py
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path
from unittest import mock

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import engine  # noqa: E402
from engine import Pose, build_tree, find_contacts, scenarios, shapes  # noqa: E402
from engine import scene as scene_module  # noqa: E402
from engine.collision.broadphase import overlapping_pairs  # noqa: E402
from engine.geometry.distance import triangle_distances  # noqa: E402

OUT = ROOT / "bench-results"
GRID = (8, 8, 4)
STEPS = 6  # the first builds the pair lists; steps 2… are the steady state
DT = 1e-3


def all_pairs(centres, radii, fixed):
    """Every body pair (no culling; fixed–fixed pairs kept too)."""
    i, j = np.triu_indices(len(radii), 1)
    return np.stack([i, j], 1).astype(np.int64)


def keep_fixed_pairs(centres, radii, fixed):
    """The broad phase without its fixed–fixed exclusion."""
    return overlapping_pairs(centres, radii, np.zeros_like(fixed))


def grid(floor: bool) -> engine.Scene:
    """The vertex-oriented grid; with ``floor`` its bottom layer is fixed."""
    template = scenarios.sphere_grid(shape=GRID, orientations="vertices")
    if not floor:
        return template
    scene = engine.Scene(gravity=(0.0, 0.0, 0.0))
    mesh = scenarios.sphere(1224)
    eps = template.epsilon[0]  # the paper's ε for every sphere, fixed ones too
    bottom = template.positions[:, 2] == template.positions[:, 2].min()
    for fixed in (True, False):
        rows = bottom == fixed
        scene.add_bodies(
            mesh,
            template.positions[rows],
            orientations=template.orientations[rows],
            fixed=fixed,
            epsilon=eps,
        )
    return scene


def run(floor: bool, broad_phase=None) -> dict:
    scene = grid(floor)
    patch = mock.patch.object(scene_module, "overlapping_pairs", broad_phase or overlapping_pairs)
    times, rows = [], []
    with patch:
        for _ in range(STEPS):
            start = time.perf_counter()
            stats = scene.step(DT)
            times.append(time.perf_counter() - start)
            rows.append(stats)
        _, pairs = scene.configuration(scene.positions, scene.orientations)
    steady = times[1:]
    return {
        "bodies": len(scene),
        "fixed": int(scene.fixed.sum()),
        "pairs_per_step": len(pairs),
        "first_step_s": times[0],
        "step_s": float(np.median(steady)),
        "comparisons_first": int(rows[0].comparisons),
        "comparisons_step": int(np.median([r.comparisons for r in rows[1:]])),
        "positions": scene.positions.copy(),
    }


def ab(name: str, floor: bool, off) -> dict:
    on, without = run(floor), run(floor, off)
    gap = float(np.abs(on.pop("positions") - without.pop("positions")).max())
    print(f"\n== {name} ({on['bodies']} bodies, {on['fixed']} fixed, {STEPS} steps of dt {DT})")
    print(f"{'':22s}{'pairs/step':>11s}{'1st step s':>11s}{'step s':>9s}{'comparisons':>13s}")
    for label, r in (("with the skip", on), ("without", without)):
        print(
            f"{label:22s}{r['pairs_per_step']:11,d}{r['first_step_s']:11.3f}{r['step_s']:9.4f}"
            f"{r['comparisons_step']:13,d}"
        )
    saving = {
        "pairs_avoided": without["pairs_per_step"] - on["pairs_per_step"],
        "time_ratio": without["step_s"] / on["step_s"],
        "first_step_ratio": without["first_step_s"] / on["first_step_s"],
        "largest_position_difference": gap,
    }
    print(
        f"saving: {saving['pairs_avoided']:,} pairs avoided per step; steady step"
        f" {saving['time_ratio']:.2f}x, first step {saving['first_step_ratio']:.2f}x;"
        f" positions differ by {gap:.1e}"
    )
    return {"with": on, "without": without, "saving": saving}


# ---------------------------------------------------------------- surrogate levels
def depth(tree) -> np.ndarray:
    out = np.zeros(len(tree), np.int64)
    for node in range(1, len(tree)):  # breadth-first: parents come first
        out[node] = out[tree.parent[node]] + 1
    return out


def replay(ta, pa, tb, pb, skip: int | None) -> dict:
    """The search of :func:`engine.find_contacts` level by level (bounding spheres, then
    the exact kernel on surrogate pairs; both nodes unfold), with the pairs at front
    level ``skip`` unfolded untested. Counts per level."""
    sa, sb = ta.views.spheres.copy(), tb.views.spheres.copy()
    sa[:, :3], sb[:, :3] = pa.apply(sa[:, :3]), pb.apply(sb[:, :3])
    tri_a = pa.apply(ta.triangles.reshape(-1, 3)).reshape(-1, 3, 3)
    tri_b = pb.apply(tb.triangles.reshape(-1, 3)).reshape(-1, 3, 3)

    def close(i, j):
        return np.linalg.norm(sa[i, :3] - sb[j, :3], axis=-1) <= sa[i, 3] + sb[j, 3]

    front = np.zeros((1, 2), np.int64) if close(0, 0) else np.zeros((0, 2), np.int64)
    leaf_pairs, per_level, level = 0, [], 0
    while len(front):
        leaf = (ta.face[front[:, 0]] >= 0) & (tb.face[front[:, 1]] >= 0)
        leaf_pairs += int(leaf.sum())
        coarse = front[~leaf]
        if not len(coarse):
            break
        if level == skip:
            hit = np.ones(len(coarse), bool)
        else:
            d = triangle_distances(tri_a[coarse[:, 0]], tri_b[coarse[:, 1]], kernel="exact")
            hit = d.distance <= ta.epsilon[coarse[:, 0]] + tb.epsilon[coarse[:, 1]]
        per_level.append((len(coarse), int(hit.sum()), level != skip))
        nxt = []
        for i, j in coarse[hit]:
            kids_a = ta.children(i) if ta.face[i] < 0 else np.array([i])
            kids_b = tb.children(j) if tb.face[j] < 0 else np.array([j])
            ka, kb = (x.ravel() for x in np.meshgrid(kids_a, kids_b, indexing="ij"))
            keep = close(ka, kb)
            if len(kids_b) > 1:  # as the engine: A's child against B's whole node first
                keep &= close(ka, j)
            nxt.append(np.stack([ka[keep], kb[keep]], 1))
        front = np.concatenate(nxt) if nxt else np.zeros((0, 2), np.int64)
        level += 1
    tested = sum(n for n, _, t in per_level if t)
    return {"levels": per_level, "comparisons": tested + leaf_pairs}


def level_cases(rng) -> dict:
    ball = build_tree(scenarios.sphere(1224), 0.005)
    plane = build_tree(shapes.plane(size=(8.0, 8.0), divisions=16), 0.01)
    small = build_tree(scenarios.sphere(80), 0.01)
    large = build_tree(scenarios.sphere(5120, diameter=8.0), 0.08)

    def rotation():
        q = rng.normal(size=4)
        return q / np.linalg.norm(q)

    def direction():
        d = rng.normal(size=3)
        return d / np.linalg.norm(d)

    n = 20
    return {
        "particle-particle (1,224 vs 1,224)": [
            (ball, Pose.identity(), ball, Pose([1 + rng.uniform(-0.008, 0.01), 0, 0], rotation()))
            for _ in range(n)
        ],
        "particle-plane (512 plane vs 1,224)": [
            (
                plane,
                Pose.identity(),
                ball,
                Pose([*rng.uniform(-3, 3, 2), 0.5 + rng.uniform(-0.005, 0.012)], rotation()),
            )
            for _ in range(n)
        ],
        "particle-plane, falling (0 … 1.5 above)": [
            (
                plane,
                Pose.identity(),
                ball,
                Pose([*rng.uniform(-3, 3, 2), 0.5 + rng.uniform(0.0, 1.5)], rotation()),
            )
            for _ in range(n)
        ],
        "scale 8 (5,120 vs 80)": [
            (large, Pose.identity(), small, Pose(direction() * rng.uniform(4.49, 4.52), rotation()))
            for _ in range(n)
        ],
    }


def levels() -> dict:
    out = {}
    for name, queries in level_cases(np.random.default_rng(0)).items():
        base = [replay(*q, None) for q in queries]
        engine_count = sum(
            find_contacts(*q, kernel="exact", precision="float64").stats.comparisons
            for q in queries
        )
        total = sum(b["comparisons"] for b in base)
        assert total == engine_count, (name, total, engine_count)  # the replay is the engine's
        depth_count = max(len(b["levels"]) for b in base)
        print(f"\n== levels, {name}: {len(queries)} poses, {total:,} comparisons")
        print(f"{'level':>6s}{'pairs':>8s}{'pass':>8s}{'pass %':>8s}{'skip it: comparisons':>22s}")
        rows = []
        for level in range(depth_count):
            pairs = sum(b["levels"][level][0] for b in base if len(b["levels"]) > level)
            passed = sum(b["levels"][level][1] for b in base if len(b["levels"]) > level)
            skipped = sum(replay(*q, level)["comparisons"] for q in queries)
            row = {"level": level, "pairs": pairs, "passed": passed}
            rows.append({**row, "comparisons_if_skipped": skipped})
            print(
                f"{level:6d}{pairs:8,d}{passed:8,d}{100 * passed / pairs:8.1f}"
                f"{skipped:14,d} ({(skipped - total) / total:+.1%})"
            )
        out[name] = {"poses": len(queries), "comparisons": total, "levels": rows}
    return out


def main() -> None:
    OUT.mkdir(exist_ok=True)
    engine.warmup()
    results = {
        "broad_phase": ab("broad phase: candidate pairs against all pairs", False, all_pairs),
        "fixed_pairs": ab("fixed floor: fixed-fixed pairs skipped or kept", True, keep_fixed_pairs),
        "levels": levels(),
    }
    (OUT / "skipping.json").write_text(json.dumps(results, indent=2))
    print(f"wrote {OUT / 'skipping.json'}")


if __name__ == "__main__":
    main()
