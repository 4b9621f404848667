"""`lanecast train`: train the ST-CNN's classifier and regressor on a windows dataset.

torch-heavy modules (``lanecast.models.train``, ``checkpoint``, ``predict``) are imported when the
command runs, so that ``lanecast --help`` stays fast.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
from pathlib import Path
from typing import TYPE_CHECKING, Any

from lanecast.io_adapters.errors import InputError, UsageError

if TYPE_CHECKING:
    from lanecast.models.finetune import FinetuneOptions
    from lanecast.models.train import TrainConfig

from lanecast.io_adapters import json_fields as jf
from lanecast.io_adapters.progress import activity
from lanecast.models.card import read_card, resolve
from lanecast.workflows.vocabulary import HelpFormatter, add_force_option


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "train",
        help="train the ST-CNN (classifier and regressor) on a windows dataset",
        description=(
            "Train the maneuver classifier (summed NLL over the 5 steps, optionally class-weighted) and the "
            "trajectory regressor (batch RMSE, ground-truth maneuvers as input) separately with Adam on the "
            "'train' split, validate on 'val' each epoch and keep each network's best epoch. Writes "
            "MODEL_DIR/stcnn.safetensors and stcnn.json (the card, with validation and test metrics). "
            "Hyper-parameters default to the shipped model's, which go beyond the paper in two ways: the "
            "NLL is weighted by (1/class frequency)^0.5 and the classifier's epoch is chosen by validation "
            "macro-F1; --class-weight-power 0 --select-classifier nll gives the paper's plain NLL. "
            "--config FILE (JSON, keys of lanecast.models.train.TrainConfig) overrides the defaults."
        ),
        epilog=(
            "examples:\n  lanecast train windows/sim --out runs/model --epochs 20 --seed 1\n"
            "  lanecast train windows/sim --out runs/regonly --regression-only   # ablation: no maneuver input\n"
            "  lanecast train windows/queue --init default --out runs/tuned --epochs 5   # fine-tune the shipped model"
        ),
        formatter_class=HelpFormatter,
    )
    p.add_argument(
        "windows", type=Path, metavar="WINDOWS", help="windows dataset directory (lanecast windows)"
    )
    p.add_argument("--out", type=Path, required=True, metavar="MODEL_DIR", help="where to write the model")
    p.add_argument("--config", type=Path, metavar="FILE", help="training config, JSON")
    defaults = shipped_defaults()

    def shipped(key: str) -> str:
        value = defaults.get(key)
        return (
            "(default: the shipped model's, see --config)"
            if value is None
            else f"(default: {value}, the shipped model's)"
        )

    p.add_argument("--epochs", type=int, help=f"passes over the training windows {shipped('epochs')}")
    p.add_argument("--seed", type=int, help=f"seed of initialisation and shuffling {shipped('seed')}")
    p.add_argument("--batch-size", type=int, help=f"windows per batch {shipped('batch_size')}")
    p.add_argument("--lr", type=float, help=f"Adam's learning rate {shipped('lr')}")
    p.add_argument("--threads", type=int, help="CPU threads (default: 2)")
    p.add_argument("--device", help="auto (GPU when there is one), cpu, cuda, ... (default: auto)")
    p.add_argument(
        "--class-weight-power",
        type=float,
        help="weight the classifier's NLL by (1/class frequency)^POWER (0: the paper's plain NLL) "
        + shipped("class_weight_power"),
    )
    p.add_argument(
        "--select-classifier",
        choices=("nll", "macro_f1"),
        help=f"validation criterion for the classifier's epoch {shipped('select_classifier')}",
    )
    p.add_argument(
        "--regression-only", action="store_true", help="regressor without maneuver input (ablation)"
    )
    p.add_argument(
        "--init",
        metavar="MODEL_DIR",
        help="fine-tune: start from this model's weights ('default': the shipped model) and keep its "
        "normalisation; the architecture is the init model's",
    )
    p.add_argument(
        "--keep-base",
        choices=("l2sp+replay", "replay", "l2sp", "none"),
        help="with --init: how fine-tuning keeps the init model's skills: rehearse its training data "
        "(its replay set) and/or an L2-SP penalty towards its weights; none: plain fine-tune "
        "(default: l2sp+replay; lr 3e-4 and 6 epochs unless given)",
    )
    p.add_argument(
        "--classifier",
        choices=("auto", "train", "freeze"),
        help="with --init: freeze keeps the init model's classifier; auto fine-tunes it where the new "
        "data holds at least 50 lane-change windows (default: freeze)",
    )
    p.add_argument(
        "--position-noise",
        type=float,
        metavar="M",
        help="augmentation: Gaussian noise (std, m) on the x, y inputs of training batches (default 0)",
    )
    add_force_option(p)
    p.set_defaults(func=run)


def shipped_defaults() -> dict[str, Any]:
    """The shipped model's training settings, read from its card's JSON (for ``--help``: no numpy,
    no torch; the card is package data, checked whenever the model is loaded)."""
    import json

    try:
        config = json.loads(resolve(None)[1].read_text(encoding="utf-8"))["training"]["config"]
    except (InputError, OSError, ValueError, KeyError, TypeError):
        return {}
    return config if isinstance(config, dict) else {}


def default_config() -> TrainConfig:
    """The shipped model's training config (architecture and hyper-parameters), else the code defaults."""
    from lanecast.models.train import TrainConfig

    try:
        card = read_card(resolve(None)[1])
        return TrainConfig.from_dict(card["training"]["config"])
    except (InputError, KeyError, ValueError, TypeError):
        return TrainConfig()


