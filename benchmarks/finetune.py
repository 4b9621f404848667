"""Fine-tuning that keeps the base model's skills: fine-tune on one traffic kind, measure on every kind.

The fine-tuning kind is a real-format stand-in of traffic the shipped model never trained on: SUMO's
``waves`` scenario (stop-and-go waves behind a lane drop), one carriageway written as an NGSIM I-80
file as NGSIM's interpolating tracker records traffic (benchmarks/real_proxy.py; held speeds, jumping
and saturating derivatives), read back through the NGSIM adapter and cut into windows split by track.
By default only its lane-keeping windows are trained on (``--with-lane-changes`` keeps all): a
congested freeway excerpt without a lane change, the case where plain fine-tuning taught the
classifier never to change lanes. Its test split is measured in full.

Every other kind is held out: one fresh simulation per shipped scenario (seeds never trained on,
highD format, clean), two more real-format stand-ins (dense traffic with video-tracker errors and
central-difference derivatives; stop_and_go as the interpolating tracker records it), and the real
NGSIM Peachtree sample (tests/data/ngsim). Per kind: RMSE at 5 s, its ratio to constant velocity,
lane-change macro-F1 (per step, where the kind holds lane changes), for the shipped model, the plain
fine-tune and each way of keeping the base (``lanecast.models.finetune``), at each learning rate.

    nice .venv/bin/python benchmarks/finetune.py --work /tmp/finetune-cache/bench --md benchmarks/finetune.md
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

SCENARIOS = ("free_flow", "dense", "wide", "on_ramp", "lane_drop", "stop_and_go", "urban", "signal")
HELD_OUT_SEED = 7101  # + scenario number; the shipped training used 101-108 and 901-908
PEACHTREE = ROOT / "tests" / "data" / "ngsim" / "peachtree_sample.csv"
#: stand-ins: kind → (scenario, seed, derivatives)
STAND_INS = {
    "dense, I-80 stand-in (video tracker)": ("dense", 7202, "central"),
    "stop_and_go, I-80 stand-in (NGSIM tracker)": ("stop_and_go", 7206, "keyframe"),
}
ERRORS = {"lon_slow": 0.3, "lon_white": 0.05, "lat_slow": 0.1, "lat_white": 0.1, "standing_jitter": False}


def simulate(work: Path, scenario: str, seed: int, minutes: float) -> Path:
    from lanecast.io_adapters.sim.recording import simulate as run
    from lanecast.io_adapters.sim.scenarios import scenario_config

    out = work / "sim" / f"{scenario}-{seed}-{minutes:g}min"
    if not (out / "01_tracks.csv").is_file():
        cfg = scenario_config(scenario, minutes=minutes, seed=seed)
        run(out, minutes=minutes, seed=seed, config=cfg, show_progress=False, overwrite=True)
    return out


def cached(path: Path, make: Any) -> Any:
    """Windows saved at ``path``, made by ``make()`` the first time."""
    from lanecast.io_adapters.windows_store.dataset import load_windows, save_windows

    if not (path / "manifest.json").is_file():
        save_windows(make(), path)
    return load_windows(path, mmap=False)


def cap(windows: Any, n: int, seed: int) -> Any:
    from lanecast.io_adapters.contracts.windows import subset

    if len(windows) <= n:
        return windows
    return subset(windows, np.sort(np.random.default_rng(seed).choice(len(windows), n, replace=False)))


def stand_in(work: Path, scenario: str, seed: int, minutes: float, derivatives: str, split: str) -> Any:
    """Windows of a simulation written as an NGSIM I-80 file with tracker errors, read back."""
    from real_proxy import write_ngsim_txt

    from lanecast.io_adapters.datasets.highd.reader import read as read_highd
    from lanecast.io_adapters.formats import registry
    from lanecast.pipeline.make_windows import make_windows

    def make() -> Any:
        case = work / f"ngsim-{scenario}-{seed}-{derivatives}" / "i-80"
        case.mkdir(parents=True, exist_ok=True)
        path = case / "trajectories-0400-0415.txt"
        args = argparse.Namespace(**ERRORS, derivatives=derivatives)
        write_ngsim_txt(
            read_highd([simulate(work, scenario, seed, minutes)]), path, noisy=True, args=args, seed=seed
        )
        return make_windows(registry.read_any([path]), split=split, seed=0)

    return cached(work / "windows" / f"ngsim-{scenario}-{seed}-{derivatives}-{split}", make)


def kinds(work: Path, minutes: float, max_windows: int) -> dict[str, Any]:
    """Every held-out kind's windows (split none), at most ``max_windows`` each."""
    from lanecast.io_adapters.datasets.highd.reader import read as read_highd
    from lanecast.io_adapters.formats import registry
    from lanecast.pipeline.make_windows import make_windows

    out = {}
    for i, name in enumerate(SCENARIOS):
        seed = HELD_OUT_SEED + i
        w = cached(
            work / "windows" / f"sim-{name}-{seed}",
            lambda n=name, s=seed: make_windows(read_highd([simulate(work, n, s, minutes)]), split="none"),
        )
        out[f"{name} (simulated, held out)"] = cap(w, max_windows, i)
    for kind, (scenario, seed, derivatives) in STAND_INS.items():
        out[kind] = cap(stand_in(work, scenario, seed, minutes, derivatives, "none"), max_windows, seed)
    out["Peachtree (real NGSIM sample)"] = cached(
        work / "windows" / "peachtree", lambda: make_windows(registry.read_any([PEACHTREE]), split="none")
    )
    return out


