"""`lanecast convert`: any supported input to a track table (Parquet) or a drive log."""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

from lanecast.io_adapters import registry
from lanecast.io_adapters.contracts import track_table
from lanecast.io_adapters.errors import InputError
from lanecast.io_adapters.files import check_output
from lanecast.workflows.vocabulary import HelpFormatter

_SUFFIX_TO_FORMAT = {".parquet": "parquet", ".pq": "parquet", ".mcap": "mcap", ".bag": "ros1"}


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "convert",
        help="convert highD, NGSIM, MCAP, ROS bags or a track table into a track table or a drive log",
        description=(
            "Read INPUTs (format detected per file, or --format) into lanecast's track table and write it as "
            "Parquet (default) or as a drive log (--to mcap|ros2|ros1)."
        ),
        epilog=(
            "examples:\n"
            "  lanecast convert data/highD/01_tracks.csv --out highd-01.parquet\n"
            "  lanecast convert trajectories-0750am-0805am.txt --out us101.parquet\n"
            "  lanecast convert highd-01.parquet --to mcap --out highd-01.mcap"
        ),
        formatter_class=HelpFormatter,
    )
    p.add_argument("inputs", nargs="+", metavar="INPUT", help="files or directories to read")
    p.add_argument("--out", required=True, type=Path, help="output path")
    p.add_argument("--format", choices=sorted(registry.READERS), help="input format (default: detected)")
    p.add_argument(
        "--to",
        choices=sorted(registry.WRITERS),
        help="output format (default: from --out's suffix, else parquet)",
    )
    p.add_argument(
        "--topic", help="for logs: the topic with tracked objects (default: every supported topic)"
    )
    p.add_argument(
        "--salvage", action="store_true", help="for damaged MCAP: read every intact chunk and report the loss"
    )
    p.set_defaults(func=run)


def output_format(out: Path, to: str | None) -> str:
    return to or _SUFFIX_TO_FORMAT.get(out.suffix.lower(), "parquet")


def run(args: argparse.Namespace) -> int:
    started = time.perf_counter()
    options = {}
    if args.topic:
        options["topic"] = args.topic
    if args.salvage:
        options["salvage"] = True
    check_output(args.out, directory=output_format(args.out, args.to) == "ros2")
    if os.path.realpath(args.out) in {os.path.realpath(p) for p in args.inputs}:
        raise InputError(args.out, "the output would overwrite an input", expected="a new output path")
    table = registry.read_any(args.inputs, fmt=args.format, **options)
    fmt = output_format(args.out, args.to)
    path = registry.write_any(table, args.out, fmt)
    n_tracks = len(track_table.track_boundaries(table)) - 1
    print(
        f"wrote {path} ({fmt}): {table.num_rows:,} rows, {n_tracks:,} tracks "
        f"in {time.perf_counter() - started:.1f} s"
    )
    return 0
