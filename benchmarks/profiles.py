"""Profiles of the hot path of each paper scenario (issue 6, item 5).

Run: ``.venv/bin/python benchmarks/profiles.py [scenario ...] [--no-py-spy]`` (scenarios:
particle-particle, particle-plane, scale-difference, sphere-grid; default all, about two
minutes). Prints tables and writes ``bench-results/profiles.json`` and, where py-spy works,
``bench-results/profiles/<scenario>-<scheme>.speedscope.json`` (open in speedscope.app).

Per scenario and scheme (the schemes the paper runs it with, dt = 1e-3): the kernels are
compiled or loaded (``engine.warmup()``), the scene is brought to a few steps before its
first contact (free fall or approach in explicit steps, then ``WARM`` steps of the scheme,
which build the tree bank, the trees' caches and the pair lists or fronts), and a
**window** of steps covering the contact phase is stepped again and again, each time from
a copy of that state (the trees and the bank are shared, so each copy costs microseconds):

1. untraced: the best window time per step (``common.best_time``), the reference;
2. cProfile (deterministic, the main thread): own and cumulative time per function, calls
   per step. A Numba kernel shows as one entry, its dispatcher call (file engine/kernels/…;
   own time = dispatch + the compiled code); grouped into numba kernels, engine host code,
   numpy, Numba's Python-level dispatch (``typeof`` of tuples), other Python, and waiting
   on worker threads. Tracing inflates Python-call-heavy code, so its shares lean to host;
3. py-spy (sampling, ``--native``, all threads, when it can attach): each sample is charged
   to the deepest engine source line on its stack and classified by what runs below it:
   compiled kernel code, Numba dispatch, numpy, the cyclic GC, libc, or the interpreter;
   samples of waiting threads (idle workers, locks, taking the GIL back) are left out.
   Unbiased shares, inclusive time per engine function, and line-level attribution.
"""

from __future__ import annotations

import argparse
import collections
import copy
import cProfile
import gc
import json
import linecache
import math
import os
import pstats
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from common import best_time  # noqa: E402

import engine  # noqa: E402
from engine import scenarios  # noqa: E402

OUT = ROOT / "bench-results"
DT = 1e-3
LEAD = 5  # window starts this many steps before the first contact
WARM = 3  # steps of the scheme before the window (caches, pair lists, fronts)
CPROFILE_SECONDS = 1.5  # untraced stepping time to trace with cProfile, per run
PYSPY_SECONDS = 4.0  # and to sample with py-spy
PYSPY_RATE = 100  # samples per second
TOP = 10
ENGINE = str(ROOT / "engine") + os.sep
KERNELS = ENGINE + "kernels" + os.sep

# scenario: (builder(scheme), schemes, window steps, whether to find the first contact)
SCENARIOS = {
    "particle-particle": (
        lambda s: scenarios.particle_particle(1224, speed=0.5, gap=0.05, scheme=s),
        ("explicit", "multiscale"),
        20,  # 5 before, ~10 in contact, 5 after
        True,
    ),
    "particle-plane": (
        lambda s: scenarios.particle_on_plane(1224, tilt_degrees=20.0, drop=0.1, scheme=s),
        ("explicit", "implicit-surrogate", "multiscale"),
        60,  # impact, hop, rolling
        True,
    ),
    "scale-difference": (
        lambda s: scenarios.scale_difference(scale=4.0, refine=True, speed=0.5, scheme=s),
        ("implicit-surrogate",),
        30,  # 80 against 1,280 triangles: ~20 contact steps
        True,
    ),
    "sphere-grid": (
        lambda s: scenarios.sphere_grid((8, 8, 4), 1224, 1.0195, s, orientations="vertices"),
        ("implicit-surrogate",),
        5,  # 640 body pairs in contact (from step 8 pairs open: the unconfined grid expands)
        False,
    ),
}


# ---------------------------------------------------------------- scenes
def clone(scene):
    """A copy of ``scene`` that shares its (read-only, cached) trees and tree bank."""
    memo = {id(t): t for t in scene.trees}
    if scene._bank is not None:
        memo[id(scene._bank)] = scene._bank
    return copy.deepcopy(scene, memo)


