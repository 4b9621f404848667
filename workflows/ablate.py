"""`lanecast ablate`: the paper's ablation study (Table II) retrained and scored on one windows dataset.

Writes ``ablation.json`` (per variant: parameters, mean and std over seeds, every run, the paper's
values), ``report.html`` / ``report.md`` (the paper's table layout, beside the paper's) and
``ablation.png`` into ``--out``. See ``lanecast.models.ablation`` for what each variant changes.
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

from lanecast.io_adapters.errors import InputError
from lanecast.workflows.arguments import integer
from lanecast.workflows.vocabulary import HelpFormatter, add_force_option

#: The ``--quick`` preset (CI, smoke tests): a few epochs on at most this many training windows.
QUICK = {"epochs": 2, "max_train_windows": 1500, "batch_size": 128}


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "ablate",
        help="retrain and score the paper's seven ablation variants (Table II)",
        description=(
            "Retrain the ST-CNN's ablation variants of Mersch et al. (IROS 2021, Table II) on the same windows "
            "(train split; validation picks the best epochs) and score them on the same test windows, for "
            "each seed: only x and y; without neighbourhood; shuffled neighbourhood; without dilation "
            "(90,681 parameters); without maneuver; sampled maneuver; full. Writes ablation.json, "
            "report.html, report.md and ablation.png into --out: RMSE at 1-5 s, mean ± std over seeds, in "
            "the paper's table layout beside the paper's values. Variants (the paper's column order): xy_only, "
            "no_neighbourhood, shuffled, no_dilation, no_maneuver, sampled_maneuver, full. Training uses the "
            "paper's settings (absolute offsets, plain RMSE and NLL, constant learning rate), not `lanecast "
            "train`'s defaults, which go beyond the paper (offsets relative to constant velocity, horizon "
            "weights, input noise): the variants compare with each other and with the paper, not with a "
            "model from `lanecast train` (whose 1 s error is several times lower). --config gives other settings."
        ),
        epilog=(
            "examples:\n"
            "  lanecast ablate windows/sim --out runs/ablation --seeds 3\n"
            "  lanecast ablate windows/sim --out runs/ablation-quick --quick --variants full,no_dilation"
        ),
        formatter_class=HelpFormatter,
    )
    p.add_argument(
        "windows", type=Path, metavar="WINDOWS", help="windows dataset directory (lanecast windows)"
    )
    p.add_argument("--out", type=Path, required=True, metavar="DIR", help="output directory")
    p.add_argument(
        "--variants",
        metavar="A,B,…",
        help="comma-separated variants (default: all seven)",
    )
    p.add_argument("--seeds", type=integer(1, 100), default=3, help="training seeds 0..N-1 per variant")
    p.add_argument("--epochs", type=integer(1, 100_000), help="epochs per training (default: 10; --quick: 2)")
    p.add_argument("--config", type=Path, metavar="JSON", help="training config (lanecast train --config)")
    p.add_argument(
        "--max-train-windows",
        type=integer(1, 100_000_000),
        metavar="N",
        help="train on at most N training windows (a seeded sample; default: all; --quick: 1500)",
    )
    p.add_argument(
        "--quick",
        action="store_true",
        help="a preset small enough for CI: 2 epochs, at most 1,500 training windows, batch 128",
    )
    p.add_argument("--threads", type=integer(1, 1024), default=1, help="torch threads")
    add_force_option(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from lanecast.io_adapters.contracts.windows import labelled, subset
    from lanecast.io_adapters.files import check_output_dir, staged_files
    from lanecast.io_adapters.ownership import GENERATOR
    from lanecast.io_adapters.windows_store.dataset import load_windows
    from lanecast.models.ablation import run_ablation, variants  # torch: not on `lanecast --help`'s path
    from lanecast.models.reports.ablation import headline_text, write_ablation_report
    from lanecast.models.train import TrainConfig

    names = [n.strip() for n in (args.variants or ",".join(variants())).split(",") if n.strip()]
    unknown = sorted(set(names) - set(variants()))
    if unknown or not names:
        raise InputError(
            None, f"unknown variant(s) {unknown}", column="--variants", expected=", ".join(variants())
        )
    check_output_dir(
        args.out, files=("ablation.json", "report.md", "report.html", "ablation.png"), force=args.force
    )
    config = TrainConfig.from_file(args.config) if args.config else TrainConfig(epochs=10)
    config.threads = args.threads
    max_train = args.max_train_windows
    if args.quick:
        config.epochs, config.batch_size = QUICK["epochs"], QUICK["batch_size"]
        max_train = max_train or QUICK["max_train_windows"]
    if args.epochs is not None:
        config.epochs = args.epochs

    windows = load_windows(args.windows, check_values=True)
    if max_train is not None:
        train_idx = labelled(windows, ("train",))
        if len(train_idx) > max_train:
            keep = np.random.default_rng(0).choice(train_idx, size=max_train, replace=False)
            others = np.setdiff1d(np.arange(len(windows)), train_idx)
            windows = subset(windows, np.sort(np.concatenate([keep, others])))
    result = run_ablation(windows, names, list(range(args.seeds)), config)
    result["windows"] = str(args.windows)
    result["max_train_windows"] = max_train
    if args.quick:
        result["quick_warning"] = (
            f"{config.epochs} epochs on at most {max_train:,} training windows, a check that the ablation "
            "runs: these figures do not compare the variants"
        )
    with staged_files(args.out, force=args.force) as stage:  # all of the report's files or none
        (stage / "ablation.json").write_text(
            json.dumps(finite({**result, "generator": GENERATOR}), indent=2, allow_nan=False) + "\n",
            encoding="utf-8",
        )
        html = args.out / write_ablation_report(stage, result).relative_to(stage)  # NaN shows "–"
    settings = f"the settings of {args.config}" if args.config else "the paper's training settings"
    print(headline_text(result))
    print(f"RMSE per window at 1-5 s (m), mean over {args.seeds} seed(s), {settings}:")
    for v in result["variants"].values():
        print(f"  {v['label']:<24}" + " ".join(f"{x:.2f}" for x in v["mean"]["rmse"]))
    if args.quick:
        print(f"  (--quick: {result['quick_warning']})")
    print(f"wrote {args.out / 'ablation.json'}, report.md, ablation.png and {html}")
    return 0


def finite(value: object) -> object:
    """JSON-ready copy: NaN and infinities become null (e.g. no lane-change window to score)."""
    if isinstance(value, dict):
        return {k: finite(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [finite(v) for v in value]
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value
