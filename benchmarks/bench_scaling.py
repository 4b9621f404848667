"""Benchmark: time and peak memory of `lanecast convert` and `lanecast windows` against input size.

    .venv/bin/python benchmarks/bench_scaling.py [--work benchmarks/_work] [--minutes 15 30 60 120]
        [--layout recordings|long] [--repeat 3] [--in-memory] [--workers 1]

Inputs (made once into --work, reused): a simulated highD recording of 15 minutes at high density
(`lanecast simulate`, seed 1) and from it, for N simulated minutes:

- ``--layout recordings`` (default): a dataset of N/15 recordings 01, 02, …, copies of it (the
  dataset grows, every piece stays the same: memory must stay flat);
- ``--layout long``: one recording of N minutes, the 15 minutes repeated in time (frames and
  vehicle ids shifted, so each copy is new traffic to the stages), or with ``--source DIR`` the
  first N minutes of a longer simulation (the vehicles that have left by then). `convert` reads
  its tracks file in blocks and writes pieces of whole tracks; `windows` cuts it into chunks of
  whole tracks with their context (docs/design.md, whole datasets): memory must stay flat too.

Each command runs in its own process (`python -m lanecast …`); wall time, user and system CPU
time and peak resident memory come from the kernel for that process (``os.wait4``). Sizes are
interleaved within every repeat; medians are reported, time per million input rows, the ratio of
that to the smallest size (linear = 1.0), and windows/s. ``--in-memory`` adds, interleaved, the
library's in-memory path (``registry.read_any`` + ``make_windows`` + ``save_windows``) for
comparison. The machine may be shared: the load average is printed with every figure.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.csv as pacsv
import pyarrow.parquet as pq

from lanecast.io_adapters.datasets.highd import reader as highd

NEIGHBOUR_IDS = tuple(highd.NEIGHBOURS)  # highD's neighbour id columns
IN_MEMORY_WINDOWS = (
    "import sys; from pathlib import Path; from lanecast.io_adapters.formats import registry; "
    "from lanecast.io_adapters.windows_store.dataset import save_windows; "
    "from lanecast.pipeline.make_windows import make_windows; "
    "save_windows(make_windows(registry.read_any([sys.argv[1]])), Path(sys.argv[2]))"
)
IN_MEMORY_CONVERT = (
    "import sys; from lanecast.io_adapters.formats import registry; "
    "registry.write_any(registry.read_any([sys.argv[1]]), sys.argv[2], 'parquet')"
)


def load() -> str:
    return "load {:.1f} {:.1f} {:.1f}".format(*os.getloadavg())


def run(cmd: list[str]) -> dict[str, float]:
    """Run ``cmd``; its wall time, CPU times (s) and peak RSS (GB), from the kernel."""
    started = time.perf_counter()
    with tempfile.TemporaryFile() as out:
        proc = subprocess.Popen(cmd, stdout=out, stderr=subprocess.STDOUT)
        _, status, usage = os.wait4(proc.pid, 0)
        wall = time.perf_counter() - started
        proc.returncode = os.waitstatus_to_exitcode(status)
        if proc.returncode != 0:
            out.seek(0)
            raise RuntimeError(f"{' '.join(cmd)} failed ({proc.returncode}):\n{out.read().decode()}")
    return {
        "wall_s": wall,
        "user_s": usage.ru_utime,
        "sys_s": usage.ru_stime,
        "peak_gb": usage.ru_maxrss / 1024**2,  # ru_maxrss is in KiB on Linux
    }


def read_csv(path: Path) -> pa.Table:
    return pacsv.read_csv(path)


def write_csv(table: pa.Table, path: Path) -> None:
    pacsv.write_csv(table, path, write_options=pacsv.WriteOptions(quoting_style="none"))


def shift_ids(table: pa.Table, columns: tuple[str, ...], by: int) -> pa.Table:
    """Add ``by`` to the id columns (0 = none stays 0)."""
    for name in columns:
        col = table.column(name)
        shifted = pc.if_else(pc.equal(col, 0), col, pc.add(col, by))
        table = table.set_column(table.column_names.index(name), name, shifted)
    return table


def tile(src: Path, dst: Path, copies: int) -> None:
    """A recording ``copies`` times as long: the 15-minute one repeated in time, each copy with
    frames after the previous copy's and new vehicle ids."""
    tracks, meta, rec = (read_csv(src / f"01_{k}.csv") for k in ("tracks", "tracksMeta", "recordingMeta"))
    frames = int(pc.max(tracks.column("frame")).as_py())
    ids = int(pc.max(tracks.column("id")).as_py())
    parts, metas = [], []
    for k in range(copies):
        t = shift_ids(tracks, ("id", *NEIGHBOUR_IDS), k * ids)
        t = t.set_column(0, "frame", pc.add(t.column("frame"), k * frames))
        m = shift_ids(meta, ("id",), k * ids)
        for name in ("initialFrame", "finalFrame"):
            m = m.set_column(m.column_names.index(name), name, pc.add(m.column(name), k * frames))
        parts.append(t)
        metas.append(m)
    dst.mkdir(parents=True, exist_ok=True)
    write_csv(pa.concat_tables(parts), dst / "01_tracks.csv")
    write_csv(pa.concat_tables(metas), dst / "01_tracksMeta.csv")
    duration = rec.column("duration").to_numpy() * copies
    write_csv(
        rec.set_column(rec.column_names.index("duration"), "duration", pa.array(duration)),
        dst / "01_recordingMeta.csv",
    )