def prepare(name: str, scheme: str):
    """The scene a window starts from (after ``WARM`` steps of ``scheme``)."""
    build, _, _, probe = SCENARIOS[name]
    scene = build(scheme)
    if probe:
        first = build("explicit")
        states = [first.state]
        for _ in range(2000):
            if first.step(DT).contacts:
                break
            states.append(first.state)
        else:
            raise RuntimeError(f"{name}: no contact within 2,000 steps")
        start = states[max(0, len(states) - 1 - LEAD - WARM)]
        scene.set_state(start.positions, start.orientations, start.velocities,
                        start.angular_velocities)  # fmt: skip
        scene.time = start.time
    for _ in range(WARM):
        scene.step(DT)
    return scene


def window(scene, steps: int) -> list:
    return [scene.step(DT) for _ in range(steps)]


# ---------------------------------------------------------------- cProfile
def category(key) -> str:
    """Group of a cProfile entry ``(file, line, function)``."""
    file, _, func = key
    if file.startswith(KERNELS):
        return "numba kernel"
    if file.startswith(ENGINE):
        return "engine host"
    if os.sep + "numba" + os.sep in file:
        return "numba dispatch"
    if os.sep + "numpy" + os.sep in file or "numpy" in func:
        return "numpy"
    if "_thread.lock" in func:
        return "wait (threads)"
    return "python"


def label(key) -> str:
    file, line, func = key
    if file == "~":
        return func
    if file.startswith(str(ROOT)):
        file = os.path.relpath(file, ROOT)
    elif "site-packages" in file:
        file = file.split("site-packages" + os.sep, 1)[1]
    else:
        file = os.path.basename(file)
    return f"{file}:{line}({func})"


FIELDS = ("function", "category", "own_ms", "own_share", "cum_ms", "cum_share")


def run_cprofile(snapshot, steps: int, reps: int) -> dict:
    scenes = [clone(snapshot) for _ in range(reps)]
    gc.collect()
    profile = cProfile.Profile()
    start = time.perf_counter()
    profile.enable()
    for scene in scenes:
        window(scene, steps)
    profile.disable()
    wall = time.perf_counter() - start
    stats = pstats.Stats(profile).stats
    n = reps * steps
    total = sum(v[2] for v in stats.values())
    groups = collections.Counter()
    rows = []
    for key, (_, calls, own, cum, _) in stats.items():
        groups[category(key)] += own
        row = (label(key), category(key), own / n * 1e3, own / total, cum / n * 1e3, cum / total)
        rows.append({**dict(zip(FIELDS, row, strict=True)), "calls": calls / n})
    own = sorted(rows, key=lambda r: -r["own_ms"])
    host = [r for r in rows if r["category"] == "engine host"]
    return {
        "steps": n,
        "ms_per_step": wall / n * 1e3,
        "groups": {k: v / total for k, v in groups.most_common()},
        "top_own": own[: 3 * TOP],
        "top_cumulative_engine": sorted(host, key=lambda r: -r["cum_ms"])[:TOP],
    }


# ---------------------------------------------------------------- py-spy
def pyspy() -> str | None:
    found = Path(sys.executable).with_name("py-spy")
    return str(found) if found.exists() else shutil.which("py-spy")


def run_pyspy(snapshot, steps: int, reps: int, path: Path) -> dict:
    """Sample this process with py-spy while it steps ``reps`` windows."""
    exe = pyspy()
    if exe is None:
        return {"error": "py-spy not installed (.venv/bin/pip install py-spy)"}
    scenes = [clone(snapshot) for _ in range(reps)]
    gc.collect()
    command = [exe, "record", "--pid", str(os.getpid()), "--rate", str(PYSPY_RATE), "--native",
               "--format", "speedscope", "--output", str(path)]  # fmt: skip
    spy = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    time.sleep(1.0)  # attach (the idle main thread is not sampled)
    if spy.poll() is not None:
        return {"error": "py-spy failed to attach: " + spy.stdout.read().strip()[-400:]}
    start = time.perf_counter()
    for scene in scenes:
        window(scene, steps)
    wall = time.perf_counter() - start
    spy.send_signal(signal.SIGINT)
    try:
        log = spy.communicate(timeout=120)[0]
    except subprocess.TimeoutExpired:
        spy.kill()
        return {"error": "py-spy did not stop"}
    if not path.exists():
        return {"error": "py-spy wrote nothing: " + log.strip()[-400:]}
    return {"ms_per_step": wall / (reps * steps) * 1e3, **speedscope(path, reps * steps)}


# native frames of a thread waiting for a lock, a condition or the GIL
WAITS = ("acquire_lock", "cond_wait", "cond_timedwait", "take_gil", "sem_wait", "sem_timedwait")


