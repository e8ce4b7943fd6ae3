"""A pile of rigid mesh bodies in a box-shaped bin, simulated with MuJoCo: a benchmark-only peer
of ``benchmarks/scenes.py`` (MuJoCo collides the meshes' convex hulls, its default).

Run alone: ``.venv/bin/python benchmarks/mujoco_scenes.py [--seconds S] [--dt DT]`` (needs
``pip install -e .[bench]``): 8 boxes of 5 cm, seeded random orientations, in a 20 cm bin.

:func:`mujoco_pile` builds an MJCF model (meshes inline, one free body per entry of
``bodies``, a floor plane at z = 0 and four thin box walls), checks that every body's mesh
vertices lie at ``R·v + position`` at time 0, steps it single-threaded for ``seconds`` of
simulated time timing each ``mj_step``, and reports timings, contacts, penetration and the
final state. MuJoCo recentres a mesh at its centre of mass in its principal frame and moves
the geom to compensate, so a geom at the body origin with the vertices as given puts the mesh
frame at the body frame: the body's pose is the mesh frame's pose.
"""

from __future__ import annotations

import argparse
import pprint
import time

import numpy as np
from scipy.spatial import ConvexHull, cKDTree

WALL_HALF_THICKNESS = 0.025  # m: thin box walls, thick enough not to be tunnelled at dt ≤ 2 ms
GRAVITY = 9.81


def _num(values) -> str:
    return " ".join(f"{float(x):.17g}" for x in np.ravel(values))


def _quat_matrix(q) -> np.ndarray:
    """Rotation matrix (3, 3) float64 of a quaternion (4,) w, x, y, z (normalised here)."""
    w, x, y, z = np.asarray(q, dtype=np.float64) / np.linalg.norm(q)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def pile_xml(meshes, bodies, *, density, half_width, wall_height, dt, friction, integrator):
    """MJCF text of the pile (arguments as :func:`mujoco_pile`)."""
    fr = f"{float(friction):.17g} 0.005 0.0001"  # MuJoCo's default torsional and rolling
    h, t = float(half_width), WALL_HALF_THICKNESS
    lines = [
        '<mujoco model="pile">',
        f'  <option timestep="{float(dt):.17g}" gravity="0 0 {-GRAVITY}"',
        f'          integrator="{integrator}"/>',
        "  <asset>",
    ]
    for i, (v, f) in enumerate(meshes):
        lines.append(f'    <mesh name="m{i}" vertex="{_num(v)}" face="{_num(np.asarray(f))}"/>')
    lines += ["  </asset>", "  <worldbody>"]
    lines.append(
        f'    <geom name="floor" type="plane" size="{h + t} {h + t} 0.1" friction="{fr}"/>'
    )
    zc, hz = 0.5 * wall_height, 0.5 * wall_height
    for name, pos, size in (
        ("wall_px", (h + t, 0, zc), (t, h + 2 * t, hz)),
        ("wall_mx", (-h - t, 0, zc), (t, h + 2 * t, hz)),
        ("wall_py", (0, h + t, zc), (h + 2 * t, t, hz)),
        ("wall_my", (0, -h - t, zc), (h + 2 * t, t, hz)),
    ):
        lines.append(
            f'    <geom name="{name}" type="box" pos="{_num(pos)}" size="{_num(size)}" '
            f'friction="{fr}"/>'
        )
    for k, (mi, pos, quat) in enumerate(bodies):
        lines += [
            f'    <body name="b{k}" pos="{_num(pos)}" quat="{_num(quat)}">',
            "      <freejoint/>",
            f'      <geom type="mesh" mesh="m{int(mi)}" density="{float(density):.17g}" '
            f'friction="{fr}"/>',
            "    </body>",
        ]
    lines += ["  </worldbody>", "</mujoco>"]
    return "\n".join(lines)


def _check_mesh_frames(m, d, meshes, bodies) -> float:
    """Largest distance (m) from a given vertex R·v + p to MuJoCo's nearest world vertex."""
    worst = 0.0
    for k, (mi, pos, quat) in enumerate(bodies):
        g = int(m.body_geomadr[m.body(f"b{k}").id])
        mesh_id = int(m.geom_dataid[g])
        a, n = int(m.mesh_vertadr[mesh_id]), int(m.mesh_vertnum[mesh_id])
        ours = np.asarray(meshes[mi][0], np.float64) @ _quat_matrix(quat).T + np.asarray(pos)
        theirs = m.mesh_vert[a : a + n] @ d.geom_xmat[g].reshape(3, 3).T + d.geom_xpos[g]
        worst = max(worst, float(cKDTree(theirs).query(ours)[0].max()))
    return worst


