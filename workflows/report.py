"""`lanecast report`: metrics of annotated logs, from the forecasts in them and the future they record.

The scoring is ``lanecast.workflows.annotation.log_scores`` (also used by ``lanecast demo``).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from lanecast.workflows.arguments import MAX_EXAMPLES, integer
from lanecast.workflows.vocabulary import HelpFormatter, add_force_option, add_model_option


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "report",
        help="metrics of annotated logs against the future recorded in them",
        description=(
            "Score the forecasts in annotated logs (the output of lanecast annotate: files, directories or a "
            "bulk run's OUT_DIR with its manifest) against the tracks' recorded futures, beside the "
            "constant-velocity and constant-acceleration baselines. Writes metrics.json, report.md and "
            "report.html into --out, overall and per log (logs/<name>/). A log that cannot be scored is "
            "named in the report and on stderr, and the others are reported: exit status 1 (2 when none is)."
        ),
        epilog="example:\n  lanecast annotate logs/ --out annotated/\n  lanecast report annotated/ --out report/\n"
        "  lanecast report annotated/ --out report-predictors/ --predictions",
        formatter_class=HelpFormatter,
    )
    p.add_argument("paths", nargs="+", type=Path, metavar="ANNOTATED", help="annotated logs or directories")
    p.add_argument("--out", required=True, type=Path, metavar="DIR", help="report directory")
    p.add_argument("--topic", help="the topic with tracked objects (default: every supported topic)")
    p.add_argument(
        "--examples", type=integer(0, MAX_EXAMPLES), default=4, help="example scenes in the overall report"
    )
    add_force_option(p)
    p.add_argument(
        "--predictions",
        action="append",
        nargs="?",
        const="",
        metavar="TOPIC",
        help="score the predictor recorded on TOPIC (repeatable; without TOPIC: every topic of Autoware's "
        "PredictedObjects) against the log's own future, beside lanecast's ST-CNN and constant velocity",
    )
    add_model_option(p)  # the model lanecast forecasts with, beside a recorded predictor
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from lanecast.io_adapters.files import check_output_dir
    from lanecast.workflows.annotation.log_scores import report_logs
    from lanecast.workflows.annotation.predictor_report import report_predictors

    check_output_dir(args.out, files=("metrics.json", "report.md", "report.html"), force=args.force)
    if args.predictions is not None:
        topics = [t for t in args.predictions if t]
        return report_predictors(
            args.paths, args.out, predictions=topics, topic=args.topic, model=args.model, force=args.force
        )
    return report_logs(args.paths, args.out, topic=args.topic, examples=args.examples, force=args.force)
