"""Traffic faster than the shipped model was trained on: the shipped weights against constant
velocity on held-out free-flowing traffic stretched along the road.

The shipped training mix tops out at 130 km/h limits (the card's target speeds: 99.5th percentile
37.7 m/s); highD's German autobahns have sections without a limit, where cars drive 150-200 km/h.
No such recording can be simulated with the named scenarios, so this script takes a held-out
``free_flow`` recording (a seed never trained on), converts it as a user would, and multiplies
``x``, ``vx`` and ``ax`` by a factor: the same drivers and lane changes, ``factor`` times as fast
(headways in time, lateral motion and lane-change durations unchanged). Each stretched table then
runs as a user runs a recording (one process per command, relative paths): ``lanecast windows``,
``lanecast evaluate --split all``. Printed: the targets' median and 95th-percentile speed, the share
of windows the model flags as out of its training distribution, RMSE at 1 and 5 s of the model and
of constant velocity, and their ratio, on all windows and on the flagged ones.

    .venv/bin/python benchmarks/faster_traffic.py --work /tmp/faster [--model DIR] [--factors 1 1.2 1.4 1.6]

A stretched recording is not real fast traffic (a real driver at 200 km/h keeps longer gaps and
changes lanes differently); it answers one question: do the forecasts fall apart, or below constant
velocity, where the target is faster than anything in training?
"""

from __future__ import annotations

import argparse
import json
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from lanecast.io_adapters.contracts.windows import TARGET_ROW  # noqa: E402

LANECAST = [sys.executable, "-m", "lanecast"]
STRETCHED = ("x", "vx", "ax")  # along the road: positions, speeds, accelerations
OOD_LINE = re.compile(r"out of distribution: ([\d,]+) of ([\d,]+) windows.*?stcnn ([\d.]+) m, cv ([\d.]+) m")


def run(args: list[str], cwd: Path) -> str:
    """One lanecast command as a user runs it; its stdout (stops the script on failure)."""
    done = subprocess.run(LANECAST + args, cwd=cwd, capture_output=True, text=True)
    if done.returncode != 0:
        sys.exit(f"lanecast {' '.join(args)} failed:\n{done.stderr}")
    return done.stdout


def stretch(table_path: Path, factor: float, out: Path) -> None:
    """The track table with x, vx, ax multiplied by ``factor``, read and written with pyarrow alone
    (its ``lanecast`` metadata travels in the schema)."""
    table = pq.read_table(table_path)
    columns = [
        pc.multiply(table.column(n), pa.scalar(factor, table.column(n).type))
        if n in STRETCHED
        else table.column(n)
        for n in table.column_names
    ]
    pq.write_table(pa.Table.from_arrays(columns, schema=table.schema), out, compression="zstd")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--work", type=Path, default=Path("/tmp/lanecast-faster"))
    ap.add_argument("--model", type=Path, default=None, help="default: the shipped model")
    ap.add_argument("--factors", type=float, nargs="+", default=[1.0, 1.2, 1.4, 1.6])
    ap.add_argument("--minutes", type=float, default=6.0)
    ap.add_argument("--seed", type=int, default=901, help="a free_flow seed the shipped model never saw")
    args = ap.parse_args()
    work = args.work.resolve()
    work.mkdir(parents=True, exist_ok=True)
    model = ["--model", str(args.model.resolve())] if args.model else []

    simulate = ["simulate", "--out", "sim", "--minutes", f"{args.minutes:g}", "--seed", str(args.seed)]
    if not (work / "sim" / "01_tracks.csv").exists():
        run([*simulate, "--scenario", "free_flow"], work)
    if not (work / "ff.parquet").exists():
        run(["convert", "sim", "--out", "ff.parquet"], work)

    print(
        "| speed factor | target speed p50 / p95 (m/s) | windows | out of distribution | RMSE 1 s / 5 s: ST-CNN | CV | ratio at 5 s | maneuver macro-F1 | on the flagged windows, 5 s: ST-CNN / CV (ratio) |"
    )
    print("|---|---|---|---|---|---|---|---|---|")
    for factor in args.factors:
        tag = f"x{factor:g}"
        stretch(work / "ff.parquet", factor, work / f"{tag}.parquet")
        for made in (f"w-{tag}", f"ev-{tag}"):
            shutil.rmtree(work / made, ignore_errors=True)
        run(["windows", f"{tag}.parquet", "--out", f"w-{tag}"], work)
        out = run(["evaluate", f"w-{tag}", "--split", "all", "--out", f"ev-{tag}", *model], work)
        metrics = json.loads((work / f"ev-{tag}" / "metrics.json").read_text())
        speeds = np.load(work / f"w-{tag}" / "inputs.npy", mmap_mode="r")[:, 2, TARGET_ROW, -1]
        st, cv = metrics["stcnn"]["rmse"], metrics["cv"]["rmse"]
        flagged = "no flags"
        found = OOD_LINE.search(out.replace("\n", " "))
        if found:
            n, total, st_ood, cv_ood = found.groups()
            share = int(n.replace(",", "")) / int(total.replace(",", ""))
            flagged = f"{100 * share:.0f} %"
            on_flagged = f"{float(st_ood):.2f} / {float(cv_ood):.2f} ({float(st_ood) / float(cv_ood):.2f})"
        elif "out of distribution: 0 of" in out:
            flagged, on_flagged = "0 %", "-"
        else:
            on_flagged = "-"
        print(
            f"| {factor:g} | {np.percentile(speeds, 50):.1f} / {np.percentile(speeds, 95):.1f} | "
            f"{metrics['stcnn']['n_windows']:,} | {flagged} | {st[0]:.2f} / {st[-1]:.2f} | {cv[0]:.2f} / {cv[-1]:.2f} | "
            f"{st[-1] / cv[-1]:.2f} | {metrics['stcnn']['maneuver_macro_f1']:.3f} | {on_flagged} |",
            flush=True,
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
