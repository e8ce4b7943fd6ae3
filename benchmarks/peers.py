"""Our contact query against Coal and python-fcl, same meshes, same poses, one run.

Run: ``.venv/bin/python benchmarks/peers.py [--repeat N]`` (peers: ``pip install -e .[bench]``;
a peer that is not installed is skipped with a note). Prints a table and writes
``bench-results/peers.json``.

Two 1,280-triangle icospheres (radius 1, ε = 0.01 per triangle: a pair is in contact when
d ≤ 0.02), B at x = 2 + gap, gaps 1.0, 0.02, −0.01, −0.1. Reference: our flat exact search
(every triangle pair, exact kernel). Queries, each timed best-of-N in this process:

* mrdem — ``find_contacts`` (hybrid multiresolution): pairs, contact points, normals, overlaps;
* coal — ``coal.collide`` on two ``BVHModelOBBRSS``, ``security_margin = ε_a + ε_b``,
  ``num_max_contacts`` above any pair count: one ``Contact`` per triangle pair (b1, b2) with
  GJK distance d − margin ≤ ``collision_distance_threshold`` (1e-12, not settable from Python);
  with ``CONTACT`` (nearest points, normal, EPA for overlapping triangles) and with
  ``NO_REQUEST`` (pairs only, no EPA since the margin is ≥ 0);
* fcl — python-fcl has no security margin (its ``CollisionRequest`` exposes none): ``collide``
  (``enable_contact=False``) returns the intersecting triangle pairs (d ≤ 0; compared also with
  our flat exact search at ε = 0), ``distance`` returns the minimum distance and one pair.

Timed: the whole call as a user makes it (result objects included; python-fcl converts every
contact to a Python object inside ``collide``; reading Coal's contacts back is not timed).
At gap 0.02 the meshes touch vertex to vertex at d = 0.02 + 1.7e-17 (2.02 − 1 rounded): a tie
that Coal's 1e-12 tolerance counts (36 pairs) and our d ≤ ε_a + ε_b does not.
"""

from __future__ import annotations

import argparse
import importlib.metadata as metadata
import json
import os
import platform
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from common import best_time  # noqa: E402

import engine  # noqa: E402
from engine import Pose, build_tree, find_contacts, shapes, triangle_distances  # noqa: E402

OUT = ROOT / "bench-results"
GAPS = (1.0, 0.02, -0.01, -0.1)
EPSILON = 0.01
MARGIN = 2 * EPSILON


def optional(name: str, dist: str):
    try:
        return __import__(name)
    except ImportError:
        print(f"note: {dist} is not installed; its rows are skipped (pip install -e .[bench])")
        return None


def pair_set(pairs) -> set[tuple[int, int]]:
    return {(int(a), int(b)) for a, b in pairs}


def compare(found: set, reference: set) -> dict:
    return {"missed": len(reference - found), "extra": len(found - reference)}


def distances(mesh, pa: Pose, pb: Pose, pairs: set) -> list[float]:
    """Exact distances of ``pairs`` (faces of A, faces of B) at the poses."""
    if not pairs:
        return []
    idx = np.array(sorted(pairs))
    tri_a, tri_b = pa.apply(mesh.vertices)[mesh.faces], pb.apply(mesh.vertices)[mesh.faces]
    d = triangle_distances(tri_a[idx[:, 0]], tri_b[idx[:, 1]], kernel="exact", threads=1)
    return [float(d.distance.min()), float(d.distance.max())]


def coal_rows(coal, mesh, pa, pb, repeat):
    model = coal.BVHModelOBBRSS()
    model.beginModel(mesh.n_faces, len(mesh.vertices))
    model.addVertices(np.asarray(mesh.vertices, np.float64))
    model.addTriangles(np.asarray(mesh.faces, np.int64))
    model.endModel()
    ta, tb = (coal.Transform3s(p.rotation, p.position) for p in (pa, pb))
    rows = []
    for label, flag in (("+contacts", "CONTACT"), ("pairs only", "NO_REQUEST")):
        flag = getattr(coal.CollisionRequestFlag, flag)
        # room for every triangle pair: the traversal stops once num_max_contacts are found
        request = coal.CollisionRequest(flag, mesh.n_faces**2)
        request.security_margin = MARGIN

        def query(request=request):
            result = coal.CollisionResult()
            coal.collide(model, ta, model, tb, request, result)
            return result

        pairs = pair_set((c.b1, c.b2) for c in query().getContacts())
        rows.append(
            {
                "peer": "coal",
                "query": f"collide margin {MARGIN:g} {label}",
                "pairs": pairs,
                "seconds": best_time(query, repeat),
            }
        )
    return rows


