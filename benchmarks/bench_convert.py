"""Benchmark: converting 15-minute medium-density simulated highD recordings (one, or a dataset of
``--recordings`` of them, as highD's 60 are).

Compared, in the same run, with the bare parse: ``pyarrow.csv.read_csv`` of the same files
(all columns, types inferred). Timed: ``registry.read_any([dir])`` (the highD adapter: parse,
checks, road frame, validated track table) and the full ``lanecast convert DIR --out X.parquet``
(in process). The goal: convert takes at most 2× the bare parse. The three are timed in turn,
``--repeat`` rounds (order reversed every round); medians with min–max, and the ratio of medians with
the range of the per-round ratios. Then the whole command as a user runs it, in fresh processes
(start-up included), against a bare ``python -c`` process that reads the files with pyarrow
(goal: at most 2×), both with Python's bytecode cache on, as in a user's shell. The load average
is printed before and after.

The recordings are simulated once into ``benchmarks/_work/sim-15min-medium-seed1[-xN]`` (and reused).

    .venv/bin/python benchmarks/bench_convert.py [--minutes 15] [--seed 1] [--repeat 5] [--recordings 1]
"""

from __future__ import annotations

import argparse
import contextlib
import io
import os
import subprocess
import sys
import time
from pathlib import Path

import pyarrow.csv as pacsv

sys.path.insert(0, str(Path(__file__).resolve().parent))

from interleave import interleaved_times, machine_line, ratio

from lanecast.io_adapters.formats import registry
from lanecast.io_adapters.sim import to_highd
from lanecast.io_adapters.sim.recording import simulate
from lanecast.workflows import cli

WORK = Path(__file__).resolve().parent / "_work"


def recording(minutes: float, seed: int, count: int = 1) -> tuple[Path, float | None]:
    """The simulated dataset's directory (``count`` recordings, numbered 1…, of seeds ``seed``…)
    and the wall time of simulating what was not there yet (None if all was reused)."""
    out = WORK / (f"sim-{minutes:g}min-medium-seed{seed}" + (f"-x{count}" if count > 1 else ""))
    started, simulated = time.perf_counter(), False
    for number in range(1, count + 1):
        if all((out / name).is_file() for name in to_highd.file_names(number).values()):
            continue
        simulate(out, minutes=minutes, seed=seed + number - 1, density="medium", recording_id=number)
        simulated = True
    return out, (time.perf_counter() - started) if simulated else None


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--minutes", type=float, default=15.0)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--repeat", type=int, default=5)
    parser.add_argument(
        "--recordings", type=int, default=1, help="recordings in the dataset (seeds --seed, --seed + 1, …)"
    )
    args = parser.parse_args()

    directory, sim_seconds = recording(args.minutes, args.seed, args.recordings)
    files = [
        directory / name for n in range(1, args.recordings + 1) for name in to_highd.file_names(n).values()
    ]
    summaries = [to_highd.summary(f) for f in files if f.name.endswith("_tracksMeta.csv")]
    size_mb = sum(f.stat().st_size for f in files) / 1e6
    rows = sum(pacsv.read_csv(f).num_rows for f in files if f.name.endswith("_tracks.csv"))
    print(f"dataset: {directory} ({args.recordings} recording(s), {size_mb:.1f} MB, {rows:,} rows)")
    print(
        f"  {sum(s['vehicles'] for s in summaries):,} vehicles ({sum(s['cars'] for s in summaries):,} cars, "
        f"{sum(s['trucks'] for s in summaries):,} trucks), {sum(s['lane_changes'] for s in summaries):,} lane changes"
    )
    if sim_seconds is not None:
        print(f"  simulated in {sim_seconds:.1f} s wall time")

    out = WORK / "bench-convert.parquet"

    def convert() -> None:
        with contextlib.redirect_stdout(io.StringIO()):
            status = cli.main(["convert", str(directory), "--out", str(out)])
        if status != 0:
            raise SystemExit(f"lanecast convert failed with status {status}")

    print(machine_line("before"))
    times = interleaved_times(
        {
            "pyarrow.csv.read_csv, each file": lambda: [pacsv.read_csv(f) for f in files],
            "registry.read_any([dir])": lambda: registry.read_any([directory]),
            "lanecast convert -> Parquet": convert,
        },
        rounds=args.repeat,
    )
    bare = times["pyarrow.csv.read_csv, each file"]
    print(f"wall seconds, median (min–max) of {args.repeat} interleaved rounds:")
    for name, samples in times.items():
        line = f"  {name:<34}{samples.text('.3f', higher_is_better=False)}"
        if samples is not bare:
            line += f"   ratio {ratio(samples, bare)}"
        print(line)
    print("  goal: convert <= 2x the bare parse")

    # The whole command as a user runs it, start-up included, against a bare pyarrow process.
    bare_process = [
        sys.executable,
        "-c",
        "import sys, pyarrow.csv as c; [c.read_csv(f) for f in sys.argv[1:]]",
    ]
    lanecast = str(Path(sys.executable).with_name("lanecast"))
    env = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}
    commands = {
        "python -c: pyarrow read_csv, each file": [*bare_process, *map(str, files)],
        "lanecast convert DIR --out X.parquet": [lanecast, "convert", str(directory), "--out", str(out)],
    }
    processes = interleaved_times(
        {
            name: (lambda argv=argv: subprocess.run(argv, check=True, capture_output=True, env=env))
            for name, argv in commands.items()
        },
        rounds=args.repeat,
    )
    bare_p, whole = processes.values()
    print(f"fresh processes, wall seconds, median (min–max) of {args.repeat} interleaved rounds:")
    for name, samples in processes.items():
        print(f"  {name:<40}{samples.text('.3f', higher_is_better=False)}")
    print(f"  ratio {ratio(whole, bare_p)}   (goal: the whole command <= 2x a bare pyarrow process)")
    print(machine_line("after"))


if __name__ == "__main__":
    main()
