"""`lanecast`: the command-line entry point. Each command lives in its own module of this package.

A command module exposes ``register(subparsers)`` which adds its parser and sets ``func`` to the
function that runs it. Heavy imports (torch, SUMO) happen inside those functions so that
``lanecast --help`` is instant.
"""

from __future__ import annotations

import argparse
import codecs
import errno
import importlib
import io
import os
import signal
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from types import FrameType
from typing import Any

import lanecast
from lanecast.io_adapters import arrow_pandas
from lanecast.io_adapters.errors import InputError, LanecastError
from lanecast.workflows.vocabulary import HelpFormatter

#: Every command and its one-line help, in the order `lanecast --help` lists them. The top-level help
#: and a command's own run import only what they need: the one command's module, not every reader
#: and model library (a test checks these lines against each module's own ``help=``).
SUMMARIES = {
    "demo": "simulate, convert, annotate and evaluate a highway with the shipped weights",
    "simulate": "simulate highway traffic with SUMO and write it as a highD recording",
    "convert": "convert highD, NGSIM, MCAP, ROS bags or a track table into a track table or a drive log",
    "info": "summarise a dataset, track table or drive log",
    "windows": "cut a track table into network windows (4x8x30 inputs, 5 s futures, maneuver labels, splits)",
    "train": "train the ST-CNN (classifier and regressor) on a windows dataset",
    "evaluate": "metrics and a report of a model against constant-velocity/-acceleration baselines",
    "export": "export a model to ONNX (then every command predicts with ONNX Runtime)",
    "ablate": "retrain and score the paper's seven ablation variants (Table II)",
    "explain": "what-if forecasts of one target with its neighbours removed (the paper's Figs. 4-5)",
    "annotate": "write forecasts into drive logs (MCAP, ROS 2 and ROS 1 bags), one machine or a Ray cluster",
    "report": "metrics of annotated logs against the future recorded in them",
}
COMMANDS = tuple(SUMMARIES)


# What lanecast prints beyond ASCII (help texts, units, arrows), spelled in ASCII for a terminal
# whose encoding lacks it (a Latin-1 or ASCII locale, PYTHONIOENCODING=ascii); anything else is "?".
ASCII_SPELLING = {
    "→": "->", "←": "<-", "…": "...", "×": "x", "–": "-", "—": "-", "−": "-", "≥": ">=", "≤": "<=",
    "±": "+/-", "·": ".", "²": "^2", "°": " deg", "µ": "u", "≈": "~", "‘": "'", "’": "'", "“": '"', "”": '"',
}  # fmt: skip


def escaped_byte(char: str) -> bool:
    """A byte of a file name that the locale's encoding could not decode (Python's surrogate escape)."""
    return "\udc80" <= char <= "\udcff"


def _spell_in_ascii(error: UnicodeError) -> tuple[str | bytes, int]:
    """Codec error handler: the characters a stream cannot encode, spelled with ASCII_SPELLING; the
    undecodable bytes of a file name (surrogate escapes) written back as the bytes they were."""
    if not isinstance(error, UnicodeEncodeError):
        raise error
    bad = error.object[error.start : error.end]
    if all(map(escaped_byte, bad)):
        return bytes(ord(c) - 0xDC00 for c in bad), error.end
    return "".join(ASCII_SPELLING.get(c, "?") for c in bad), error.end


codecs.register_error("lanecast-ascii", _spell_in_ascii)


def printable_everywhere() -> None:
    """stdout and stderr never fail on a character their encoding lacks: ``lanecast demo --help``
    on a terminal that is not UTF-8 printed a traceback at its first arrow."""
    for stream in (sys.stdout, sys.stderr):
        # a C locale gives "surrogateescape", which still fails on an en dash, and stderr's
        # "backslashreplace" printed an error's en dash as \u2013 and a file name's bytes as \udcc3;
        # the handler keeps surrogate-escaped file-name bytes as they were
        if isinstance(stream, io.TextIOWrapper) and stream.errors in (
            "strict",
            "surrogateescape",
            "backslashreplace",
        ):
            stream.reconfigure(errors="lanecast-ascii")


class VersionAction(argparse.Action):
    """``--version``: the version is looked up only when asked for (see lanecast.__getattr__)."""

    def __init__(self, option_strings: list[str], dest: str, **kwargs: Any) -> None:
        super().__init__(option_strings, dest, nargs=0, default=argparse.SUPPRESS, **kwargs)

    def __call__(self, parser: argparse.ArgumentParser, *_: Any) -> None:
        print(f"lanecast {lanecast.__version__}")
        parser.exit()


def build_parser(only: str | bool | None = True) -> argparse.ArgumentParser:
    """The command line's parser. ``only``: True builds every command's parser (importing every
    command module); a command's name builds that one and lists the others by their one-line help;
    None builds none (the top-level help and ``--version``), for a start-up that imports nothing else."""
    parser = argparse.ArgumentParser(
        prog="lanecast",
        description="Highway maneuver and trajectory prediction (Mersch et al., IROS 2021) for datasets and drive logs.",
        epilog="Start with: lanecast demo",
        formatter_class=HelpFormatter,
    )
    parser.add_argument("--version", action=VersionAction, help="show lanecast's version and exit")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name in COMMANDS:
        if only is not True and name != only:
            sub.add_parser(name, help=SUMMARIES[name], add_help=False)  # listed, not built
            continue
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


def subcommand(parser: argparse.ArgumentParser, name: str) -> argparse.ArgumentParser:
    """The parser of command ``name``."""
    command = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return command.choices[name]


