"""Benchmark: the windows stage on a 15-minute simulated highD-sized recording, interleaved with its
baselines in one run.

    .venv/bin/python benchmarks/bench_windows.py [--sim-dir DIR] [--minutes 15] [--rounds 5] [--reference-windows 400]

Three comparisons, each in rounds whose order reverses every round (benchmarks/interleave.py),
medians with min–max and the load average printed:

1. lanecast's ``make_windows`` (stride 10, in this process, each result freed before the next call)
   against the per-window pandas reference (``benchmarks/reference_windows.py``) on an evenly
   spread sample of the same windows: windows/s of each, and their largest difference;
2. the whole ``lanecast windows DIR --out X`` command (a fresh process: start-up, reading the highD
   CSVs, the stage, writing the dataset) against the same work without the command line (a fresh
   ``python -c`` process that imports the library, then reads, cuts and writes, and reports the
   seconds of that work alone, its imports not counted). The goal: the whole command at most 1.5×
   the stage alone.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import reference_windows
from interleave import Samples, machine_line, ratio, round_orders

from lanecast.io_adapters.contracts import track_table
from lanecast.io_adapters.datasets.highd import reader as highd
from lanecast.io_adapters.sim import recording
from lanecast.pipeline.make_windows import make_windows
from lanecast.pipeline.resample import resample

ROOT = Path(__file__).resolve().parents[1]
STAGE_ALONE = """
import sys, time
from lanecast.io_adapters.formats import streaming
from lanecast.pipeline.write_windows import write_windows
import lanecast.io_adapters.datasets.highd.reader  # the reader's imports too: not the stage's work
start = time.perf_counter()
with streaming.spill_directory(sys.argv[2]) as spill:
    pieces = streaming.plan([sys.argv[1]], fmt=None, spill_dir=spill.path, options={}, long="context")
    write_windows(pieces, sys.argv[2])
print(time.perf_counter() - start)
"""


def main() -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument(
        "--sim-dir", type=Path, default=ROOT / "benchmarks" / "_work" / "sim-15min-medium-seed1"
    )
    parser.add_argument("--minutes", type=float, default=15.0)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--reference-windows", type=int, default=400, help="windows the reference computes")
    args = parser.parse_args()

    print(machine_line("before"))
    if not (args.sim_dir / "01_tracks.csv").is_file():
        start = time.perf_counter()
        recording.simulate(args.sim_dir, minutes=args.minutes, seed=args.seed, density="medium")
        print(f"simulated {args.minutes:g} min (seed {args.seed}) in {time.perf_counter() - start:.1f} s")
    table = highd.read([args.sim_dir])
    print(f"recording {args.sim_dir}: {table.num_rows:,} rows at 25 Hz")

    # 1. the stage against the per-window reference, same windows (neighbours from the source ids)
    ours = make_windows(table, stride=10, neighbours="source")
    frames = {name: rec.coordinate_frame for name, rec in track_table.read_meta(table).recordings.items()}
    tracks = reference_windows.prepare(resample(table).to_pandas(), frames)
    n_ref = min(args.reference_windows, len(ours))
    sample = np.linspace(0, len(ours) - 1, n_ref).astype(int)
    rec = ours.index.column("recording").to_pylist()
    tid = ours.index.column("track_id").to_numpy()
    t0 = ours.index.column("t0_ns").to_numpy() // 100_000_000
    ref = [reference_windows.window(tracks, rec[i], int(tid[i]), int(t0[i])) for i in sample]
    diff_in = max(float(np.abs(r[0] - ours.inputs[i]).max()) for r, i in zip(ref, sample, strict=True))
    diff_fut = max(float(np.abs(r[2] - ours.future[i]).max()) for r, i in zip(ref, sample, strict=True))
    same = all(
        np.array_equal(r[1], ours.present[i]) and np.array_equal(r[3], ours.maneuver[i])
        for r, i in zip(ref, sample, strict=True)
    )
    n_ours = len(ours)
    del ours
    rates: dict[str, list[float]] = {"lanecast make_windows": [], "pandas reference, per window": []}
    for order in round_orders(list(rates), args.rounds):
        for name in order:
            start = time.perf_counter()
            if name.startswith("lanecast"):
                windows = make_windows(table, stride=10, neighbours="source")
                del windows
                rates[name].append(n_ours / (time.perf_counter() - start))
            else:
                for i in sample:
                    reference_windows.window(tracks, rec[i], int(tid[i]), int(t0[i]))
                rates[name].append(n_ref / (time.perf_counter() - start))
    print(
        f"\n1. windows/s, median (min–max; best) of {args.rounds} interleaved rounds ({n_ours:,} windows at stride 10):"
    )
    for name, values in rates.items():
        print(f"  {name:<32}{Samples(values).text()}")
    ours_s, ref_s = (Samples(v) for v in rates.values())
    print(f"  lanecast / reference: {ratio(ours_s, ref_s)}")
    print(f"  agreement on {n_ref} windows: max |inputs diff| {diff_in:.2e}, max |future diff| {diff_fut:.2e}, "
          f"present and maneuvers equal: {same}")  # fmt: skip

    # 2. the whole command against the stage alone, each a fresh process
    seconds: dict[str, list[float]] = {
        "lanecast windows (whole command)": [],
        "the stage alone (library)": [],
    }
    lanecast = [str(Path(sys.executable).with_name("lanecast"))]
    with tempfile.TemporaryDirectory() as tmp:
        for order in round_orders(list(seconds), args.rounds + 1):
            for name in order:
                out = Path(tmp) / "w"
                if name.startswith("lanecast"):
                    start = time.perf_counter()
                    subprocess.run([*lanecast, "windows", str(args.sim_dir), "--out", str(out)], check=True,
                                   capture_output=True)  # fmt: skip
                    seconds[name].append(time.perf_counter() - start)
                else:
                    done = subprocess.run([sys.executable, "-c", STAGE_ALONE, str(args.sim_dir), str(out)],
                                          check=True, capture_output=True, text=True)  # fmt: skip
                    seconds[name].append(float(done.stdout.strip().splitlines()[-1]))
        for values in seconds.values():
            del values[0]  # the first round warms the page cache
    print(f"\n2. seconds, median (min–max; best) of {args.rounds} interleaved rounds, fresh processes:")
    for name, values in seconds.items():
        print(f"  {name:<36}{Samples(values).text('.2f', higher_is_better=False)}")
    whole, alone = (Samples(v) for v in seconds.values())
    print(f"  whole command / stage alone: {ratio(whole, alone)}   (goal <= 1.5)")
    print(machine_line("after"))
    return 0


if __name__ == "__main__":
    sys.exit(main())
