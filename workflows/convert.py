"""`lanecast convert`: any supported input to a track table (Parquet) or a drive log."""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

from lanecast.io_adapters.datasets.csp import cli as csp_cli
from lanecast.io_adapters.errors import InputError, UsageError
from lanecast.io_adapters.formats import registry
from lanecast.io_adapters.formats.registry import ROS2_STORAGES as STORAGES
from lanecast.workflows.bulk import backends
from lanecast.workflows.vocabulary import HelpFormatter, add_force_option, add_location_option

_SUFFIX_TO_FORMAT = {".parquet": "parquet", ".pq": "parquet", ".mcap": "mcap", ".bag": "ros1"}
_FORMAT_SUFFIXES = {"parquet": (".parquet", ".pq"), "mcap": (".mcap",), "ros1": (".bag",)}


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "convert",
        help="convert highD, NGSIM, MCAP, ROS bags or a track table into a track table or a drive log",
        description=(
            "Read INPUTs (format detected per file, or --format) into lanecast's track table and write it as "
            "Parquet (default) or as a drive log (--to mcap|ros2|ros1; the format follows --out's suffix). Parquet output streams: one "
            "recording (or a group of small ones, or whole tracks of a long one) at a time is read and "
            "written, so memory stays bounded; --partition writes a dataset directory of one Parquet file per "
            "piece instead of one file (every command reads either). --workers/--engine ray read "
            "recordings in parallel with the same result as one process."
        ),
        epilog=(
            "examples:\n"
            "  lanecast convert sim/ --out sim.parquet\n"
            "  lanecast convert sim.parquet --out logs/sim.mcap\n"
            "  lanecast convert sim.parquet --to ros2 --out logs/sim-bag   # a ROS 2 bag, MCAP storage\n"
            "  lanecast convert sim-queue/01_tracks.csv --out queue.parquet   # a highD recording, by any of its files\n"
            "  lanecast convert lanecast-demo/highd/ --out highd/ --partition --workers 2   # the demo's, highD format\n"
            "with a dataset downloaded (NGSIM: data.transportation.gov; highD: levelxdata.com):\n"
            "  lanecast convert ngsim/ --out us101.parquet   # trajectories-0750am-0805am.txt … are US-101\n"
            "  lanecast convert ngsim/*.txt --to csp --out csp/   # TrainSet.mat … for CS-LSTM, PiP and kin"
        ),
        formatter_class=HelpFormatter,
    )
    p.add_argument(
        "inputs",
        nargs="+",
        metavar="INPUT",
        help="highD, NGSIM, MCAP, ROS 1/2 bag or track-table files or directories",
    )
    p.add_argument("--out", required=True, type=Path, help="output path")
    p.add_argument("--format", choices=sorted(registry.READERS), help="input format (default: detected)")
    add_location_option(p)
    p.add_argument(
        "--to",
        choices=sorted([*registry.WRITERS, "csp"]),
        help="output format (default: from --out's suffix, else parquet); " + csp_cli.HELP,
    )
    p.add_argument(
        "--storage",
        choices=STORAGES,
        default=STORAGES[0],
        help="storage of a ROS 2 bag (sqlite3 for tools that read nothing else)",
    )
    p.add_argument(
        "--topic", help="for logs: the topic with tracked objects (default: every supported topic)"
    )
    p.add_argument(
        "--salvage", action="store_true", help="for damaged MCAP: read every intact chunk and report the loss"
    )
    p.add_argument(
        "--partition",
        action="store_true",
        help="Parquet: write a dataset directory, one file per recording or group of small ones "
        "(default: one file)",
    )
    backends.add_arguments(p, "recordings processed")
    add_force_option(p)
    p.set_defaults(func=run)


