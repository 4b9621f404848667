"""Parsed NGSIM files → one track table: recordings named, repeated rows dropped, kinematics.

One recording per (location, source file, period): ``ngsim-<location>-<file stem>``, and where one
file holds several recording periods (periods.py) ``...-p1``, ``...-p2`` in time order. Positions,
lengths, speeds and accelerations are converted from feet; ``frame`` is ``Frame_ID`` and
``time_ns = Frame_ID * 1e8``. Within a recording, exact duplicate (vehicle, frame) rows are dropped;
duplicates with differing values keep the first row in file order and are reported on stderr; both
are counted in the recording metadata.
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa

from lanecast.io_adapters.contracts import track_schema, track_table
from lanecast.io_adapters.datasets.ngsim.columns import CLASSES, FEET, FRAME_NS, FRAME_RATE, USED_COLUMNS
from lanecast.io_adapters.datasets.ngsim.kinematics import kinematics
from lanecast.io_adapters.datasets.ngsim.locations import is_freeway
from lanecast.io_adapters.datasets.ngsim.parse import Parsed
from lanecast.io_adapters.datasets.ngsim.periods import check_period_continuity, check_small_location, periods
from lanecast.io_adapters.datasets.ngsim.wrong_way import check_wrong_way
from lanecast.io_adapters.errors import InputError

FORMAT = "ngsim"


def assemble(files: list[Parsed], split_periods: bool) -> pa.Table:
    """One validated track table of the parsed ``files``, their recordings checked and named."""
    names: list[str] = []
    metas: dict[str, track_table.RecordingMeta] = {}
    origin: dict[str, Path] = {}
    parts: list[dict[str, np.ndarray]] = []
    for parsed in files:
        cols = parsed.columns
        period, epochs = periods(cols, split_periods)
        check_small_location(parsed)
        check_period_continuity(parsed, period)
        check_wrong_way(parsed, period)
        key = parsed.location_code * len(epochs) + period
        n_rows = key.size
        code = np.empty(n_rows, dtype=np.int64)
        for loc_index, loc in enumerate(parsed.locations):
            loc_keys = np.unique(key[parsed.location_code == loc_index])
            for rank, k in enumerate(loc_keys, start=1):
                rows = key == k
                name = recording_name(loc, parsed.path, rank, loc_keys.size)
                if name in metas:
                    raise InputError(
                        parsed.path,
                        f"recording {name!r} also comes from {origin[name]}",
                        expected="input files with distinct names per location",
                    )
                origin[name] = parsed.path
                epoch, start = int(epochs[k % len(epochs)]), int(cols["global_time"][rows].min())
                metas[name] = recording_meta(
                    parsed.path, loc, parsed.location_source, epoch, start, rank, loc_keys.size
                )
                code[rows] = len(names)
                names.append(name)
        direction = parsed.direction if parsed.direction is not None else np.full(n_rows, np.nan)
        parts.append({**cols, "recording": code, "direction": direction})
    merged = parts[0] if len(parts) == 1 else {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
    return to_track_table(merged, names, metas, [str(p.path) for p in files])


def recording_name(location: str, path: Path, period: int, n_periods: int) -> str:
    """``ngsim-<location>-<file stem>``, with ``-p<period>`` where the file has several periods."""
    return f"ngsim-{location}-{path.stem}" + (f"-p{period}" if n_periods > 1 else "")


#: Global_Time epochs (ms) taken as dates: 1990 to 2100
PLAUSIBLE_EPOCH_MS = (631_152_000_000, 4_102_444_800_000)


def recording_meta(
    path: Path, location: str, source: str, epoch: int, start: int, period: int, n_periods: int
) -> track_table.RecordingMeta:
    """The metadata of one recording of file ``path``: its location (found from ``source``), the
    epoch and first Global_Time of its period, and how each column was converted."""
    freeway = is_freeway(location)
    extra = {
        "location": location,
        "location_source": source,
        "road_type": "freeway" if freeway else "arterial",
        "global_time_start": start,
        "global_time_epoch": epoch,
        "global_time_note": "Global_Time as given by the source (ms); epoch = Global_Time - 100 * Frame_ID",
        # the Unix time of time_ns 0, where drive logs written from the recording put it: only where
        # Global_Time is a plausible date in ms (the CSV export's Peachtree values are not)
        **(
            {"start_time_ns": epoch * 1_000_000}
            if PLAUSIBLE_EPOCH_MS[0] < epoch < PLAUSIBLE_EPOCH_MS[1]
            else {}
        ),
        "period": period if n_periods > 1 else None,
        "time": "time_ns = Frame_ID * 1e8 (frame = Frame_ID at 10 Hz)",
        "units": "converted from feet (x 0.3048)",
        "centre": (
            "x = Local_Y - v_Length/2, y = -Local_X (road frame: x along travel, y left)"
            if freeway
            else "front bumper (Local_Y, -Local_X) moved back by v_Length/2 along the heading"
        ),
        "heading": (
            "atan2(vy, vx); vy = gradient of y over +-0.5 s; 0 below 0.5 m/s"
            if freeway
            else "direction of motion of the front bumper (differences over +-0.5 s, above 1 m/s, agreeing "
            "with v_Vel and Direction), held through stops, averaged over +-0.5 s"
        ),
        "lane_id": "NGSIM Lane_ID as given (arterials: 0 and >= 10 are intersections, turn bays)",
    }
    frame = "road" if freeway else "local"
    return track_table.RecordingMeta(FRAME_RATE, frame, [str(path)], extra)


def to_track_table(
    cols: dict[str, np.ndarray],
    names: list[str],
    metas: dict[str, track_table.RecordingMeta],
    files: list[str],
) -> pa.Table:
    n = cols["vehicle_id"].size
    rec = cols["recording"]
    vehicle = cols["vehicle_id"].astype(np.int64)
    frame = cols["frame_id"].astype(np.int64)
    if not _is_sorted(rec, vehicle, frame):
        order = np.lexsort((np.arange(n), frame, vehicle, rec))  # stable: file order within a key
        cols = {k: v[order] for k, v in cols.items()}
        rec, vehicle, frame = rec[order], vehicle[order], frame[order]

    same_key = np.zeros(n, dtype=bool)
    same_key[1:] = (rec[1:] == rec[:-1]) & (vehicle[1:] == vehicle[:-1]) & (frame[1:] == frame[:-1])
    first_of_key = np.maximum.accumulate(np.where(same_key, 0, np.arange(n)))
    identical = np.ones(n, dtype=bool)
    for name in (*USED_COLUMNS, "direction"):
        v = cols[name]
        identical &= (v == v[first_of_key]) | (np.isnan(v) & np.isnan(v[first_of_key]))
    n_rec = len(names)
    exact = np.bincount(rec[same_key & identical], minlength=n_rec)
    conflicting = np.bincount(rec[same_key & ~identical], minlength=n_rec)
    for k in np.flatnonzero(conflicting).tolist():
        source = ", ".join(metas[names[k]].source_files)
        print(
            f"lanecast: {source}: {conflicting[k]:,} rows repeat a (Vehicle_ID, Frame_ID) of recording "
            f"{names[k]!r} with different values; kept the first of each in file order",
            file=sys.stderr,
        )
    rows_read = np.bincount(rec, minlength=n_rec)
    for i, name in enumerate(names):
        extra = metas[name].extra
        extra["rows_read"] = int(rows_read[i])
        extra["duplicate_rows_dropped"] = int(exact[i])
        extra["conflicting_duplicates_dropped"] = int(conflicting[i])

    if same_key.any():
        keep = ~same_key
        cols = {k: v[keep] for k, v in cols.items()}
        rec, vehicle, frame = rec[keep], vehicle[keep], frame[keep]
    freeway = np.array([metas[name].coordinate_frame == "road" for name in names])[rec]
    kin = kinematics(cols, rec, vehicle, frame, freeway)

    cls = cols["v_class"].astype(np.int64)
    cls_code = np.where((cls >= 1) & (cls <= 3), cls, 0).astype(np.int32)
    columns: dict[str, Any] = {
        "recording": pa.DictionaryArray.from_arrays(pa.array(rec.astype(np.int32)), pa.array(names)),
        "track_id": vehicle,
        "frame": frame,
        "time_ns": frame * FRAME_NS,
        **kin,
        "length": (cols["v_length"] * FEET).astype(np.float32),
        "width": (cols["v_width"] * FEET).astype(np.float32),
        "lane_id": cols["lane_id"].astype(np.int32),
        "object_class": pa.DictionaryArray.from_arrays(pa.array(cls_code), pa.array(CLASSES)),
        "preceding_id": track_schema.neighbour_ids(cols["preceding"]),
        "following_id": track_schema.neighbour_ids(cols["following"]),
    }
    meta = track_table.TableMeta(FORMAT, metas, files)
    table = track_table.build_table(columns, meta)
    track_table.validate(table, source=", ".join(files))
    return table


def _is_sorted(rec: np.ndarray, vehicle: np.ndarray, frame: np.ndarray) -> bool:
    """Rows already in (recording, vehicle, frame) order (as the original .txt files are) [n]."""
    same_rec = rec[1:] == rec[:-1]
    same_vehicle = same_rec & (vehicle[1:] == vehicle[:-1])
    ordered = (
        (rec[1:] > rec[:-1])
        | (same_rec & (vehicle[1:] > vehicle[:-1]))
        | (same_vehicle & (frame[1:] >= frame[:-1]))
    )
    return bool(ordered.all())
