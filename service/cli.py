"""``mrdem`` command line: ``serve`` here; ``info`` and ``warmup`` from the engine."""

from __future__ import annotations

import argparse
import sys

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


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="mrdem", description="mrdem: multiresolution DEM")
    sub = parser.add_subparsers(dest="command", required=True)
    run = sub.add_parser("serve", help="run the HTTP service (settings from MRDEM_*)")
    run.add_argument("--host", help="overrides MRDEM_HOST")
    run.add_argument("--port", type=int, help="overrides MRDEM_PORT")
    run.add_argument("--data-dir", help="overrides MRDEM_DATA_DIR")
    sub.add_parser("info", help="versions, CPU and kernel cache")
    sub.add_parser("warmup", help="compile every kernel (or load it from the cache)")
    args = parser.parse_args(sys.argv[1:] if argv is None else argv)
    if args.command != "serve":
        return engine_cli.main([args.command])
    given = {"host": args.host, "port": args.port, "data_dir": args.data_dir}
    serve(Settings(**{k: v for k, v in given.items() if v is not None}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
