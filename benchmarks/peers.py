"""Our contact and distance queries against Coal and python-fcl, same meshes, same poses, one run.

Run: ``.venv/bin/python benchmarks/peers.py [--repeat N] [--passes P] [--quick]`` (peers:
``pip install -e .[bench]``; a peer that is not installed is skipped with a note). Prints two
tables and writes ``bench-results/peers.json``.

Cases (ε = 0.01 per triangle: a pair is in contact when d ≤ 0.02), each at four gaps — far
or roomy, near touching, slightly overlapping (−0.01), deeper overlap (−0.1):

* icospheres of 80, 320, 1,280 and 5,120 triangles (``icosphere(1..4)``, radius 1), B at
  x = 2 + gap, gaps 1.0, 0.02, −0.01, −0.1;
* a chain link: two 1,024-triangle tori (``torus(1, 0.3, 32, 16)``), B turned 90° about x
  so that its ring passes through A's hole, at x = 0.6 + gap (the smooth tubes are ``gap``
  apart), gaps 0.3, 0.02, −0.01, −0.1;
* a 1,280-triangle sphere of radius 0.5 in the hole of the same torus, at x = 0.2 − gap
  (gap 0.2: centred, every point of the hole's rim equally near), gaps 0.2, 0.02, −0.01, −0.1.

Oracles: our flat exact search (every triangle pair, exact kernel, float64) for contacts,
with ε = 0.01 and with ε = 0 (intersecting pairs); for the distance, the exact kernel on
every face pair (chunks of paired calls), its minimum and a face pair attaining it.

Queries, all in this process on one thread; each is timed in P passes over all cases (best of
N calls per pass, the minimum over passes kept: samples spread over the run, which a shared
machine needs):

* margin contacts — ours: ``find_contacts`` (hybrid, hierarchy; float64 and float32);
  Coal: ``coal.collide`` on two ``BVHModelOBBRSS``, ``security_margin = ε_a + ε_b``,
  ``num_max_contacts`` above any pair count, with ``CONTACT`` (nearest points, normal, EPA)
  and ``NO_REQUEST`` (pairs only); one ``Contact`` per triangle pair (b1, b2) with GJK
  distance d − margin ≤ ``collision_distance_threshold`` (1e-12, not settable from
  Python). python-fcl has no security margin (its ``CollisionRequest`` exposes none):
  ``collide`` (``enable_contact=False``) returns the intersecting pairs, compared also with
  the ε = 0 oracle;
* distance — ours: :func:`engine.mesh_distance` (float64); Coal: ``coal.distance``;
  python-fcl: ``fcl.distance``; both with nearest points. Each returns one face pair;
  meshes that intersect give 0 (none of the three returns a penetration depth here).

Timed: the whole call as a user makes it (result objects included; python-fcl converts every
contact to a Python object inside ``collide``; reading Coal's contacts back is not timed).
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
from engine import (  # noqa: E402
    Pose,
    build_tree,
    find_contacts,
    mesh_distance,
    shapes,
    triangle_distances,
)

OUT = ROOT / "bench-results"
EPSILON = 0.01
MARGIN = 2 * EPSILON
QUARTER_X = [np.cos(np.pi / 4), np.sin(np.pi / 4), 0.0, 0.0]  # 90° about x
ORACLE_CHUNK = 1 << 20  # face pairs per paired call of the distance oracle
MESHES = {
    **{
        f"ico{20 * 4**k}": (f"icosphere({k})", lambda k=k: shapes.icosphere(k))
        for k in (1, 2, 3, 4)
    },
    "torus": ("torus(1, 0.3, 32, 16)", lambda: shapes.torus(1.0, 0.3, 32, 16)),
    "ball": ("icosphere(3, radius=0.5)", lambda: shapes.icosphere(3, radius=0.5)),
}
SPHERE_GAPS = (1.0, 0.02, -0.01, -0.1)


def beside(gap: float) -> tuple:
    """B's (position, orientation) for icospheres: beside A along x."""
    return [2 + gap, 0, 0], [1, 0, 0, 0]


def linked(gap: float) -> tuple:
    """B's pose for the chain link: its ring through A's hole, tubes ``gap`` apart."""
    return [0.6 + gap, 0, 0], QUARTER_X


def in_hole(gap: float) -> tuple:
    """The radius-0.5 sphere in the torus's hole (rim radius 0.7), ``gap`` from the rim."""
    return [0.2 - gap, 0, 0], [1, 0, 0, 0]


