"""Generalisation of the shipped training recipe: per scenario, leave one regime out, fine-tuning.

Uses the simulations and windows cached by ``benchmarks/train_shipped.py --work WORK`` (run that first)
and the shipped model it wrote. Three measurements, all on the held-out recordings (seeds never
trained on), RMSE per window at 5 s beside constant velocity:

1. the shipped model (trained on the whole mix) on each scenario;
2. leave one regime out: the same recipe trained without the congested scenarios (stop_and_go,
   urban, signal), tested on every scenario;
3. fine-tuning: that model fine-tuned (``train(..., init_from=...)``, as ``lanecast train --init``)
   on the training recording of one congested scenario (--regime, its minutes in the mix), versus
   the same recording from scratch. "Recovered" = (left-out − fine-tuned) / (left-out − shipped) on
   that regime: the share of the gain of training on the full mix that the fine-tuning recovers.

    .venv/bin/python benchmarks/generalisation.py --work /tmp/lanecast-shipped
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

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

CONGESTED = ("stop_and_go", "urban", "signal")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--work", type=Path, default=Path("/tmp/lanecast-shipped"))
    ap.add_argument("--model", type=Path, default=None, help="the mix model (default: the shipped one)")
    ap.add_argument("--epochs", type=int, default=12)
    ap.add_argument("--finetune-epochs", type=int, default=4)
    ap.add_argument("--regime", default="stop_and_go")
    ap.add_argument("--threads", type=int, default=1)
    args = ap.parse_args()

    import numpy as np
    from train_shipped import MIX, cached_windows, mix_model

    from lanecast.io_adapters.contracts.windows import subset
    from lanecast.models.baselines import constant_velocity
    from lanecast.models.evaluation import evaluate
    from lanecast.models.predict import STCNNForecaster
    from lanecast.models.train import train

    started = time.perf_counter()
    print(f"load average before: {os.getloadavg()}", flush=True)
    windows, held_out, train_scen, test_scen = cached_windows(args.work)
    shipped, config = mix_model(args.model, args.epochs, args.threads)

    keep = ~np.isin(train_scen, CONGESTED)
    left_out = train(subset(windows, keep), config)
    left_out_f = STCNNForecaster(left_out.model, left_out.card, "without_congestion")
    print(f"trained without {', '.join(CONGESTED)} in {time.perf_counter() - started:.0f} s", flush=True)

    regime = subset(windows, train_scen == args.regime)
    ft_cfg = dataclasses.replace(config, epochs=args.finetune_epochs, lr=config.lr / 3)
    t0 = time.perf_counter()
    tuned = train(regime, ft_cfg, init_from=(left_out.model, left_out.card))
    ft_s = time.perf_counter() - t0
    scratch = train(regime, dataclasses.replace(config, epochs=args.epochs))
    tuned_f = STCNNForecaster(tuned.model, tuned.card, "fine_tuned")
    scratch_f = STCNNForecaster(scratch.model, scratch.card, f"scratch_{args.regime}_only")

    table: dict[str, Any] = {}
    for name in MIX:
        part = subset(held_out, test_scen == name)
        models = [shipped, left_out_f, constant_velocity()]
        if name == args.regime:
            models += [tuned_f, scratch_f]
        m = evaluate(part, models, splits=("none",), top_k=1)[0]
        table[name] = {k: {"rmse": v["rmse"], "rmse_lane_change": v["rmse_lane_change"],
                           "maneuver_macro_f1": v["maneuver_macro_f1"], "n_windows": v["n_windows"]}
                       for k, v in m.items()}  # fmt: skip
    r = table[args.regime]
    gain = r["without_congestion"]["rmse"][-1] - r["mix"]["rmse"][-1]
    recovered = (r["without_congestion"]["rmse"][-1] - r["fine_tuned"]["rmse"][-1]) / gain if gain else None
    out = {
        "congested_left_out": CONGESTED,
        "regime": args.regime,
        "regime_training_minutes": MIX[args.regime][0],
        "regime_training_windows": len(regime),
        "finetune_epochs": args.finetune_epochs,
        "finetune_seconds": round(ft_s, 1),
        "recovered_share_at_5s": recovered,
        "table": table,
        "load_average_after": os.getloadavg(),
    }
    (args.work / "generalisation.json").write_text(json.dumps(out, indent=1))
    print("RMSE at 5 s (m) on held-out recordings; n windows; ratio to CV:")
    for name, models in table.items():
        cv = models["cv"]["rmse"][-1]
        cells = ", ".join(f"{k} {v['rmse'][-1]:.2f} ({v['rmse'][-1] / cv:.2f}x)" for k, v in models.items())
        print(f"  {name:<12} n={models['cv']['n_windows']:>5}  {cells}")
    print(
        f"fine-tuning on {MIX[args.regime][0]:g} simulated minutes of {args.regime} "
        f"({len(regime):,} windows, {args.finetune_epochs} epochs, {ft_s:.0f} s) recovers "
        f"{'n/a' if recovered is None else f'{100 * recovered:.0f} %'} of the mix model's gain at 5 s"
    )
    print(f"load average after: {os.getloadavg()}; total {time.perf_counter() - started:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