def mujoco_pile(
    meshes,
    bodies,
    *,
    density,
    half_width,
    wall_height,
    dt,
    seconds,
    friction,
    settle_speed=1e-3,
    integrator="Euler",
) -> dict:
    """Simulate a pile of free mesh bodies in a bin with MuJoCo and time its steps.

    meshes: list of ``(vertices (v, 3) float64, faces (f, 3) int64)`` in metres, any frame
    (MuJoCo collides their convex hulls). bodies: list of ``(mesh_index int, position (3,)
    float64, quaternion (4,) float64 w, x, y, z)``: the pose of the body's mesh frame. density
    kg/m³; the bin: floor plane z = 0, walls at x, y = ±half_width of height wall_height (m);
    gravity (0, 0, −9.81); sliding ``friction`` on every geom; timestep ``dt`` s for
    ``seconds`` s; ``integrator``: an MJCF name ("Euler", "implicitfast", "implicit", "RK4").
    ``settle_speed`` (m/s): the dict's ``settled`` says whether every body's centre of mass is
    slower than it at the end.

    Returns a dict of floats and ints: ``wall_per_step_s`` (median of the per-``mj_step``
    perf_counter times), ``wall_total_s`` (their sum: stepping only), ``steps``,
    ``wall_per_simulated_second_s``, ``contacts`` (``ncon`` at the end) and
    ``contacts_mean_last_10pct``, ``largest_penetration_m`` (largest −dist at the end, 0 if
    none) and ``largest_penetration_run_m`` (over every step), ``kinetic_energy_end_j``,
    ``largest_speed_end_m_s`` (centre-of-mass speed), ``escaped`` (centres of mass outside
    |x|, |y| ≤ half_width or below z = 0), ``settled``, ``mass_total_kg``, ``warnings`` (MuJoCo
    warning counts, by name, nonzero only), ``mesh_frame_error_m``, ``bodies``,
    ``mujoco_version``, ``dt``, ``seconds``, ``integrator``.
    """
    import mujoco

    xml = pile_xml(
        meshes,
        bodies,
        density=density,
        half_width=half_width,
        wall_height=wall_height,
        dt=dt,
        friction=friction,
        integrator=integrator,
    )
    m = mujoco.MjModel.from_xml_string(xml)
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    frame_error = _check_mesh_frames(m, d, meshes, bodies)
    scale = max(float(np.ptp(np.asarray(v), axis=0).max()) for v, _ in meshes)
    if frame_error > 1e-6 * scale:  # mesh_vert is float32
        raise AssertionError(f"mesh frame mismatch at time 0: {frame_error:.3g} m")

    steps = int(round(seconds / dt))
    step_s = np.empty(steps)
    ncon = np.empty(steps, dtype=np.int64)
    pen_run = 0.0
    for s in range(steps):
        t0 = time.perf_counter()
        mujoco.mj_step(m, d)
        step_s[s] = time.perf_counter() - t0
        ncon[s] = d.ncon
        if d.ncon:
            pen_run = max(pen_run, -float(d.contact.dist[: d.ncon].min()))
    mujoco.mj_forward(m, d)  # contacts, inertia and positions of the final state (untimed)

    ids = np.array([m.body(f"b{k}").id for k in range(len(bodies))], dtype=np.int64)
    speeds = np.zeros(len(bodies))
    for i, b in enumerate(ids):
        vel = np.zeros(6)  # (angular, linear) at the centre of mass, world frame
        mujoco.mj_objectVelocity(m, d, mujoco.mjtObj.mjOBJ_BODY, int(b), vel, 0)
        speeds[i] = np.linalg.norm(vel[3:])
    momentum = np.zeros(m.nv)  # M·qvel (mj_mulM: same call in MuJoCo 3 and 4)
    mujoco.mj_mulM(m, d, momentum, d.qvel)
    kinetic = 0.5 * float(d.qvel @ momentum)
    com = d.xipos[ids]
    out = (np.abs(com[:, 0]) > half_width) | (np.abs(com[:, 1]) > half_width) | (com[:, 2] < 0)
    total = float(step_s.sum())
    tail = ncon[-max(1, steps // 10) :] if steps else np.zeros(1)
    dist = d.contact.dist[: d.ncon]
    warnings = {
        mujoco.mjtWarning(i).name: int(d.warning[i].number)
        for i in range(len(d.warning))
        if d.warning[i].number
    }
    return {
        "wall_per_step_s": float(np.median(step_s)) if steps else 0.0,
        "wall_total_s": total,
        "steps": steps,
        "wall_per_simulated_second_s": total / seconds,
        "contacts": int(d.ncon),
        "contacts_mean_last_10pct": float(tail.mean()),
        "largest_penetration_m": max(0.0, -float(dist.min())) if d.ncon else 0.0,
        "largest_penetration_run_m": pen_run,
        "kinetic_energy_end_j": kinetic,
        "largest_speed_end_m_s": float(speeds.max()) if len(speeds) else 0.0,
        "settled": bool((speeds < settle_speed).all()),
        "escaped": int(out.sum()),
        "mass_total_kg": float(m.body_mass[ids].sum()),
        "warnings": warnings,
        "mesh_frame_error_m": frame_error,
        "bodies": len(bodies),
        "mujoco_version": mujoco.__version__,
        "dt": float(dt),
        "seconds": float(seconds),
        "integrator": integrator,
    }


def box_mesh(edge: float) -> tuple[np.ndarray, np.ndarray]:
    """A cube of side ``edge`` (m) centred at the origin: vertices (8, 3) float64, faces
    (12, 3) int64, wound counter-clockwise seen from outside."""
    v = (np.indices((2, 2, 2)).reshape(3, -1).T - 0.5) * edge
    faces = ConvexHull(v).simplices.astype(np.int64)
    a, b, c = v[faces[:, 0]], v[faces[:, 1]], v[faces[:, 2]]
    inward = np.einsum("ij,ij->i", np.cross(b - a, c - a), a + b + c) < 0
    faces[inward] = faces[inward][:, ::-1]
    return v, faces


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seconds", type=float, default=1.0)
    parser.add_argument("--dt", type=float, default=1e-3)
    args = parser.parse_args()
    rng = np.random.default_rng(0)
    bodies = []
    for layer in range(2):
        for i in range(2):
            for j in range(2):
                q = rng.normal(size=4)
                pos = (-0.045 + 0.09 * i, -0.045 + 0.09 * j, 0.05 + 0.09 * layer)
                bodies.append((0, np.array(pos), q / np.linalg.norm(q)))
    result = mujoco_pile(
        [box_mesh(0.05)],
        bodies,
        density=800.0,
        half_width=0.1,
        wall_height=0.3,
        dt=args.dt,
        seconds=args.seconds,
        friction=0.5,
    )
    pprint.pprint(result, sort_dicts=False)


if __name__ == "__main__":
    main()
