"""The contact search's precision in a scene (issue 6): float32 against float64 on the
scenarios of ``benchmarks/accuracy.py``, dt = 1e-3, every scheme.

``benchmarks/search_pareto.py`` times contact queries alone, where float32 returns the float64
oracle's pairs 6–8 % faster. This script asks what the precision does to time stepping: per
scenario × scheme × precision, wall time, Picard iterations per step, steps that did not
converge, and the largest distance between the two precisions' final positions. Writes
``bench-results/precision.json``.

    .venv/bin/python benchmarks/precision.py
"""

from __future__ import annotations

import json
import sys
import time
import warnings
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from accuracy import SCENARIOS, SCHEMES  # noqa: E402

import engine  # noqa: E402
from engine import TunnellingWarning  # noqa: E402

OUT = ROOT / "bench-results"
DT = 1e-3


def run(build, seconds: float, scheme: str, precision: str) -> dict:
    scene = build(scheme)
    scene.precision = precision  # before the first search builds the scene's tree bank
    steps = round(seconds / DT)
    iterations, failed = [], 0
    start = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", TunnellingWarning)
        for _ in range(steps):
            row = scene.step(DT)
            iterations.append(row.picard_iterations)
            failed += not row.converged
    return {
        "seconds": time.perf_counter() - start,
        "steps": steps,
        "picard_iterations": float(np.mean(iterations)),
        "not_converged": failed,
        "positions": scene.positions.copy(),
    }


def main() -> None:
    OUT.mkdir(exist_ok=True)
    engine.warmup()
    rows = []
    print(
        f"{'scenario':18s}{'scheme':>20s}{'precision':>10s}{'seconds':>9s}{'Picard/step':>12s}"
        f"{'not conv.':>10s}{'f32-f64 pos':>12s}"
    )
    for name, (build, seconds) in SCENARIOS.items():
        for scheme in SCHEMES:
            pair = {p: run(build, seconds, scheme, p) for p in ("float64", "float32")}
            diff = float(
                np.abs(pair["float32"].pop("positions") - pair["float64"].pop("positions")).max()
            )
            for precision, r in pair.items():
                rows.append({"scenario": name, "scheme": scheme, "precision": precision, **r})
                rows[-1]["position_difference"] = diff
                print(
                    f"{name:18s}{scheme:>20s}{precision:>10s}{r['seconds']:9.3f}"
                    f"{r['picard_iterations']:12.2f}{r['not_converged']:10d}{diff:12.1e}",
                    flush=True,
                )
    (OUT / "precision.json").write_text(json.dumps({"dt": DT, "rows": rows}, indent=2))
    print(f"wrote {OUT / 'precision.json'}")


if __name__ == "__main__":
    main()
