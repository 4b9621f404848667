"""What the acceleration input is worth on NGSIM-format data: a model's forecasts with its
acceleration channel as recorded, zeroed, or averaged over the last 0.5 s or 1 s of the history.

NGSIM's ``v_Acc`` comes from an interpolating video tracker: 0 while a speed is held, saturated
where it jumps (BENCHMARKS.md). On the real Peachtree sample the shipped model loses to constant
velocity at 1 s, and the breakdown there points at the acceleration of cars leaving a queue. This
prints, for each windows dataset given (cut by ``lanecast windows``, all splits), RMSE per horizon
of constant velocity and of the model with each variant of that one channel, at inference only (the
model is not retrained): whether a smoothed acceleration would help real data, and what it costs on
simulated NGSIM-format stand-ins (``benchmarks/real_proxy.py``'s ``<scenario>-noisy/w``).

    .venv/bin/python benchmarks/acceleration_input.py WINDOWS_DIR [...] [--model DIR]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from lanecast.io_adapters.contracts.windows import CHANNELS  # noqa: E402
from lanecast.io_adapters.windows_store.dataset import load_windows  # noqa: E402
from lanecast.models.baselines import constant_velocity  # noqa: E402
from lanecast.models.predict import STCNNForecaster  # noqa: E402

ACC = CHANNELS.index("a")


def trailing_mean(values: np.ndarray, present: np.ndarray, frames: int) -> np.ndarray:
    """Mean of ``values`` [N, V, T] over each frame and the ``frames`` − 1 before it (fewer at the
    start of the history), over present frames only; 0 where absent."""
    v = np.where(present, values, 0.0)
    pad = ((0, 0), (0, 0), (frames, 0))
    total = np.cumsum(np.pad(v, pad), axis=-1)
    count = np.cumsum(np.pad(present.astype(np.float64), pad), axis=-1)
    sums = total[..., frames:] - total[..., :-frames]
    n = count[..., frames:] - count[..., :-frames]
    return np.where(present, sums / np.maximum(n, 1), 0.0).astype(values.dtype)


def rmse_per_horizon(offsets: np.ndarray, future: np.ndarray) -> np.ndarray:
    """offsets, future [N, 5, 2] → RMSE per horizon [5] (m)."""
    return np.sqrt(((offsets - future) ** 2).sum(-1).mean(0))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("windows", type=Path, nargs="+", help="windows datasets (lanecast windows)")
    ap.add_argument("--model", type=Path, default=None, help="model directory (default: the shipped one)")
    args = ap.parse_args()
    model = STCNNForecaster.load(args.model)
    cv = constant_velocity()
    for directory in args.windows:
        w = load_windows(directory)
        inputs, present, future = np.asarray(w.inputs), np.asarray(w.present), np.asarray(w.future)
        variants = {"as recorded": inputs}
        zeroed = inputs.copy()
        zeroed[:, ACC] = 0.0
        variants["zeroed"] = zeroed
        for frames in (5, 10):
            smoothed = inputs.copy()
            smoothed[:, ACC] = trailing_mean(inputs[:, ACC], present, frames)
            variants[f"mean of the last {frames / 10:.1f} s"] = smoothed
        print(f"{directory}: {len(inputs):,} windows; RMSE 1-5 s (m)")
        base = rmse_per_horizon(cv.predict(inputs, present, top_k=1).offsets, future)
        print(f"  {'constant velocity':42s}" + " ".join(f"{r:.3f}" for r in base))
        for name, x in variants.items():
            r = rmse_per_horizon(model.predict(x, present, top_k=1).offsets, future)
            ratio = " ".join(f"{q:.2f}" for q in r / base)
            print(
                f"  {'model, acceleration ' + name:42s}"
                + " ".join(f"{v:.3f}" for v in r)
                + f"   ({ratio} x CV)"
            )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
