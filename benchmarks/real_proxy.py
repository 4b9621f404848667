"""Real-format stand-ins for recordings we cannot download: simulated traffic written as an NGSIM
I-80 file, with NGSIM-like measurement errors, then run as a user runs a real recording.

No NGSIM I-80/US-101 or highD recording can be downloaded on this machine, yet the shipped model must
hold on them (docs/design.md §2; BENCHMARKS.md "Shipped model and real traffic"). This script takes
held-out SUMO scenarios (seeds never trained on), keeps one carriageway (I-80 and US-101 are one-way
road frames), and writes it as NGSIM's 18-column ``trajectories-*.txt`` in feet, front bumper,
10 Hz, with errors of the kind the NGSIM literature describes (video tracking; speeds and
accelerations differentiated from noisy positions):

* ``Local_Y`` (longitudinal): a slow error (sum of sinusoids, periods 2-10 s, std ``--lon-slow``)
  plus white jitter (std ``--lon-white``);
* ``Local_X`` (lateral): white jitter (std ``--lat-white``) plus a slow error (``--lat-slow``);
* standing vehicles keep the error they had when they stopped (NGSIM's standing boxes do not
  jitter and report speed 0); ``--standing-jitter`` gives them the same errors as moving ones;
* ``v_Vel``: the central difference of the noisy ``Local_Y`` over ±0.2 s; ``v_Acc``: the central
  difference of ``v_Vel`` over ±0.2 s, clipped to ±11.2 ft/s² as NGSIM's are;
* or (``--derivatives keyframe``) as NGSIM's interpolating tracker gives them: positions measured in
  a random share of each track's frames and linear between, ``v_Vel`` and ``v_Acc`` forward
  differences (speeds held for frames, then jumping; accelerations 0, then saturating).

Then, exactly as a user runs a recording (one process per command, relative paths):
``lanecast convert trajectories.txt --out t.parquet``, ``lanecast windows t.parquet --out w``,
``lanecast evaluate w --out r --split all [--model M]``, and prints RMSE per horizon of the model
and of constant velocity, with the ratio. A clean copy (no errors, the same traffic) runs beside it.

    .venv/bin/python benchmarks/real_proxy.py --work /tmp/proxy [--model DIR] [--scenarios lane_drop stop_and_go dense]

These are simulations with assumed errors, not real recordings: they test the adapter path and the
model's robustness to measurement noise, not its fit to real drivers.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from lanecast.io_adapters.contracts.track_runs import row_extent, run_starts  # noqa: E402
from lanecast.io_adapters.datasets.highd.reader import read as read_highd  # noqa: E402
from lanecast.io_adapters.sim.recording import simulate  # noqa: E402
from lanecast.io_adapters.sim.scenarios import scenario_config  # noqa: E402
from lanecast.io_adapters.sim.tracking_errors import (  # noqa: E402
    NGSIM_MAX_ACC,
    STANDING_MS,
    central_difference,
    forward_difference,
    held_while_standing,
    interpolate_between,
    keyframes,
    slow_error,
)

FT = 0.3048
SEEDS = {
    "free_flow": 9101,
    "dense": 9102,
    "wide": 9103,
    "on_ramp": 9104,
    "lane_drop": 9105,
    "stop_and_go": 9106,
    "urban": 9107,
    "signal": 9108,
    "waves": 9109,
}  # never trained on (train_shipped: 101-109, 901-909)


#: printf formats of the 18 columns of a raw NGSIM .txt (ids and counts whole, feet to the mm)
NGSIM_TXT_FORMAT = (
    ["%d"] * 4 + ["%.3f"] * 4 + ["%.1f"] * 2 + ["%d", "%.2f", "%.2f"] + ["%d"] * 3 + ["%.2f"] * 2
)


def save_ngsim_txt(path: Path, columns: list) -> None:
    """Write 18 columns as a raw NGSIM .txt (whitespace-separated, as the published files)."""
    table = np.column_stack([np.asarray(c, dtype=float) for c in columns])
    np.savetxt(path, table, fmt=NGSIM_TXT_FORMAT, delimiter="   ")


def write_ngsim_txt(table, path: Path, *, noisy: bool, args: argparse.Namespace, seed: int) -> int:
    """One carriageway of a highD-read track table as an NGSIM .txt (feet, front bumper). Rows written."""
    rec = table.column("recording").to_numpy().astype(str) if table.num_rows else np.array([])
    keep = np.char.endswith(rec, "-lower")
    cols = {
        c: table.column(c).to_numpy(zero_copy_only=False)[keep]
        for c in ("track_id", "frame", "x", "y", "vx", "vy", "length", "width", "lane_id", "object_class")
    }
    frame = cols["frame"].astype(np.int64)
    # SUMO scenarios run at 10 Hz already; keep the rows on NGSIM's 0.1 s grid.
    track = cols["track_id"].astype(np.int64)
    order = np.lexsort((frame, track))
    track, frame = track[order], frame[order]
    x, y = cols["x"][order].astype(float), cols["y"][order].astype(float)
    length, width = cols["length"][order].astype(float), cols["width"][order].astype(float)
    lane = cols["lane_id"][order]
    cls = cols["object_class"][order]
    t = frame * 0.1
    new = run_starts(track)
    run = np.cumsum(new) - 1
    first, last = row_extent(new)
    rng = np.random.default_rng(seed)
    front = x + length / 2  # m, along travel
    lateral = -y  # m, to the right
    if noisy:
        lon_error = slow_error(track, t, args.lon_slow, rng) + rng.normal(0, args.lon_white, track.size)
        lat_error = slow_error(track, t, args.lat_slow, rng) + rng.normal(0, args.lat_white, track.size)
        if not args.standing_jitter:
            standing = np.hypot(cols["vx"][order], cols["vy"][order]) < STANDING_MS
            lon_error = held_while_standing(lon_error, standing, first)
            lat_error = held_while_standing(lat_error, standing, first)
        front, lateral = front + lon_error, lateral + lat_error
    if noisy and args.derivatives == "keyframe":
        measured = keyframes(run, first, last, rng)
        front, lateral = interpolate_between(front, measured), interpolate_between(lateral, measured)
        speed = np.maximum(forward_difference(front, first, last, 0.1), 0.0)
        acc = np.clip(forward_difference(speed, first, last, 0.1), -NGSIM_MAX_ACC, NGSIM_MAX_ACC)
    else:
        speed = np.maximum(central_difference(front, first, last, 2, 0.1), 0.0)
        acc = np.clip(central_difference(speed, first, last, 2, 0.1), -NGSIM_MAX_ACC, NGSIM_MAX_ACC)
    # NGSIM lanes: 1 = left-most; the highD lane ids of one carriageway ordered by mean lateral position.
    lanes = np.unique(lane[lane > 0])
    mean_lat = np.array([lateral[lane == k].mean() for k in lanes])
    ngsim_lane = np.zeros(lane.size, np.int64)
    for rank, k in enumerate(lanes[np.argsort(mean_lat)]):
        ngsim_lane[lane == k] = rank + 1
    total = np.bincount(run)[run]
    lateral_ft = (lateral - lateral.min() + 1.0) / FT
    front_ft = (front - front.min() + 5.0) / FT
    v_class = np.where(cls == "truck", 3, 2)
    epoch_ms = 1113433136100 - 100 * int(frame.min())
    columns = [
        track,
        frame,
        total,
        epoch_ms + 100 * frame,
        lateral_ft,
        front_ft,
        6042842.0 + lateral_ft,
        2133117.0 + front_ft,
        length / FT,
        width / FT,
        v_class,
        speed / FT,
        acc / FT,
        ngsim_lane,
        np.zeros_like(track),
        np.zeros_like(track),
        np.zeros(track.size),
        np.zeros(track.size),
    ]
    save_ngsim_txt(path, columns)
    return int(track.size)


def lanecast(cwd: Path, *argv: str) -> None:
    exe = Path(sys.executable).with_name("lanecast")
    cmd = [str(exe) if exe.exists() else sys.executable, *([] if exe.exists() else ["-m", "lanecast"]), *argv]
    done = subprocess.run(cmd, cwd=cwd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    if done.returncode:
        raise SystemExit(f"lanecast {' '.join(argv)} failed in {cwd}:\n{done.stderr[-2000:]}")


def run_case(case_dir: Path, model: str | None) -> dict[str, list[float]]:
    """convert → windows → evaluate in ``case_dir`` (holding i-80/trajectories-0400-0415.txt)."""
    lanecast(case_dir, "convert", "i-80/trajectories-0400-0415.txt", "--out", "t.parquet")
    lanecast(case_dir, "windows", "t.parquet", "--out", "w")
    extra = ["--model", model] if model else []
    lanecast(case_dir, "evaluate", "w", "--out", "r", "--split", "all", "--examples", "0", *extra)
    metrics = json.loads((case_dir / "r" / "metrics.json").read_text())
    return {name: metrics[name]["rmse"] for name in ("stcnn", "cv")} | {
        "n": [metrics["stcnn"].get("n_windows", 0)]
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--work", type=Path, required=True)
    ap.add_argument("--model", help="model directory (default: the shipped weights)")
    ap.add_argument("--scenarios", nargs="+", default=["lane_drop", "stop_and_go", "dense"])
    ap.add_argument("--minutes", type=float, default=3.0)
    ap.add_argument("--lon-slow", type=float, default=0.3, help="m, std of the slow longitudinal error")
    ap.add_argument("--lon-white", type=float, default=0.05, help="m, std of longitudinal jitter")
    ap.add_argument("--lat-slow", type=float, default=0.1, help="m, std of the slow lateral error")
    ap.add_argument("--lat-white", type=float, default=0.1, help="m, std of lateral jitter")
    ap.add_argument(
        "--derivatives",
        choices=("central", "keyframe"),
        default="central",
        help="noisy copies: speed and acceleration as central differences of the noisy positions over "
        "+-0.2 s (default), or as an interpolating tracker gives them (positions measured in some frames, "
        "linear between: speeds held, then jumping; accelerations 0, then saturating, like NGSIM's)",
    )
    ap.add_argument(
        "--standing-jitter", action="store_true", help="standing vehicles jitter too (default: held still)"
    )
    args = ap.parse_args()
    model = str(Path(args.model).resolve()) if args.model else None
    print(f"load average: {os.getloadavg()}; model: {model or 'shipped'}")
    for name in args.scenarios:
        sim = args.work / f"sim-{name}"
        if not (sim / "01_tracks.csv").exists():
            simulate(
                sim,
                minutes=args.minutes,
                seed=SEEDS[name],
                show_progress=False,
                config=scenario_config(name, minutes=args.minutes, seed=SEEDS[name]),
                overwrite=True,
            )
        table = read_highd(sim)
        for noisy in (False, True):
            case = args.work / f"{name}-{'noisy' if noisy else 'clean'}"
            (case / "i-80").mkdir(parents=True, exist_ok=True)
            rows = write_ngsim_txt(
                table, case / "i-80" / "trajectories-0400-0415.txt", noisy=noisy, args=args, seed=SEEDS[name]
            )
            res = run_case(case, model)
            ratio = [m / c for m, c in zip(res["stcnn"], res["cv"], strict=True)]
            print(f"{name:12s} {'noisy' if noisy else 'clean'}  rows {rows:,} windows {res['n'][0]:,}")
            print("   stcnn " + " ".join(f"{v:5.2f}" for v in res["stcnn"]))
            print("   cv    " + " ".join(f"{v:5.2f}" for v in res["cv"]))
            print("   ratio " + " ".join(f"{v:5.2f}" for v in ratio), flush=True)


if __name__ == "__main__":
    main()