#: TrainConfig fields with a lowest value beyond their type's (a learning rate of 0 fine-tunes nothing:
#: the init model's weights, as a test wants them)
_LOWEST = {"epochs": 1, "batch_size": 1, "threads": 1, "lr": 0.0, "seed": 0}
#: and a highest: beyond these a run trains for ever, allocates without end or diverges at once (an
#: epoch count of 10**12 ran until killed; a seed beyond int64 failed in numpy after loading the data)
_HIGHEST = {
    "epochs": 100_000,
    "batch_size": 1 << 20,
    "threads": 1024,
    "lr": 10.0,
    "seed": 2**63 - 1,
    "class_weight_power": 10.0,
    "position_noise_m": 100.0,
}


def check_config(config: TrainConfig, options: dict[str, Any], file: Path | None) -> None:
    """UsageError for a training setting of the wrong type or range (an epoch count of 0 trained
    nothing and saved the random initial weights; a batch size of 0, a learning rate of NaN, a
    thread count of 0, an unknown device or a string where a number belongs failed deep in torch),
    naming the option, or the config file and its key."""
    for f in dataclasses.fields(config):
        value, kind = getattr(config, f.name), str(f.type)
        from_file = file is not None and f.name not in options
        where = f"--config {file}" if from_file else f"--{f.name.replace('_', '-')}"
        key = f"{f.name}: " if from_file else ""
        ok = {
            "int": isinstance(value, int) and not isinstance(value, bool),
            "float": isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value),
            "str": isinstance(value, str),
            "bool": isinstance(value, bool),
        }.get(kind, True)
        lowest, highest = _LOWEST.get(f.name), _HIGHEST.get(f.name)
        if ok and lowest is not None:
            ok = value >= lowest
        if ok and highest is not None:
            ok = value <= highest
        if not ok:
            number = "a number" if kind == "float" else "an integer"
            if lowest is not None and highest is not None:
                what = f"{number} from {lowest} to {highest}"
            elif lowest is not None:
                what = f"{number} >= {lowest}"
            elif highest is not None:
                what = f"{number} <= {highest}"
            else:
                what = f"a {kind}"
            raise UsageError(where, f"{key}{value!r}", expected=what)
    if config.device != "auto":
        import torch

        try:
            torch.device(config.device)
        except RuntimeError as exc:
            raise UsageError(
                "--device", f"{config.device!r}: {exc}", expected="auto, cpu, cuda, cuda:N, mps"
            ) from exc


def train_and_save(
    windows_dir: Path,
    out: Path,
    config: TrainConfig,
    *,
    top_k: int = 3,
    init: str | None = None,
    keep: FinetuneOptions | None = None,
) -> dict[str, Any]:
    """Train (from the weights of model ``init`` if given, "default" = the shipped model), evaluate
    on val and test (if present), save; return the card. ``keep``: how a fine-tune keeps the init
    model's skills (lanecast.models.finetune; default FinetuneOptions())."""

    with activity("train: loading torch and the windows"):
        from lanecast.io_adapters.windows_store.dataset import load_windows
        from lanecast.models.baselines import constant_velocity
        from lanecast.models.checkpoint import save_checkpoint
        from lanecast.models.evaluation import evaluate
        from lanecast.models.predict import STCNNForecaster
        from lanecast.models.train import train

        windows = load_windows(windows_dir, check_values=True)
    data = {
        "windows": str(windows_dir),
        "sources": windows.manifest.get("sources"),
        "counts": windows.manifest.get("counts"),
    }
    init_from = None
    if init is not None:
        from lanecast.models.checkpoint import load_checkpoint

        init_from = load_checkpoint(None if init == "default" else init)
        config = dataclasses.replace(config, model=init_from[0].config)
        data["init"] = "shipped model" if init == "default" else str(init)
    try:
        if init_from is not None and init is not None:
            from lanecast.models.finetune import FinetuneOptions, finetune_from

            result = finetune_from(init, windows, config, keep or FinetuneOptions(), data)
        else:
            result = train(windows, config, data_card=data, init_from=init_from)
    except InputError as exc:  # e.g. no labelled training windows: in the dataset given
        raise exc.naming(windows_dir) from exc
    forecaster = STCNNForecaster(result.model, result.card)
    metrics: dict[str, Any] = {}
    for name, splits in (("validation", ("val",)), ("test", ("test",))):
        try:
            with activity(f"train: scoring the model on the {name} windows"):
                scores = evaluate(windows, [forecaster, constant_velocity()], splits=splits, top_k=top_k)[0]
        except InputError:  # no labelled windows in that split
            metrics[name] = None
            continue
        metrics[name] = {**scores["stcnn"], "constant_velocity_rmse": scores["cv"]["rmse"]}
    card = {**result.card, "metrics": metrics}
    save_checkpoint(result.model, card, out)
    return card