def output_format(out: Path, to: str | None) -> str:
    """The format ``--out`` (and ``--to``) ask for; a suffix lanecast would not write is refused
    (``--out x.csv`` never gets Parquet bytes under a CSV name)."""
    suffix = out.suffix.lower()
    fmt = to or _SUFFIX_TO_FORMAT.get(suffix) or (None if suffix else "parquet")
    if fmt is None:
        raise UsageError(
            f"--out {out}",
            f"lanecast does not write {suffix} files",
            expected="a .parquet, .mcap or .bag name, or --to ros2 and a directory name",
        )
    wanted = _FORMAT_SUFFIXES.get(fmt, ())
    if suffix and wanted and suffix not in wanted:
        raise UsageError(
            f"--out {out}", f"--to {fmt} writes {wanted[0]} files", expected=f"a {wanted[0]} name"
        )
    if fmt == "ros2" and suffix in _SUFFIX_TO_FORMAT:
        raise UsageError(
            f"--out {out}", "a ROS 2 bag is a directory", expected="a directory name without a file suffix"
        )
    return fmt


def run(args: argparse.Namespace) -> int:
    from lanecast.io_adapters.contracts import track_table
    from lanecast.io_adapters.files import check_output, check_output_dir
    from lanecast.io_adapters.formats import streaming
    from lanecast.io_adapters.logs.conventions import BAG_FILES
    from lanecast.io_adapters.ownership import check_replaceable_files, check_replaceable_output
    from lanecast.pipeline.resample import resample
    from lanecast.workflows.bulk import freed_memory

    if args.to == "csp":  # research .mat sets, written by their own package
        return csp_cli.run_csp(args, resample=resample)
    started = time.perf_counter()
    options: dict[str, object] = {}
    if args.topic:
        options["topic"] = args.topic
    if args.salvage:
        options["salvage"] = True
    if args.location:
        options["location"] = args.location
    fmt = output_format(args.out, args.to)
    directory = fmt == "ros2" or (fmt == "parquet" and args.partition)
    if directory:  # a directory holding a user's files is refused before the work, not after it
        check_output_dir(args.out, replaces=BAG_FILES if fmt == "ros2" else streaming.PARTS)
        if fmt == "ros2" and args.out.is_dir() and any(args.out.iterdir()):
            check_replaceable_output(args.out, force=args.force)  # a user's own bag is not replaced
        elif args.out.is_dir():
            check_replaceable_files(
                args.out, tuple(p.name for p in args.out.glob("*.parquet")), force=args.force
            )
    else:
        check_output(args.out)
        check_replaceable_output(args.out, force=args.force)
    if os.path.realpath(args.out) in {os.path.realpath(p) for p in args.inputs}:
        raise InputError(args.out, "the output would overwrite an input", expected="a new output path")
    backends.check(args.workers, args.engine)
    freed_memory.keep_freed_memory()  # pieces reuse what the previous one freed
    if fmt != "parquet":  # drive logs are written from the whole table
        table = registry.read_any(args.inputs, fmt=args.format, **options)
        if table.num_rows == 0:  # a log without objects, which no reader (lanecast's either) would take
            raise InputError(
                ", ".join(map(str, args.inputs)), "no rows", expected="at least one row to convert"
            )
        path = registry.write_any(
            table, args.out, fmt, **({"storage": args.storage} if fmt == "ros2" else {})
        )
        rows, tracks = table.num_rows, len(track_table.track_boundaries(table)) - 1
    else:
        with streaming.spill_directory(args.out) as spill:  # NGSIM exports: a spill per recording
            pieces = streaming.plan(
                args.inputs, fmt=args.format, spill_dir=spill.path, options=options, long="tracks"
            )
            if not pieces:  # inputs that read as tables of no rows (a Parquet table of none)
                raise InputError(
                    ", ".join(map(str, args.inputs)), "no rows", expected="at least one row to convert"
                )
            ordered_map = backends.mapper_from_args(args, args.inputs, args.out)
            rows, tracks = streaming.convert(pieces, args.out, directory=directory, ordered_map=ordered_map)
        path = args.out
    print(f"wrote {path} ({fmt}): {rows:,} rows, {tracks:,} tracks in {time.perf_counter() - started:.1f} s")
    return 0