def kind(frames: list) -> str:
    """What a sample below its deepest engine line is doing (frames: that line's callees,
    outermost first)."""
    names = [f["name"] for f in frames]
    files = [f.get("file") or "" for f in frames]
    if any(n.startswith("gc_collect") for n in names):
        return "gc"
    if any(w in n for n in names for w in WAITS):
        return "wait"
    if "?" in files:  # compiled code (no symbols), and what it calls (NRT allocations)
        tail = files[len(files) - files[::-1].index("?") :]
        if tail and all("libc" in f for f in tail) and not any("alloc" in n for n in names):
            return "wait"  # a nogil kernel returning: taking the GIL back (futex)
        return "numba kernel"
    if any(os.sep + "numba" + os.sep in f or "_dispatcher" in f for f in files):
        return "numba dispatch"  # typing the arguments, choosing the overload
    if any(os.sep + "numpy" + os.sep in f for f in files):
        return "numpy"
    if files and "libc" in files[-1]:
        return "libc"
    return "interpreter"


def speedscope(path: Path, steps: int) -> dict:
    """Samples per engine source line and per kind (see :func:`kind`)."""
    data = json.loads(path.read_text())
    frames = data["shared"]["frames"]
    lines, kinds = collections.defaultdict(collections.Counter), collections.Counter()
    functions = collections.Counter()  # inclusive: samples with the function on the stack
    total, waiting, threads = 0.0, 0.0, 0
    for profile in data["profiles"]:
        threads += 1
        for stack, weight in zip(profile["samples"], profile["weights"], strict=True):
            chain = [frames[i] for i in stack]  # outermost first
            deepest = max(
                (i for i, f in enumerate(chain) if (f.get("file") or "").startswith(ENGINE)),
                default=None,
            )
            if deepest is None:
                python = [f["name"] for f in chain if (f.get("file") or "").endswith(".py")]
                where = "(outside engine) " + (python[-1] if python else chain[-1]["name"])
                what = kind(chain)
            else:
                f = chain[deepest]
                where = f"{os.path.relpath(f['file'], ROOT)}:{f['line']} {f['name']}"
                what = kind(chain[deepest + 1 :])
            if what == "wait":
                waiting += weight  # an idle worker, a lock or the GIL: not CPU time
                continue
            lines[where][what] += weight
            kinds[what] += weight
            total += weight
            for name in {f["name"] for f in chain if (f.get("file") or "").startswith(ENGINE)}:
                functions[name] += weight
    if not total:
        return {"error": "no samples"}
    top = []
    for where, mix in sorted(lines.items(), key=lambda x: -sum(x[1].values()))[: 2 * TOP]:
        weight = sum(mix.values())
        file, _, rest = where.partition(":")
        source = linecache.getline(str(ROOT / file), int(rest.split()[0])) if rest else ""
        kinds_here = {k: v / weight for k, v in mix.most_common()}
        top.append({"line": where, "source": source.strip()[:60], "share": weight / total})
        top[-1].update(ms=weight / steps * 1e3, kinds=kinds_here)
    return {
        "samples": int(round(total * PYSPY_RATE)),
        "waiting_samples": int(round(waiting * PYSPY_RATE)),
        "threads": threads,
        "cpu_ms_per_step": total / steps * 1e3,
        "kinds": {k: v / total for k, v in kinds.most_common()},
        "functions": {k: v / total for k, v in functions.most_common(3 * TOP)},
        "top_lines": top,
    }


# ---------------------------------------------------------------- one run
def profile(name: str, scheme: str, use_pyspy: bool) -> dict:
    snapshot = prepare(name, scheme)
    steps = SCENARIOS[name][2]
    rows = window(clone(snapshot), steps)  # a first pass (and its statistics)
    trial = [clone(snapshot) for _ in range(4)]
    seconds = best_time(lambda: window(trial.pop(), steps), repeat=3)
    reps = max(2, min(400, math.ceil(CPROFILE_SECONDS / seconds)))
    out = {"scenario": name, "scheme": scheme, "window_steps": steps}
    out["ms_per_step"] = seconds / steps * 1e3
    out["contact_steps"] = sum(r.contacts > 0 for r in rows)
    for field in ("picard_iterations", "evaluations", "body_pairs", "contacts", "comparisons"):
        out[field] = float(np.mean([getattr(r, field) for r in rows]))
    out["cprofile"] = run_cprofile(snapshot, steps, reps)
    if use_pyspy:
        folder = OUT / "profiles"
        folder.mkdir(exist_ok=True)
        reps = max(2, min(600, math.ceil(PYSPY_SECONDS / seconds)))
        out["pyspy"] = run_pyspy(snapshot, steps, reps, folder / f"{name}-{scheme}.speedscope.json")
    return out


