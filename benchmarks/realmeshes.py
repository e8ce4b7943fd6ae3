"""Real meshes end to end beside Coal: loading and repair, tree builds (time, peak memory,
statistics) and margin contacts on random near poses (issue 13, point 7).

Run: ``.venv/bin/python benchmarks/realmeshes.py [--quick] [--only NAME ...] [--poses N]
[--passes P] [--build-repeats R] [--no-contacts]`` (needs Coal, ``pip install -e .[bench]``,
and ``../shared/meshes/``). Prints three tables, writes ``bench-results/realmeshes.json``.

Meshes: every STL/OBJ of ``../shared/meshes/`` through :func:`engine.load_mesh` with its
defaults, which repair (``mesh.repair.summary()`` is reported; a mesh they reject is counted
as rejected, its message shown, and left out),
and real meshes subdivided (:func:`subdivide_to`: midpoint split, whole levels, then a spread
subset of faces) to ≥ 50k (panda_link1 ×4), ≥ 125k (ur5e_upperarm_visual ×4) and ≥ 1M
triangles (iiwa_link7_visual ×16, then 1 face in 6.4 split once more; ``--quick`` skips it).
``--only`` keeps the named meshes and the contact pairs among them.

Builds, each in a fresh subprocess of this script, ours then Coal's per mesh:

* ours: ``build_tree(mesh, ε)``, ε = 1 % of the mesh's bounding-box diagonal, branching 8,
  after warm-up builds on icospheres in the same process (Numba compilation and cache loading
  excluded); Numba's default thread count;
* Coal: ``BVHModelOBBRSS``: ``beginModel``, ``addVertices``, ``addTriangles``, ``endModel``
  (the numpy entry points; ``addSubModel`` takes only ``StdVec_Vec3s``), one thread;
* time: the minimum over ``--build-repeats`` builds in the subprocess (3, quick 1; always 1
  from 200k triangles up); peak memory: ``malloc_trim``, then ``VmHWM`` reset
  (``/proc/self/clear_refs``) after loading the mesh and warming up, and the first build's
  ``VmHWM`` minus ``VmRSS`` before it: what the build adds at its peak, its result included.

Margin contacts, in this process on the trees the build subprocesses saved: every mesh up to
200k triangles against itself and the pairs in ``CROSS``. A at the identity; B turned by a
uniform random rotation, its box centre on a uniform random ray from A's at the distance where
the meshes stop intersecting (bisection on ``coal.collide``) plus δ ~ U(−2, 1)·margin, margin
= ε_a + ε_b (so d ≤ margin somewhere: every pose has contacts). Ours: ``find_contacts``
(hybrid, float64); Coal: ``coal.collide``, ``security_margin`` = margin, ``CONTACT``,
``num_max_contacts`` = F_a·F_b. Pairs compared pair for pair; a disagreement is a *tie* when
the pair's exact distance is within ``TIE``·margin of the margin. Where F_a·F_b ≤
``--flat-budget`` both are compared with our flat exact search too. Timing: ``--passes``
passes over every pose of every pair, ours then Coal per pose (best of 5 calls under 2 ms,
else one), the minimum (and median) over passes kept per pose; a pair's ratio is ours / Coal
of the sums over its poses.
"""

from __future__ import annotations

import argparse
import contextlib
import ctypes
import gc
import importlib.metadata as metadata
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

OUT = ROOT / "bench-results"
SHARED = ROOT.parent / "shared" / "meshes"
EPSILON_FRACTION = 0.01  # ε = 1 % of the bounding-box diagonal
BRANCHING = 8
TIE = 1e-9  # |d - margin| <= TIE * margin: a tie at the margin
BIG = 200_000  # triangles from which a build subprocess builds once
# (name, source mesh, target triangles): midpoint subdivisions of real meshes
GENERATED = [
    ("panda_link1_x4", "panda_link1", 50_000),
    ("ur5e_upperarm_visual_x4", "ur5e_upperarm_visual", 125_000),
    ("iiwa_link7_visual_1M", "iiwa_link7_visual", 1_000_000),
]
CROSS = [
    ("can", "lemon"),
    ("milk", "cereal"),
    ("bottle", "bread"),
    ("handles", "can"),
    ("panda_link1", "ur5e_upperarm_visual"),
    ("spot_body", "iiwa_link7_visual"),
    ("ur5e_upperarm_visual_x4", "panda_link1_x4"),
    ("iiwa_link7_visual_1M", "can"),
    ("iiwa_link7_visual_1M", "milk"),
]
# self pairs up to this many triangles: 1M x 1M near poses give up to 1.2e7 pairs (Coal 26 s);
# 1M x panda_link1 up to 3.5e6 (6.5 s); panda_link1_x4 x itself up to 8e5 (1.4 s)
SELF_LIMIT = 200_000


