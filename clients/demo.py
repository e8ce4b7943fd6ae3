"""``mrdem demo`` (``python -m clients.demo``): the paper's particle-on-plane scenario run
through the client against a service — a local one started for the demo unless ``--url``
is given. Writes into ``--out``:

* ``particle_on_plane.csv`` — per step: time, height of the centre above the plane, speed,
  contact points, Picard iterations;
* ``particle_on_plane.png`` — height and contact count over time (needs matplotlib:
  ``pip install 'mrdem[demo]'``; without it the PNG is skipped and the reason printed);
* ``vtk/frame_NNNN.vtk`` and ``vtk/particle_on_plane.pvd`` — the sphere and the plane as
  a time series for ParaView (legacy VTK polydata, one file per frame).

Imports neither engine nor service: the service runs as a separate process
(:mod:`mrdem_common.serving`).
"""

from __future__ import annotations

import argparse
import contextlib
import math
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import trimesh

from mrdem_common.rotation import rotation_matrix
from mrdem_common.serving import ServiceProcess, ServiceStartError

from .sync import Client

TILT = math.radians(20.0)
NORMAL = np.array([math.sin(TILT), 0.0, math.cos(TILT)])
DOWNHILL = np.array([math.cos(TILT), 0.0, -math.sin(TILT)])


@contextlib.contextmanager
def local_service():
    """``python -m service`` on a free port with a temporary store (its output on this
    process's); yields its URL. ``SystemExit`` saying why if it does not get ready."""
    with tempfile.TemporaryDirectory() as tmp:
        service = ServiceProcess(Path(tmp) / "d", ready_timeout=900)
        try:
            service.start()
        except ServiceStartError as exc:
            raise SystemExit(str(exc)) from None
        try:
            yield service.url
        finally:
            service.stop(grace=30)


def run(url: str, steps: int, dt: float, every: int) -> dict:
    ball = trimesh.creation.icosphere(subdivisions=3, radius=0.5)  # the paper's 1,280
    with Client(url) as client:
        info = client.upload_mesh(ball, epsilon=0.01)
        start = NORMAL * (0.5 + 0.02 + 0.1) - 2.0 * DOWNHILL  # 0.1 above, 2 uphill
        scene = client.create_scene(
            bodies=[{"mesh": info, "position": start.tolist()}],
            planes=[{"point": [0, 0, 0], "normal": NORMAL.tolist(), "size": 8.0}],
            dt=dt,
            scheme="implicit-surrogate",
            contact_model={"law": "paper", "damping": 0.3, "friction": 0.5},
            max_halvings=2,  # the impact step is retried as halves if Picard stalls
        )
        rows, frames = [], []
        done = 0
        while done < steps:
            n = min(every, steps - done)
            state = scene.step(n)
            done += n
            for k, stats in enumerate(state.stats):
                rows.append((state.time - (n - 1 - k) * dt, stats))
            frames.append((state.time, state.positions[0].copy(), state.orientations[0].copy()))
        scene.delete()
    return {"ball": ball, "rows": rows, "frames": frames, "final": state}


def write_csv(path: Path, result: dict) -> None:
    lines = ["time,contacts,picard_iterations,converged"]
    for t, s in result["rows"]:
        lines.append(f"{t:.6f},{s['contacts']},{s['picard_iterations']},{int(s['converged'])}")
    path.write_text("\n".join(lines) + "\n")


def heights(result: dict) -> tuple[np.ndarray, np.ndarray]:
    times = np.array([t for t, _, _ in result["frames"]])
    centre = np.array([p for _, p, _ in result["frames"]])
    return times, centre @ NORMAL - 0.5  # the gap under the sphere's surface


def write_png(path: Path, result: dict) -> str | None:
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return "matplotlib is not installed (pip install 'mrdem[demo]')"
    times, gap = heights(result)
    steps = np.array([t for t, _ in result["rows"]])
    contacts = np.array([s["contacts"] for _, s in result["rows"]])
    fig, (top, bottom) = plt.subplots(2, 1, sharex=True, figsize=(7, 5))
    top.plot(times, gap)
    top.set_ylabel("gap below the sphere")
    top.set_title("particle on a 20° plane, through the mrdem service")
    bottom.step(steps, contacts, where="post")
    bottom.set_ylabel("contact points")
    bottom.set_xlabel("time")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return None


def write_vtk(folder: Path, result: dict) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    ball = result["ball"]
    u = np.cross(NORMAL, [0.0, 1.0, 0.0])
    u /= np.linalg.norm(u)
    v = np.cross(NORMAL, u)
    plane = np.array([s * u * 4 + t * v * 4 for s, t in ((-1, -1), (1, -1), (1, 1), (-1, 1))])
    entries = []
    for i, (t, position, orientation) in enumerate(result["frames"]):
        points = np.vstack([ball.vertices @ rotation_matrix(orientation).T + position, plane])
        n = len(ball.vertices)
        polygons = [f"3 {a} {b} {c}" for a, b, c in ball.faces] + [f"4 {n} {n + 1} {n + 2} {n + 3}"]
        size = 4 * len(ball.faces) + 5
        name = f"frame_{i:04d}.vtk"
        text = [
            "# vtk DataFile Version 3.0",
            f"mrdem particle on plane, t = {t:.6f}",
            "ASCII",
            "DATASET POLYDATA",
            f"POINTS {len(points)} double",
            *(f"{x:.9g} {y:.9g} {z:.9g}" for x, y, z in points),
            f"POLYGONS {len(polygons)} {size}",
            *polygons,
        ]
        (folder / name).write_text("\n".join(text) + "\n")
        entries.append(f'    <DataSet timestep="{t:.6f}" file="{name}"/>')
    pvd = folder / "particle_on_plane.pvd"
    pvd.write_text(
        '<?xml version="1.0"?>\n<VTKFile type="Collection" version="0.1">\n  <Collection>\n'
        + "\n".join(entries)
        + "\n  </Collection>\n</VTKFile>\n"
    )
    return pvd


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="mrdem demo", description=__doc__.splitlines()[0])
    parser.add_argument("--url", help="a running service (default: start one)")
    parser.add_argument("--out", default="demo-output", help="output folder")
    parser.add_argument("--steps", type=int, default=600)
    parser.add_argument("--dt", type=float, default=1e-3)
    parser.add_argument("--every", type=int, default=10, help="steps per request and frame")
    args = parser.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    with contextlib.nullcontext(args.url) if args.url else local_service() as url:
        start = time.perf_counter()
        result = run(url, args.steps, args.dt, args.every)
        seconds = time.perf_counter() - start
    write_csv(out / "particle_on_plane.csv", result)
    skipped = write_png(out / "particle_on_plane.png", result)
    pvd = write_vtk(out / "vtk", result)
    _, gap = heights(result)
    print(
        f"{args.steps} steps of {args.dt:g} s through {url} in {seconds:.1f} s;"
        f" lowest gap {gap.min():.4f}, final {gap[-1]:.4f}; wrote {out}/particle_on_plane.csv,"
        f" {pvd}" + (f"; no PNG: {skipped}" if skipped else f", {out}/particle_on_plane.png")
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