# (case, mesh A, mesh B, gaps, pose of B for a gap); A is at the identity
CASES = [
    *((f"icospheres {n[3:]}", n, n, SPHERE_GAPS, beside) for n in ("ico80", "ico320")),
    *((f"icospheres {n[3:]}", n, n, SPHERE_GAPS, beside) for n in ("ico1280", "ico5120")),
    ("tori, chain link", "torus", "torus", (0.3, 0.02, -0.01, -0.1), linked),
    ("torus, sphere in hole", "torus", "ball", (0.2, 0.02, -0.01, -0.1), in_hole),
]


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


def posed(mesh, pose: Pose) -> np.ndarray:
    """(F, 3, 3) float64 world-frame triangles of ``mesh`` at ``pose``."""
    return pose.apply(mesh.vertices)[mesh.faces]


def pair_distances(tri_a: np.ndarray, tri_b: np.ndarray, pairs) -> np.ndarray:
    """(k,) float64 exact distances of the face pairs ``pairs (k, 2)``."""
    idx = np.array(sorted(pairs), dtype=np.int64).reshape(-1, 2)
    if not len(idx):
        return np.zeros(0)
    return triangle_distances(tri_a[idx[:, 0]], tri_b[idx[:, 1]], kernel="exact").distance


def span(values: np.ndarray) -> list[float]:
    """[min, max] of ``values``, or [] when there are none."""
    return [float(values.min()), float(values.max())] if len(values) else []