# ---------------------------------------------------------------------- build subprocesses
def _status() -> dict[str, int]:
    """VmRSS and VmHWM of this process in bytes."""
    out = {}
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith(("VmRSS:", "VmHWM:")):
            key, value = line.split(":")
            out[key] = int(value.split()[0]) * 1024
    return out


def _reset_peak() -> bool:
    try:
        Path("/proc/self/clear_refs").write_text("5")  # resets VmHWM to VmRSS (Linux >= 4.0)
        return True
    except OSError:
        return False


def _measured(build, repeat: int) -> dict:
    """Time ``repeat`` calls of ``build`` (minimum) and the peak memory of the first."""
    gc.collect()
    with contextlib.suppress(OSError, AttributeError):  # free heap memory back to the system,
        ctypes.CDLL("libc.so.6").malloc_trim(0)  # so that the baseline holds none to reuse
    reset = _reset_peak()
    base = _status()["VmRSS"]
    seconds, first = [], None
    for _ in range(repeat):
        start = time.perf_counter()
        result = build()
        seconds.append(time.perf_counter() - start)
        if first is None:
            first, peak = result, _status()["VmHWM"] - base
        del result
    return dict(
        seconds=min(seconds), all_seconds=seconds, peak_bytes=peak, peak_reset=reset, first=first
    )


def coal_model(coal, vertices: np.ndarray, faces: np.ndarray):
    """Coal's OBBRSS BVH of ``vertices (V, 3) float64`` and ``faces (F, 3) int64`` through the
    numpy entry points (``addSubModel`` takes only ``StdVec_Vec3s`` / ``StdVec_Triangle``)."""
    model = coal.BVHModelOBBRSS()
    model.beginModel(len(faces), len(vertices))
    model.addVertices(vertices)
    model.addTriangles(faces)
    model.endModel()
    return model


def worker(args) -> None:
    """Body of a build subprocess: prints one JSON line."""
    with np.load(args.mesh) as data:
        vertices, faces = data["vertices"], data["faces"]
    if args.worker == "coal":
        import coal

        v, f = np.ascontiguousarray(vertices, np.float64), np.ascontiguousarray(faces, np.int64)
        coal_model(coal, np.eye(3), np.array([[0, 1, 2]]))  # warm-up
        row = _measured(lambda: coal_model(coal, v, f), args.repeat)
        model = row.pop("first")
        row.update(model_bytes=int(model.memUsage(False)), bvs=int(model.getNumBVs()))
    else:
        from engine import Mesh, build_tree, shapes

        mesh = Mesh(vertices, faces)
        if not np.array_equal(mesh.faces, faces):  # the parent's faces index the contacts
            raise SystemExit("the mesh changed when rebuilt from its arrays")
        for k in (3, 5):  # 1,280 then 20,480 triangles, the second only if builds are fast
            start = time.perf_counter()
            build_tree(shapes.icosphere(k), 0.01, BRANCHING)
            if time.perf_counter() - start > 1.0:
                break
        row = _measured(lambda: build_tree(mesh, args.epsilon, BRANCHING), args.repeat)
        tree = row.pop("first")
        s = tree.stats
        stats = dict(levels=len(s.nodes_per_level), nodes=len(tree), surrogates=s.surrogates)
        row.update(stats, root_epsilon=s.root_epsilon, volume_ratio=s.volume_ratio)
        if args.tree_out:
            tree.save(args.tree_out)
    print(json.dumps(row))


def run_worker(kind: str, mesh_file: Path, epsilon: float, repeat: int, tree_out, timeout):
    cmd = [sys.executable, __file__, "--worker", kind, "--mesh", str(mesh_file)]
    cmd += ["--epsilon", repr(epsilon), "--repeat", str(repeat)]
    cmd += ["--tree-out", str(tree_out)] if tree_out else []
    try:
        done = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, check=False)
    except subprocess.TimeoutExpired:
        return {"error": f"timed out after {timeout} s"}
    if done.returncode != 0:
        return {"error": done.stderr.strip().splitlines()[-1] if done.stderr else "failed"}
    return json.loads(done.stdout.strip().splitlines()[-1])


