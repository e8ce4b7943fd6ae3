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
  (gap 0.2: centred, every point of the hole's rim equally near), gaps 0.2, 0.02, −0.01, −0.1;
* real meshes from ``../shared/meshes/`` (:func:`engine.load_mesh`, repaired; skipped when
  the folder is absent), ε = 1 mm: lemon × bread (528 × 104 triangles), can × milk (956 ×
  242, both dirty), panda_link1 against itself (12,516) and ur5e_upperarm × iiwa_link7
  (34,119 × 42,616, skipped by ``--quick``). B gets a seeded uniform random rotation and
  direction (:func:`realmeshes.near_pose`): bisection on our exact ε = 0 search finds where
  the meshes first touch along the ray, then B moves ``gap`` further out (far 50 mm, near
  touching 1 mm) or in (slight overlap −1 mm, deeper −10 mm).

Oracles: our flat exact search (every triangle pair, exact kernel, float64) for contacts,
with ε = 0.01 and with ε = 0 (intersecting pairs); for the distance, the exact kernel on
every face pair (chunks of paired calls), its minimum and a face pair attaining it. Above
``FLAT_BUDGET`` face pairs (the two largest real pairs) the contact oracle is the exact
kernel through the hierarchy (equal to the flat search by the tests of Lemma 1), and the
distance oracle is that search at leaf ε = d/2, d the exact distance of the face pair our
``mesh_distance`` returned: every face pair within d is then a contact, so their minimum is
the minimum over all face pairs.

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
Every row prints its time as a ratio to Coal's (``collide`` with ``CONTACT`` for contacts,
``distance`` for distances) from the same run; with matplotlib, ``bench-results/peers.png``
plots our ratios against the meshes' sizes, one colour per gap.
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
from realmeshes import near_pose  # noqa: E402

import engine  # noqa: E402
from engine import (  # noqa: E402
    Pose,
    build_tree,
    find_contacts,
    load_mesh,
    mesh_distance,
    shapes,
    triangle_distances,
)

OUT = ROOT / "bench-results"
EPSILON = 0.01
QUARTER_X = [np.cos(np.pi / 4), np.sin(np.pi / 4), 0.0, 0.0]  # 90° about x
ORACLE_CHUNK = 1 << 20  # face pairs per paired call of the distance oracle
FLAT_BUDGET = 20_000_000  # face pairs up to which the oracles visit every pair
SHARED = ROOT.parent / "shared" / "meshes"
REAL_EPSILON = 0.001  # metres: a 2 mm margin on parts of 4 to 90 cm
REAL_FILES = {
    "lemon": "lemon.stl",
    "bread": "bread.stl",
    "can": "can.stl",
    "milk": "milk.stl",
    "panda_link1": "panda_link1.stl",
    "ur5e_upperarm": "ur5e_upperarm_visual.obj",
    "iiwa_link7": "iiwa_link7_visual.obj",
}
# name: (description, factory, leaf ε)
MESHES = {
    **{
        f"ico{20 * 4**k}": (f"icosphere({k})", lambda k=k: shapes.icosphere(k), EPSILON)
        for k in (1, 2, 3, 4)
    },
    "torus": ("torus(1, 0.3, 32, 16)", lambda: shapes.torus(1.0, 0.3, 32, 16), EPSILON),
    "ball": ("icosphere(3, radius=0.5)", lambda: shapes.icosphere(3, radius=0.5), EPSILON),
    **{
        name: (f"load_mesh({file!r})", lambda f=file: load_mesh(SHARED / f), REAL_EPSILON)
        for name, file in REAL_FILES.items()
    },
}
SPHERE_GAPS = (1.0, 0.02, -0.01, -0.1)
REAL_GAPS = (0.05, 0.001, -0.001, -0.01)
GAP_KINDS = ("far", "near touching", "slight overlap", "deeper overlap")  # by index in gaps
SEED = 15


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
    # real meshes: B's pose is drawn once the trees exist (real_placement)
    ("lemon x bread", "lemon", "bread", REAL_GAPS, None),
    ("can x milk", "can", "milk", REAL_GAPS, None),
    ("panda_link1 x panda_link1", "panda_link1", "panda_link1", REAL_GAPS, None),
    ("ur5e_upperarm x iiwa_link7", "ur5e_upperarm", "iiwa_link7", REAL_GAPS, None),
]
BIG = {"ico5120", "iiwa_link7"}  # cases with these meshes are skipped by --quick


