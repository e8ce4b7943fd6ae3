"""Benchmark of surrogate fitting (paper Appendix A; docs/trees.md, "Surrogate fitting").

Run: ``.venv/bin/python benchmarks/surrogates.py [--sweep]``. Prints tables and writes
``bench-results/surrogates.json``.

* the paper's surrogate-properties table (the last "surrogate-properties:bounding-sphere"
  table: unit-diameter spheres of |T| = 80, 320, 1,280 triangles stretched along one axis
  by η, leaf ε = 0): root diameter (longest edge) d and root ε of (a) the initial
  enclosing triangle, (b) the fitted surrogate (``fit="epsilon"``), (c) the paper's
  literal functional (the raw fit, before the never-worse guard of ``build_tree``), next
  to the paper's values, with the root's ε-region volume over the bounding sphere's;
* tree build time, 80 … 5,120 triangles (ε = 0.01), per construction;
* mean ε-region volume per level, per construction;
* triangle comparisons of the multiresolution contact search over random poses;
* ``--sweep``: the same comparisons with one parameter of the default fit varied at a
  time (the measurements behind the chosen values).
"""

from __future__ import annotations

import dataclasses
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import engine  # noqa: E402
from engine import Pose, build_tree, find_contacts, shapes  # noqa: E402
from engine.trees.surrogates import (  # noqa: E402
    FITS,
    enclosing_triangle,
    fit_triangle,
    largest_distance,
    region_volume,
)

OUT = ROOT / "bench-results"
ETAS = (1.0, 1.2, 1.4, 1.8, 2.6)
SIZES = {80: 1, 320: 2, 1280: 3}  # |T| -> icosphere subdivisions
#: The paper's last surrogate-properties table (label
#: table:surrogate-properties:bounding-sphere, "at the finest level ε = 0"):
#: η -> {|T|: (d_kmax, ε_kmax)}; r_sphere = η / 2.
PAPER = {
    1.0: {80: (0.09, 0.49), 320: (0.09, 0.50), 1280: (0.08, 0.52)},
    1.2: {80: (0.10, 0.55), 320: (0.10, 0.56), 1280: (0.10, 0.56)},
    1.4: {80: (0.34, 0.54), 320: (0.12, 0.65), 1280: (0.11, 0.66)},
    1.8: {80: (0.14, 0.84), 320: (0.89, 0.53), 1280: (1.35, 0.51)},
    2.6: {80: (1.54, 0.58), 320: (2.24, 0.51), 1280: (2.36, 0.52)},
}
CONSTRUCTIONS = ("initial", "epsilon", "paper")


def _root(tri: np.ndarray, eps: float, radius: float) -> dict:
    edges = np.linalg.norm(tri - np.roll(tri, 1, axis=0), axis=1)
    ratio = region_volume(tri, eps) / (4 / 3 * np.pi * radius**3)
    return {"d": float(edges.max()), "epsilon": float(eps), "volume_ratio": float(ratio)}


def surrogate_properties() -> list[dict]:
    rows = []
    for n, k in SIZES.items():
        print(f"\n|T| = {n}: root diameter d, root ε, ε-region volume / bounding sphere V")
        print(
            f"{'η':>4} {'r_sph':>5} | {'paper d':>7} {'ε':>5} | {'initial d':>9} {'ε':>5} {'V':>5}"
            f" | {'fitted d':>8} {'ε':>5} {'V':>5} | {'literal d':>9} {'ε':>5} {'V':>5}"
        )
        for eta in ETAS:
            mesh = shapes.stretched_sphere(k, eta, radius=0.5)  # unit diameter, stretched
            initial = build_tree(mesh, 0.0, fit="initial")
            fitted = build_tree(mesh, 0.0)
            tris = mesh.triangles
            points = np.unique(tris.reshape(-1, 3), axis=0)
            literal = fit_triangle(points, tris, enclosing_triangle(points, tris), FITS["paper"])
            literal_eps = largest_distance(points, literal)
            radius = initial.bounding_radius
            row = {
                "triangles": n,
                "eta": eta,
                "r_sphere": radius,
                "paper": dict(zip(("d", "epsilon"), PAPER[eta][n], strict=True)),
                "initial": _root(initial.triangles[0], initial.epsilon[0], radius),
                "fitted": _root(fitted.triangles[0], fitted.epsilon[0], radius),
                "literal": _root(literal, literal_eps, radius),
            }
            rows.append(row)
            p, a, b, c = row["paper"], row["initial"], row["fitted"], row["literal"]
            print(
                f"{eta:4.1f} {radius:5.2f} | {p['d']:7.2f} {p['epsilon']:5.2f}"
                + "".join(
                    f" | {r['d']:{w}.2f} {r['epsilon']:5.2f} {r['volume_ratio']:5.2f}"
                    for r, w in ((a, 9), (b, 8), (c, 9))
                )
            )
    return rows


def build_times() -> list[dict]:
    rows = []
    print("\nbuild time (ε = 0.01, best of 3), seconds")
    print(f"{'triangles':>9} " + " ".join(f"{c:>8}" for c in CONSTRUCTIONS))
    for k in range(1, 5):
        mesh = shapes.icosphere(k)
        row = {"triangles": mesh.n_faces}
        for fit in CONSTRUCTIONS:
            best = np.inf
            for _ in range(3):
                start = time.perf_counter()
                build_tree(mesh, 0.01, fit=fit)
                best = min(best, time.perf_counter() - start)
            row[fit] = best
        rows.append(row)
        print(f"{mesh.n_faces:9d} " + " ".join(f"{row[c]:8.2f}" for c in CONSTRUCTIONS))
    return rows


