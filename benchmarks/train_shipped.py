"""Train the shipped weights (models/weights/stcnn-sumo.*) on simulated highway traffic, reproducibly.

1. Simulate the training recordings (several seeds and densities, 60 simulated minutes in all) and
   held-out test recordings (seeds never used in training) with SUMO, as highD files.
2. Windows: training recordings split by track with the seeded hash split (train/val used; their
   test share is reported as ``test_same_recordings``); test recordings entirely held out.
3. Train the ST-CNN (both networks) and the regression-only ablation with the same config.
4. Evaluate on the held-out recordings: ST-CNN, constant velocity, constant acceleration,
   regression-only; write the card (test metrics included), the weights, and a report.

    .venv/bin/python benchmarks/train_shipped.py --work /tmp/lanecast-shipped \
        --class-weight-power 0.5 --select-classifier macro_f1      # the shipped weights (≈ 12 min)

The shipped classifier goes beyond the paper (stated in the card, ``beyond_the_paper``): its NLL is
weighted by (1/class frequency)**0.5 and its best epoch is chosen by validation macro-F1. With the
paper's plain NLL (selected on NLL, or on macro-F1) its lane-change recall stayed at ~25–40 % per
step, and on lane-change windows the maneuver-conditioned regressor, fed "straight", then did worse
at 5 s than the regression-only ablation. Without the two flags the script trains the paper's loss.

Simulations and windows are cached in --work (delete it to start from scratch); the same arguments
give the same recordings and, on the same machine and thread count, the same weights.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

# (recording id, seed, density, minutes): 60 simulated minutes for training, 20 held out.
TRAIN_RECORDINGS = (
    (1, 11, "low", 12.0),
    (2, 12, "medium", 12.0),
    (3, 13, "high", 12.0),
    (4, 14, "medium", 12.0),
    (5, 15, "high", 12.0),
)
TEST_RECORDINGS = ((51, 901, "medium", 10.0), (52, 902, "high", 10.0))


def simulate_one(work: Path, rec_id: int, seed: int, density: str, minutes: float) -> Path:
    from lanecast.io_adapters.sim import sumo_highway

    out = work / "sim" / f"{rec_id:02d}-seed{seed}-{density}-{minutes:g}min"
    if not (out / f"{rec_id:02d}_tracks.csv").is_file():
        sumo_highway.simulate(
            out, minutes=minutes, seed=seed, density=density, recording_id=rec_id, show_progress=False
        )
    return out


def windows_for(dirs: list[Path], out: Path, split: str) -> Path:
    from lanecast.io_adapters.contracts.windows import concat_windows, save_windows
    from lanecast.io_adapters.datasets import highd
    from lanecast.pipeline.make_windows import make_windows

    if not (out / "manifest.json").is_file():
        parts = [make_windows(highd.read([d]), split=split, seed=0) for d in dirs]
        merged = concat_windows(parts)
        merged.manifest = {
            **parts[0].manifest,
            "sources": [str(d) for d in dirs],
            "counts": {
                s: int(sum(p.manifest["counts"].get(s, 0) for p in parts))
                for s in ("train", "val", "test", "none")
            },
        }
        save_windows(merged, out)
    return out


def direction_agreement(windows: Any) -> float:
    """Share of windows labelled left/right at t0+3 s whose lateral displacement (history start → t0+5 s,
    window frame) has the label's sign: a check of the labels' directions (≈ 0.5 means random)."""
    import numpy as np

    label = np.asarray(windows.maneuver[:, 2])
    sel = label > 0
    d = np.asarray(windows.future[sel, -1, 1]) - np.asarray(windows.inputs[sel, 1, 4, 0])
    return float(np.mean((d > 0) == (label[sel] == 1))) if sel.any() else float("nan")


def deviations(config: Any) -> list[str]:
    """What the shipped training does beyond the paper (for the card)."""
    out = [
        f"optimiser: Adam lr {config.lr:g}, batch {config.batch_size}, {config.epochs} epochs "
        "(the paper: lr 7e-5, 300 epochs)"
    ]
    if config.class_weight_power > 0:
        out.append(
            f"classifier loss: NLL weighted per step by its true class, (1/frequency)**{config.class_weight_power:g} "
            "normalised to mean 1 over the training steps (the paper: plain NLL); raises lane-change recall, "
            "which the ~97 % straight steps otherwise suppress"
        )
    if config.select_classifier != "nll":
        out.append(f"classifier's best epoch chosen by validation {config.select_classifier} (not NLL)")
    if config.lr_schedule != "constant":
        out.append(f"learning-rate schedule: {config.lr_schedule} decay to 0 over the run, both networks")
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--work", type=Path, default=Path("/tmp/lanecast-shipped"))
    ap.add_argument("--out", type=Path, default=ROOT / "models" / "weights")
    ap.add_argument("--epochs", type=int, default=30)
    ap.add_argument("--batch-size", type=int, default=256)
    ap.add_argument("--lr", type=float, default=1e-3)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--threads", type=int, default=1, help="1: the 2 cores are shared here")
    ap.add_argument(
        "--class-weight-power",
        type=float,
        default=0.0,
        help="classifier NLL weighted by (inverse class frequency)**POWER (0: the paper's plain NLL)",
    )
    ap.add_argument(
        "--select-classifier",
        choices=("nll", "macro_f1"),
        default="nll",
        help="the classifier's best epoch on validation by NLL (the paper) or macro-F1",
    )
    ap.add_argument("--lr-schedule", choices=("constant", "cosine"), default="constant")
    ap.add_argument("--jobs", type=int, default=2, help="simulations in parallel")
    args = ap.parse_args()

    from lanecast.io_adapters.contracts.windows import load_windows
    from lanecast.models.baselines import constant_acceleration, constant_velocity
    from lanecast.models.checkpoint import SHIPPED_STEM, save_checkpoint
    from lanecast.models.evaluation import always_straight, evaluate, example_scenes, write_metrics
    from lanecast.models.predict import STCNNForecaster
    from lanecast.models.report import write_report
    from lanecast.models.stcnn import STCNNConfig
    from lanecast.models.train import TrainConfig, train

    t_start = time.perf_counter()
    args.work.mkdir(parents=True, exist_ok=True)
    with ProcessPoolExecutor(args.jobs) as pool:
        futures = {r: pool.submit(simulate_one, args.work, *r) for r in TRAIN_RECORDINGS + TEST_RECORDINGS}
        sims = {r: f.result() for r, f in futures.items()}
    t_sim = time.perf_counter() - t_start
    print(f"simulated {sum(r[3] for r in sims):g} min in {t_sim:.0f} s", flush=True)
    train_dir = windows_for([sims[r] for r in TRAIN_RECORDINGS], args.work / "windows-train", "hash")
    test_dir = windows_for([sims[r] for r in TEST_RECORDINGS], args.work / "windows-test", "none")
    windows, held_out = load_windows(train_dir), load_windows(test_dir)
    print(
        f"windows: training recordings {windows.manifest['counts']}, held out {len(held_out):,}", flush=True
    )

    config = TrainConfig(
        epochs=args.epochs,
        batch_size=args.batch_size,
        lr=args.lr,
        seed=args.seed,
        threads=args.threads,
        class_weight_power=args.class_weight_power,
        select_classifier=args.select_classifier,
        lr_schedule=args.lr_schedule,
    )
    data = {
        "kind": "SUMO simulated highway (lanecast.io_adapters.sim.sumo_highway), highD format, 3 lanes per direction",
        "train_recordings": [
            dict(zip(("recording_id", "seed", "density", "minutes"), r, strict=True))
            for r in TRAIN_RECORDINGS
        ],
        "split": "seeded hash split by track (seed 0) within the training recordings: train/val",
        "test_recordings": [
            dict(zip(("recording_id", "seed", "density", "minutes"), r, strict=True)) for r in TEST_RECORDINGS
        ],
        "counts": windows.manifest["counts"],
        "label_direction_agreement": direction_agreement(windows),
    }
    t0 = time.perf_counter()
    result = train(windows, config, data_card=data)
    print(
        f"trained ST-CNN in {time.perf_counter() - t0:.0f} s, best epochs {result.card['training']['best_epoch']}",
        flush=True,
    )
    reg_cfg = dataclasses.replace(config, model=STCNNConfig(maneuver_input=False))
    t0 = time.perf_counter()
    reg = train(windows, reg_cfg, data_card=data, classifier_from=result.model)  # same classifier
    print(f"trained regression-only in {time.perf_counter() - t0:.0f} s", flush=True)
    save_checkpoint(reg.model, {**reg.card, "metrics": {}}, args.work / "regression-only")

    stcnn = STCNNForecaster(result.model, result.card, "stcnn")
    reg_only = STCNNForecaster(reg.model, reg.card, "stcnn_regression_only")
    models = [stcnn, constant_velocity(), constant_acceleration(), reg_only]
    test, preds, idx = evaluate(held_out, models, splits=("none",), top_k=3)
    val = evaluate(windows, [stcnn], splits=("val",), top_k=3)[0]["stcnn"]
    same = evaluate(windows, [stcnn], splits=("test",), top_k=3)[0]["stcnn"]
    reference = always_straight(held_out, idx)
    card = {
        **result.card,
        "metrics": {
            "validation": val,
            "test": test["stcnn"],
            "test_data": "held-out simulated recordings "
            + ", ".join(f"seed {r[1]} ({r[2]}, {r[3]:g} min)" for r in TEST_RECORDINGS),
            "test_baselines": {k: v for k, v in test.items() if k != "stcnn"},
            "test_always_straight": reference,
            "test_same_recordings": same,
        },
        "beyond_the_paper": deviations(config),
        "reproduce": "python benchmarks/train_shipped.py " + " ".join(sys.argv[1:]),
    }
    card_path = save_checkpoint(result.model, card, args.out, SHIPPED_STEM)
    report = args.work / "report"
    meta = {
        "windows": str(test_dir),
        "split": "all (held-out recordings)",
        "model": str(card_path),
        "top_k": 3,
        "always_straight": reference,
    }
    write_metrics(report / "metrics.json", test, meta)
    write_report(report, test, meta, example_scenes(held_out, idx, preds["stcnn"], 4))

    print(f"wrote {card_path} and {card_path.with_suffix('.safetensors')}; report in {report}")
    print(
        f"held-out test: {len(idx):,} windows; RMSE per window at 1-5 s (m), lane-change RMSE at 5 s, macro-F1:"
    )
    for name, m in test.items():
        f1 = m["maneuver_macro_f1"]
        print(
            f"  {name:<24}{' '.join(f'{v:.2f}' for v in m['rmse'])}   LC@5s {m['rmse_lane_change'][-1]:.2f}   "
            f"F1 {'-' if f1 is None else f'{f1:.3f}'}"
        )
    print(f"  always straight: {json.dumps(reference)}")
    ratio = test["stcnn"]["rmse"][-1] / test["cv"]["rmse"][-1]
    print(f"RMSE@5s ST-CNN / CV = {ratio:.2f}; total wall time {time.perf_counter() - t_start:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
