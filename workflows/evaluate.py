"""`lanecast evaluate`: the ST-CNN beside the constant-velocity and constant-acceleration baselines.

Writes ``metrics.json`` (one entry per model: ``stcnn``, ``cv``, ``ca`` and, when given,
``stcnn_regression_only``; plus ``meta``), ``report.md`` and a self-contained ``report.html``.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from lanecast.io_adapters.cores import default_threads
from lanecast.io_adapters.errors import InputError
from lanecast.io_adapters.progress import activity
from lanecast.models.card import provenance, provenance_line, resolve
from lanecast.workflows.arguments import MANEUVER_SEQUENCES, MAX_EXAMPLES, integer
from lanecast.workflows.vocabulary import HelpFormatter, add_force_option, add_model_option

SPLITS = {"test": ("test",), "val": ("val",), "all": ("train", "val", "test", "none")}


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "evaluate",
        help="metrics and a report of a model against constant-velocity/-acceleration baselines",
        description=(
            "Evaluate the ST-CNN (default: the shipped model) and the kinematic baselines on a windows "
            "dataset: RMSE at 1-5 s (per window and per vehicle, 95 % bootstrap intervals), ADE/FDE, "
            "minADE/minFDE@K, miss rate (FDE > 2 m), RMSE on lane-change windows; maneuver accuracy beside "
            "always-straight's, macro-F1 over the classes present or predicted (a false lane change counts), "
            "F1 per class with its support, precision/recall, confusion matrix, Brier score and a "
            "calibration plot; one row per recording; example scenes and a failure gallery. Writes "
            "metrics.json, report.md and report.html into --out."
        ),
        epilog="example:\n  lanecast evaluate windows/sim --model runs/model --out runs/report --split test",
        formatter_class=HelpFormatter,
    )
    p.add_argument(
        "windows", type=Path, metavar="WINDOWS", help="windows dataset directory (lanecast windows)"
    )
    add_model_option(p)
    p.add_argument(
        "--regression-only", type=Path, metavar="MODEL", help="a regression-only variant to compare"
    )
    p.add_argument("--out", type=Path, required=True, metavar="DIR", help="report directory")
    p.add_argument("--split", choices=sorted(SPLITS), default="test", help="windows to evaluate")
    p.add_argument(
        "--top-k", type=integer(1, MANEUVER_SEQUENCES), default=3, help="maneuver sequences for minADE/minFDE"
    )
    p.add_argument(
        "--examples", type=integer(0, MAX_EXAMPLES), default=4, help="example scenes in the report"
    )
    p.add_argument("--batch-size", type=integer(1, 1 << 20), default=4096, help="windows per inference batch")
    add_force_option(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import numpy as np
    import torch  # heavy: loaded when the command runs, not for `lanecast --help`

    from lanecast.io_adapters.files import check_output_dir, staged_files
    from lanecast.io_adapters.windows_store.dataset import load_windows
    from lanecast.models.baselines import constant_acceleration, constant_velocity
    from lanecast.models.evaluation import (
        always_straight,
        evaluate,
        example_scenes,
        out_of_distribution_note,
        speed_band_note,
        write_metrics,
    )
    from lanecast.models.predict import STCNNForecaster
    from lanecast.models.predictions import Forecaster
    from lanecast.models.reports.document import write_report
    from lanecast.models.reports.tables import headline, model_name

    check_output_dir(
        args.out, files=("metrics.json", "report.md", "report.html"), force=args.force
    )  # before the work
    torch.set_num_threads(default_threads())  # the free cores, as every command that predicts
    windows = load_windows(args.windows, check_values=True)
    forecasters: list[Forecaster] = [
        STCNNForecaster.load(args.model, "stcnn"),
        constant_velocity(),
        constant_acceleration(),
    ]
    if args.regression_only is not None:
        forecasters.append(STCNNForecaster.load(args.regression_only, "stcnn_regression_only"))
    try:
        with activity(f"evaluate: {len(forecasters)} forecasters on the {args.split} windows"):
            metrics, preds, idx = evaluate(
                windows, forecasters, splits=SPLITS[args.split], top_k=args.top_k, batch_size=args.batch_size
            )
    except InputError as exc:  # e.g. no labelled windows in the split: in the dataset given
        raise exc.naming(args.windows) from exc
    meta = {
        "windows": str(args.windows),
        "split": args.split,
        "model": (prov := provenance(args.model))["model"],
        "model_sha256": prov["sha256"],
        "model_trained_on": prov["trained_on"],
        "regression_only_model": None
        if args.regression_only is None
        else str(resolve(args.regression_only)[1]),
        "top_k": args.top_k,
        "always_straight": always_straight(windows, idx),
        "sources": windows.manifest.get("sources"),
    }
    ood_note = out_of_distribution_note(preds, np.asarray(windows.future[idx]))
    if ood_note is not None:
        meta["out_of_distribution"] = ood_note
    scenes = example_scenes(windows, idx, preds["stcnn"], args.examples)
    with staged_files(
        args.out, force=args.force
    ) as stage:  # an interrupted run leaves none of the report's files
        with activity("evaluate: writing the report and its figures"):
            write_metrics(stage / "metrics.json", metrics, meta)
            write_report(stage, metrics, meta, scenes)
    share = "" if args.split == "all" else f" of {len(windows):,}"
    for line in headline(metrics):
        print(line)
    print(f"evaluated {len(idx):,}{share} windows ({args.split}); {provenance_line(prov)}")
    print("RMSE per window at 1-5 s (m):")
    for name, m in metrics.items():
        rmse = " ".join("–" if v is None else f"{v:.2f}" for v in m["rmse"])
        f1, acc = m["maneuver_macro_f1"], m["maneuver_accuracy"]
        maneuvers = "" if f1 is None else f"   macro-F1 {f1:.3f}, accuracy {acc:.3f}"
        print(f"  {model_name(name):<28}{rmse}{maneuvers}")
    straight = meta["always_straight"]
    print(
        f"  {'always straight':<28}{'':<24}   macro-F1 {straight['maneuver_macro_f1']:.3f}, "
        f"accuracy {straight['maneuver_accuracy']:.3f}"
    )
    print("  (macro-F1 over the maneuver classes present or predicted: a false lane change counts)")
    band_note = speed_band_note(metrics)
    if band_note is not None:
        print(f"by target speed, {model_name('stcnn')}: {band_note} (report: By target speed)")
    print(f"wrote {args.out / 'metrics.json'}, report.md, report.html")
    if args.split != "all" and len(idx) < len(windows):
        print(
            f"(the {args.split} split only: a model that never trained on this dataset, such as the shipped "
            f"one on your own recordings, can be measured on all {len(windows):,} windows with --split all)"
        )
    if ood_note is not None:
        print(f"out of distribution: {ood_note}")
    return 0