def with_split(windows: Any, split: str) -> Any:
    """``windows`` relabelled as split ``split`` (the evaluation reads one split)."""
    index = windows.index
    i = index.schema.get_field_index("split")
    windows.index = index.set_column(i, "split", pa.array([split] * index.num_rows))
    return windows


def measure(models: list[Any], sets: dict[str, Any]) -> dict[str, dict[str, Any]]:
    """kind → model → RMSE at 5 s, CV's, the ratio, lane-change macro-F1 (None without lane changes)."""
    from lanecast.models.baselines import constant_velocity
    from lanecast.models.evaluation import evaluate

    out: dict[str, dict[str, Any]] = {}
    for kind, w in sets.items():
        m = evaluate(w, [*models, constant_velocity()], splits=("none",), top_k=1)[0]
        cv = m["cv"]["rmse"][-1]
        changes = int(np.count_nonzero(np.asarray(w.maneuver) > 0))
        out[kind] = {
            name: {
                "rmse5": r["rmse"][-1],
                "ratio": r["rmse"][-1] / cv,
                "f1": r["maneuver_macro_f1"] if changes else None,
                "n": r["n_windows"],
            }
            for name, r in m.items()
        }
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--work", type=Path, default=Path("/tmp/finetune-cache/bench"))
    ap.add_argument("--md", type=Path, default=None, help="write the tables (markdown) here")
    ap.add_argument("--minutes", type=float, default=2.0, help="per held-out simulation and stand-in")
    ap.add_argument("--finetune-minutes", type=float, default=6.0)
    ap.add_argument("--max-windows", type=int, default=1500, help="per held-out kind")
    ap.add_argument("--with-lane-changes", action="store_true", help="fine-tune on all windows of the kind")
    ap.add_argument("--epochs", type=int, default=None, help="default: lanecast.models.finetune's")
    ap.add_argument("--lrs", type=float, nargs="+", default=None, help="default: lanecast.models.finetune's")
    ap.add_argument("--methods", nargs="+", default=["none", "l2sp", "replay", "l2sp+replay"])
    ap.add_argument("--l2sp-weights", type=float, nargs="+", default=None, help="default: FinetuneOptions'")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument(
        "--classifier",
        default=None,
        help="FinetuneOptions.classifier of the runs keeping the base (default: its)",
    )
    ap.add_argument("--seed", type=int, default=0, help="fine-tuning's seed (shuffling, augmentation)")
    ap.add_argument("--tag", default="finetune", help="results go to WORK/TAG.json")
    ap.add_argument(
        "--merge", type=Path, nargs="+", help="train nothing: render these results (TAG.json) together"
    )
    ap.add_argument(
        "--columns", nargs="+", help="with --merge: the models of the per-kind table (default: all)"
    )
    args = ap.parse_args()
    if args.merge:
        return merge(args.merge, args.md, args.columns)

    import torch

    from lanecast.io_adapters.contracts.windows import labelled, subset
    from lanecast.models.card import SHIPPED_STEM, WEIGHTS_DIR
    from lanecast.models.checkpoint import load_checkpoint
    from lanecast.models.finetune import (
        FINETUNE_EPOCHS,
        FINETUNE_LR,
        FinetuneOptions,
        finetune,
        load_replay,
        replay_path,
    )
    from lanecast.models.predict import STCNNForecaster
    from lanecast.models.train import TrainConfig

    torch.set_num_threads(args.threads)
    started = time.perf_counter()
    load_before = os.getloadavg()
    args.work.mkdir(parents=True, exist_ok=True)
    sets = kinds(args.work, args.minutes, args.max_windows)
    tune = stand_in(args.work, "waves", 7209, args.finetune_minutes, "keyframe", "pip")
    own = "waves, I-80 stand-in (NGSIM tracker): its test split"
    sets = {own: with_split(subset(tune, labelled(tune, ("test",))), "none"), **sets}
    if not args.with_lane_changes:
        keeping = ~np.any(np.asarray(tune.maneuver) > 0, axis=1)
        tune = subset(tune, keeping | (tune.index.column("split").to_numpy(zero_copy_only=False) == "test"))
    print(f"data ready in {time.perf_counter() - started:.0f} s: "
          + ", ".join(f"{k} {len(v)}" for k, v in sets.items()), flush=True)  # fmt: skip

    base = load_checkpoint(None)
    weights = WEIGHTS_DIR / f"{SHIPPED_STEM}.safetensors"
    replay = load_replay(replay_path(weights))
    config = dataclasses.replace(
        TrainConfig.from_dict(base[1]["training"]["config"]), threads=args.threads, seed=args.seed
    )
    epochs = args.epochs or FINETUNE_EPOCHS
    models = [STCNNForecaster(*load_checkpoint(None), name="shipped")]
    runs: dict[str, Any] = {}
    for lr in args.lrs or [FINETUNE_LR]:
        for method in args.methods:
            for weight in (args.l2sp_weights or [FinetuneOptions.l2sp_weight]) if "l2sp" in method else [0.0]:
                name = f"{method}{f' α={weight:g}' if weight else ''} lr={lr:g}"
                opts = FinetuneOptions(
                    keep_base=method,
                    l2sp_weight=weight,
                    classifier="train" if method == "none" else args.classifier or FinetuneOptions.classifier,
                )
                cfg = dataclasses.replace(config, lr=lr, epochs=epochs)
                t0 = time.perf_counter()
                result = finetune(
                    tune,
                    cfg,
                    load_checkpoint(None),
                    base_name="shipped",
                    base_sha256=base[1].get("weights_sha256"),
                    replay=replay,
                    options=opts,
                )
                seconds = time.perf_counter() - t0
                runs[name] = {"seconds": round(seconds, 1), "finetune": result.card["finetune"]}
                models.append(STCNNForecaster(result.model, result.card, name=name))
                print(
                    f"{name}: {seconds:.0f} s; classifier {result.card['finetune']['classifier']}", flush=True
                )
    table = measure(models, sets)
    out = {
        "args": {k: str(v) for k, v in vars(args).items()},
        "epochs": epochs,
        "finetune_windows": {s: len(labelled(tune, (s,))) for s in ("train", "val")},
        "runs": runs,
        "table": table,
        "load_average": [load_before, os.getloadavg()],
        "seconds": round(time.perf_counter() - started, 1),
    }
    (args.work / f"{args.tag}.json").write_text(json.dumps(out, indent=1))
    text = report(table, own, [m.name for m in models], out)
    print(text)
    if args.md:
        args.md.write_text(text)
    return 0