def shares(groups: dict) -> str:
    return ", ".join(f"{k} {v:.0%}" for k, v in groups.items() if v >= 0.005)


def report(r: dict) -> None:
    c = r["cprofile"]
    print(
        f"\n== {r['scenario']} / {r['scheme']}: {r['window_steps']}-step window"
        f" ({r['contact_steps']} in contact), {r['ms_per_step']:.3f} ms/step untraced;"
        f" per step: Picard {r['picard_iterations']:.2f}, searches {r['evaluations']:.2f},"
        f" body pairs {r['body_pairs']:.1f}, contacts {r['contacts']:.1f},"
        f" comparisons {r['comparisons']:.0f}"
    )
    print(
        f"cProfile ({c['steps']} steps, {c['ms_per_step']:.3f} ms/step traced ="
        f" {c['ms_per_step'] / r['ms_per_step']:.1f}x): {shares(c['groups'])}"
    )
    print(f"  {'own ms':>7s} {'own%':>5s} {'cum ms':>7s} {'cum%':>5s} {'calls':>6s}  "
          f"{'group':14s} function")  # fmt: skip
    for x in [*c["top_own"][:TOP], None, *c["top_cumulative_engine"][:6]]:
        print(
            "  engine functions by cumulative time:"
            if x is None
            else f"  {x['own_ms']:7.3f} {x['own_share']:5.1%} {x['cum_ms']:7.3f}"
            f" {x['cum_share']:5.1%} {x['calls']:6.1f}  {x['category']:14s} {x['function']}"
        )
    s = r.get("pyspy")
    if not s:
        return
    if "error" in s:
        print(f"py-spy: {s['error']}")
        return
    print(
        f"py-spy ({s['samples']} busy samples, {s['waiting_samples']} waiting left out,"
        f" {s['threads']} threads, {s['ms_per_step']:.3f}"
        f" ms/step while sampled, {s['cpu_ms_per_step']:.3f} CPU ms/step): {shares(s['kinds'])}"
    )
    inclusive = [f"{k} {v:.0%}" for k, v in s["functions"].items() if v < 0.95][: 2 * TOP]
    for at in range(0, len(inclusive), 5):
        print(("  inclusive: " if at == 0 else "             ") + ", ".join(inclusive[at : at + 5]))
    print(f"  {'share':>6s} {'ms':>7s}  {'engine line (deepest on the stack)':48s} below it")
    for x in s["top_lines"][:TOP]:
        mix = ", ".join(f"{k} {v:.0%}" for k, v in list(x["kinds"].items())[:3])
        print(f"  {x['share']:6.1%} {x['ms']:7.3f}  {x['line'][:48]:48s} {mix}")
        if x["source"]:
            print(f"  {'':15s}{x['source']}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("scenario", nargs="*", help=", ".join(SCENARIOS) + " (default: all)")
    parser.add_argument("--no-py-spy", action="store_true", help="cProfile only")
    args = parser.parse_args()
    names = args.scenario or list(SCENARIOS)
    for name in names:
        if name not in SCENARIOS:
            parser.error(f"unknown scenario {name!r}; choose from {', '.join(SCENARIOS)}")
    OUT.mkdir(exist_ok=True)
    wall = time.perf_counter()
    warm = engine.warmup()
    print(
        f"warm-up {warm:.1f} s; dt {DT:g}; cores {os.cpu_count()}; py-spy"
        f" {'off' if args.no_py_spy else pyspy() or 'not installed'}"
    )
    runs = []
    for name in names:
        for scheme in SCENARIOS[name][1]:
            runs.append(profile(name, scheme, not args.no_py_spy))
            report(runs[-1])
    path = OUT / "profiles.json"
    if len(names) < len(SCENARIOS) and path.exists():  # keep the other scenarios' runs
        kept = json.loads(path.read_text()).get("runs", [])
        runs = [r for r in kept if r["scenario"] not in names] + runs
    constants = ("DT", "LEAD", "WARM", "CPROFILE_SECONDS", "PYSPY_SECONDS", "PYSPY_RATE")
    settings = {k.lower(): globals()[k] for k in constants} | {"cpu_count": os.cpu_count()}
    results = {"settings": settings, "runs": runs, "seconds": time.perf_counter() - wall}
    path.write_text(json.dumps(results, indent=2))
    print(f"\ntotal {results['seconds']:.0f} s; wrote {path}")


if __name__ == "__main__":
    main()
