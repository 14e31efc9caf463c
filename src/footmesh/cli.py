"""Command-line interface: ``footmesh <command> ...``; ``main(argv) -> exit code`` so tests can call it."""

from __future__ import annotations

import argparse
import logging
import sys

from footmesh import __version__

log = logging.getLogger("footmesh")


class UserError(Exception):
    """An error caused by the input, reported as one clear line and a non-zero exit, never a traceback."""


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="footmesh", description=__doc__)
    parser.add_argument("--version", action="version", version=f"footmesh {__version__}")
    parser.add_argument("-v", "--verbose", action="store_true", help="more log output")
    sub = parser.add_subparsers(dest="command", required=True)
    _add_model_commands(sub)
    _add_demo_command(sub)
    return parser


# --- footmesh demo ------------------------------------------------------------------------------------------


def _add_demo_command(sub: argparse._SubParsersAction) -> None:
    demo = sub.add_parser(
        "demo", help="sample, pose, canonicalise and measure a foot; write OBJ, JSON and PNG"
    )
    demo.add_argument("--out", default="demo_out", help="output folder (default: demo_out)")
    demo.add_argument("--seed", type=int, default=0, help="random seed (default: 0)")
    demo.add_argument("--side", choices=("left", "right"), default="left")
    demo.set_defaults(func=_run_demo)


def _run_demo(args: argparse.Namespace) -> int:
    from footmesh.demo import DemoConfig, run_demo

    run_demo(args.out, DemoConfig(seed=args.seed, side=args.side))
    return 0


# --- footmesh model ... -------------------------------------------------------------------------------------


def _add_model_commands(sub: argparse._SubParsersAction) -> None:
    model = sub.add_parser("model", help="build and inspect foot models")
    model_sub = model.add_subparsers(dest="model_command", required=True)
    del model_sub  # subcommands are added below by the modules' owners


# --- entry point ---------------------------------------------------------------------------------------------


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.DEBUG if args.verbose else logging.INFO, format="%(message)s")
    try:
        return int(args.func(args) or 0)
    except (UserError, FileNotFoundError, ValueError) as exc:
        print(f"footmesh: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("footmesh: interrupted", file=sys.stderr)
        return 130
