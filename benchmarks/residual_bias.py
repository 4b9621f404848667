"""Is the shipped network biased where it misses 0.6x constant velocity? Its mean error at 5 s.

Per held-out scenario: the mean 5 s error (along and across the road) of the network and of
constant velocity, the RMSE ratio to CV, and the ratio once the network's mean error is removed
(what a per-scenario calibration fitted on the test itself, an upper bound, could give). A ratio
that barely moves says the miss is spread error, not an offset a correction could take away.

Uses the held-out windows cached by ``benchmarks/train_shipped.py --work WORK`` (run that first).

    .venv/bin/python benchmarks/residual_bias.py --work /tmp/lanecast-shipped
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--work", type=Path, default=Path("/tmp/lanecast-shipped"))
    ap.add_argument("--model", type=Path, default=None, help="default: the shipped model")
    args = ap.parse_args()

    import numpy as np
    from train_shipped import MIX, cached_windows

    from lanecast.models.baselines import reference_offsets
    from lanecast.models.predict import STCNNForecaster

    _, held_out, _, scenario = cached_windows(args.work)
    inputs, present = np.asarray(held_out.inputs), np.asarray(held_out.present)
    future = np.asarray(held_out.future)[:, 4]  # [N, 2] at 5 s
    error = STCNNForecaster.load(args.model).predict(inputs, present).offsets[:, 4] - future
    cv_error = reference_offsets(inputs, "cv")[:, 4] - future

    def rmse(e: np.ndarray) -> float:
        return float(np.sqrt((e**2).sum(-1).mean()))

    print(
        "scenario     windows  mean error at 5 s, along/across (m): ST-CNN | CV   RMSE ratio to CV: as is | mean removed"
    )
    for name in MIX:
        k = scenario == name
        e, c = error[k], cv_error[k]
        print(
            f"{name:12s} {k.sum():7,d}  {e.mean(0)[0]:+.2f} / {e.mean(0)[1]:+.2f} | {c.mean(0)[0]:+.2f} / {c.mean(0)[1]:+.2f}"
            f"        {rmse(e) / rmse(c):.2f} | {rmse(e - e.mean(0)) / rmse(c):.2f}"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
