"""The ``bioslam`` command: one module per subcommand, each exposing ``register(subparsers)``.

A subcommand module adds its parser and sets ``func`` to a callable taking the parsed
arguments and returning a dict: the one-line JSON summary printed last on stdout.
"""

from __future__ import annotations

import argparse
import importlib
import json
import sys
from collections.abc import Sequence

from bioslam import __version__

SUBCOMMAND_MODULES = ("info", "sim", "run", "demo", "eval", "batch")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="bioslam",
        description="Biologically-inspired 2D LiDAR SLAM: odometry, boundary cells, "
        "pose cells and a cognitive map.",
    )
    parser.add_argument("--version", action="version", version=f"bioslam {__version__}")
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in SUBCOMMAND_MODULES:
        importlib.import_module(f"bioslam.cli.{name}").register(subparsers)
    return parser


def print_summary(summary: dict) -> None:
    """Print the machine-readable summary as the last stdout line."""
    print(json.dumps(summary, sort_keys=False, default=float), flush=True)


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 0
    try:
        summary = args.func(args)
    except (FileNotFoundError, ValueError, RuntimeError) as exc:
        print(f"bioslam {args.command}: error: {exc}", file=sys.stderr)
        return 2
    if summary is not None:
        print_summary(summary)
    return 0


if __name__ == "__main__":
    sys.exit(main())
