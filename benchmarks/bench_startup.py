"""Benchmark: what a user waits for before any work, each a whole fresh process.

    .venv/bin/python benchmarks/bench_startup.py [--rounds 7]

Times ``python -c pass`` (the interpreter alone), ``lanecast --help``, ``--version``, the ``--help``
of every command, and ``lanecast info`` on the 14-row highD recording in ``tests/data/highd``, in
interleaved rounds (order reversed every round); medians with min–max and the load average. Goals:
``--help``, ``--version`` and ``info`` on a small file in at most 0.25 s.

The processes run with Python's bytecode cache on, as in a user's shell (the first round, not
counted, writes it): an environment with ``PYTHONDONTWRITEBYTECODE`` set (some containers and CI
images) compiles every lanecast module at every start, 0.03–0.05 s more.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from interleave import Samples, machine_line, round_orders

from lanecast.workflows.cli import SUMMARIES

ROOT = Path(__file__).resolve().parents[1]


def main() -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--rounds", type=int, default=7)
    args = parser.parse_args()
    lanecast = str(Path(sys.executable).with_name("lanecast"))
    runs = {
        "python -c pass": [sys.executable, "-c", "pass"],
        "lanecast --help": [lanecast, "--help"],
        "lanecast --version": [lanecast, "--version"],
        **{f"lanecast {name} --help": [lanecast, name, "--help"] for name in SUMMARIES},
        "lanecast info tests/data/highd": [lanecast, "info", str(ROOT / "tests" / "data" / "highd")],
    }
    env = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}
    print(machine_line("before"))
    seconds: dict[str, list[float]] = {name: [] for name in runs}
    for order in round_orders(list(runs), args.rounds + 1):
        for name in order:
            start = time.perf_counter()
            subprocess.run(runs[name], check=True, capture_output=True, env=env)
            seconds[name].append(time.perf_counter() - start)
    print(f"wall seconds of the whole process, median (min–max; best) of {args.rounds} interleaved rounds:")
    for name, values in seconds.items():
        print(f"  {name:<34}{Samples(values[1:]).text('.3f', higher_is_better=False)}")  # round 1 warms
    print(machine_line("after"))
    return 0


if __name__ == "__main__":
    sys.exit(main())
