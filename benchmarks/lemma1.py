"""Lemma 1 at scale: the multiresolution search returns exactly the flat exact search's pairs.

Run: ``.venv/bin/python benchmarks/lemma1.py [--poses N]`` (default 10,000). Random poses of
six shape pairs (noisy sphere η_r = 1.4, stretched sphere η = 1.8, torus, box, plane; 320-ish
triangles each, ε = 0.03), B placed along a random direction at 0.2 … 1.1 × the sum of the
bounding radii: separated, near and overlapping configurations. Each pose runs the hybrid
multiresolution search and the flat exact search in the same precision; any missed or extra
finest-level pair is counted. The poses of each case also run as one ``find_contacts_batch``
call, whose pairs must equal the flat search's too. Writes ``bench-results/lemma1.json``.
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

from engine import Pose, build_tree, find_contacts, find_contacts_batch, shapes  # noqa: E402

SHAPES = {
    "noisy": lambda: shapes.noisy_sphere(subdivisions=2, eta_r=1.4, seed=3),
    "stretched": lambda: shapes.stretched_sphere(subdivisions=2, eta=1.8),
    "torus": lambda: shapes.torus(major_segments=24, minor_segments=12),
    "box": lambda: shapes.box(extents=(1.6, 1.0, 0.6)),
    "plane": lambda: shapes.plane(size=(3.0, 3.0), divisions=8),
}
PAIRS = [
    ("noisy", "noisy"),
    ("noisy", "torus"),
    ("stretched", "box"),
    ("torus", "torus"),
    ("box", "plane"),
    ("noisy", "plane"),
]


def random_pose(rng, position) -> Pose:
    q = rng.normal(size=4)
    return Pose(position, q / np.linalg.norm(q))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--poses", type=int, default=10_000)
    args = parser.parse_args()
    trees = {name: build_tree(make(), epsilon=0.03, seed=0) for name, make in SHAPES.items()}
    rng = np.random.default_rng(2026)
    rows = []
    start = time.perf_counter()
    per_case = -(-args.poses // (len(PAIRS) * 2))  # round up: at least --poses in total
    for precision in ("float64", "float32"):
        for name_a, name_b in PAIRS:
            ta, tb = trees[name_a], trees[name_b]
            reach = ta.bounding_radius + tb.bounding_radius
            row = {
                "a": name_a,
                "b": name_b,
                "precision": precision,
                "poses": 0,
                "missed": 0,
                "extra": 0,
                "with_contact": 0,
                "contact_pairs": 0,
                "comparisons_tree": 0,
                "comparisons_flat": 0,
                "batch_mismatches": 0,
            }
            queries, flats = [], []
            for _ in range(per_case):
                direction = rng.normal(size=3)
                direction /= np.linalg.norm(direction)
                pa = random_pose(rng, rng.normal(size=3))
                pb = random_pose(rng, pa.position + direction * reach * rng.uniform(0.2, 1.1))
                flat = find_contacts(
                    ta, pa, tb, pb, kernel="exact", hierarchy=False, precision=precision
                )
                tree = find_contacts(ta, pa, tb, pb, kernel="hybrid", precision=precision)
                want = {tuple(p) for p in flat.pairs.tolist()}
                got = {tuple(p) for p in tree.pairs.tolist()}
                row["poses"] += 1
                row["missed"] += len(want - got)
                row["extra"] += len(got - want)
                row["with_contact"] += bool(want)
                row["contact_pairs"] += len(want)
                row["comparisons_tree"] += tree.stats.comparisons
                row["comparisons_flat"] += flat.stats.comparisons
                queries.append((ta, pa, tb, pb))
                flats.append(flat.pairs)
            batch = find_contacts_batch(queries, precision=precision)
            row["batch_mismatches"] = sum(
                not np.array_equal(got.pairs, want) for got, want in zip(batch, flats, strict=True)
            )
            rows.append(row)
            print(
                f"{precision} {name_a:9s} {name_b:9s} poses {row['poses']:5d}  "
                f"with contact {row['with_contact']:5d}  pairs {row['contact_pairs']:7d}  "
                f"missed {row['missed']}  extra {row['extra']}  batch mismatches "
                f"{row['batch_mismatches']}  comparisons "
                f"{row['comparisons_tree'] / max(row['comparisons_flat'], 1):.4f} of flat"
            )
    total = {
        k: sum(r[k] for r in rows)
        for k in ("poses", "missed", "extra", "with_contact", "contact_pairs", "batch_mismatches")
    }
    total["seconds"] = time.perf_counter() - start
    print(f"total: {total}")
    out = ROOT / "bench-results"
    out.mkdir(exist_ok=True)
    (out / "lemma1.json").write_text(json.dumps({"rows": rows, "total": total}, indent=2))


if __name__ == "__main__":
    main()
