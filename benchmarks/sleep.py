"""What sleeping saves (issue 6): a field of boxes at rest on a plane and one ball dropped
onto a corner of it, stepped with and without ``Scene(sleep=True)``.

Per run: time and triangle comparisons per step, body pairs of the narrow phase, bodies
asleep, and how far the two runs' final states differ. Writes ``bench-results/sleep.json``.

    .venv/bin/python benchmarks/sleep.py
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import engine  # noqa: E402
from engine import PaperSpring, Scene, shapes  # noqa: E402
from engine.dynamics.sleep import Sleep  # noqa: E402

OUT = ROOT / "bench-results"
SIDE = 8  # boxes per side
STEPS = 800
DT = 1e-3


def build(sleep) -> Scene:
    scene = Scene(
        contact_model=PaperSpring(damping=0.5, friction=0.5),
        sleep=sleep,
        scheme="implicit-surrogate",
    )
    scene.add_plane(size=2.0 * SIDE + 4.0, divisions=8, epsilon=0.01)
    box = shapes.box((0.5, 0.5, 0.5))
    eps = 0.01 * box.diameter  # halos given: the measured figures used 1 % of the diameter
    low = 0.25 + 0.998 * (0.01 + eps)
    grid = (np.arange(SIDE) - (SIDE - 1) / 2) * 1.5
    positions = [(x, y, low) for x in grid for y in grid]
    scene.add_bodies(box, positions, epsilon=eps)
    corner = (grid[0], grid[0], 0.5 + 0.2 + 0.8)
    scene.add_body(shapes.icosphere(2, radius=0.2), position=corner, epsilon=0.004)
    return scene


def run(sleep) -> dict:
    scene = build(sleep)
    rows = []
    start = time.perf_counter()
    for _ in range(STEPS):
        rows.append(scene.step(DT))
    seconds = time.perf_counter() - start
    return {
        "scene": scene,
        "seconds": seconds,
        "ms_per_step": 1e3 * seconds / STEPS,
        "comparisons": float(np.mean([r.comparisons for r in rows])),
        "body_pairs": float(np.mean([r.body_pairs for r in rows])),
        "sleeping_last": rows[-1].sleeping,
        "sleeping_mean": float(np.mean([r.sleeping for r in rows])),
    }


def main() -> None:
    OUT.mkdir(exist_ok=True)
    engine.warmup()
    awake, asleep = run(False), run(Sleep(speed=1e-3, steps=30))
    diff = float(np.abs(awake["scene"].positions - asleep["scene"].positions).max())
    print(
        f"{SIDE * SIDE} boxes at rest on a plane, one ball dropped on a corner box,"
        f" {STEPS} implicit-surrogate steps of {DT:g} s"
    )
    print(f"{'run':10s}{'ms/step':>9s}{'comparisons':>13s}{'pairs':>8s}{'asleep (end)':>14s}")
    for name, r in (("no sleep", awake), ("sleep", asleep)):
        print(
            f"{name:10s}{r['ms_per_step']:9.3f}{r['comparisons']:13.1f}{r['body_pairs']:8.1f}"
            f"{r['sleeping_last']:14d}"
        )
    print(
        f"saving: {awake['ms_per_step'] / asleep['ms_per_step']:.1f}x time,"
        f" {awake['comparisons'] / max(asleep['comparisons'], 1e-9):.1f}x comparisons;"
        f" final positions differ by at most {diff:.2e}"
    )
    results = {
        k: {kk: v for kk, v in r.items() if kk != "scene"}
        for k, r in (("awake", awake), ("sleep", asleep))
    }
    results["max_position_difference"] = diff
    (OUT / "sleep.json").write_text(json.dumps(results, indent=2))


if __name__ == "__main__":
    main()