# ---------------------------------------------------------------------- meshes
def make_mesh(vertices, faces):
    from engine import Mesh

    return Mesh(vertices, faces)  # repaired by default


def load_real(path: Path) -> tuple:
    """(mesh, row): ``load_mesh`` with its defaults (repair); mesh None if it rejects."""
    from engine import InvalidMeshError, load_mesh

    row = {"name": path.stem, "file": path.name, "rejected": None}
    start = time.perf_counter()
    try:
        mesh = load_mesh(path)
    except InvalidMeshError as exc:
        row["rejected"] = str(exc)
        return None, row | {"load_seconds": time.perf_counter() - start, "repair": None}
    row["load_seconds"] = time.perf_counter() - start
    return mesh, row | {"repair": repair_info(mesh)}


def repair_info(mesh):
    """``mesh.repair.summary()``: what load_mesh's repair changed."""
    return mesh.repair.summary()


def subdivide_to(mesh, target: int):
    """Midpoint subdivision of ``mesh`` to at least ``target`` triangles: whole levels while
    4·F ≤ 1.1·target, then an evenly spread subset of faces once more (T-junctions; the
    surface is unchanged)."""
    import trimesh

    v, f = np.asarray(mesh.vertices), np.asarray(mesh.faces, np.int64)
    while 4 * len(f) <= 1.1 * target:
        v, f = trimesh.remesh.subdivide(v, f)
    mesh = make_mesh(v, f)
    while mesh.n_faces < target:  # again if repair dropped faces too small to keep
        m = -(-(target - mesh.n_faces) // 3)
        some = np.linspace(0, mesh.n_faces - 1, m).astype(int)
        mesh = make_mesh(*trimesh.remesh.subdivide(mesh.vertices, mesh.faces, face_index=some))
    return mesh


def mesh_rows(args) -> tuple[dict, list[dict]]:
    meshes, rows = {}, []
    for path in sorted(p for p in SHARED.iterdir() if p.suffix.lower() in (".stl", ".obj")):
        mesh, row = load_real(path)
        rows.append(row)
        if mesh is not None:
            meshes[path.stem] = mesh
    for name, source, target in GENERATED:
        named = bool(args.only) and name in args.only
        if (args.only and not named) or (args.quick and target >= 1_000_000 and not named):
            continue
        start = time.perf_counter()
        meshes[name] = subdivide_to(meshes[source], target)
        gen = {"name": name, "file": f"{source} subdivided to >= {target:,}", "rejected": None}
        gen["load_seconds"] = time.perf_counter() - start
        rows.append(gen | {"repair": repair_info(meshes[name])})
    keep = set(args.only or meshes)
    unknown = keep - set(meshes)
    if unknown:
        sys.exit(f"unknown mesh(es) {sorted(unknown)}; known: {sorted(meshes)}")
    for row in rows:
        m = meshes.get(row["name"])
        if m is None:  # rejected by load_mesh
            row.update(triangles=0, vertices=0, diameter=0.0, closed=None)
            continue
        row.update(triangles=m.n_faces, vertices=m.n_vertices, diameter=m.diameter)
        row["closed"] = bool(m.is_closed)
    rows = [r for r in rows if r["name"] in keep]
    return {n: m for n, m in meshes.items() if n in keep}, rows


# ---------------------------------------------------------------------- builds
def build_rows(meshes: dict, tmp: Path, args) -> list[dict]:
    rows = []
    for name, mesh in meshes.items():
        mesh_file = tmp / f"{name}.npz"
        np.savez(mesh_file, vertices=mesh.vertices, faces=mesh.faces)
        eps = EPSILON_FRACTION * mesh.diameter
        repeat = 1 if mesh.n_faces >= BIG else args.build_repeats
        tree_file = tmp / f"{name}.tree.npz"
        ours = run_worker("ours", mesh_file, eps, repeat, tree_file, args.build_timeout)
        peer = run_worker("coal", mesh_file, eps, repeat, None, args.build_timeout)
        row = dict(name=name, triangles=mesh.n_faces, epsilon=eps, repeat=repeat, ours=ours)
        row.update(coal=peer, tree=None if "error" in ours else str(tree_file))
        if "error" not in ours and "error" not in peer:
            row["time_ratio"] = ours["seconds"] / peer["seconds"]
            row["memory_ratio"] = ours["peak_bytes"] / max(peer["peak_bytes"], 1)
        rows.append(row)
        print_build(row, mesh.diameter)
    return rows


def print_build(r: dict, diameter: float) -> None:
    o, c = r["ours"], r["coal"]
    mib = 1 << 20
    if "error" in o or "error" in c:
        side = [
            x.get("error") or f"{x['seconds']:.3f} s, {x['peak_bytes'] / mib:.1f} MiB"
            for x in (o, c)
        ]
        print(f"  {r['name']:<26} {r['triangles']:>9,}  ours: {side[0]}; coal: {side[1]}")
        return
    print(
        f"  {r['name']:<26} {r['triangles']:>9,} {o['seconds']:9.3f} {c['seconds']:8.3f}"
        f" {r['time_ratio']:7.1f} {o['peak_bytes'] / mib:9.1f} {c['peak_bytes'] / mib:8.1f}"
        f" {r['memory_ratio']:6.1f} {o['levels']:6d} {o['nodes']:10,}"
        f" {o['root_epsilon'] / diameter:8.3f} {o['volume_ratio']:7.3f}"
    )


# ---------------------------------------------------------------------- contacts
class Coal:
    """Coal models of the meshes (built once, not timed) and the queries on them."""

    def __init__(self, coal, meshes: dict) -> None:
        self.coal, self.models = coal, {}
        for name, mesh in meshes.items():
            v = np.ascontiguousarray(mesh.vertices, np.float64)
            self.models[name] = coal_model(coal, v, mesh.faces.astype(np.int64))

    def query(self, a, b, pa, pb, margin: float, capacity: int, flag: str = "CONTACT"):
        coal = self.coal
        ma, mb = self.models[a], self.models[b]
        ta, tb = (coal.Transform3s(p.rotation, p.position) for p in (pa, pb))
        request = coal.CollisionRequest(getattr(coal.CollisionRequestFlag, flag), capacity)
        request.security_margin = margin

        def collide():
            result = coal.CollisionResult()
            coal.collide(ma, ta, mb, tb, request, result)
            return result

        return collide

    def intersect(self, a, b, pa, pb) -> bool:
        return self.query(a, b, pa, pb, 0.0, 1, "NO_REQUEST")().isCollision()


def near_pose(intersects, mesh_a, mesh_b, margin, rng, delta=None):
    """A random pose of B near A (see the module docstring) and its δ / margin.

    ``intersects(pose_b) -> bool`` says whether the meshes intersect with A at the identity;
    ``delta`` (in margins) is drawn from U(−2, 1) unless given."""
    from engine import Pose

    ca, cb = mesh_a.bounds.mean(axis=0), mesh_b.bounds.mean(axis=0)
    for _ in range(20):
        q, u = rng.normal(size=4), rng.normal(size=3)  # uniform rotation and direction
        q, u = q / np.linalg.norm(q), u / np.linalg.norm(u)
        rot = Pose([0, 0, 0], q).rotation

        def at(s, q=q, u=u, rot=rot):
            return Pose(ca + s * u - rot @ cb, q)

        lo, hi = 0.0, (mesh_a.diameter + mesh_b.diameter) / 2 + 2 * margin
        if intersects(at(lo)):
            break
    while hi - lo > 1e-4 * margin:  # lo intersects (unless 20 draws found none), hi does not
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if intersects(at(mid)) else (lo, mid)
    delta = rng.uniform(-2.0, 1.0) if delta is None else delta
    return Pose.identity(), at(hi + delta * margin), delta


def timed(fn) -> float:
    """Seconds of one call of ``fn``, or the best of 5 for calls under 2 ms."""
    best = np.inf
    for _ in range(5):
        start = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - start)
        if best > 2e-3:
            break
    return best


