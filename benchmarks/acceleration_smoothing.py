"""Would a smoothed acceleration input, trained with, hold on real data? An experiment, not the
shipped model.

``benchmarks/acceleration_input.py`` smooths the acceleration channel at inference only: on the real
Peachtree sample that beats constant velocity, on the NGSIM-format stand-ins it costs up to 0.1 of
CV, because the shipped weights were trained on the raw channel. This trains the shipped recipe (the
card's training config, the windows a ``train_shipped.py`` run cached in ``--work``) on windows whose
acceleration channel is the mean of its last ``--frames`` frames, then evaluates it with the same
smoothing on the held-out simulation, on Peachtree and on stand-in windows, beside the shipped
model on the raw channel and constant velocity.

    .venv/bin/python benchmarks/acceleration_smoothing.py --work /tmp/ship18 --out /tmp/acc-smooth \\
        --windows /tmp/cardt/win /tmp/proxy/dense-noisy/w ...
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from acceleration_input import ACC, rmse_per_horizon, trailing_mean  # noqa: E402

from lanecast.io_adapters.contracts.windows import Windows  # noqa: E402
from lanecast.io_adapters.windows_store.dataset import load_windows  # noqa: E402
from lanecast.models.baselines import constant_velocity  # noqa: E402
from lanecast.models.checkpoint import load_checkpoint, save_checkpoint  # noqa: E402
from lanecast.models.predict import STCNNForecaster  # noqa: E402
from lanecast.models.train import TrainConfig, train  # noqa: E402


def smoothed(windows: Windows, frames: int) -> Windows:
    """The same windows with the acceleration channel averaged over its last ``frames`` frames."""
    inputs = np.array(windows.inputs)
    inputs[:, ACC] = trailing_mean(inputs[:, ACC], np.asarray(windows.present), frames)
    return dataclasses.replace(windows, inputs=inputs)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--work", type=Path, required=True, help="a train_shipped.py work directory")
    ap.add_argument("--out", type=Path, required=True, help="where the experiment's model is written")
    ap.add_argument("--frames", type=int, default=10, help="frames at 10 Hz averaged (default 10: 1 s)")
    ap.add_argument("--windows", type=Path, nargs="*", default=[], help="further windows datasets")
    args = ap.parse_args()

    _, card = load_checkpoint(None)
    config = TrainConfig.from_dict(card["training"]["config"])
    model_dir = args.out / "weights"
    if not (model_dir / "stcnn.json").is_file():
        t0 = time.perf_counter()
        result = train(smoothed(load_windows(args.work / "windows-train"), args.frames), config)
        save_checkpoint(result.model, result.card, model_dir)
        print(f"trained in {time.perf_counter() - t0:.0f} s", flush=True)
    experiment = STCNNForecaster.load(model_dir)
    shipped, cv = STCNNForecaster.load(None), constant_velocity()
    for directory in [args.work / "windows-test", *args.windows]:
        w = load_windows(directory)
        raw, present, future = np.asarray(w.inputs), np.asarray(w.present), np.asarray(w.future)
        smooth = smoothed(w, args.frames).inputs
        base = rmse_per_horizon(cv.predict(raw, present, top_k=1).offsets, future)
        rows = {
            "constant velocity": base,
            "shipped, raw acceleration": rmse_per_horizon(
                shipped.predict(raw, present, top_k=1).offsets, future
            ),
            f"trained on a {args.frames / 10:g} s mean": rmse_per_horizon(
                experiment.predict(smooth, present, top_k=1).offsets, future
            ),
        }
        print(f"{directory}: {len(raw):,} windows; RMSE 1-5 s (m), ratio to CV")
        for name, r in rows.items():
            ratio = " ".join(f"{q:.2f}" for q in r / base)
            print(f"  {name:28s}" + " ".join(f"{v:.3f}" for v in r) + f"   ({ratio})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
