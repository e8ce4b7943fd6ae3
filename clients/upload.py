"""``mrdem upload`` (``python -m clients.upload``): upload mesh files to a running service
and wait for their surrogate trees, with a progress line while a build runs; prints each
mesh's id, size and what the service's repair changed.

    mrdem upload gear.stl scene.obj --url http://127.0.0.1:8000 --epsilon 0.001

Exit status: 0 when every file was uploaded and built, 1 otherwise (each failure is
printed with the service's reason; a ``--timeout`` expiry prints the job's URL, whose
build goes on). Imports neither engine nor service.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path
from typing import TextIO

from .errors import ClientError
from .models import BuildJob, MeshInfo
from .sync import Client

__all__ = ["ProgressLine", "describe", "main"]


class ProgressLine:
    """``progress`` callback of :meth:`Client.upload_mesh` that rewrites one line of
    ``out`` (a terminal): the job's status, tree levels and nodes built so far, seconds
    waited. When ``out`` is not a terminal (a log, a pipe), one plain line per change of
    status or level instead."""

    def __init__(self, name: str, out: TextIO | None = None) -> None:
        self.name, self.out = name, out or sys.stderr
        self.start = time.monotonic()
        self.shown = False
        isatty = getattr(self.out, "isatty", None)
        self.terminal = bool(isatty and isatty())
        self.last: tuple | None = None

    def __call__(self, job: BuildJob) -> None:
        seconds = time.monotonic() - self.start
        text = (
            f"{self.name}: {job.status} — {job.triangles:,} triangles, level {job.levels},"
            f" {job.nodes:,} nodes ({seconds:.1f} s)"
        )
        if self.terminal:
            self.out.write("\r" + text.ljust(79))
            self.shown = True
        elif (job.status, job.levels) != self.last:
            self.out.write(text + "\n")
        self.last = (job.status, job.levels)
        self.out.flush()

    def end(self) -> None:
        """End the progress line (if one was written on a terminal)."""
        if self.shown:
            self.out.write("\n")
            self.out.flush()
            self.shown = False


def describe(info: MeshInfo) -> str:
    """One line about an uploaded mesh: id, size, tree and the repair report."""
    text = (
        f"{info.id}: {info.triangles:,} triangles, {info.vertices:,} vertices,"
        f" ε {info.epsilon:.6g}, {info.levels} tree levels"
        f"{', watertight' if info.watertight else ', open'}"
        f"{'' if info.created else ' (already stored)'}"
    )
    if info.repair.get("changed"):
        counts = [
            f"{k.replace('_', ' ')} {v:,}"
            for k, v in info.repair.items()
            if isinstance(v, int) and not isinstance(v, bool) and v
        ]
        text += "; repaired: " + (", ".join(counts) or "yes")
    return text


def _say(text: str) -> None:
    sys.stdout.write(text + "\n")
    sys.stdout.flush()


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="mrdem upload", description="upload mesh files and wait for their trees"
    )
    parser.add_argument("files", nargs="+", type=Path, help="STL, OBJ, PLY, OFF or GLB files")
    parser.add_argument(
        "--url", default=os.environ.get("MRDEM_URL", "http://127.0.0.1:8000"), help="service"
    )
    parser.add_argument("--api-key", default=os.environ.get("MRDEM_API_KEY"))
    parser.add_argument("--epsilon", type=float, help="ε of the mesh (default: the service's)")
    parser.add_argument("--branching", type=int, help="tree branching (default: 8)")
    parser.add_argument(
        "--strict", action="store_true", help="reject meshes that need repair instead"
    )
    parser.add_argument("--no-wait", action="store_true", help="do not wait for the trees")
    parser.add_argument("--timeout", type=float, help="seconds to wait per mesh (default: all)")
    parser.add_argument("--quiet", action="store_true", help="no progress line")
    args = parser.parse_args(argv)
    failed = 0
    with Client(args.url, api_key=args.api_key) as client:
        for path in args.files:
            line = ProgressLine(path.name)
            try:
                outcome = client.upload_mesh(
                    path,
                    epsilon=args.epsilon,
                    branching=args.branching,
                    strict=True if args.strict else None,
                    wait=not args.no_wait,
                    timeout=args.timeout,
                    progress=None if args.quiet else line,
                )
            except (ClientError, OSError) as error:
                line.end()
                _say(f"{path}: {error}")
                failed += 1
                continue
            line.end()
            if isinstance(outcome, BuildJob):  # --no-wait and the build goes on
                _say(f"{path}: building as {outcome.url} (mesh {outcome.mesh})")
            else:
                _say(f"{path}: {describe(outcome)}")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