def level_volumes() -> list[dict]:
    rows = []
    for name, mesh in (
        ("icosphere 5120", shapes.icosphere(4)),
        ("stretched 1280 η=1.8", shapes.stretched_sphere(3, 1.8)),
    ):
        trees = {fit: build_tree(mesh, 0.01, fit=fit) for fit in CONSTRUCTIONS}
        print(f"\n{name} (ε = 0.01): mean ε-region volume of the surrogates per level")
        print(
            f"{'level':>5} {'nodes':>5} "
            + " ".join(f"{c:>9}" for c in CONSTRUCTIONS)
            + "  fitted/initial"
        )
        base = trees["initial"]
        for level in range(int(base.level.max())):
            nodes = np.flatnonzero((base.level == level) & (base.face < 0))
            means = {
                fit: float(np.mean([region_volume(t.triangles[i], t.epsilon[i]) for i in nodes]))
                for fit, t in trees.items()
            }
            rows.append({"mesh": name, "level": level, "nodes": len(nodes), **means})
            print(
                f"{level:5d} {len(nodes):5d} "
                + " ".join(f"{means[c]:9.5f}" for c in CONSTRUCTIONS)
                + f"  {means['epsilon'] / means['initial']:14.3f}"
            )
    return rows


def _quaternion(rng: np.random.Generator) -> np.ndarray:
    q = rng.normal(size=4)
    return q / np.linalg.norm(q)


def comparisons(fit) -> dict:
    """Triangle comparisons of the contact search, summed over random poses (seeded):
    1,280-triangle icospheres and 1,224-triangle UV spheres at gaps 0.3, 0.02, −0.01 in
    random directions; the UV sphere over an 8×8 plane; 1,280-triangle spheres stretched
    by 1.8 at centre distances 1.8, 2.2, 2.6. 12 random orientations each, ε = 0.01."""
    trees = {
        "icosphere": build_tree(shapes.icosphere(3), 0.01, fit=fit),
        "uv": build_tree(shapes.paper_sphere(1224), 0.01, fit=fit),
        "stretched": build_tree(shapes.stretched_sphere(3, 1.8), 0.01, fit=fit),
        "plane": build_tree(shapes.plane(size=(6.0, 6.0), divisions=8), 0.01, fit=fit),
    }
    rng = np.random.default_rng(0)
    totals = {}
    for name, offsets in (
        ("icosphere", (2.3, 2.02, 1.99)),
        ("uv", (2.3, 2.02, 1.99)),
        ("uv-plane", (1.3, 1.02, 0.99)),
        ("stretched", (1.8, 2.2, 2.6)),
    ):
        a = trees["uv" if name == "uv-plane" else name]
        b = trees["plane"] if name == "uv-plane" else a
        total = 0
        for _ in range(12):
            for offset in offsets:
                if name == "uv-plane":
                    pa, pb = Pose([0, 0, offset], _quaternion(rng)), Pose.identity()
                else:
                    d = rng.normal(size=3)
                    pa = Pose(np.zeros(3), _quaternion(rng))
                    pb = Pose(offset * d / np.linalg.norm(d), _quaternion(rng))
                total += find_contacts(a, pa, b, pb).stats.comparisons
        totals[name] = total
    totals["total"] = sum(totals.values())
    return totals


def contact_comparisons() -> list[dict]:
    print("\ncontact-search triangle comparisons over random poses (fewer is better)")
    rows = []
    for fit in CONSTRUCTIONS:
        rows.append({"fit": fit, **comparisons(fit)})
        print(f"{fit:>8}: " + "  ".join(f"{k} {v}" for k, v in rows[-1].items() if k != "fit"))
    return rows


def sweep() -> list[dict]:
    print("\nparameter sweep around the default fit: comparisons (total)")
    default = FITS["epsilon"]
    variants = [("default", default)]
    for field, values in (
        ("weight_paper", (0.0, 0.03, 0.1, 0.2, 0.5, 1.0)),
        ("beta", (16.0, 32.0, 128.0)),
        ("alpha_area", (0.0, 1e-3, 1e-2)),
        ("alpha_inside", (1.0, 100.0)),
    ):
        for value in values:
            variants.append((f"{field}={value:g}", dataclasses.replace(default, **{field: value})))
    rows = []
    for label, params in variants:
        result = comparisons(params)
        mesh = shapes.stretched_sphere(3, 1.0, radius=0.5)
        root = build_tree(mesh, 0.0, fit=params).stats.volume_ratio
        rows.append({"variant": label, "root_volume_ratio_eta1": root, **result})
        print(f"{label:>20}: {result['total']:7d}  (root V at η = 1, 1,280 triangles: {root:.2f})")
    return rows


def main() -> None:
    OUT.mkdir(exist_ok=True)
    engine.warmup()
    results = {
        "parameters": {k: (dataclasses.asdict(v) if v else None) for k, v in FITS.items()},
        "surrogate_properties": surrogate_properties(),
        "build": build_times(),
        "levels": level_volumes(),
        "comparisons": contact_comparisons(),
    }
    if "--sweep" in sys.argv[1:]:
        results["sweep"] = sweep()
    (OUT / "surrogates.json").write_text(json.dumps(results, indent=2))
    print(f"wrote {OUT / 'surrogates.json'}")


if __name__ == "__main__":
    main()
