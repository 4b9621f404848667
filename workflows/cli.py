"""`lanecast`: the command-line entry point. Each command lives in its own module of this package.

A command module exposes ``register(subparsers)`` which adds its parser and sets ``func`` to the
function that runs it. Heavy imports (torch, SUMO) happen inside those functions so that
``lanecast --help`` is instant.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Sequence

from lanecast.io_adapters.errors import LanecastError

COMMANDS = ("demo", "simulate", "convert", "info", "windows", "train", "evaluate", "annotate", "report")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="lanecast",
        description="Highway maneuver and trajectory prediction (Mersch et al., IROS 2021) for datasets and drive logs.",
        epilog="Start with: lanecast demo",
    )
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name in COMMANDS:
        try:
            module = importlib.import_module(f"lanecast.workflows.{name}")
        except ModuleNotFoundError as exc:
            if exc.name == f"lanecast.workflows.{name}":
                continue
            raise
        module.register(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        status = args.func(args)
    except LanecastError as exc:
        print(f"lanecast {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"lanecast {args.command}: interrupted", file=sys.stderr)
        return 130
    return int(status or 0)


if __name__ == "__main__":
    sys.exit(main())
