"""`lanecast annotate`: write forecasts into drive logs (MCAP, ROS 2 bags, ROS 1 bags → MCAP).

The command only parses its options: one log end to end is ``lanecast.workflows.annotation.annotate_log``, many
logs (manifest, resume, local processes or Ray) are ``lanecast.workflows.bulk.runner``.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

from lanecast.io_adapters.errors import UsageError
from lanecast.workflows.arguments import MANEUVER_SEQUENCES, integer, number
from lanecast.workflows.bulk import backends
from lanecast.workflows.vocabulary import HelpFormatter, add_model_option


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "annotate",
        help="write forecasts into drive logs (MCAP, ROS 2 and ROS 1 bags), one machine or a Ray cluster",
        description=(
            "For each log: read its tracks, forecast every vehicle with 3 s of history every --every seconds, and "
            "write a new log into OUT_DIR with every original record copied byte for byte plus /lanecast/forecast "
            "(foxglove.SceneUpdate: a line per target coloured by maneuver — straight grey, left blue, right "
            "orange, as in the reports — top-K alternatives fainter) and /lanecast/prediction (JSON), merged in log time. ROS 2 logs "
            "stay ROS 2 (foxglove_msgs/msg/SceneUpdate in CDR); ROS 1 bags become MCAP. OUT_DIR/manifest.jsonl "
            "records what made every output (options, model checksum, input checksum); a rerun skips what is done "
            "and unchanged and redoes the rest. Outputs mirror the input tree under OUT_DIR; a file there that "
            "lanecast did not write is never overwritten. A log that fails is named in the manifest and on "
            "stderr, and the others are annotated: exit status 1 (2 when none is)."
        ),
        epilog=(
            "examples:\n"
            "  lanecast annotate logs/ --out annotated/\n"
            "  lanecast annotate logs/ --out annotated/ --workers 2 --every 0.5   # redoes: other options\n"
            "with a Ray cluster (the ray extra; logs and --out on storage every node mounts):\n"
            "  lanecast annotate logs/ --out /shared/annotated --engine ray --address ray://head:10001"
        ),
        formatter_class=HelpFormatter,
    )
    p.add_argument(
        "inputs",
        nargs="+",
        type=Path,
        metavar="LOG_OR_DIR",
        help="MCAP logs or ROS 1/2 bags, or directories searched for them",
    )
    p.add_argument("--out", required=True, type=Path, metavar="OUT_DIR", help="output directory")
    add_model_option(p)
    p.add_argument("--topic", help="topic with tracked objects (default: every supported topic)")
    p.add_argument(
        "--every",
        type=number(0, 86_400, "s", above=True),
        default=1.0,
        metavar="SECONDS",
        help="forecast period",
    )
    p.add_argument(
        "--top-k", type=integer(1, MANEUVER_SEQUENCES), default=3, help="alternatives drawn per target"
    )
    p.add_argument(
        "--encoding",
        choices=("auto", "protobuf", "json", "autoware"),
        default="auto",
        help="SceneUpdate encoding in plain MCAP (default: JSON for all-JSON logs, else protobuf; ROS 2: CDR); "
        "autoware: as auto, and the forecasts as Autoware PredictedObjects on /lanecast/predicted_objects",
    )
    p.add_argument(
        "--forecasts",
        type=Path,
        metavar="PARQUET_OR_DIR",
        help="use precomputed forecasts (a table, or DIR/<log name>.parquet per log) instead of the model",
    )
    p.add_argument(
        "--explain",
        action="store_true",
        help="also /lanecast/explain: each target's what-if forecasts, one per neighbour removed (entity "
        "'<id> without F', as lanecast explain draws them)",
    )
    p.add_argument(
        "--salvage",
        action="store_true",
        help="for damaged MCAP: annotate every intact chunk (the output holds those) and report the loss",
    )
    backends.add_arguments(p, "logs annotated")
    p.add_argument(
        "--force", action="store_true", help="redo every log, even those the manifest says are done"
    )
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from lanecast.io_adapters.files import check_output
    from lanecast.models.runtime import check_model
    from lanecast.workflows.annotation.annotate_log import AnnotateOptions, read_forecasts_table
    from lanecast.workflows.bulk import runner as bulk

    if not (math.isfinite(args.every) and round(args.every * 10) >= 1):  # the forecast grid is 10 Hz
        raise UsageError("--every", f"{args.every} s", expected="at least 0.1 s (rounded to 0.1 s)")
    check_output(args.out, directory=True)  # a file there, or on its path: before loading anything
    if args.forecasts is not None and args.forecasts.is_file():  # one table for every log: check it once
        read_forecasts_table(args.forecasts)
    if args.forecasts is None or args.explain:
        # a bad model (card, weights, ONNX graph) is one error up front, not one per log, and it
        # leaves OUT_DIR untouched: no manifest, no lock
        check_model(args.model)
    options = AnnotateOptions(
        model_dir=args.model,
        topic=args.topic,
        every_s=args.every,
        top_k=args.top_k,
        encoding=args.encoding,
        forecasts=args.forecasts,
        explain=args.explain,
        salvage=args.salvage,
    )
    result = bulk.run_bulk(
        args.inputs,
        args.out,
        options,
        workers=args.workers,
        engine=args.engine,
        address=args.address,
        retries=args.retries,
        force=args.force,
    )
    print(result.summary())
    if not result.failed:
        return 0
    # The error of a failed log on stderr, last, as every command reports one (the summary above
    # and the manifest, if kept, list them all); status 1 if other logs are done, else 2 as for any
    # refused input (a run that made OUT_DIR and annotated nothing removed it again).
    failed = result.failed
    kept = (result.out_dir / bulk.MANIFEST).is_file()
    more = (
        f"{len(failed)} logs failed"
        + (f" (see {result.out_dir / bulk.MANIFEST})" if kept else "")
        + ", the first: "
        if len(failed) > 1
        else ""
    )
    print(f"lanecast annotate: error: {more}{failed[0]['error']}", file=sys.stderr)
    return 1 if result.done or result.skipped else 2
