"""``mrdem`` command line: engine information and kernel warm-up.

``mrdem info``    versions, CPU, vector ISA seen by LLVM, kernel cache directory.
``mrdem warmup``  compile (or load from the cache) every kernel; prints the seconds.

The service adds ``mrdem serve``; the command then moves to the service layer
(engine must not import it).
"""

from __future__ import annotations

import argparse
import json
import platform
import sys


def _info() -> dict:
    import llvmlite.binding as llvm
    import numba
    import numpy as np

    from engine.geometry.distance import DEFAULT_ITERATIONS
    from engine.kernels.jit import KERNEL_SOURCE_HASH

    return {
        "python": platform.python_version(),
        "numpy": np.__version__,
        "numba": numba.__version__,
        "cpu": llvm.get_host_cpu_name(),
        "kernel_cache": numba.config.CACHE_DIR,
        "kernel_source_hash": KERNEL_SOURCE_HASH,
        "default_iterations": DEFAULT_ITERATIONS,
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="mrdem", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    sub.add_parser("info", help="versions, CPU and kernel cache")
    warm = sub.add_parser("warmup", help="compile every kernel (or load it from the cache)")
    warm.add_argument(
        "--workers",
        type=int,
        default=None,
        help="processes compiling at once (default: 1 on a warm cache, else 2 or 1 per CPU)",
    )
    args = parser.parse_args(argv)
    if args.command == "info":
        print(json.dumps(_info(), indent=2))
    elif args.command == "warmup":
        from engine.errors import InvalidArgumentError
        from engine.warmup import warmup

        try:
            print(f"kernels ready in {warmup(args.workers):.2f} s")
        except InvalidArgumentError as exc:
            parser.error(str(exc))
    return 0


if __name__ == "__main__":
    sys.exit(main())