def pair_cases(meshes: dict, trees: dict) -> list[tuple[str, str]]:
    ok = [n for n in meshes if n in trees]
    pairs = [(n, n) for n in ok if meshes[n].n_faces <= SELF_LIMIT]
    return pairs + [(a, b) for a, b in CROSS if a in ok and b in ok]


def compare_pose(meshes, trees, coal: Coal, a, b, rng, args) -> dict:
    """One random near pose of the pair (a, b): both searches' pairs, their disagreements'
    exact distances, the flat exact search where affordable, and both queries as callables."""
    from engine import Pose, find_contacts, triangle_distances

    ta, tb = trees[a], trees[b]
    margin = ta.leaf_epsilon + tb.leaf_epsilon
    capacity = meshes[a].n_faces * meshes[b].n_faces
    pa, pb, delta = near_pose(
        lambda pose: coal.intersect(a, b, Pose.identity(), pose),
        meshes[a],
        meshes[b],
        margin,
        rng,
    )

    def ours():
        return find_contacts(ta, pa, tb, pb)

    peer = coal.query(a, b, pa, pb, margin, capacity)
    mine = {tuple(p) for p in ours().pairs.tolist()}
    theirs = {(c.b1, c.b2) for c in peer().getContacts()}
    pose = dict(delta_over_margin=delta, position_b=pb.position.tolist())
    pose.update(orientation_b=pb.orientation.tolist(), ours=len(mine), coal=len(theirs))
    pose.update(only_ours=len(mine - theirs), only_coal=len(theirs - mine), non_ties=0)
    if diff := sorted(mine ^ theirs):
        idx = np.array(diff, np.int64)
        tri_a = pa.apply(meshes[a].vertices)[meshes[a].faces[idx[:, 0]]]
        tri_b = pb.apply(meshes[b].vertices)[meshes[b].faces[idx[:, 1]]]
        ratio = triangle_distances(tri_a, tri_b, kernel="exact").distance / margin
        off = np.abs(ratio - 1.0)
        pose.update(max_tie=float(off.max()), non_ties=int((off > TIE).sum()))
        # which side of the margin: only-ours pairs within it are contacts the peer missed
        ours_only = np.array([pair in mine for pair in diff])
        pose.update(
            only_ours_within=int((ratio[ours_only] <= 1.0).sum()),
            only_coal_within=int((ratio[~ours_only] <= 1.0).sum()),
            only_ours_max_ratio=float(ratio[ours_only].max()) if ours_only.any() else None,
        )
    if capacity <= args.flat_budget:
        flat = find_contacts(ta, pa, tb, pb, kernel="exact", hierarchy=False).pairs.tolist()
        flat = {tuple(p) for p in flat}
        pose["flat"] = len(flat)
        pose["ours_vs_flat"] = [len(flat - mine), len(mine - flat)]  # missed, extra
        pose["coal_vs_flat"] = [len(flat - theirs), len(theirs - flat)]
    return pose | {"fn": {"ours": ours, "coal": peer}, "ours_s": [], "coal_s": []}


