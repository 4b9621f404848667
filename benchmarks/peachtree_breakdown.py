"""Where a model wins or loses against constant velocity on the real NGSIM Peachtree sample.

The sample (tests/data/ngsim, never trained on) is an arterial queue at a red light: most targets
stand, some creep. This splits its windows into standing targets (speed at t0 below 0.1 m/s) and
moving ones, and prints RMSE per horizon of each model and of CV for both groups, each model's ratio
to CV over all windows (unrounded), the mean along-road forecast of the moving ones against where
they went, and the same model with its acceleration input zeroed (how much the derivative inputs
cost here).

    .venv/bin/python benchmarks/peachtree_breakdown.py [MODEL_DIR ...]   # default: the shipped model
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from lanecast.io_adapters.contracts.windows import TARGET_ROW  # noqa: E402
from lanecast.io_adapters.formats import registry  # noqa: E402
from lanecast.models.baselines import reference_offsets  # noqa: E402
from lanecast.models.predict import STCNNForecaster  # noqa: E402
from lanecast.pipeline.make_windows import make_windows  # noqa: E402

PEACHTREE = ROOT / "tests" / "data" / "ngsim" / "peachtree_sample.csv"
STANDING_MS = 0.1


def rmse(pred: np.ndarray, true: np.ndarray) -> np.ndarray:
    """RMSE per horizon over windows: pred, true float [N, 5, 2] → [5]."""
    return np.sqrt(((pred - true) ** 2).sum(-1).mean(0))


def main() -> None:
    windows = make_windows(registry.read_any([PEACHTREE]), split="none")
    inputs, present, future = (
        np.asarray(windows.inputs),
        np.asarray(windows.present),
        np.asarray(windows.future),
    )
    cv = reference_offsets(inputs, "cv")
    standing = inputs[:, 2, TARGET_ROW, -1] < STANDING_MS
    groups = {"all": np.ones(len(standing), bool), "standing": standing, "moving": ~standing}
    print(f"{len(standing)} windows, {int(standing.sum())} standing targets; RMSE 1-5 s (m)")

    def show(name: str, pred: np.ndarray) -> None:
        cells = "   ".join(
            f"{g} {' '.join(f'{v:.2f}' for v in rmse(pred[k], future[k]))}" for g, k in groups.items()
        )
        print(f"  {name:<22} {cells}")

    show("cv", cv)
    for model_dir in sys.argv[1:] or [None]:
        model = STCNNForecaster.load(model_dir)
        label = "shipped" if model_dir is None else Path(model_dir).name
        pred = model.predict(inputs, present).offsets
        show(label, pred)
        ratio = rmse(pred, future) / rmse(cv, future)
        print(f"  {label}: ratio to cv, all, 1-5 s: {' '.join(f'{v:.3f}' for v in ratio)}")
        zeroed = inputs.copy()
        zeroed[:, 3] = 0.0
        show(f"{label}, acc. zeroed", model.predict(zeroed, present).offsets)
        moving = ~standing
        print(
            f"  moving targets, mean along-road offset 1-5 s: {label} "
            f"{' '.join(f'{v:.2f}' for v in pred[moving, :, 0].mean(0))}, went "
            f"{' '.join(f'{v:.2f}' for v in future[moving, :, 0].mean(0))}, cv "
            f"{' '.join(f'{v:.2f}' for v in cv[moving, :, 0].mean(0))}"
        )


if __name__ == "__main__":
    main()