def parse(parser: argparse.ArgumentParser, argv: Sequence[str] | None) -> argparse.Namespace:
    """The arguments; one the command does not take is refused with the command's own usage and name
    (``lanecast demo --bogus`` showed the top-level usage and 'lanecast: error:', as if the
    command were wrong)."""
    given = list(sys.argv[1:] if argv is None else argv)
    commands = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction)).choices
    first = next((a for a in given if not a.startswith("-")), None)
    if first is not None and first not in commands and given.index(first) == 0:
        import difflib  # only for a mistyped command: not on every start

        close = difflib.get_close_matches(first, list(commands), n=1, cutoff=0.6)
        hint = f"; did you mean {close[0]!r}?" if close else ""
        parser.error(f"unknown command {first!r}{hint} (commands: {', '.join(commands)})")
    args, extra = parser.parse_known_args(argv)
    if extra:
        subcommand(parser, args.command).error(f"unrecognized arguments: {' '.join(extra)}")
    return args


#: what an OSError without a file name means about the output: the disk it is written to
OUTPUT_ERRNOS = {
    errno.ENOSPC: "free space on its disk",
    errno.EDQUOT: "room in your disk quota",
    errno.EFBIG: "a file size the system allows (ulimit -f)",
}


def environment_error(exc: OSError, args: argparse.Namespace) -> str:
    """An OSError as one line naming the path. A write that fails for lack of space comes from a
    library (pyarrow, a file's flush) without a file name, and pyarrow's text is its own ('Error
    writing bytes to file. Detail: [errno 28] …'): the output is --out, the reason the errno's."""
    if exc.filename:
        return f"{exc.filename}: {exc.strerror or exc}"
    out = getattr(args, "out", None)
    if exc.errno in OUTPUT_ERRNOS and out is not None:
        reason = os.strerror(exc.errno)
        return f"{out}: {reason} (expected {OUTPUT_ERRNOS[exc.errno]} for --out, or another --out)"
    return exc.strerror or str(exc)  # pyarrow's text names the file ('Failed to open local file …')


def utf8_expected() -> str:
    """How to make file names reach pyarrow as they are on disk."""
    if codecs.lookup(sys.getfilesystemencoding()).name == "utf-8":  # the name's bytes are not UTF-8
        return "a file or folder name in UTF-8: rename it"
    return "a UTF-8 locale: run with LC_ALL=C.UTF-8 or PYTHONUTF8=1"


def non_utf8_names(args: argparse.Namespace) -> str | None:
    """pyarrow opens files by their names in UTF-8. In a locale whose file-name encoding is another
    (C without UTF-8 mode: ASCII; ISO-8859-1), a non-ASCII name in a path given or in the working
    directory reached it as other bytes: a traceback after the demo's simulation (ASCII), or 'No such
    file or directory' for a folder that exists (Latin-1). Refused up front, naming the path."""
    encoding = sys.getfilesystemencoding()
    if codecs.lookup(encoding).name == "utf-8":
        return None
    given = [v for value in vars(args).values() for v in (value if isinstance(value, list) else [value])]
    paths = [Path(v) for v in given if isinstance(v, Path) or (isinstance(v, str) and os.path.lexists(v))]
    try:
        paths.append(Path.cwd())
    except OSError:  # a working directory removed since: every command says so itself
        pass
    named = next((path for path in paths if not str(path).isascii()), None)
    if named is None:
        return None
    return (
        f"{named}: a name beyond ASCII, which this locale encodes in {encoding} but pyarrow in UTF-8 "
        f"(expected {utf8_expected()})"
    )


def unencodable_path(exc: UnicodeEncodeError) -> str | None:
    """A path holding bytes this locale cannot decode (surrogate escapes: a non-ASCII file or folder
    name in a C locale without UTF-8 mode) cannot be handed to pyarrow, which takes UTF-8 text only:
    one line naming the path and the way out, not a traceback. None for any other encode error."""
    if not any(map(escaped_byte, exc.object[exc.start : exc.end])):
        return None
    path = Path(exc.object)  # named up to the first name with such bytes, not a temporary file in it
    named = next((p for p in reversed((path, *path.parents)) if any(map(escaped_byte, p.name))), path)
    encoding = sys.getfilesystemencoding()
    return f"{named}: a name not in this locale's encoding ({encoding}), which pyarrow needs (expected {utf8_expected()})"


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
    for action in subcommand(parser, args.command)._actions:
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
    """Run the command in ``argv``; None: this process's command line (the ``lanecast`` script,
    ``python -m lanecast``), which also defers pandas in the process (io_adapters/arrow_pandas.py)."""
    printable_everywhere()
    if argv is None:
        arrow_pandas.defer()
    given = list(sys.argv[1:] if argv is None else argv)
    command = next((a for a in given if not a.startswith("-")), None)
    parser = build_parser(only=command if command in SUMMARIES else None)
    if not given:  # `lanecast` alone: what it can do, not a usage error
        parser.print_help()
        return 0
    args = parse(parser, argv)
    if (refused := non_utf8_names(args)) is not None:
        print(f"lanecast {args.command}: error: {refused}", file=sys.stderr)
        return 2
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
        print(f"lanecast {args.command}: error: {environment_error(exc, args)}", file=sys.stderr)
        return 2
    except UnicodeEncodeError as exc:
        message = unencodable_path(exc)
        if message is None:
            raise
        print(f"lanecast {args.command}: error: {message}", file=sys.stderr)
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
