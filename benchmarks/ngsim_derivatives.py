"""How NGSIM files record speed and acceleration: the statistics that tell an interpolating tracker.

NGSIM's ``v_Vel`` is held for frames and then jumps; its ``v_Acc`` is 0 while the speed is held and
saturates at ±11.2 ft/s² where it jumps. ``benchmarks/real_proxy.py --derivatives keyframe`` and the
training's interpolated copies (``lanecast.io_adapters.sim.tracking_errors``) imitate that; this
script prints, for real files and for the stand-ins alike, over the rows of moving vehicles
(``v_Vel`` > 3 ft/s): the share whose speed equals the previous frame's ("held"), the share with
``v_Acc`` 0 and with |``v_Acc``| >= 11 ft/s² ("saturated"), percentiles of the speed jumps (ft/s)
where the speed changes, and the std of ``v_Acc`` (ft/s²).

    .venv/bin/python benchmarks/ngsim_derivatives.py tests/data/ngsim/peachtree_sample.csv \\
        /tmp/proxy/kfcal/dense-noisy/i-80/trajectories-0400-0415.txt
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import pandas as pd

from lanecast.io_adapters.datasets.ngsim.reader import TXT_COLUMNS


def derivative_statistics(path: Path) -> dict[str, float]:
    """The statistics of the module docstring for one NGSIM .csv (with header) or .txt file."""
    if path.suffix == ".txt":
        d = pd.read_csv(path, sep=r"\s+", header=None, names=list(TXT_COLUMNS), usecols=range(18))
    else:
        d = pd.read_csv(path, usecols=["Vehicle_ID", "Frame_ID", "v_Vel", "v_Acc"])
    d = d.sort_values(["Vehicle_ID", "Frame_ID"]).drop_duplicates(["Vehicle_ID", "Frame_ID"])
    vid, vel, acc = d["Vehicle_ID"].to_numpy(), d["v_Vel"].to_numpy(), d["v_Acc"].to_numpy()
    same_track = np.r_[False, vid[1:] == vid[:-1]]
    step = np.r_[np.nan, np.diff(vel)]
    moving = vel > 3.0
    held = same_track & (step == 0)
    jumps = np.abs(step[moving & same_track & ~held])
    p50, p90, p99 = np.percentile(jumps, [50, 90, 99]) if jumps.size else (np.nan,) * 3
    return {
        "moving_rows": int(moving.sum()),
        "held": float(held[moving].mean()),
        "acc_zero": float((acc[moving] == 0).mean()),
        "saturated": float((np.abs(acc[moving]) >= 11.0).mean()),
        "jump_p50": float(p50),
        "jump_p90": float(p90),
        "jump_p99": float(p99),
        "acc_std": float(acc[moving].std()),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("files", nargs="+", type=Path)
    args = ap.parse_args()
    print(
        "file | moving rows | held | v_Acc 0 | saturated | speed jump p50/p90/p99 (ft/s) | v_Acc std (ft/s²)"
    )
    for path in args.files:
        s = derivative_statistics(path)
        print(
            f"{path} | {s['moving_rows']:,} | {s['held']:.2f} | {s['acc_zero']:.2f} | {s['saturated']:.2f} | "
            f"{s['jump_p50']:.2f} / {s['jump_p90']:.2f} / {s['jump_p99']:.2f} | {s['acc_std']:.2f}"
        )


if __name__ == "__main__":
    main()