def merge(paths: list[Path], md: Path | None, columns: list[str] | None) -> int:
    """Render several runs' results (the same kinds) as one report; a model name two runs share
    gets the later run's file stem appended."""
    from finetune_report import render

    merged: dict[str, Any] = {"runs": {}, "seconds": 0.0, "load_average": []}
    table: dict[str, Any] = {}
    for path in paths:
        run = json.loads(path.read_text())
        for name, info in run["runs"].items():
            new = name if name not in merged["runs"] else f"{name} {path.stem}"
            merged["runs"][new] = info
            for kind, row in run["table"].items():
                table.setdefault(kind, {"shipped": row["shipped"], "cv": row["cv"]})[new] = row[name]
        merged["seconds"] += run["seconds"]
        merged["load_average"] += run["load_average"]
        merged["epochs"], merged["finetune_windows"] = run["epochs"], run["finetune_windows"]
    own = next(iter(table))
    text = render(table, own, ["shipped", *merged["runs"]], merged, columns)
    print(text)
    if md:
        md.write_text(text)
    return 0


def report(table: dict[str, Any], own: str, names: list[str], out: dict[str, Any]) -> str:
    """The side-by-side table per kind and, per method, the acceptance checks."""
    from finetune_report import render

    return render(table, own, names, out)


if __name__ == "__main__":
    sys.exit(main())