def fcl_rows(fcl, mesh, pa, pb, repeat):
    model = fcl.BVHModel()  # fcl::BVHModel<OBBRSS>
    model.beginModel(len(mesh.vertices), mesh.n_faces)
    model.addSubModel(np.asarray(mesh.vertices, np.float64), np.asarray(mesh.faces, np.int64))
    model.endModel()
    oa, ob = (fcl.CollisionObject(model, fcl.Transform(p.rotation, p.position)) for p in (pa, pb))
    request = fcl.CollisionRequest(num_max_contacts=mesh.n_faces**2, enable_contact=False)

    def collide():
        result = fcl.CollisionResult()
        fcl.collide(oa, ob, request, result)
        return result

    def distance():
        result = fcl.DistanceResult()
        fcl.distance(oa, ob, fcl.DistanceRequest(enable_nearest_points=True), result)
        return result

    near = distance()
    return [
        {
            "peer": "fcl",
            "query": "collide, no margin (d <= 0)",
            "pairs": pair_set((c.b1, c.b2) for c in collide().contacts),
            "seconds": best_time(collide, repeat),
        },
        {
            "peer": "fcl",
            "query": "distance (min d, one pair)",
            "pairs": {(int(near.b1), int(near.b2))} if near.min_distance <= MARGIN else set(),
            "min_distance": float(near.min_distance),
            "seconds": best_time(distance, repeat),
        },
    ]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=30, help="best of N timed calls")
    repeat = parser.parse_args().repeat
    coal, fcl = optional("coal", "coal"), optional("fcl", "python-fcl")
    engine.warmup()
    mesh = shapes.icosphere(3)
    tree, touching_tree = build_tree(mesh, EPSILON), build_tree(mesh, 0.0)
    gaps = []
    for gap in GAPS:
        pa, pb = Pose.identity(), Pose([2.0 + gap, 0, 0], [1, 0, 0, 0])
        exact = {"kernel": "exact", "hierarchy": False}
        oracle = pair_set(find_contacts(tree, pa, tree, pb, **exact).pairs)
        touching = pair_set(find_contacts(touching_tree, pa, touching_tree, pb, **exact).pairs)
        rows = [
            {
                "peer": "mrdem",
                "query": "find_contacts (hybrid)",
                "pairs": pair_set(find_contacts(tree, pa, tree, pb).pairs),
                "seconds": best_time(
                    lambda pa=pa, pb=pb: find_contacts(tree, pa, tree, pb), repeat
                ),
            }
        ]
        rows += coal_rows(coal, mesh, pa, pb, repeat) if coal else []
        rows += fcl_rows(fcl, mesh, pa, pb, repeat) if fcl else []
        ours = rows[0]["seconds"]
        for row in rows:
            found = row.pop("pairs")
            row.update(n_pairs=len(found), **compare(found, oracle))
            row["mismatch_d"] = distances(mesh, pa, pb, (found - oracle) | (oracle - found))
            if row["peer"] == "fcl" and row["query"].startswith("collide"):
                row["vs_touching"] = compare(found, touching)
            row["us"] = row.pop("seconds") * 1e6
            row["ratio"] = row["us"] / (ours * 1e6)  # peer time / our time
        gaps.append({"gap": gap, "oracle_pairs": len(oracle), "touching_pairs": len(touching)})
        gaps[-1]["rows"] = rows
    report(gaps)
    versions = library_versions(coal, fcl)
    setup = {"mesh": "icosphere(3), 1,280 triangles, radius 1", "epsilon": EPSILON}
    setup.update(margin=MARGIN, repeat=repeat, timer="best_time (min of N after one warm-up)")
    OUT.mkdir(exist_ok=True)
    (OUT / "peers.json").write_text(
        json.dumps({"versions": versions, "setup": setup, "gaps": gaps}, indent=2)
    )
    print(f"versions: {versions}\nwrote {OUT / 'peers.json'}")


def library_versions(coal, fcl) -> dict:
    cpu = Path("/proc/cpuinfo")
    models = (
        [x for x in cpu.read_text().splitlines() if x.startswith("model name")]
        if cpu.exists()
        else []
    )
    versions = {
        "python": platform.python_version(),
        "cpu": models[0].split(":")[1].strip() if models else platform.processor(),
        "cpus": os.cpu_count(),
    }
    imported = {"coal": coal, "libcoal": coal, "python-fcl": fcl}
    for dist in ("mrdem", "numpy", "numba", "coal", "libcoal", "python-fcl"):
        if dist in imported and imported[dist] is None:
            versions[dist] = None  # skipped in this run
            continue
        try:
            versions[dist] = metadata.version(dist)
        except metadata.PackageNotFoundError:
            versions[dist] = None
    if fcl:  # the C++ FCL bundled in the python-fcl wheel
        libs = sorted((Path(fcl.__file__).parents[1] / "python_fcl.libs").glob("libfcl-*.so.*"))
        versions["fcl (C++, bundled)"] = libs[0].name.split(".so.")[1] if libs else None
    return versions


def report(gaps: list[dict]) -> None:
    head = (
        f"{'gap':>6}  {'query':<42} {'pairs':>5} {'missed':>6} {'extra':>5} {'us':>9} {'x ours':>7}"
    )
    print(head + "   mismatched pairs' d (min, max)")
    for g in gaps:
        print(
            f"{g['gap']:+6.2f}  oracle: flat exact, {g['oracle_pairs']} pairs with d <= {MARGIN:g}"
            f" ({g['touching_pairs']} with d <= 0)"
        )
        for r in g["rows"]:
            name = f"{r['peer']} {r['query']}"
            d = r["mismatch_d"]
            note = f"({d[0]:.17g}, {d[1]:.17g})" if d else ""
            if "vs_touching" in r:
                t = r["vs_touching"]
                note += f"  vs d <= 0 oracle: missed {t['missed']} extra {t['extra']}"
            if "min_distance" in r:
                note += f"  min d = {r['min_distance']:.17g}"
            print(
                f"{'':6}  {name:<42} {r['n_pairs']:5d} {r['missed']:6d} {r['extra']:5d}"
                f" {r['us']:9.1f} {r['ratio']:7.2f}   {note}"
            )


if __name__ == "__main__":
    main()
