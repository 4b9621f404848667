"""Benchmark: converting a 15-minute medium-density simulated highD recording.

Compared, in the same run, with the bare parse: ``pyarrow.csv.read_csv`` of the same three files
(all columns, types inferred). Timed: ``registry.read_any([dir])`` (the highD adapter: parse,
checks, road frame, validated track table) and the full ``lanecast convert DIR --out X.parquet``
(in process). The goal: convert takes at most 2× the bare parse. The three are timed in turn,
``--repeat`` rounds (order reversed every round); medians with min–max, and the ratio of medians with
the range of the per-round ratios. Then the whole command as a user runs it, in fresh processes
(start-up included), against a bare ``python -c`` process that reads the three files with pyarrow
(goal: at most 2×). The load average is printed before and after.

The recording is simulated once into ``benchmarks/_work/sim-15min-medium-seed1`` (and reused).

    .venv/bin/python benchmarks/bench_convert.py [--minutes 15] [--seed 1] [--repeat 5]
"""

from __future__ import annotations

import argparse
import contextlib
import io
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


def recording(minutes: float, seed: int) -> tuple[Path, float | None]:
    """The simulated recording's directory and the wall time of simulating it (None if reused)."""
    out = WORK / f"sim-{minutes:g}min-medium-seed{seed}"
    if all((out / name).is_file() for name in to_highd.file_names(1).values()):
        return out, None
    started = time.perf_counter()
    simulate(out, minutes=minutes, seed=seed, density="medium")
    return out, time.perf_counter() - started


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--minutes", type=float, default=15.0)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--repeat", type=int, default=5)
    args = parser.parse_args()

    directory, sim_seconds = recording(args.minutes, args.seed)
    files = [directory / name for name in to_highd.file_names(1).values()]
    summary = to_highd.summary(files[1])
    size_mb = sum(f.stat().st_size for f in files) / 1e6
    rows = pacsv.read_csv(files[0]).num_rows
    print(f"recording: {directory} ({size_mb:.1f} MB, {rows:,} rows)")
    print(
        f"  {summary['vehicles']:,} vehicles ({summary['cars']:,} cars, {summary['trucks']:,} trucks), "
        f"{summary['lane_changes']:,} lane changes"
    )
    if sim_seconds is not None:
        print(f"  simulated {args.minutes:g} min in {sim_seconds:.1f} s wall time")

    out = WORK / "bench-convert.parquet"

    def convert() -> None:
        with contextlib.redirect_stdout(io.StringIO()):
            status = cli.main(["convert", str(directory), "--out", str(out)])
        if status != 0:
            raise SystemExit(f"lanecast convert failed with status {status}")

    print(machine_line("before"))
    times = interleaved_times(
        {
            "pyarrow.csv.read_csv, 3 files": lambda: [pacsv.read_csv(f) for f in files],
            "registry.read_any([dir])": lambda: registry.read_any([directory]),
            "lanecast convert -> Parquet": convert,
        },
        rounds=args.repeat,
    )
    bare = times["pyarrow.csv.read_csv, 3 files"]
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
    commands = {
        "python -c: pyarrow read_csv, 3 files": [*bare_process, *map(str, files)],
        "lanecast convert DIR --out X.parquet": [lanecast, "convert", str(directory), "--out", str(out)],
    }
    processes = interleaved_times(
        {
            name: (lambda argv=argv: subprocess.run(argv, check=True, capture_output=True))
            for name, argv in commands.items()
        },
        rounds=args.repeat,
    )
    bare_p, whole = processes.values()
    print(f"fresh processes, wall seconds, median (min–max) of {args.repeat} interleaved rounds:")
    for name, samples in processes.items():
        print(f"  {name:<38}{samples.text('.3f', higher_is_better=False)}")
    print(f"  ratio {ratio(whole, bare_p)}   (goal: the whole command <= 2x a bare pyarrow process)")
    print(machine_line("after"))


if __name__ == "__main__":
    main()