def truncate(src: Path, dst: Path, minutes: float) -> None:
    """The first ``minutes`` of a longer recording: the vehicles that have left by then."""
    tracks, meta, rec = (read_csv(src / f"01_{k}.csv") for k in ("tracks", "tracksMeta", "recordingMeta"))
    rate = float(rec.column("frameRate")[0].as_py())
    keep = meta.filter(pc.less_equal(meta.column("finalFrame"), int(minutes * 60 * rate)))
    ids = keep.column("id")
    dst.mkdir(parents=True, exist_ok=True)
    write_csv(tracks.filter(pc.is_in(tracks.column("id"), ids)), dst / "01_tracks.csv")
    write_csv(keep, dst / "01_tracksMeta.csv")
    write_csv(
        rec.set_column(rec.column_names.index("duration"), "duration", pa.array([minutes * 60.0])),
        dst / "01_recordingMeta.csv",
    )


def many(src: Path, dst: Path, count: int) -> None:
    """``count`` recordings 01, 02, …: copies of ``src``'s recording 01."""
    dst.mkdir(parents=True, exist_ok=True)
    rec_lines = (src / "01_recordingMeta.csv").read_text().splitlines(keepends=True)
    for n in range(1, count + 1):
        for kind in ("tracks", "tracksMeta"):  # hard links: the same bytes, no extra disk
            target = dst / f"{n:02d}_{kind}.csv"
            target.unlink(missing_ok=True)
            os.link(src / f"01_{kind}.csv", target)
        rest = rec_lines[1].split(",", 1)[1]
        (dst / f"{n:02d}_recordingMeta.csv").write_text(rec_lines[0] + f"{n},{rest}")


