"""How far below constant velocity can a network get in near-constant-speed traffic? A specialist bound.

The issue asks RMSE@5 s <= 0.6x constant velocity on every held-out scenario; the mix model misses it
in free flow, dense and wide traffic. Is that the mix (a model spread over congestion too) or the
traffic (speed changes nobody can foresee)? For each scenario named, this trains the shipped recipe
from scratch on that scenario's training recording alone (and its measured copies) and evaluates it
on that scenario's held-out recording, beside the mix model and constant velocity; it also splits
CV's squared error at 5 s into its along-road and across-road parts.

Uses the windows cached by ``benchmarks/train_shipped.py --work WORK`` (run that first).

    .venv/bin/python benchmarks/specialist.py --work /tmp/lanecast-shipped --scenarios free_flow dense wide
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--work", type=Path, default=Path("/tmp/lanecast-shipped"))
    ap.add_argument("--model", type=Path, default=None, help="the mix model (default: the shipped one)")
    ap.add_argument("--scenarios", nargs="+", default=["free_flow", "dense", "wide"])
    ap.add_argument("--epochs", type=int, default=12)
    ap.add_argument("--threads", type=int, default=1)
    args = ap.parse_args()

    import numpy as np
    from train_shipped import cached_windows, mix_model

    from lanecast.io_adapters.contracts.windows import subset
    from lanecast.models.baselines import constant_velocity, reference_offsets
    from lanecast.models.evaluation import evaluate
    from lanecast.models.predict import STCNNForecaster
    from lanecast.models.train import train

    started = time.perf_counter()
    print(f"load average before: {os.getloadavg()}", flush=True)
    windows, held_out, train_scen, test_scen = cached_windows(args.work)
    mix, config = mix_model(args.model, args.epochs, args.threads)
    print("RMSE at 1 s and 5 s (m) on the held-out recording; ratio to CV at 5 s:")
    for name in args.scenarios:
        t0 = time.perf_counter()
        own = train(subset(windows, train_scen == name), config)
        specialist = STCNNForecaster(own.model, own.card, "specialist")
        part = subset(held_out, test_scen == name)
        m = evaluate(part, [mix, specialist, constant_velocity()], splits=("none",), top_k=1)[0]
        cv5 = m["cv"]["rmse"][-1]
        cells = ", ".join(
            f"{k} {v['rmse'][0]:.2f}/{v['rmse'][-1]:.2f} ({v['rmse'][-1] / cv5:.2f}x)" for k, v in m.items()
        )
        err = reference_offsets(np.asarray(part.inputs), "cv")[:, -1] - np.asarray(part.future)[:, -1]
        lon_share = float((err[:, 0] ** 2).sum() / (err**2).sum())
        print(
            f"  {name:<10} n={len(part):>5} train={int((train_scen == name).sum()):>6} ({time.perf_counter() - t0:.0f} s): "
            f"{cells}; CV's 5 s squared error along the road {100 * lon_share:.0f} %",
            flush=True,
        )
    print(f"load average after: {os.getloadavg()}; total {time.perf_counter() - started:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