def contact_rows(meshes: dict, trees: dict, coal_module, args) -> list[dict]:
    coal = Coal(coal_module, {n: meshes[n] for n in trees})
    cases = []
    for index, (a, b) in enumerate(pair_cases(meshes, trees)):
        rng = np.random.default_rng([args.seed, index])
        poses = [compare_pose(meshes, trees, coal, a, b, rng, args) for _ in range(args.poses)]
        margin = trees[a].leaf_epsilon + trees[b].leaf_epsilon
        faces = [meshes[a].n_faces, meshes[b].n_faces]
        cases.append(dict(pair=[a, b], triangles=faces, margin=margin, poses=poses))
    for _ in range(args.passes):  # interleaved: ours then Coal per pose, every pose per pass
        for case in cases:
            for pose in case["poses"]:
                for who in ("ours", "coal"):
                    pose[f"{who}_s"].append(timed(pose["fn"][who]))
    for case in cases:
        p = case["poses"]
        for pose in p:
            del pose["fn"]
            for who in ("ours", "coal"):
                pose[f"{who}_min_s"] = min(pose[f"{who}_s"])
                pose[f"{who}_median_s"] = float(np.median(pose[f"{who}_s"]))
        for key in ("ours", "coal", "only_ours", "only_coal", "non_ties"):
            case[key] = sum(x[key] for x in p)
        case["max_tie"] = max(x.get("max_tie", 0.0) for x in p)
        for key in ("only_ours_within", "only_coal_within"):
            case[key] = sum(x.get(key, 0) for x in p)
        for stat in ("min", "median"):  # over passes; then median over poses, ratio of sums
            for who in ("ours", "coal"):
                case[f"{who}_{stat}_s"] = float(np.median([x[f"{who}_{stat}_s"] for x in p]))
            ours, peer = (sum(x[f"{who}_{stat}_s"] for x in p) for who in ("ours", "coal"))
            case[f"ratio_{stat}"] = ours / peer  # ours / Coal
        if "flat" in p[0]:
            for key in ("ours_vs_flat", "coal_vs_flat"):
                case[key] = np.sum([x[key] for x in p], axis=0).tolist()
        print_contacts(case)
    return cases


