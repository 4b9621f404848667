"""`lanecast evaluate`: the ST-CNN beside the constant-velocity and constant-acceleration baselines.

Writes ``metrics.json`` (one entry per model: ``stcnn``, ``cv``, ``ca`` and, when given,
``stcnn_regression_only``; plus ``meta``), ``report.md`` and a self-contained ``report.html``.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

import numpy as np

SPLITS = {"test": ("test",), "val": ("val",), "all": ("train", "val", "test", "none")}


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "evaluate",
        help="metrics and a report of a model against constant-velocity/-acceleration baselines",
        description=(
            "Evaluate the ST-CNN (default: the shipped model) and the kinematic baselines on a windows "
            "dataset: RMSE at 1-5 s (per window and per vehicle), ADE/FDE, minADE/minFDE@K, maneuver "
            "accuracy, precision/recall, confusion matrix, RMSE on lane-change windows. Writes "
            "metrics.json, report.md and report.html into the report directory."
        ),
        epilog="example:\n  lanecast evaluate windows/ --model runs/model --report runs/report --split test",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument(
        "windows", type=Path, metavar="WINDOWS", help="windows dataset directory (lanecast windows)"
    )
    p.add_argument("--model", type=Path, help="model directory or file (default: the shipped model)")
    p.add_argument(
        "--regression-only", type=Path, metavar="MODEL", help="a regression-only variant to compare"
    )
    p.add_argument("--report", type=Path, required=True, metavar="DIR", help="output directory")
    p.add_argument(
        "--split", choices=sorted(SPLITS), default="test", help="windows to evaluate (default: test)"
    )
    p.add_argument("--top-k", type=int, default=3, help="maneuver sequences for minADE/minFDE (default: 3)")
    p.add_argument("--examples", type=int, default=4, help="example scenes in the report (default: 4)")
    p.add_argument("--batch-size", type=int, default=4096)
    p.set_defaults(func=run)


def vehicle_ids(index: Any) -> np.ndarray:
    """One integer per (recording, track_id) of a windows index → int64 [N]."""
    rec = index.column("recording").to_numpy(zero_copy_only=False)
    _, rec_code = np.unique(rec.astype(str), return_inverse=True)
    track = index.column("track_id").to_numpy()
    _, code = np.unique(np.stack([rec_code.ravel(), track], axis=1), axis=0, return_inverse=True)
    return code.ravel().astype(np.int64)


def evaluate(
    windows: Any,
    forecasters: list[Any],
    *,
    splits: tuple[str, ...] = ("test",),
    top_k: int = 3,
    batch_size: int = 4096,
) -> tuple[dict[str, Any], dict[str, Any], np.ndarray]:
    """Metrics of every forecaster on the labelled windows of ``splits``.

    Returns (model name → ``lanecast.models.metrics.summary``, model name → Predictions, window indices [M]).
    """
    from lanecast.io_adapters.errors import InputError
    from lanecast.models.metrics import summary
    from lanecast.models.train import labelled

    idx = labelled(windows, splits)
    if len(idx) == 0:
        raise InputError(
            None,
            f"no labelled windows in split(s) {', '.join(splits)}",
            expected="windows with known futures",
        )
    inputs, present = np.asarray(windows.inputs[idx]), np.asarray(windows.present[idx])
    future, maneuver = np.asarray(windows.future[idx]), np.asarray(windows.maneuver[idx])
    vehicle = vehicle_ids(windows.index.take(idx))
    metrics, preds = {}, {}
    for f in forecasters:
        p = f.predict(inputs, present, top_k=top_k, batch_size=batch_size)
        preds[f.name] = p
        metrics[f.name] = summary(
            p.offsets, future, maneuver, vehicle, candidates=p.top_offsets, predicted_maneuver=p.maneuver
        )
    return metrics, preds, idx


def example_scenes(windows: Any, idx: np.ndarray, pred: Any, count: int) -> list[Any]:
    """Up to ``count`` scenes: a correctly predicted left and right lane change, a straight window,
    and the largest 5 s error (deterministic choices)."""
    from lanecast.models.report import Scene

    if count <= 0 or pred.maneuver is None:
        return []
    true = np.asarray(windows.maneuver[idx])
    future = np.asarray(windows.future[idx])
    err5 = np.hypot(*(pred.offsets[:, -1] - future[:, -1]).T)
    picks: list[tuple[str, int]] = []
    for cls, label in ((1, "left lane change"), (2, "right lane change")):
        hit = np.flatnonzero(np.any(true == cls, axis=1) & np.any(pred.maneuver == cls, axis=1))
        if hit.size:
            picks.append((f"{label}, predicted", int(hit[np.argmax(pred.probs[hit, :, cls].max(axis=1))])))
    straight = np.flatnonzero(np.all(true == 0, axis=1))
    if straight.size:
        picks.append(("straight driving", int(straight[straight.size // 2])))
    picks.append(("largest error at 5 s", int(np.argmax(err5))))
    scenes = []
    rec = windows.index.column("recording").to_numpy(zero_copy_only=False)
    tid = windows.index.column("track_id").to_numpy()
    t0 = windows.index.column("t0_ns").to_numpy()
    for title, i in picks[:count]:
        w = int(idx[i])
        scenes.append(
            Scene(
                title=f"{title}: {rec[w]} track {tid[w]} at t0 = {t0[w] / 1e9:.1f} s (error at 5 s {err5[i]:.2f} m)",
                inputs=np.asarray(windows.inputs[w]),
                present=np.asarray(windows.present[w]),
                future=future[i],
                offsets=pred.offsets[i],
                maneuver=pred.maneuver[i],
                alternatives=pred.top_offsets[i],
                alt_probs=pred.top_probs[i],
            )
        )
    return scenes


def write_metrics(path: Path, metrics: dict[str, Any], meta: dict[str, Any]) -> Path:
    """metrics.json: one key per model name plus ``meta``."""
    from lanecast.io_adapters.files import atomic_path

    with atomic_path(path) as tmp:
        tmp.write_text(json.dumps({**metrics, "meta": meta}, indent=2, allow_nan=False) + "\n")
    return path


def always_straight(windows: Any, idx: np.ndarray) -> dict[str, Any]:
    """Maneuver accuracy and macro-F1 of always predicting straight (the reference a classifier must beat)."""
    from lanecast.models.metrics import accuracy, confusion_matrix, macro_f1

    true = np.asarray(windows.maneuver[idx])
    conf = confusion_matrix(true, np.zeros_like(true))
    return {"maneuver_accuracy": accuracy(conf), "maneuver_macro_f1": macro_f1(conf)}


def run(args: argparse.Namespace) -> int:
    import torch

    from lanecast.io_adapters.contracts.windows import load_windows
    from lanecast.models.baselines import constant_acceleration, constant_velocity
    from lanecast.models.checkpoint import resolve
    from lanecast.models.predict import STCNNForecaster
    from lanecast.models.report import write_report

    torch.set_num_threads(max(1, min(2, torch.get_num_threads())))
    windows = load_windows(args.windows)
    forecasters: list[Any] = [
        STCNNForecaster.load(args.model, "stcnn"),
        constant_velocity(),
        constant_acceleration(),
    ]
    if args.regression_only is not None:
        forecasters.append(STCNNForecaster.load(args.regression_only, "stcnn_regression_only"))
    metrics, preds, idx = evaluate(
        windows, forecasters, splits=SPLITS[args.split], top_k=args.top_k, batch_size=args.batch_size
    )
    meta = {
        "windows": str(args.windows),
        "split": args.split,
        "model": str(resolve(args.model)[1]),
        "regression_only_model": None
        if args.regression_only is None
        else str(resolve(args.regression_only)[1]),
        "top_k": args.top_k,
        "always_straight": always_straight(windows, idx),
        "sources": windows.manifest.get("sources"),
    }
    args.report.mkdir(parents=True, exist_ok=True)
    write_metrics(args.report / "metrics.json", metrics, meta)
    scenes = example_scenes(windows, idx, preds["stcnn"], args.examples)
    write_report(args.report, metrics, meta, scenes)
    print(f"evaluated {len(idx):,} windows ({args.split}); RMSE per window at 1-5 s (m):")
    for name, m in metrics.items():
        rmse = " ".join("–" if v is None else f"{v:.2f}" for v in m["rmse"])
        f1 = m["maneuver_macro_f1"]
        print(f"  {name:<24}{rmse}   macro-F1 {'–' if f1 is None else f'{f1:.3f}'}")
    print(f"wrote {args.report / 'metrics.json'}, report.md, report.html")
    return 0
