"""``mrdem`` command line: ``serve``, ``demo`` and ``upload`` (the client programs
``clients.demo`` and ``clients.upload``, run as separate processes), ``bench`` (the
benchmark scripts); ``info`` and ``warmup`` from the engine."""

from __future__ import annotations

import argparse
import subprocess
import sys
import time
from pathlib import Path

from pydantic import ValidationError

from engine import cli as engine_cli

from .settings import Settings

__all__ = ["main", "serve"]


def serve(settings: Settings | None = None) -> None:
    """Run the service with uvicorn (one process; settings from ``MRDEM_*``)."""
    import uvicorn

    from .app import create_app

    settings = settings or Settings()
    uvicorn.run(
        create_app(settings),
        host=settings.host,
        port=settings.port,
        log_level="info",
        timeout_graceful_shutdown=10,
    )


BENCHMARKS = ("kernels", "trees", "surrogates", "lemma1", "broadphase", "dynamics", "service")
QUICK = ("kernels", "dynamics", "service")  # the scripts that take --quick


def bench(names: list[str], quick: bool, root: Path | None = None) -> int:
    """Run ``benchmarks/<name>.py`` of a source checkout one after another, each one's
    output into ``bench-results/<name>.log``, with a progress bar; returns the number of
    scripts that failed."""
    root = root or Path(__file__).resolve().parents[1]
    folder = root / "benchmarks"
    if not folder.is_dir():
        print("mrdem bench needs a source checkout (benchmarks/ next to service/)")
        return 1
    (root / "bench-results").mkdir(exist_ok=True)
    failed = 0
    begin = time.perf_counter()
    for i, name in enumerate(names):
        command = [sys.executable, str(folder / f"{name}.py")]
        if quick and name in QUICK:
            command.append("--quick")
        log = root / "bench-results" / f"{name}.log"
        start = time.perf_counter()
        with open(log, "wb") as out:
            proc = subprocess.Popen(command, cwd=root, stdout=out, stderr=subprocess.STDOUT)
            while proc.poll() is None:
                _progress(i, len(names), name, time.perf_counter() - start)
                time.sleep(0.5)
        failed += proc.returncode != 0
        status = "ok" if proc.returncode == 0 else f"FAILED ({proc.returncode})"
        print(
            f"\r{_bar(i + 1, len(names))} {name}: {status} in"
            f" {time.perf_counter() - start:.0f} s -> {log}" + " " * 10
        )
    print(f"{len(names) - failed}/{len(names)} benchmarks in {time.perf_counter() - begin:.0f} s")
    return failed


def _bar(done: int, total: int, width: int = 24) -> str:
    filled = round(width * done / total)
    return f"[{'#' * filled}{'-' * (width - filled)}] {done}/{total}"


def _progress(done: int, total: int, name: str, seconds: float) -> None:
    print(f"\r{_bar(done, total)} {name} ({seconds:.0f} s)", end="", flush=True)


def _settings(command: str, **given) -> Settings | None:
    """The settings from ``MRDEM_*`` and ``given`` (its None values left out); None, once
    what is wrong with them is printed (each problem with its variable's name)."""
    try:
        return Settings(**{k: v for k, v in given.items() if v is not None})
    except ValidationError as error:
        for problem in error.errors():
            where = f"MRDEM_{problem['loc'][0]}".upper() if problem["loc"] else "settings"
            print(f"mrdem {command}: {where}: {problem['msg']}", file=sys.stderr)
        return None


