"""`lanecast`: the command-line entry point. Each command lives in its own module of this package.

A command module exposes ``register(subparsers)`` which adds its parser and sets ``func`` to the
function that runs it. Heavy imports (torch, SUMO) happen inside those functions so that
``lanecast --help`` is instant.
"""

from __future__ import annotations

import argparse
import codecs
import importlib
import io
import os
import signal
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from types import FrameType

from lanecast import __version__
from lanecast.io_adapters.errors import InputError, LanecastError
from lanecast.workflows.vocabulary import HelpFormatter

COMMANDS = (
    "demo",
    "simulate",
    "convert",
    "info",
    "windows",
    "train",
    "evaluate",
    "export",
    "ablate",
    "explain",
    "annotate",
    "report",
)


# What lanecast prints beyond ASCII (help texts, units, arrows), spelled in ASCII for a terminal
# whose encoding lacks it (a Latin-1 or ASCII locale, PYTHONIOENCODING=ascii); anything else is "?".
ASCII_SPELLING = {
    "→": "->", "←": "<-", "…": "...", "×": "x", "–": "-", "—": "-", "−": "-", "≥": ">=", "≤": "<=",
    "±": "+/-", "·": ".", "²": "^2", "°": " deg", "µ": "u", "≈": "~", "‘": "'", "’": "'", "“": '"', "”": '"',
}  # fmt: skip


def _spell_in_ascii(error: UnicodeError) -> tuple[str | bytes, int]:
    """Codec error handler: the characters a stream cannot encode, spelled with ASCII_SPELLING; the
    undecodable bytes of a file name (surrogate escapes) written back as the bytes they were."""
    if not isinstance(error, UnicodeEncodeError):
        raise error
    bad = error.object[error.start : error.end]
    if all("\udc80" <= c <= "\udcff" for c in bad):
        return bytes(ord(c) - 0xDC00 for c in bad), error.end
    return "".join(ASCII_SPELLING.get(c, "?") for c in bad), error.end


codecs.register_error("lanecast-ascii", _spell_in_ascii)


def printable_everywhere() -> None:
    """stdout and stderr never fail on a character their encoding lacks: ``lanecast demo --help``
    on a terminal that is not UTF-8 printed a traceback at its first arrow."""
    for stream in (sys.stdout, sys.stderr):
        # a C locale gives "surrogateescape", which still fails on an en dash; the handler keeps
        # surrogate-escaped file-name bytes as they were
        if isinstance(stream, io.TextIOWrapper) and stream.errors in ("strict", "surrogateescape"):
            stream.reconfigure(errors="lanecast-ascii")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="lanecast",
        description="Highway maneuver and trajectory prediction (Mersch et al., IROS 2021) for datasets and drive logs.",
        epilog="Start with: lanecast demo",
        formatter_class=HelpFormatter,
    )
    parser.add_argument("--version", action="version", version=f"lanecast {__version__}")
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


def _stdout_closed() -> int:
    """The reader of stdout went away (``lanecast info … | head``): stop quietly, as Unix tools do.

    Python would report the failed flush of stdout at exit: point stdout at /dev/null first."""
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, sys.stdout.fileno())
    os.close(devnull)
    return 141  # 128 + SIGPIPE, what a shell reports for a tool killed by the closed pipe


def what_is_needed(exc: LanecastError, parser: argparse.ArgumentParser, args: argparse.Namespace) -> str:
    """For an input named on the command line that does not exist (a --help example run before the
    one that makes its input, or one on a dataset not at hand): which argument it is and what that
    argument takes, from the command's own help."""
    if (
        not isinstance(exc, InputError)
        or exc.expected is not None
        or exc.reason != "no such file or directory"
    ):
        return ""
    command = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    for action in command.choices[args.command]._actions:
        given = getattr(args, action.dest, None)
        values = given if isinstance(given, list) else [given]
        if not action.option_strings and action.help and exc.path in {str(Path(v)) for v in values if v}:
            return f" (expected {action.metavar}: {action.help})"
    return ""


class Terminated(KeyboardInterrupt):
    """SIGTERM (a batch system stopping the job): handled as Ctrl-C is, so that temporary outputs
    are removed on the way out instead of left beside the output."""


def _on_sigterm(pid: int) -> Callable[[int, FrameType | None], None]:
    def handler(signum: int, _frame: FrameType | None) -> None:
        if os.getpid() != pid:  # a forked worker: end as the default handler does
            signal.signal(signum, signal.SIG_DFL)
            os.kill(os.getpid(), signum)
            return
        raise Terminated

    return handler


def main(argv: Sequence[str] | None = None) -> int:
    printable_everywhere()
    parser = build_parser()
    if not (sys.argv[1:] if argv is None else argv):  # `lanecast` alone: what it can do, not a usage error
        parser.print_help()
        return 0
    args = parser.parse_args(argv)
    try:
        previous = signal.signal(signal.SIGTERM, _on_sigterm(os.getpid()))
    except ValueError:  # not the main thread: no handler of ours
        previous = None
    try:
        status = args.func(args)
        sys.stdout.flush()
    except BrokenPipeError:
        return _stdout_closed()
    except LanecastError as exc:
        print(f"lanecast {args.command}: error: {exc}{what_is_needed(exc, parser, args)}", file=sys.stderr)
        return 2
    except OSError as exc:  # the environment, not a bug: a full disk, a vanished or unwritable path
        where = f"{exc.filename}: " if exc.filename else ""
        print(f"lanecast {args.command}: error: {where}{exc.strerror or exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt as exc:
        terminated = isinstance(exc, Terminated)
        print(f"lanecast {args.command}: {'terminated' if terminated else 'interrupted'}", file=sys.stderr)
        return 143 if terminated else 130  # 128 + SIGTERM or SIGINT, as a shell reports them
    finally:
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)
    return int(status or 0)


if __name__ == "__main__":
    sys.exit(main())
