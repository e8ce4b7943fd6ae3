"""Where a running process spends its time inside Numba kernels, by sampling it with gdb.

Run: ``.venv/bin/python benchmarks/kernel_samples.py PID [--samples 400] [--interval 0.01]``
(needs ``gdb``; attaching needs the same user and ``kernel.yama.ptrace_scope`` ≤ 1, or root).
Prints a table and writes ``bench-results/kernel_samples.json``.

Numba registers its compiled code with gdb's JIT interface, so ``info symbol`` names the
kernel a sample lands in (cProfile and py-spy see one opaque call). The process is stopped
``--samples`` times, ``--interval`` seconds apart, on its main thread. A sample inside
Numba's reference counting (``NRT_incref``, ``NRT_decref``: leaf functions that push
nothing) is charged to its caller, read from the return address on the stack, with the
offset in the caller: that is how the counting inside the traversal's loops was found
(docs/kernels.md, "Reference counting in branchy loops").
"""

from __future__ import annotations

import argparse
import json
import re
import subprocess
import sys
import tempfile
from collections import Counter
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "bench-results"

GDB_SCRIPT = r"""
import gdb, os, re, signal, threading, time, json
pid = gdb.selected_inferior().pid
samples = []
for _ in range(__SAMPLES__):
    threading.Timer(__INTERVAL__, os.kill, (pid, signal.SIGINT)).start()
    gdb.execute("continue", to_string=True)
    pc = int(gdb.selected_frame().pc())
    where = gdb.execute(f"info symbol {pc}", to_string=True).split(" in section")[0]
    if where.startswith(("NRT_incref", "NRT_decref")):
        ret = int(gdb.parse_and_eval("*(unsigned long*)$rsp"))
        caller = gdb.execute(f"info symbol {ret}", to_string=True)
        offset = re.search(r"\+ (\d+) in section", caller)
        where = "refcount <- " + caller.split(" in section")[0].split(" + ")[0]
        where += f" +{offset.group(1)}" if offset else ""
    samples.append(where)
print("SAMPLES " + json.dumps(samples))
gdb.execute("detach")
"""


def _name(symbol: str) -> str:
    """A sampled symbol shortened to its qualified function name."""
    symbol = re.sub(r"\[abi:[^\]]*\]", "", symbol)
    symbol = re.sub(r"\(.*\)", "", symbol)  # the argument types
    if not symbol.startswith("refcount"):
        symbol = symbol.split(" + ")[0]
    return symbol[:110]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("pid", type=int)
    parser.add_argument("--samples", type=int, default=400)
    parser.add_argument("--interval", type=float, default=0.01)
    args = parser.parse_args()
    script = GDB_SCRIPT.replace("__SAMPLES__", str(args.samples))
    script = script.replace("__INTERVAL__", str(args.interval))
    with tempfile.NamedTemporaryFile("w", suffix=".py") as handle:
        handle.write(script)
        handle.flush()
        run = subprocess.run(
            ["gdb", "-p", str(args.pid), "-batch", "-ex", "handle SIGINT stop nopass"]
            + ["-x", handle.name],
            capture_output=True,
            text=True,
        )
    line = next((s for s in run.stdout.splitlines() if s.startswith("SAMPLES ")), None)
    if line is None:
        sys.exit(f"gdb gave no samples:\n{run.stderr[-2000:]}")
    samples = [_name(s) for s in json.loads(line[len("SAMPLES ") :])]
    counts = Counter(samples)
    print(f"{'share':>6} {'samples':>7}  where")
    for where, count in counts.most_common(30):
        print(f"{count / len(samples):6.1%} {count:7d}  {where}")
    OUT.mkdir(exist_ok=True)
    target = OUT / "kernel_samples.json"
    target.write_text(
        json.dumps({"pid": args.pid, "samples": dict(counts.most_common())}, indent=1)
    )
    print(f"wrote {target}")


if __name__ == "__main__":
    main()
