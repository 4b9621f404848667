"""lanecast's csp writer against conv-social-pooling's ``preprocess_data.m`` under GNU Octave, and
lanecast alone on NGSIM-sized input.

    .venv/bin/python benchmarks/csp_speed.py --script PATH/preprocess_data.m --work /tmp/csp \\
        [--sizes 2.5 5 15] [--repeats 3] [--octave-budget-s 1800]
    .venv/bin/python benchmarks/csp_speed.py --ngsim-sized --work /tmp/csp

Sizes are simulated minutes per simulation: six NGSIM .txt files from three simulations
(benchmarks/csp_inputs.py). Each repeat runs, size by size, ``lanecast convert … --to csp`` and
the research script under Octave (niced), one after the other, so that both see the same load;
medians of wall and CPU seconds are printed, and the ratio of CPU seconds (on a shared machine
a niced process's wall time measures the other users more than itself). The script's cost grows faster than its input: a size whose
predicted Octave CPU time (from the growth fitted to the sizes measured, rows^k) exceeds
``--octave-budget-s`` is not run but extrapolated, and printed as such.

``--ngsim-sized``: six files of about a million rows each (the 15-minute files repeated six times
in time, ids shifted; ``--base-minutes``/``--copies`` choose others, ``--files`` names them),
converted once by lanecast (``--workers 2``) in a fresh process: wall time and peak resident
memory (ru_maxrss of the child).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import resource
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import csp_inputs as ci


def rows_of(paths: list[Path]) -> int:
    total = 0
    for p in paths:
        with p.open("rb") as fh:
            total += sum(block.count(b"\n") for block in iter(lambda fh=fh: fh.read(1 << 20), b""))
    return total


def growth(points: list[tuple[int, float]]) -> tuple[float, float] | None:
    """Least-squares (k, log a) of seconds = a · rows^k over the measured points."""
    if len(points) < 2:
        return None
    xs = [math.log(r) for r, _ in points]
    ys = [math.log(s) for _, s in points]
    mx, my = statistics.fmean(xs), statistics.fmean(ys)
    k = sum((x - mx) * (y - my) for x, y in zip(xs, ys, strict=True)) / sum((x - mx) ** 2 for x in xs)
    return k, my - k * mx


def compare(args: argparse.Namespace) -> dict:
    inputs = {m: ci.make_inputs(args.work, m) for m in args.sizes}
    rows = {m: rows_of(p) for m, p in inputs.items()}
    ours: dict[float, list[tuple[float, float]]] = {m: [] for m in args.sizes}
    theirs: dict[float, list[tuple[float, float]]] = {m: [] for m in args.sizes}
    for r in range(args.repeats):
        for m in args.sizes:
            out = args.work / f"lanecast-{m:g}min"
            ours[m].append(ci.run_lanecast(inputs[m], out, "--workers", str(args.workers)))
            measured = [(rows[s], statistics.median(c for _, c in t)) for s, t in theirs.items() if t]
            fit = growth(measured)
            if measured and fit is None:  # quadratic until two sizes are measured
                fit = (2.0, math.log(measured[0][1]) - 2.0 * math.log(measured[0][0]))
            predicted = math.exp(fit[1]) * rows[m] ** fit[0] if fit else 0.0
            if r < args.octave_repeats and 0 < args.octave_budget_s and predicted <= args.octave_budget_s:
                theirs[m].append(ci.run_octave(args.script, inputs[m], args.work / f"octave-{m:g}min-{r}"))
            line = f"repeat {r + 1}, {m:g} min ({rows[m]:,} rows): lanecast {ours[m][-1][0]:.1f} s"
            line += f" ({ours[m][-1][1]:.1f} s CPU)"
            if len(theirs[m]) > r:
                line += f", octave {theirs[m][-1][0]:.1f} s ({theirs[m][-1][1]:.1f} s CPU)"
            print(line, flush=True)
    measured = [(rows[m], statistics.median(c for _, c in t)) for m, t in theirs.items() if t]
    fit = growth(measured)
    result: dict = {"load": os.getloadavg(), "sizes": []}
    print(
        f"\n{'minutes':>8} {'rows':>9} {'lanecast s':>11} {'CPU s':>7} {'octave CPU s':>13} {'ratio (CPU)':>12}"
    )
    for m in args.sizes:
        wall, cpu = statistics.median(w for w, _ in ours[m]), statistics.median(c for _, c in ours[m])
        if theirs[m]:
            oc, how = statistics.median(c for _, c in theirs[m]), "measured"
        elif fit:
            oc, how = math.exp(fit[1]) * rows[m] ** fit[0], "extrapolated"
        else:
            oc, how = float("nan"), "not run"
        mark = "*" if how == "extrapolated" else " "
        print(f"{m:>8g} {rows[m]:>9,} {wall:>11.2f} {cpu:>7.2f} {oc:>12.1f}{mark} {oc / cpu:>11.0f}x")
        result["sizes"].append(
            {
                "minutes": m,
                "rows": rows[m],
                "lanecast_wall_cpu_s": ours[m],
                "octave_wall_cpu_s": theirs[m],
                "octave_cpu_s": oc,
                "octave": how,
                "ratio_cpu": oc / cpu,
            }
        )
    if fit:
        extrapolated = any(not theirs[m] for m in args.sizes)
        print(
            f"octave's CPU time grows as rows^{fit[0]:.2f} over the measured sizes"
            + (" (* extrapolated with it)" if extrapolated else "")
        )
        result["octave_growth_exponent"] = fit[0]
    print(f"load average {os.getloadavg()}")
    return result


def ngsim_sized(args: argparse.Namespace) -> dict:
    if args.files:
        big = args.files
    else:
        base = ci.make_inputs(args.work, args.base_minutes)
        big = ci.tiled(base, args.work / f"ngsim-sized-{args.base_minutes:g}x{args.copies}", args.copies)
    rows = rows_of(big)
    out = args.work / "lanecast-ngsim-sized"
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    before, cpu_before = usage.ru_maxrss, usage.ru_utime + usage.ru_stime
    started = time.perf_counter()
    took, _ = ci.run_lanecast(big, out, "--workers", str(args.workers))
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    peak_kb, cpu = usage.ru_maxrss, usage.ru_utime + usage.ru_stime - cpu_before
    elapsed = time.perf_counter() - started
    sizes = {p.name: p.stat().st_size for p in sorted(out.glob("*.mat"))}
    print(
        f"{len(big)} files, {rows:,} rows: lanecast {took:.1f} s wall, {cpu:.1f} s CPU (all its processes),"
        f" peak RSS {peak_kb / 1024:.0f} MiB"
        f" (earlier children {before / 1024:.0f} MiB); outputs {sizes}; load average {os.getloadavg()}"
    )
    return {
        "rows": rows,
        "seconds": elapsed,
        "cpu_seconds": cpu,
        "peak_rss_mib": peak_kb / 1024,
        "outputs": sizes,
        "load": os.getloadavg(),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--script", type=Path, help="conv-social-pooling's preprocess_data.m")
    ap.add_argument("--work", type=Path, required=True)
    ap.add_argument("--sizes", type=float, nargs="+", default=[2.5, 5.0, 15.0])
    ap.add_argument("--repeats", type=int, default=3, help="lanecast runs per size")
    ap.add_argument("--octave-repeats", type=int, default=1, help="Octave runs per size")
    ap.add_argument("--octave-budget-s", type=float, default=1800.0)
    ap.add_argument("--ngsim-sized", action="store_true", help="lanecast alone on six ~1M-row files")
    ap.add_argument("--copies", type=int, default=6, help="--ngsim-sized: repeats of each base file")
    ap.add_argument(
        "--base-minutes", type=float, default=15.0, help="--ngsim-sized: minutes of the base files"
    )
    ap.add_argument("--files", type=Path, nargs="+", help="--ngsim-sized: these NGSIM files instead")
    ap.add_argument("--workers", type=int, default=2, help="lanecast's --workers")
    ap.add_argument("--json", type=Path, help="also write the figures here")
    args = ap.parse_args()
    if args.ngsim_sized:
        result = ngsim_sized(args)
    else:
        if args.script is None:
            ap.error("--script is required to compare with the research script")
        if not ci.octave_found():
            print("octave is not installed (Debian: apt-get install octave): nothing compared")
            return
        result = compare(args)
    if args.json:
        args.json.write_text(json.dumps(result, indent=1) + "\n")


if __name__ == "__main__":
    main()