def real_placement(index: int, case, meshes: dict, trees: dict):
    """``place(gap)`` for a real-mesh case: B at a seeded random rotation and direction,
    ``gap`` beyond the point where the meshes first touch along that ray (bisection on our
    exact search at ε = 0, A at the identity)."""
    _, a, b, gaps, _ = case
    touching_a, touching_b = trees[a][1], trees[b][1]
    margin = trees[a][0].leaf_epsilon + trees[b][0].leaf_epsilon

    def intersects(pose_b: Pose) -> bool:
        found = find_contacts(touching_a, Pose.identity(), touching_b, pose_b, kernel="exact")
        return len(found.pairs) > 0

    def place(gap: float) -> tuple:
        rng = np.random.default_rng([SEED, index, gaps.index(gap)])
        _, pose_b, _ = near_pose(intersects, meshes[a], meshes[b], margin, rng, gap / margin)
        return pose_b.position, pose_b.orientation

    return place


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


def bounded_distance_oracle(trees, pa, pb, tri_a, tri_b, upper: float) -> tuple:
    """Minimum exact distance over every face pair, given an ``upper`` bound on it (the exact
    distance of some face pair), and a pair attaining it: every pair within ``upper`` is a
    contact of the exact search at leaf ε = upper / 2 (rounded up), so the minimum over those
    contacts is the minimum over all pairs."""
    epsilon = 0.5 * upper * (1 + 1e-9)
    tree_a, tree_b = (t.with_leaf_epsilon(epsilon) for t in trees)
    pairs = find_contacts(tree_a, pa, tree_b, pb, kernel="exact").pairs
    d = triangle_distances(tri_a[pairs[:, 0]], tri_b[pairs[:, 1]], kernel="exact").distance
    k = int(np.argmin(d))
    return float(d[k]), (int(pairs[k, 0]), int(pairs[k, 1]))


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

    def contact_rows(self, a, b, pa, pb, capacity, margin) -> list[dict]:
        rows = []
        if self.coal:
            coal = self.coal
            ma, mb = self.coal_models[a], self.coal_models[b]
            ta, tb = (coal.Transform3s(p.rotation, p.position) for p in (pa, pb))
            for label, flag in (("+contacts", "CONTACT"), ("pairs only", "NO_REQUEST")):
                # room for every triangle pair: the traversal stops at num_max_contacts
                request = coal.CollisionRequest(getattr(coal.CollisionRequestFlag, flag), capacity)
                request.security_margin = margin

                def query(request=request):
                    result = coal.CollisionResult()
                    coal.collide(ma, ta, mb, tb, request, result)
                    return result

                pairs = pair_set((c.b1, c.b2) for c in query().getContacts())
                rows.append(
                    {
                        "peer": "coal",
                        "query": f"collide margin {margin:g} {label}",
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
    margin = tree_a.leaf_epsilon + tree_b.leaf_epsilon
    flat = mesh_a.n_faces * mesh_b.n_faces <= FLAT_BUDGET
    exact = {"kernel": "exact", "hierarchy": not flat, "precision": "float64"}
    oracle = pair_set(find_contacts(tree_a, pa, tree_b, pb, **exact).pairs)
    touching = pair_set(find_contacts(trees[a][1], pa, trees[b][1], pb, **exact).pairs)
    if flat:
        d_oracle, where = distance_oracle(tri_a, tri_b)
    else:
        found = mesh_distance(tree_a, pa, tree_b, pb).faces
        upper = float(pair_distances(tri_a, tri_b, [tuple(found)])[0])
        d_oracle, where = bounded_distance_oracle(
            (trees[a][1], trees[b][1]), pa, pb, tri_a, tri_b, upper
        )

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
    contacts += peers.contact_rows(a, b, pa, pb, mesh_a.n_faces * mesh_b.n_faces, margin)
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
        "gap_kind": GAP_KINDS[case[3].index(gap)],
        "margin": margin,
        "oracle": "flat" if flat else "exact kernel through the hierarchy",
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
    on the machine spoils one pass of a row, not all), then the ratio to Coal's row (its
    ``collide`` with ``CONTACT``, its ``distance``; our first row without Coal)."""
    for _ in range(passes):
        for case in results:
            for row in case["contacts"] + case["distance"]:
                seconds = best_time(row["timed"], repeat)
                row["us"] = min(row.get("us", np.inf), seconds * 1e6)
    for case in results:
        for rows in (case["contacts"], case["distance"]):
            coal = [r for r in rows if r["peer"] == "coal"]
            reference = coal[0] if coal else rows[0]  # collide with CONTACT; distance
            for row in rows:
                del row["timed"]
                row["ratio"] = row["us"] / reference["us"]  # time / Coal's (else ours)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=10, help="best of N calls per pass")
    parser.add_argument("--passes", type=int, default=5, help="timing passes over all cases")
    parser.add_argument(
        "--quick", action="store_true", help="skip the 5,120-triangle and iiwa_link7 cases"
    )
    parser.add_argument("--no-real", action="store_true", help="skip the real meshes")
    parser.add_argument("--only", nargs="+", metavar="TEXT", help="cases whose label contains one")
    args = parser.parse_args()
    coal, fcl = optional("coal", "coal"), optional("fcl", "python-fcl")
    engine.warmup()
    real = not args.no_real and SHARED.is_dir()
    if not args.no_real and not real:
        print(f"note: {SHARED} is absent; the real-mesh cases are skipped")
    cases = [
        c
        for c in CASES
        if not (args.quick and {c[1], c[2]} & BIG)
        and (real or c[1] not in REAL_FILES)
        and (not args.only or any(text in c[0] for text in args.only))
    ]
    names = sorted({c[1] for c in cases} | {c[2] for c in cases})
    meshes = {name: MESHES[name][1]() for name in names}
    trees = {
        name: (build_tree(m, MESHES[name][2]), build_tree(m, 0.0)) for name, m in meshes.items()
    }
    cases = [
        c if c[4] else (*c[:4], real_placement(i, c, meshes, trees)) for i, c in enumerate(cases)
    ]
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
        "epsilon": {name: MESHES[name][2] for name in names},
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
    plot(results, OUT / "peers.png")


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
        f"oracle {c['oracle_pairs']} pairs with d <= {c['margin']:g} "
        f"({c['touching_pairs']} with d <= 0), "
        f"min d = {c['oracle_distance']:.17g}"
    )
    print(f"  {'query':<44} {'pairs':>6} {'missed':>6} {'extra':>5} {'us':>10} {'x Coal':>7}")
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
    print(f"  {'query':<44} {'distance':>22} {'|d - oracle|':>12} {'us':>10} {'x Coal':>7}")
    for r in c["distance"]:
        print(
            f"  {r['peer'] + ' ' + r['query']:<44} {r['distance']:22.17g} {r['error']:12.2e} "
            f"{r['us']:10.1f} {r['ratio']:7.2f}  faces {r['faces']} (d {r['face_pair_d']:.17g})"
        )


def plot(results: list[dict], target: Path) -> None:
    """Our time over Coal's against the meshes' triangles (F_a + F_b), margin contacts and
    distance side by side; colour: the gap, marker: icospheres, tori or real meshes."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        print("matplotlib missing: no PNG")
        return
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2), sharey=True)
    for ax, key, title in zip(
        axes,
        ("contacts", "distance"),
        ("margin contacts (find_contacts)", "mesh_distance"),
        strict=True,
    ):
        for c in results:
            ours = next(r for r in c[key] if r["peer"] == "mrdem")
            if not any(r["peer"] == "coal" for r in c[key]):
                continue
            kind = GAP_KINDS.index(c["gap_kind"])
            family = "real" if c["meshes"][0] in REAL_FILES else c["case"].split(",")[0]
            marker = {"icospheres": "o", "tori": "^", "torus": "v", "real": "s"}.get(family, "o")
            ax.scatter(sum(c["faces"]), ours["ratio"], color=f"C{kind}", marker=marker, s=28)
        ax.axhline(1.0, color="k", lw=0.8)
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("triangles in the pair (F_a + F_b)")
        ax.set_title(title, fontsize=10)
    axes[0].set_ylabel("our time / Coal's (one run)")
    handles = [
        plt.Line2D([], [], ls="", marker="o", color=f"C{k}", label=name)
        for k, name in enumerate(GAP_KINDS)
    ] + [
        plt.Line2D([], [], ls="", marker=m, color="grey", label=name)
        for m, name in (("o", "icospheres"), ("^", "tori"), ("v", "sphere in torus"), ("s", "real"))
    ]
    axes[1].legend(handles=handles, fontsize=8, loc="best")
    fig.tight_layout()
    fig.savefig(target, dpi=90)
    print(f"wrote {target}")


if __name__ == "__main__":
    main()