def print_contacts(c: dict) -> None:
    flat = c.get("ours_vs_flat")
    flat = f"{flat[0]}/{flat[1]} | {c['coal_vs_flat'][0]}/{c['coal_vs_flat'][1]}" if flat else "-"
    name = " x ".join(c["pair"]) if c["pair"][0] != c["pair"][1] else f"{c['pair'][0]} (self)"
    print(
        f"  {name:<44} {c['margin']:8.2g} {c['ours']:9,} {c['coal']:9,}"
        f" {c['only_ours']:5d}/{c['only_coal']:<5d} {c['non_ties']:4d} {c['max_tie']:8.1e}"
        f" {c['only_ours_within']:5d}/{c['only_coal_within']:<5d}"
        f" {flat:>13} {c['ours_min_s'] * 1e3:9.3f} {c['coal_min_s'] * 1e3:9.3f}"
        f" {c['ratio_min']:6.2f} {c['ratio_median']:6.2f}"
    )


# ---------------------------------------------------------------------- machine, main
def machine() -> dict:
    info = Path("/proc/cpuinfo").read_text() if Path("/proc/cpuinfo").exists() else ""
    lines = info.splitlines()
    model = next((x.split(":", 1)[1].strip() for x in lines if x.startswith("model name")), "")
    flags = set(next((x.split(":", 1)[1].split() for x in lines if x.startswith("flags")), []))
    mem = Path("/proc/meminfo").read_text().split()[1] if Path("/proc/meminfo").exists() else 0
    out = {
        "cpu": model or platform.processor(),
        "cores": os.cpu_count(),
        "cores_usable": len(os.sched_getaffinity(0)),
        "memory_gib": int(mem) / 2**20,
        "isa": [f for f in ("avx512f", "avx2", "fma", "avx") if f in flags],
        "python": platform.python_version(),
    }
    for dist in ("mrdem", "numpy", "numba", "trimesh", "coal"):
        try:
            out[dist] = metadata.version(dist)
        except metadata.PackageNotFoundError:
            out[dist] = None
    git = ["git", "-C", str(ROOT)]
    run = subprocess.run
    out["commit"] = run([*git, "rev-parse", "HEAD"], capture_output=True, text=True).stdout.strip()
    dirty = run([*git, "status", "--porcelain", "engine"], capture_output=True, text=True).stdout
    out["engine_uncommitted"] = [line[3:] for line in dirty.splitlines()]
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="skip the >= 1M-triangle mesh")
    parser.add_argument("--only", nargs="+", metavar="NAME", help="keep only these meshes")
    parser.add_argument("--poses", type=int, help="random near poses per pair (6; quick 3)")
    parser.add_argument("--passes", type=int, help="timing passes (5; quick 3)")
    parser.add_argument("--seed", type=int, default=13)
    parser.add_argument("--build-repeats", type=int, help="builds per subprocess (3; quick 1)")
    parser.add_argument("--build-timeout", type=float, default=1200.0, help="s per subprocess")
    parser.add_argument("--flat-budget", type=float, default=3e7, help="most F_a*F_b for flat")
    parser.add_argument("--no-contacts", action="store_true", help="meshes and builds only")
    for name in ("--worker", "--mesh", "--tree-out"):
        parser.add_argument(name, help=argparse.SUPPRESS)
    parser.add_argument("--epsilon", type=float, help=argparse.SUPPRESS)
    parser.add_argument("--repeat", type=int, default=1, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.worker:
        return worker(args)
    args.poses = args.poses or (3 if args.quick else 6)
    args.passes = args.passes or (3 if args.quick else 5)
    args.build_repeats = args.build_repeats or (1 if args.quick else 3)
    try:
        import coal
    except ImportError:
        sys.exit("realmeshes.py compares with Coal: pip install -e .[bench]")
    from engine import SurrogateTree

    started = time.perf_counter()
    host = machine()
    print(
        f"machine: {host['cpu']}, {host['cores_usable']} of {host['cores']} cores, "
        f"ISA {' '.join(host['isa'])}, {host['memory_gib']:.0f} GiB; numba {host['numba']}, "
        f"coal {host['coal']}, commit {host['commit'][:10]}"
    )
    meshes, rows = mesh_rows(args)
    print(
        f"\nmeshes ({sum(r['rejected'] is not None for r in rows)} rejected by load_mesh's "
        f"defaults):\n  {'name':<26} {'triangles':>9} {'vertices':>9} {'closed':>6}  repair"
    )
    for r in rows:
        note = r["repair"]
        if r["rejected"]:  # the message after the file name
            note = f"REJECTED ({r['rejected'].split(chr(39) + ': ')[-1][:80]}...)"
        print(
            f"  {r['name']:<26} {r['triangles']:>9,} {r['vertices']:>9,} {r['closed']!s:>6}  {note}"
        )
    print(
        f"\nbuilds (fresh subprocess each; s = min of repeats; peak = MiB over the baseline):\n"
        f"  {'mesh':<26} {'triangles':>9} {'ours s':>9} {'coal s':>8} {'o/coal':>7}"
        f" {'ours MiB':>9} {'coal MiB':>8} {'o/coal':>6} {'levels':>6} {'nodes':>10}"
        f" {'rootε/d':>8} {'vol.rat':>7}"
    )
    with tempfile.TemporaryDirectory(prefix="realmeshes-") as tmp:
        builds = build_rows(meshes, Path(tmp), args)
        files = {b["name"]: b.pop("tree") for b in builds}
        trees = {name: SurrogateTree.load(f) for name, f in files.items() if f}
    contacts = []
    if not args.no_contacts:
        print(
            f"\nmargin contacts, {args.poses} random near poses per pair, {args.passes} passes"
            f" (pairs summed over poses; only ours/only coal; !tie: those with"
            f" |d - margin| > {TIE:g} margin; in o/c: of the only-ours / only-coal pairs,"
            f" those within the margin (exact d); flat: missed/extra of ours | coal;"
            f" ms: median over poses of the min over passes;"
            f" ours/coal of the sums of min and of median):\n"
            f"  {'pair':<44} {'margin':>8} {'ours':>9} {'coal':>9} {'only o/c':>11}"
            f" {'!tie':>4} {'max tie':>8} {'in o/c':>11} {'vs flat':>13} {'ours ms':>9}"
            f" {'coal ms':>9} {'o/c':>6} {'o/c md':>6}"
        )
        contacts = contact_rows(meshes, trees, coal, args)
    seconds = time.perf_counter() - started
    setup = {k: v for k, v in vars(args).items() if k not in ("worker", "mesh", "tree_out")}
    setup.update(epsilon_fraction=EPSILON_FRACTION, branching=BRANCHING, tie=TIE, seconds=seconds)
    OUT.mkdir(exist_ok=True)
    result = dict(machine=host, setup=setup, meshes=rows, builds=builds, contacts=contacts)
    (OUT / "realmeshes.json").write_text(json.dumps(result, indent=2))
    print(f"\n{seconds:.0f} s; wrote {OUT / 'realmeshes.json'}")
    plot_builds(builds, OUT / "realmeshes_builds.png")


def plot_builds(builds: list[dict], path: Path) -> None:
    """Build seconds against triangles, ours and Coal's, log-log (needs matplotlib)."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return
    rows = sorted(
        (b for b in builds if b.get("ours") and b.get("coal")), key=lambda b: b["triangles"]
    )
    if not rows:
        return
    n = [b["triangles"] for b in rows]
    fig, ax = plt.subplots(figsize=(6.4, 4.2))
    ax.loglog(n, [b["ours"]["seconds"] for b in rows], "o-", label="mrdem build_tree (2 threads)")
    ax.loglog(n, [b["coal"]["seconds"] for b in rows], "s--", label="Coal OBBRSS build")
    ax.set_xlabel("triangles")
    ax.set_ylabel("build seconds (fresh process, no compile)")
    ax.set_title("Tree builds on real meshes (one run)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