def distance_oracle(tri_a: np.ndarray, tri_b: np.ndarray) -> tuple[float, tuple[int, int]]:
    """Minimum exact distance over every face pair and a pair attaining it (paired calls of
    the exact kernel over rows of A, all threads)."""
    best, where = np.inf, (-1, -1)
    rows = max(1, ORACLE_CHUNK // len(tri_b))
    for start in range(0, len(tri_a), rows):
        block = tri_a[start : start + rows]
        a = np.repeat(block, len(tri_b), axis=0)
        b = np.tile(tri_b, (len(block), 1, 1))
        d = triangle_distances(a, b, kernel="exact").distance
        k = int(np.argmin(d))
        if d[k] < best:
            best, where = float(d[k]), (start + k // len(tri_b), k % len(tri_b))
    return best, where


class Peers:
    """BVH models of the meshes for Coal and python-fcl (built once, not timed)."""

    def __init__(self, coal, fcl, meshes: dict) -> None:
        self.coal, self.fcl = coal, fcl
        self.coal_models, self.fcl_models = {}, {}
        for name, mesh in meshes.items():
            verts, faces = np.asarray(mesh.vertices, np.float64), np.asarray(mesh.faces, np.int64)
            if coal:
                model = coal.BVHModelOBBRSS()
                model.beginModel(mesh.n_faces, len(verts))
                model.addVertices(verts)
                model.addTriangles(faces)
                model.endModel()
                self.coal_models[name] = model
            if fcl:
                model = fcl.BVHModel()  # fcl::BVHModel<OBBRSS>
                model.beginModel(len(verts), mesh.n_faces)
                model.addSubModel(verts, faces)
                model.endModel()
                self.fcl_models[name] = model

    def contact_rows(self, a, b, pa, pb, capacity) -> list[dict]:
        rows = []
        if self.coal:
            coal = self.coal
            ma, mb = self.coal_models[a], self.coal_models[b]
            ta, tb = (coal.Transform3s(p.rotation, p.position) for p in (pa, pb))
            for label, flag in (("+contacts", "CONTACT"), ("pairs only", "NO_REQUEST")):
                # room for every triangle pair: the traversal stops at num_max_contacts
                request = coal.CollisionRequest(getattr(coal.CollisionRequestFlag, flag), capacity)
                request.security_margin = MARGIN

                def query(request=request):
                    result = coal.CollisionResult()
                    coal.collide(ma, ta, mb, tb, request, result)
                    return result

                pairs = pair_set((c.b1, c.b2) for c in query().getContacts())
                rows.append(
                    {
                        "peer": "coal",
                        "query": f"collide margin {MARGIN:g} {label}",
                        "pairs": pairs,
                        "timed": query,
                    }
                )
        if self.fcl:
            fcl = self.fcl
            oa = fcl.CollisionObject(self.fcl_models[a], fcl.Transform(pa.rotation, pa.position))
            ob = fcl.CollisionObject(self.fcl_models[b], fcl.Transform(pb.rotation, pb.position))
            request = fcl.CollisionRequest(num_max_contacts=capacity, enable_contact=False)

            def collide():
                result = fcl.CollisionResult()
                fcl.collide(oa, ob, request, result)
                return result

            rows.append(
                {
                    "peer": "fcl",
                    "query": "collide, no margin (d <= 0)",
                    "pairs": pair_set((c.b1, c.b2) for c in collide().contacts),
                    "timed": collide,
                }
            )
        return rows

    def distance_rows(self, a, b, pa, pb) -> list[dict]:
        rows = []
        if self.coal:
            coal = self.coal
            ma, mb = self.coal_models[a], self.coal_models[b]
            ta, tb = (coal.Transform3s(p.rotation, p.position) for p in (pa, pb))

            def coal_distance():
                result = coal.DistanceResult()
                coal.distance(ma, ta, mb, tb, coal.DistanceRequest(True), result)
                return result

            r = coal_distance()
            rows.append(
                {
                    "peer": "coal",
                    "query": "distance, nearest points",
                    "distance": float(r.min_distance),
                    "faces": (int(r.b1), int(r.b2)),
                    "points": (r.getNearestPoint1(), r.getNearestPoint2()),
                    "timed": coal_distance,
                }
            )
        if self.fcl:
            fcl = self.fcl
            oa = fcl.CollisionObject(self.fcl_models[a], fcl.Transform(pa.rotation, pa.position))
            ob = fcl.CollisionObject(self.fcl_models[b], fcl.Transform(pb.rotation, pb.position))

            def fcl_distance():
                result = fcl.DistanceResult()
                fcl.distance(oa, ob, fcl.DistanceRequest(enable_nearest_points=True), result)
                return result

            r = fcl_distance()
            rows.append(
                {
                    "peer": "fcl",
                    "query": "distance, nearest points",
                    "distance": float(r.min_distance),
                    "faces": (int(r.b1), int(r.b2)),
                    "points": tuple(r.nearest_points),
                    "timed": fcl_distance,
                }
            )
        return rows


def run_case(case, gap, meshes, trees, peers) -> dict:
    """One case at one gap: oracles, every query's result against them, and each query as a
    callable (``timed``) for :func:`time_all`."""
    label, a, b, _, place = case
    position, orientation = place(gap)
    pa, pb = Pose.identity(), Pose(position, orientation)
    mesh_a, mesh_b = meshes[a], meshes[b]
    tree_a, tree_b = trees[a][0], trees[b][0]
    tri_a, tri_b = posed(mesh_a, pa), posed(mesh_b, pb)
    exact = {"kernel": "exact", "hierarchy": False, "precision": "float64"}
    oracle = pair_set(find_contacts(tree_a, pa, tree_b, pb, **exact).pairs)
    touching = pair_set(find_contacts(trees[a][1], pa, trees[b][1], pb, **exact).pairs)
    d_oracle, where = distance_oracle(tri_a, tri_b)

    contacts = []
    for precision in ("float64", "float32"):

        def ours(precision=precision):
            return find_contacts(tree_a, pa, tree_b, pb, precision=precision)

        contacts.append(
            {
                "peer": "mrdem",
                "query": f"find_contacts (hybrid, {precision})",
                "pairs": pair_set(ours().pairs),
                "timed": ours,
            }
        )
    contacts += peers.contact_rows(a, b, pa, pb, mesh_a.n_faces * mesh_b.n_faces)
    for row in contacts:
        found = row.pop("pairs")
        row.update(n_pairs=len(found), **compare(found, oracle))
        mismatch = pair_distances(tri_a, tri_b, (found - oracle) | (oracle - found))
        row["mismatch_d"] = span(mismatch)
        if row["peer"] == "fcl":
            row["vs_touching"] = compare(found, touching)
            mismatch = pair_distances(tri_a, tri_b, (found - touching) | (touching - found))
            row["vs_touching"]["mismatch_d"] = span(mismatch)

    def ours_distance():
        return mesh_distance(tree_a, pa, tree_b, pb)

    r = ours_distance()
    distances = [
        {
            "peer": "mrdem",
            "query": "mesh_distance (float64)",
            "distance": r.distance,
            "faces": tuple(int(f) for f in r.faces),
            "points": (r.point_a, r.point_b),
            "timed": ours_distance,
            "node_pairs": r.node_pairs,
            "probes": r.probes,
        }
    ]
    distances += peers.distance_rows(a, b, pa, pb)
    for row in distances:
        p, q = (np.asarray(x, np.float64) for x in row.pop("points"))
        face_d = pair_distances(tri_a, tri_b, [row["faces"]])
        row.update(
            error=abs(row["distance"] - d_oracle),
            face_pair_d=float(face_d[0]),  # exact distance of the returned face pair
            points_error=abs(float(np.linalg.norm(q - p)) - row["distance"]),
        )
    return {
        "case": label,
        "meshes": [a, b],
        "faces": [mesh_a.n_faces, mesh_b.n_faces],
        "gap": gap,
        "pose_b": [list(map(float, position)), list(map(float, orientation))],  # (x, q wxyz)
        "oracle_pairs": len(oracle),
        "touching_pairs": len(touching),
        "oracle_distance": d_oracle,
        "oracle_faces": list(where),
        "contacts": contacts,
        "distance": distances,
    }


def time_all(results: list[dict], repeat: int, passes: int) -> None:
    """Time every row's query: best of ``repeat`` calls in each of ``passes`` passes over all
    cases, the minimum kept (samples spread over the run, so that a burst of load elsewhere
    on the machine spoils one pass of a row, not all), then the ratio to our row."""
    for _ in range(passes):
        for case in results:
            for row in case["contacts"] + case["distance"]:
                seconds = best_time(row["timed"], repeat)
                row["us"] = min(row.get("us", np.inf), seconds * 1e6)
    for case in results:
        for rows in (case["contacts"], case["distance"]):
            for row in rows:
                del row["timed"]
                row["ratio"] = row["us"] / rows[0]["us"]  # peer time / our time


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=10, help="best of N calls per pass")
    parser.add_argument("--passes", type=int, default=5, help="timing passes over all cases")
    parser.add_argument("--quick", action="store_true", help="skip the 5,120-triangle case")
    args = parser.parse_args()
    coal, fcl = optional("coal", "coal"), optional("fcl", "python-fcl")
    engine.warmup()
    cases = [c for c in CASES if not (args.quick and c[1] == "ico5120")]
    names = sorted({c[1] for c in cases} | {c[2] for c in cases})
    meshes = {name: MESHES[name][1]() for name in names}
    trees = {name: (build_tree(m, EPSILON), build_tree(m, 0.0)) for name, m in meshes.items()}
    peers = Peers(coal, fcl, meshes)
    results = []
    for case in cases:
        for gap in case[3]:
            results.append(run_case(case, gap, meshes, trees, peers))
    time_all(results, args.repeat, args.passes)
    for case in results:
        report(case)
    versions = library_versions(coal, fcl)
    setup = {
        "meshes": {name: MESHES[name][0] for name in names},
        "epsilon": EPSILON,
        "margin": MARGIN,
        "repeat": args.repeat,
        "passes": args.passes,
        "timer": "min over passes of best_time (min of N after one warm-up), one thread",
        "pose_a": "identity",
    }
    OUT.mkdir(exist_ok=True)
    (OUT / "peers.json").write_text(
        json.dumps({"versions": versions, "setup": setup, "cases": results}, indent=2)
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


def report(c: dict) -> None:
    """Print one case at one gap: contacts, then distances."""
    print(
        f"\n{c['case']} ({c['faces'][0]} x {c['faces'][1]} triangles), gap {c['gap']:+g}: "
        f"oracle {c['oracle_pairs']} pairs with d <= {MARGIN:g} "
        f"({c['touching_pairs']} with d <= 0), "
        f"min d = {c['oracle_distance']:.17g}"
    )
    print(f"  {'query':<44} {'pairs':>6} {'missed':>6} {'extra':>5} {'us':>10} {'x ours':>7}")
    for r in c["contacts"]:
        d = r["mismatch_d"]
        note = f"mismatched d in [{d[0]:.17g}, {d[1]:.17g}]" if d else ""
        if "vs_touching" in r:
            t = r["vs_touching"]
            note += f"  vs d <= 0: missed {t['missed']} extra {t['extra']}"
            if t["mismatch_d"]:
                note += f" (d in [{t['mismatch_d'][0]:.3g}, {t['mismatch_d'][1]:.3g}])"
        print(
            f"  {r['peer'] + ' ' + r['query']:<44} {r['n_pairs']:6d} {r['missed']:6d} "
            f"{r['extra']:5d} {r['us']:10.1f} {r['ratio']:7.2f}  {note}"
        )
    print(f"  {'query':<44} {'distance':>22} {'|d - oracle|':>12} {'us':>10} {'x ours':>7}")
    for r in c["distance"]:
        print(
            f"  {r['peer'] + ' ' + r['query']:<44} {r['distance']:22.17g} {r['error']:12.2e} "
            f"{r['us']:10.1f} {r['ratio']:7.2f}  faces {r['faces']} (d {r['face_pair_d']:.17g})"
        )


if __name__ == "__main__":
    main()