def run(args: argparse.Namespace) -> int:
    from lanecast.io_adapters.files import check_output_dir
    from lanecast.models.train import TrainConfig

    check_output_dir(
        args.out, files=("stcnn.safetensors", "stcnn.json"), force=args.force
    )  # before minutes of training
    config = TrainConfig.from_file(args.config) if args.config else default_config()
    names = (
        "epochs",
        "seed",
        "batch_size",
        "lr",
        "threads",
        "device",
        "class_weight_power",
        "select_classifier",
        "position_noise",
    )
    overrides = {("position_noise_m" if k == "position_noise" else k): getattr(args, k) for k in names}
    overrides = {k: v for k, v in overrides.items() if v is not None}
    try:
        config = dataclasses.replace(config, **overrides)
    except ValueError as exc:  # TrainConfig's own range checks
        raise UsageError("training options", str(exc)) from exc
    check_config(config, overrides, args.config)
    keep = finetune_options(args, config, overrides)
    if keep is not None:
        config = keep[1]
    if args.regression_only:
        config = dataclasses.replace(config, model=dataclasses.replace(config.model, maneuver_input=False))
    card = train_and_save(args.windows, args.out, config, init=args.init, keep=keep and keep[0])
    for line in summary(card, config.epochs):
        print(line)
    if card.get("finetune"):
        from lanecast.models.finetune import summary as finetune_summary

        print(f"  {finetune_summary(card)}")
    print(f"wrote {args.out}/stcnn.safetensors and stcnn.json")
    return 0


def finetune_options(
    args: argparse.Namespace, config: TrainConfig, overrides: dict[str, Any]
) -> tuple[FinetuneOptions, TrainConfig] | None:
    """With --init: how to keep the init model (--keep-base, --classifier) and the config with
    fine-tuning's learning rate and epochs where neither an option nor --config set them; None
    without --init (where --keep-base and --classifier are refused)."""
    if args.init is None:
        for name in ("keep_base", "classifier"):
            if getattr(args, name) is not None:
                raise UsageError(
                    f"--{name.replace('_', '-')}", "given without --init", expected="--init MODEL_DIR"
                )
        return None
    from lanecast.models.finetune import FINETUNE_EPOCHS, FINETUNE_LR, FinetuneOptions

    given = {k: getattr(args, k) for k in ("keep_base", "classifier") if getattr(args, k) is not None}
    preset: dict[str, Any] = {
        k: v for k, v in (("lr", FINETUNE_LR), ("epochs", FINETUNE_EPOCHS)) if k not in overrides
    }
    if args.config is not None:  # a config file's own values win over fine-tuning's defaults
        keys = jf.loads(args.config.read_bytes(), "config")
        preset = {k: v for k, v in preset.items() if k not in keys}
    return FinetuneOptions(**given), dataclasses.replace(config, **preset)


def summary(card: dict[str, Any], epochs: int) -> list[str]:
    """What a training run says: its size, the best epochs, each split's RMSE beside constant
    velocity's, and a warning where the classifier had no lane change to learn from."""
    t = card["training"]
    best = t["best_epoch"]
    lines = [
        f"trained {t['data']['train_windows']:,} windows x {epochs} epochs in {t['train_seconds']:.0f} s "
        f"({t['train_samples_per_s']:,.0f} samples/s); best epochs: classifier {best['classifier']}, "
        f"regressor {best['regressor']}"
    ]
    for name, m in card["metrics"].items():
        if not m:
            continue
        rmse = " ".join(f"{v:.2f}" for v in m["rmse"])
        cv = m.get("constant_velocity_rmse")
        versus = ""
        if cv:
            ratio = m["rmse"][-1] / cv[-1] if cv[-1] > 0 else float("nan")
            versus = f" (constant velocity {' '.join(f'{v:.2f}' for v in cv)} m; {ratio:.2f}x at 5 s)"
        lines.append(
            f"  {name}: RMSE 1-5 s {rmse} m{versus}, maneuver accuracy {m['maneuver_accuracy']:.3f}, "
            f"macro-F1 {m['maneuver_macro_f1']:.3f}"
        )
    counts = t["data"].get("train_maneuver_counts") or []
    if len(counts) == 3 and counts[1] + counts[2] == 0:
        lines.append(
            f"  note: the training split holds no lane change ({counts[0]:,} straight steps): the classifier "
            "had nothing but 'straight' to learn, and a validation macro-F1 near 1 is trivial; add "
            "recordings with lane changes, or fine-tune the shipped model (--init default)"
        )
    return lines
