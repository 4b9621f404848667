"""Benchmark: the windows stage on a 15-minute simulated highD-sized recording, against the
per-window pandas reference (benchmarks/reference_windows.py), both in one run.

    .venv/bin/python benchmarks/bench_windows.py [--sim-dir DIR] [--minutes 15] [--reference-windows 400]

Prints: simulation (not timed against the goal), convert (highD CSV -> track table), windows at
stride 10 and 1, each cold (first call in the process: its output memory is faulted in fresh,
which is expensive in a sandbox) and warm (wall and CPU time, windows/s, per-stage times), saving, the reference's windows/s
on a sample of windows, the speed-up, the largest difference between the two on that sample, and
convert + windows + save of the recording. The machine may be shared: figures are preliminary.
"""

from __future__ import annotations

import argparse
import os
import resource
import statistics
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import reference_windows

from lanecast.io_adapters.contracts import track_table
from lanecast.io_adapters.datasets.highd import reader as highd
from lanecast.io_adapters.sim import recording
from lanecast.io_adapters.windows_store.dataset import save_windows
from lanecast.pipeline import labels as labels_mod
from lanecast.pipeline import neighbours as nb_mod
from lanecast.pipeline import window_tensors
from lanecast.pipeline.make_windows import make_windows
from lanecast.pipeline.resample import resample

T = TypeVar("T")


def timed(fn: Callable[..., T], *args: Any, **kwargs: Any) -> tuple[T, float, float]:
    wall, cpu = time.perf_counter(), time.process_time()
    out = fn(*args, **kwargs)
    return out, time.perf_counter() - wall, time.process_time() - cpu


def main() -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument(
        "--sim-dir", type=Path, default=Path(tempfile.gettempdir()) / "lanecast-bench" / "sim15"
    )
    parser.add_argument("--minutes", type=float, default=15.0)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--reference-windows", type=int, default=400, help="windows the reference computes")
    args = parser.parse_args()

    print(f"cores: {os.cpu_count()}, load average: {os.getloadavg()}")
    if not (args.sim_dir / "01_tracks.csv").is_file():
        _, wall, _ = timed(
            recording.simulate, args.sim_dir, minutes=args.minutes, seed=args.seed, show_progress=False
        )
        print(f"simulated {args.minutes:g} min (seed {args.seed}) in {wall:.1f} s -> {args.sim_dir}")
    else:
        print(f"using the simulated recording in {args.sim_dir}")

    table, t_read, c_read = timed(highd.read, [args.sim_dir])
    print(
        f"convert (highD CSV -> track table): {table.num_rows:,} rows in {t_read:.2f} s (cpu {c_read:.2f} s)"
    )

    results = {}
    for stride in (10, 1):
        for run in ("cold", "warm"):  # cold: first call in the process (fresh memory to fault in)
            w, wall, cpu = timed(make_windows, table, stride=stride)
            if run == "cold":
                results[stride] = (w, wall, cpu)
            t = w.manifest["timings"]
            print(
                f"make_windows stride {stride:>2} ({run}): {len(w):,} windows in {wall:.2f} s wall / "
                f"{cpu:.2f} s cpu = {len(w) / wall:,.0f} windows/s wall ({len(w) / cpu:,.0f} per cpu-s); "
                f"stage seconds summed over threads: resample {t['resample_s']:.2f}, "
                f"neighbours {t['neighbours_s']:.2f}, labels+tensors {t['windows_s']:.2f}"
            )
            del w
        # Steady state: repeated calls, each result freed before the next (what a batch job sees).
        samples, n = [], 0
        for _ in range(7 if stride == 10 else 3):
            w, wall, _ = timed(make_windows, table, stride=stride)
            n = len(w)
            del w
            samples.append(wall)
        mid = statistics.median(samples)
        print(
            f"make_windows stride {stride:>2} (steady, median of {len(samples)}): {n:,} windows in {mid:.2f} s "
            f"= {n / mid:,.0f} windows/s wall (best {n / min(samples):,.0f})"
        )
    # The tensor stage alone (gather of the stride-1 windows), prepared once.
    cols = nb_mod.columns(resample(table))
    nb_rows = nb_mod.neighbour_rows(resample(table), cols).rows
    labels = labels_mod.row_labels(cols)
    _, fwd = window_tensors.runs(cols)
    t0_rows = window_tensors.window_rows(cols, stride=1)
    for workers in (1, 2, 1, 2):
        r0 = resource.getrusage(resource.RUSAGE_SELF)
        arrays, wall, _ = timed(window_tensors.gather, cols, nb_rows, labels, t0_rows, fwd, workers=workers)
        r1 = resource.getrusage(resource.RUSAGE_SELF)
        print(
            f"tensor stage only, {t0_rows.size:,} windows, {workers} thread(s): {wall:.2f} s wall "
            f"(user {r1.ru_utime - r0.ru_utime:.2f} s, sys {r1.ru_stime - r0.ru_stime:.2f} s) "
            f"= {t0_rows.size / wall:,.0f} windows/s"
        )
        del arrays
    w10, wall10, _ = results[10]
    del results[1]
    with tempfile.TemporaryDirectory() as tmp:
        _, t_save, _ = timed(save_windows, w10, Path(tmp) / "w")
    print(f"save_windows (stride 10): {t_save:.2f} s")
    print(
        f"convert + windows (stride 10) + save of the {args.minutes:g}-min recording: "
        f"{t_read + wall10 + t_save:.1f} s (goal < 30 s)"
    )

    # The reference on an evenly spread sample of the stride-10 windows, same inputs (source ids).
    ours, t_ours, _ = timed(make_windows, table, stride=10, neighbours="source")
    frames = {name: rec.coordinate_frame for name, rec in track_table.read_meta(table).recordings.items()}
    tracks, t_prep, _ = timed(reference_windows.prepare, resample(table).to_pandas(), frames)
    n_ref = min(args.reference_windows, len(ours))
    sample = np.linspace(0, len(ours) - 1, n_ref).astype(int)
    rec = ours.index.column("recording").to_pylist()
    tid = ours.index.column("track_id").to_numpy()
    t0 = ours.index.column("t0_ns").to_numpy() // 100_000_000
    start = time.perf_counter()
    ref = [reference_windows.window(tracks, rec[i], int(tid[i]), int(t0[i])) for i in sample]
    t_ref = time.perf_counter() - start
    ref_rate = n_ref / t_ref
    our_rate = len(ours) / t_ours
    diff_in = max(float(np.abs(r[0] - ours.inputs[i]).max()) for r, i in zip(ref, sample, strict=True))
    same_present = all(np.array_equal(r[1], ours.present[i]) for r, i in zip(ref, sample, strict=True))
    diff_fut = max(float(np.abs(r[2] - ours.future[i]).max()) for r, i in zip(ref, sample, strict=True))
    same_man = all(np.array_equal(r[3], ours.maneuver[i]) for r, i in zip(ref, sample, strict=True))
    print(
        f"reference (pandas, per window): {n_ref} windows in {t_ref:.2f} s = {ref_rate:,.0f} windows/s "
        f"(+ {t_prep:.2f} s grouping once)"
    )
    print(
        f"lanecast (same inputs, neighbours from the source ids): {len(ours):,} windows in {t_ours:.2f} s "
        f"= {our_rate:,.0f} windows/s -> {our_rate / ref_rate:,.0f}x the reference"
    )
    print(
        f"agreement on the sample: max |inputs diff| {diff_in:.2e}, present equal {same_present}, "
        f"max |future diff| {diff_fut:.2e}, maneuvers equal {same_man}"
    )
    print(f"load average at the end: {os.getloadavg()}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
