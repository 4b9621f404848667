"""`lanecast info`: what is in a dataset, table or log: recordings, tracks, frames, duration, lane changes."""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc

from lanecast.io_adapters import registry
from lanecast.io_adapters.contracts import track_table


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "info",
        help="summarise a dataset, track table or drive log",
        description="Print the format, recordings, tracks, frames, duration, frame rate and lane changes of PATH.",
        epilog="example:\n  lanecast info highd-01.parquet",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("paths", nargs="+", metavar="PATH")
    p.add_argument("--format", choices=sorted(registry.READERS), help="input format (default: detected)")
    p.set_defaults(func=run)


def summarise(table: pa.Table) -> list[dict[str, object]]:
    """One dict per recording: tracks, rows, frames, duration (s), frame rate, lane changes, vehicles per class."""
    meta = track_table.read_meta(table)
    names = table.column("recording").cast(pa.string()).to_numpy(zero_copy_only=False)
    changes = np.zeros(table.num_rows, dtype=bool)
    changes[track_table.lane_change_rows(table)] = True
    starts = track_table.track_boundaries(table)
    out = []
    for name in sorted(meta.recordings):
        rows = names == name
        rate = meta.recordings[name].frame_rate
        frames = table.column("frame").to_numpy()[rows]
        first_rows = starts[:-1][rows[starts[:-1]]]
        classes = pc.value_counts(table.column("object_class").take(pa.array(first_rows)).cast(pa.string()))
        out.append(
            {
                "recording": name,
                "tracks": int(np.unique(table.column("track_id").to_numpy()[rows]).size),
                "rows": int(rows.sum()),
                "frames": int(np.unique(frames).size),
                "duration_s": float((frames.max() - frames.min() + 1) / rate) if frames.size else 0.0,
                "frame_rate": rate,
                "lane_changes": int(changes[rows].sum()),
                "classes": {c["values"]: c["counts"] for c in classes.to_pylist()},
            }
        )
    return out


def run(args: argparse.Namespace) -> int:
    formats = sorted({args.format or registry.detect(p) for p in args.paths})
    table = registry.read_any(args.paths, fmt=args.format)
    meta = track_table.read_meta(table)
    print(f"{', '.join(str(Path(p)) for p in args.paths)}")
    print(f"  format: {', '.join(formats)} (source: {meta.source_format}); units: m, m/s, m/s^2, rad, ns")
    rows = summarise(table)
    header = f"  {'recording':<28}{'tracks':>8}{'frames':>9}{'duration':>11}{'rate':>8}{'lane chg':>10}  vehicles by class"
    print(header)
    for r in rows:
        classes = ", ".join(f"{k} {v}" for k, v in sorted(r["classes"].items()))  # type: ignore[attr-defined]
        print(
            f"  {r['recording']:<28}{r['tracks']:>8,}{r['frames']:>9,}{r['duration_s']:>10.1f}s"
            f"{r['frame_rate']:>6g}Hz{r['lane_changes']:>10,}  {classes}"
        )
    total_tracks = sum(int(r["tracks"]) for r in rows)  # type: ignore[call-overload]
    total_changes = sum(int(r["lane_changes"]) for r in rows)  # type: ignore[call-overload]
    print(
        f"  total: {len(rows)} recordings, {total_tracks:,} tracks, {table.num_rows:,} rows, {total_changes:,} lane changes"
    )
    return 0
