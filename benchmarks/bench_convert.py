"""Benchmark: converting a 15-minute medium-density simulated highD recording.

Compared, in the same run, with the bare parse: ``pyarrow.csv.read_csv`` of the same three files
(all columns, types inferred). Timed: ``registry.read_any([dir])`` (the highD adapter: parse,
checks, road frame, validated track table) and the full ``lanecast convert DIR --out X.parquet``
(in process). The goal: convert takes at most 2× the bare parse. Median of ``--repeat`` runs.

The recording is simulated once into ``benchmarks/_work/sim-15min-medium-seed1`` (and reused).

    .venv/bin/python benchmarks/bench_convert.py [--minutes 15] [--seed 1] [--repeat 5]
"""

from __future__ import annotations

import argparse
import contextlib
import io
import statistics
import time
from collections.abc import Callable
from pathlib import Path

import pyarrow.csv as pacsv

from lanecast.io_adapters import registry
from lanecast.io_adapters.sim import sumo_highway
from lanecast.workflows import cli

WORK = Path(__file__).resolve().parent / "_work"


def recording(minutes: float, seed: int) -> tuple[Path, float | None]:
    """The simulated recording's directory and the wall time of simulating it (None if reused)."""
    out = WORK / f"sim-{minutes:g}min-medium-seed{seed}"
    if all((out / name).is_file() for name in sumo_highway.file_names(1).values()):
        return out, None
    started = time.perf_counter()
    sumo_highway.simulate(out, minutes=minutes, seed=seed, density="medium")
    return out, time.perf_counter() - started


def median_time(fn: Callable[[], object], repeat: int) -> float:
    times = []
    for _ in range(repeat):
        started = time.perf_counter()
        fn()
        times.append(time.perf_counter() - started)
    return statistics.median(times)


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--minutes", type=float, default=15.0)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--repeat", type=int, default=5)
    args = parser.parse_args()

    directory, sim_seconds = recording(args.minutes, args.seed)
    files = [directory / name for name in sumo_highway.file_names(1).values()]
    summary = sumo_highway.summary(files[1])
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

    # Warm the caches (files, imports) once, then time alternately-ordered repetitions.
    for f in files:
        pacsv.read_csv(f)
    registry.read_any([directory])
    bare = median_time(lambda: [pacsv.read_csv(f) for f in files], args.repeat)
    read = median_time(lambda: registry.read_any([directory]), args.repeat)
    full = median_time(convert, args.repeat)
    print(f"median of {args.repeat} (preliminary: shared machine):")
    print(f"  pyarrow.csv.read_csv, 3 files      {bare:7.3f} s")
    print(f"  registry.read_any([dir])           {read:7.3f} s   ratio {read / bare:5.2f}x")
    print(f"  lanecast convert -> Parquet        {full:7.3f} s   ratio {full / bare:5.2f}x   (goal <= 2x)")


if __name__ == "__main__":
    main()
