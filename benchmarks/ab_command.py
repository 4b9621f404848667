"""Benchmark: one `lanecast` command run by two or more code trees, interleaved (A B, B A, …).

    .venv/bin/python benchmarks/ab_command.py --rounds 8 before=/tmp/before after=. -- \
        windows benchmarks/_work/scaling-out/8x15min.parquet --workers 1

Each NAME=TREE is a checkout of lanecast (e.g. ``git worktree add /tmp/before main`` or ``git
archive main | tar -x -C /tmp/before``); the command after ``--`` runs as ``python -m lanecast …``
in its own process with ``PYTHONPATH=TREE`` (so the tree's code runs, not the installed one) and
``--out`` a scratch directory per tree. Wall time, user + system CPU time and peak resident memory
come from the kernel for that process (``os.wait4``), as in bench_scaling.py. The order of the
trees reverses every round, so that load from other work hits all of them alike; the first
round compares every output file of each tree with the first tree's (``filecmp``, byte for
byte; manifest.json holds timings and is left out). Reports medians with min–max, windows per
wall-second and per CPU-second where the command prints its window count, and the ratios of
every tree to the first with the range of the per-round ratios.
"""

from __future__ import annotations

import argparse
import filecmp
import os
import re
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from interleave import machine_line, round_orders


def run(tree: Path, command: list[str], out: Path) -> dict[str, float]:
    shutil.rmtree(out, ignore_errors=True)
    out.unlink(missing_ok=True)  # an output that is one file (a ROS 1 bag)
    env = dict(os.environ, PYTHONPATH=str(tree))
    started = time.perf_counter()
    with tempfile.TemporaryFile() as log:
        proc = subprocess.Popen(
            [sys.executable, "-m", "lanecast", *command, "--out", str(out)],
            env=env,
            stdout=log,
            stderr=subprocess.STDOUT,
            cwd=tempfile.gettempdir(),  # not the tree: `lanecast` resolves through PYTHONPATH only
        )
        _, status, usage = os.wait4(proc.pid, 0)
        wall = time.perf_counter() - started
        log.seek(0)
        text = log.read().decode(errors="replace")
    if os.waitstatus_to_exitcode(status) != 0:
        raise RuntimeError(f"{tree}: lanecast {' '.join(command)} failed:\n{text}")
    found = re.search(r"([\d,]+) windows", text)
    return {
        "wall_s": wall,
        "cpu_s": usage.ru_utime + usage.ru_stime,
        "sys_s": usage.ru_stime,
        "peak_gb": usage.ru_maxrss / 1024**2,
        "windows": float(found.group(1).replace(",", "")) if found else 0.0,
        "load1": os.getloadavg()[0],
    }


def same_outputs(a: Path, b: Path) -> list[str]:
    """One line per output file of ``a`` (the output itself where it is one file): identical or
    DIFFERENT in ``b``."""
    if a.is_file():
        same = b.is_file() and filecmp.cmp(a, b, shallow=False)
        return [f"  {b.name}: {'identical' if same else 'DIFFERENT'}"]
    lines = []
    for name in sorted(os.listdir(a)):
        if name == "manifest.json":
            continue
        same = (b / name).is_file() and filecmp.cmp(a / name, b / name, shallow=False)
        lines.append(f"  {b.name} {name}: {'identical' if same else 'DIFFERENT'}")
    return lines


def main() -> int:
    argv = sys.argv[1:]
    command = argv[argv.index("--") + 1 :] if "--" in argv else []
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("trees", nargs="+", metavar="NAME=TREE")
    parser.add_argument("--rounds", type=int, default=6)
    parser.add_argument("--scratch", type=Path, default=Path(tempfile.gettempdir()) / "lanecast-ab")
    args = parser.parse_args(argv[: argv.index("--")] if "--" in argv else argv)
    if not command:
        parser.error("give the command after --, e.g. -- windows TABLE --workers 1")
    trees = {name: Path(path).resolve() for name, path in (t.split("=", 1) for t in args.trees)}
    names = list(trees)
    print(f"cores: {os.cpu_count()}, python {sys.version.split()[0]}, {machine_line('before')}")
    print(f"command: python -m lanecast {' '.join(command)} --out SCRATCH/NAME")
    results: dict[str, list[dict[str, float]]] = {name: [] for name in names}
    for r, order in enumerate(round_orders(names, args.rounds)):
        for name in order:
            got = run(trees[name], command, args.scratch / name)
            results[name].append(got)
            print(
                f"round {r} {name:>10}: wall {got['wall_s']:5.2f} s, cpu {got['cpu_s']:5.2f} s "
                f"(sys {got['sys_s']:.2f}), peak {got['peak_gb']:.2f} GB, load {got['load1']:.2f}",
                flush=True,
            )
        if r == 0:
            for name in names[1:]:
                print("\n".join(same_outputs(args.scratch / names[0], args.scratch / name)))
    print(machine_line("after"))
    print(
        "| tree | wall s | CPU s (user+sys) | sys s | peak GB | windows / wall-s | windows / CPU-s | load |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for name in names:
        rows = results[name]

        def med(key: str, rows: list[dict[str, float]] = rows) -> float:
            return statistics.median(x[key] for x in rows)

        def span(key: str, rows: list[dict[str, float]] = rows) -> str:
            return f"{min(x[key] for x in rows):.2f}–{max(x[key] for x in rows):.2f}"

        windows = rows[0]["windows"]
        rates = f"{windows / med('wall_s'):,.0f} | {windows / med('cpu_s'):,.0f}" if windows else "| "
        print(
            f"| {name} | {med('wall_s'):.2f} ({span('wall_s')}) | {med('cpu_s'):.2f} ({span('cpu_s')}) "
            f"| {med('sys_s'):.2f} | {med('peak_gb'):.2f} | {rates} | {span('load1')} |"
        )
    first = results[names[0]]
    for name in names[1:]:
        for key in ("wall_s", "cpu_s"):
            per_round = [b[key] / a[key] for a, b in zip(first, results[name], strict=True)]
            print(
                f"{name} / {names[0]} {key[:-2]}: median of rounds {statistics.median(per_round):.3f} "
                f"(per round {min(per_round):.3f}–{max(per_round):.3f})"
            )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
