"""``footmesh serve``: the command-line side of the web app, importable without FastAPI installed."""

from __future__ import annotations

import argparse

from footmesh.errors import InputError
from footmesh.web.settings import LOCAL_HOSTS, WebSettings

ANY_ADDRESS = ("0.0.0.0", "::", "")


def add_serve_command(sub: argparse._SubParsersAction) -> None:
    """Add ``serve`` to the ``footmesh`` command's subparsers."""
    d = WebSettings()
    serve = sub.add_parser("serve", help="run the web app: upload a foot photo, see the 3D foot, measurements, sizes")
    serve.add_argument("--host", default="127.0.0.1", help="address to listen on (default 127.0.0.1: this machine)")
    serve.add_argument("--port", type=int, default=8000, help="port (default 8000)")
    serve.add_argument("--workers", type=int, default=d.workers, help=f"measurements at once (default {d.workers})")
    serve.add_argument("--queue", type=int, default=d.queue, help=f"requests that may wait (default {d.queue})")
    serve.add_argument(
        "--time-limit", type=float, default=d.time_limit_s, help=f"seconds per measurement (default {d.time_limit_s:g})"
    )
    serve.add_argument(
        "--max-upload-mb", type=float, default=d.max_upload_bytes / 2**20, help="largest upload in MB (default 30)"
    )
    serve.add_argument(
        "--max-megapixels", type=float, default=d.max_pixels / 1e6, help="largest photo in megapixels (default 50)"
    )
    serve.add_argument(
        "--allowed-host",
        action="append",
        default=[],
        metavar="NAME",
        help="a host name clients use to reach the server (repeatable; default: this machine's names and --host)",
    )
    serve.set_defaults(func=run_serve)


def settings_from_args(args: argparse.Namespace) -> WebSettings:
    """``WebSettings`` from the ``serve`` arguments (``InputError`` for impossible limits)."""
    named = [] if args.host in ANY_ADDRESS or args.host in LOCAL_HOSTS else [args.host]
    try:
        return WebSettings(
            allowed_hosts=LOCAL_HOSTS + tuple(named) + tuple(args.allowed_host),
            workers=args.workers,
            queue=args.queue,
            time_limit_s=args.time_limit,
            max_upload_bytes=int(args.max_upload_mb * 2**20),
            max_pixels=int(args.max_megapixels * 1e6),
        )
    except ValueError as exc:  # WebSettings validates its limits: here they are the user's flags
        raise InputError(str(exc)) from None


def run_serve(args: argparse.Namespace) -> int:
    """Run the server until interrupted; a missing "web" extra is a one-line error."""
    if not 0 < args.port < 65536:
        raise InputError(f"--port must be 1..65535, got {args.port}")
    settings = settings_from_args(args)
    try:
        from footmesh.web.server import serve
    except ImportError as exc:
        hint = f"footmesh serve needs the web extra: pip install 'footmesh[web]' (missing {exc.name})"
        raise InputError(hint) from None
    serve(args.host, args.port, settings)
    return 0