def _cluster(args) -> int:
    """``mrdem cluster serve``: the service on the Ray cluster at ``--address``."""
    try:
        from .cluster import run
        from .cluster.deployment import scaling
    except ImportError as exc:
        print(f"mrdem cluster needs Ray: pip install 'mrdem[cluster]' ({exc})", file=sys.stderr)
        return 2
    settings = _settings(
        "cluster serve",
        host=args.host,
        port=args.port,
        replicas=args.replicas,
        replicas_max=args.replicas_max,
        replica_cpus=args.replica_cpus,
    )
    if settings is None:
        return 2
    try:  # before reaching for the cluster
        scaling(settings, settings.replicas, settings.replica_cpus)
    except ValueError as error:
        print(f"mrdem cluster serve: {error}", file=sys.stderr)
        return 2
    if not (settings.store_url and settings.object_store_url):
        print(
            "mrdem cluster serve: replicas share their store; set MRDEM_STORE_URL"
            " (postgresql://…) and MRDEM_OBJECT_STORE_URL (s3://bucket/prefix)",
            file=sys.stderr,
        )
        return 2
    run(
        settings.model_copy(update={"data_dir": settings.data_dir.resolve()}),
        args.address,
        settings.replicas,
        settings.replica_cpus,
        blocking=not args.detach,
    )
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="mrdem", description="mrdem: multiresolution DEM")
    sub = parser.add_subparsers(dest="command", required=True)
    run = sub.add_parser("serve", help="run the HTTP service (settings from MRDEM_*)")
    run.add_argument("--host", help="overrides MRDEM_HOST")
    run.add_argument("--port", type=int, help="overrides MRDEM_PORT")
    run.add_argument("--data-dir", help="overrides MRDEM_DATA_DIR")
    cluster = sub.add_parser(
        "cluster", help="scale out on Ray: `mrdem cluster serve` (needs mrdem[cluster])"
    )
    cluster_sub = cluster.add_subparsers(dest="cluster_command", required=True)
    on_ray = cluster_sub.add_parser(
        "serve",
        help="deploy the service on a Ray cluster (Serve replicas, scenes as actors); settings"
        " from MRDEM_*, MRDEM_STORE_URL and MRDEM_OBJECT_STORE_URL required",
    )
    on_ray.add_argument(
        "--address", default="auto", help="the Ray cluster (default: auto, the one joined)"
    )
    on_ray.add_argument("--replicas", type=int, help="overrides MRDEM_REPLICAS")
    on_ray.add_argument(
        "--replicas-max",
        type=int,
        help="overrides MRDEM_REPLICAS_MAX (above --replicas: replicas added and removed by load)",
    )
    on_ray.add_argument("--replica-cpus", type=float, help="overrides MRDEM_REPLICA_CPUS")
    on_ray.add_argument("--host", help="overrides MRDEM_HOST (Serve's HTTP proxy)")
    on_ray.add_argument("--port", type=int, help="overrides MRDEM_PORT")
    on_ray.add_argument(
        "--detach", action="store_true", help="deploy and return (the app keeps running)"
    )
    sub.add_parser("info", help="versions, CPU and kernel cache")
    warm = sub.add_parser("warmup", help="compile every kernel (or load it from the cache)")
    warm.add_argument("--workers", type=int, help="processes compiling at once")
    sub.add_parser(
        "demo",
        help="particle on a plane through the client: CSV, PNG and VTK (see --help)",
        add_help=False,
    )
    sub.add_parser(
        "upload",
        help="upload mesh files to a service and wait for their trees, with progress",
        add_help=False,
    )
    marks = sub.add_parser("bench", help="run the benchmarks (source checkout) with progress")
    marks.add_argument("names", nargs="*", help=f"any of {', '.join(BENCHMARKS)} (all)")
    marks.add_argument("--quick", action="store_true", help="shorter runs where supported")
    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] in (["demo"], ["upload"]):  # client programs: service never imports clients
        return subprocess.call([sys.executable, "-m", f"clients.{argv[0]}", *argv[1:]])
    args = parser.parse_args(argv)
    if args.command == "warmup" and args.workers is not None:
        return engine_cli.main(["warmup", "--workers", str(args.workers)])
    if args.command in ("info", "warmup"):
        return engine_cli.main([args.command])
    if args.command == "bench":
        unknown = sorted(set(args.names) - set(BENCHMARKS))
        if unknown:
            parser.error(f"unknown benchmarks {unknown}; choose from {list(BENCHMARKS)}")
        return bench(list(args.names) or list(BENCHMARKS), args.quick)
    if args.command == "cluster":
        return _cluster(args)
    settings = _settings("serve", host=args.host, port=args.port, data_dir=args.data_dir)
    if settings is None:
        return 2
    serve(settings)
    return 0


if __name__ == "__main__":
    sys.exit(main())