def prepare(args: argparse.Namespace) -> dict[str, Path]:
    lanecast = [sys.executable, "-m", "lanecast"]
    base = args.work / "sim-15min-high-seed1"
    if not (base / "01_tracks.csv").is_file():
        print(f"simulating 15 min (high density, seed 1) into {base} … ({load()})", flush=True)
        subprocess.run(
            [
                *lanecast,
                "simulate",
                "--out",
                str(base),
                "--minutes",
                "15",
                "--seed",
                "1",
                "--density",
                "high",
            ],
            check=True,
        )
    inputs: dict[str, Path] = {}
    for minutes in args.minutes:
        copies = max(minutes // 15, 1)
        if args.layout == "recordings":  # the dataset grows, every piece stays 15 minutes
            name, path = f"{copies}x15min", args.work / f"scaling-{copies}x15min"
            if not (path / f"{copies:02d}_tracks.csv").is_file():
                many(base, path, copies)
        elif args.source:
            name, path = f"{minutes}min-sim", args.work / f"scaling-{minutes}min-sim"
            if not (path / "01_tracks.csv").is_file():
                truncate(args.source, path, minutes)
        else:  # one recording of the whole length: memory is set by it
            name, path = f"{minutes}min-1rec", args.work / f"scaling-{minutes}min-1rec"
            if not (path / "01_tracks.csv").is_file():
                tile(base, path, copies)
        inputs[name] = path
    return inputs


def main() -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--work", type=Path, default=Path(__file__).resolve().parent / "_work")
    parser.add_argument("--minutes", type=int, nargs="+", default=[15, 30, 60, 120])
    parser.add_argument(
        "--layout",
        choices=("recordings", "long"),
        default="recordings",
        help="recordings: N minutes as N/15 recordings of 15 min; long: one recording of N minutes",
    )
    parser.add_argument(
        "--source", type=Path, help="a longer simulated recording to truncate instead of tiling"
    )
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument(
        "--in-memory", action="store_true", help="also the in-memory library path, interleaved"
    )
    parser.add_argument("--workers", type=int, default=1)
    args = parser.parse_args()

    print(f"cores: {os.cpu_count()}, python {sys.version.split()[0]}, {load()}")
    inputs = prepare(args)
    out = args.work / "scaling-out"
    out.mkdir(parents=True, exist_ok=True)
    lanecast = [sys.executable, "-m", "lanecast"]
    variants = ["streaming"] + (["in-memory"] if args.in_memory else [])
    results: dict[tuple[str, str, str], list[dict[str, float]]] = {}
    sizes: dict[str, tuple[int, int]] = {}
    for r in range(args.repeat):
        for name, path in inputs.items():
            for variant in variants:
                table = out / f"{name}.parquet"
                windows = out / f"{name}-windows"
                if variant == "streaming":
                    convert = [
                        *lanecast,
                        "convert",
                        str(path),
                        "--out",
                        str(table),
                        "--workers",
                        str(args.workers),
                    ]
                    cut = [
                        *lanecast,
                        "windows",
                        str(table),
                        "--out",
                        str(windows),
                        "--workers",
                        str(args.workers),
                    ]
                else:
                    convert = [sys.executable, "-c", IN_MEMORY_CONVERT, str(path), str(table)]
                    cut = [sys.executable, "-c", IN_MEMORY_WINDOWS, str(table), str(windows)]
                for step, cmd in (("convert", convert), ("windows", cut)):
                    figures = run(cmd)
                    figures["load1"] = os.getloadavg()[0]
                    results.setdefault((name, variant, step), []).append(figures)
                    print(
                        f"repeat {r + 1} {name:>12} {variant:>9} {step:>8}: wall {figures['wall_s']:6.1f} s, "
                        f"user {figures['user_s']:6.1f} s, sys {figures['sys_s']:5.1f} s, "
                        f"peak {figures['peak_gb']:.2f} GB ({load()})",
                        flush=True,
                    )
                if name not in sizes:
                    manifest = json.loads((windows / "manifest.json").read_text())
                    sizes[name] = (pq.ParquetFile(table).metadata.num_rows, int(manifest["n_windows"]))
    print()
    print(
        "medians over",
        args.repeat,
        "repeats; per Mrow = per million input rows (25 Hz); ratio = per-Mrow time / smallest size's",
    )
    header = "| input | rows | windows | path | step | wall s | cpu s (user+sys) | sys s | peak GB | cpu s per Mrow | ratio | windows/s (wall) | load 1 min |"
    print(header)
    print("|" + "---|" * (header.count("|") - 1))
    first_name = next(iter(inputs))
    for variant in variants:
        for step in ("convert", "windows"):
            base_cost = None
            for name in inputs:
                runs = results[(name, variant, step)]
                med = {k: statistics.median(x[k] for x in runs) for k in runs[0]}
                cpu = statistics.median(x["user_s"] + x["sys_s"] for x in runs)
                rows, n_windows = sizes[name]
                per_mrow = cpu / (rows / 1e6)
                if name == first_name:
                    base_cost = per_mrow
                ratio = per_mrow / base_cost if base_cost else float("nan")
                wps = f"{n_windows / med['wall_s']:,.0f}" if step == "windows" else ""
                print(
                    f"| {name} | {rows:,} | {n_windows:,} | {variant} | {step} | {med['wall_s']:.1f} | {cpu:.1f} | "
                    f"{med['sys_s']:.1f} | {med['peak_gb']:.2f} | {per_mrow:.2f} | {ratio:.2f} | {wps} | {med['load1']:.1f} |"
                )
    return 0


if __name__ == "__main__":
    sys.exit(main())
