"""NGSIM's CSV export read incrementally: one recording (location and period) at a time.

The export mixes four locations and several recording periods in one file of 11.8 M rows. Read
at once it needs about 10 GB; here it is read twice with pyarrow's streaming CSV reader, a block
at a time: first the Location, Global_Time and Frame_ID columns (the periods are clusters of the
epoch Global_Time - 100 * Frame_ID over the whole file, as in periods.py), then every used column,
each block's rows appended to a spill file (Arrow IPC) per recording. Each spill is then one piece
of the dataset, converted on its own (possibly in another process) exactly as reader.read converts
that recording: the same names, metadata, duplicate handling and kinematics.

A block that does not parse or check cleanly sends the whole file through reader.read's own
parser, which names the line and column of the problem (an error path, not bounded in memory).
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.csv as pacsv

from lanecast.io_adapters.datasets import csv_errors
from lanecast.io_adapters.datasets.ngsim import reader
from lanecast.io_adapters.datasets.ngsim.checks import checked_ranges
from lanecast.io_adapters.datasets.ngsim.columns import GLOBAL_TIME_PER_FRAME, USED_COLUMNS
from lanecast.io_adapters.datasets.ngsim.convert import recording_meta, recording_name, to_track_table
from lanecast.io_adapters.datasets.ngsim.locations import is_freeway, location_codes, normalise_location
from lanecast.io_adapters.datasets.ngsim.parse import csv_columns
from lanecast.io_adapters.datasets.ngsim.periods import MAX_STRAY_ROWS, clusters, few_rows, stray_pair
from lanecast.io_adapters.datasets.ngsim.sniff import header_names
from lanecast.io_adapters.datasets.ngsim.wrong_way import wrong_way
from lanecast.io_adapters.errors import InputError

BLOCK_BYTES = 16 << 20  # bytes of CSV per block: memory per block is a few times this


@dataclass(frozen=True)
class SpilledRecording:
    """One recording of a CSV export, spilled to ``spill`` (Arrow IPC, the used columns)."""

    name: str
    source: str  # the CSV export
    spill: str
    location: str
    epoch: int
    start: int  # smallest Global_Time
    period: int
    n_periods: int

    def to_json(self) -> str:
        return json.dumps(asdict(self), sort_keys=True)

    @classmethod
    def from_json(cls, text: str) -> SpilledRecording:
        return cls(**json.loads(text))


def streamable(path: Path) -> bool:
    """A CSV export with a Location column (the form that mixes locations in one file)."""
    first = csv_errors.read_first_line(path).decode("utf-8", errors="replace")
    if "," not in first:
        return False
    return "location" in {name.strip().lower() for name in header_names(first)}


def _layout(path: Path) -> tuple[str, dict[str, str], list[str], dict[str, pa.DataType]]:
    """(first line, lower-case name -> CSV name, columns to read, their types) as reader.read reads them."""
    first = csv_errors.read_first_line(path).decode("utf-8", errors="replace")
    by_lower, wanted, types = csv_columns(path, first)  # InputError: reader.read names it
    if "location" not in by_lower:
        raise ValueError("not a CSV export with a Location column")
    return first, by_lower, wanted, types


def _blocks(path: Path, columns: list[str], types: dict[str, pa.DataType]) -> Any:
    return pacsv.open_csv(
        path,
        read_options=pacsv.ReadOptions(block_size=BLOCK_BYTES),
        convert_options=pacsv.ConvertOptions(
            include_columns=columns,
            column_types={c: types[c] for c in columns},
            strings_can_be_null=False,
        ),
    )


def _locations(column: pa.Array) -> tuple[np.ndarray, list[str]]:
    """Per-row location names (normalised as reader.read does) as codes into the returned names."""
    import pyarrow.compute as pc  # only for a CSV export's locations: not on every start

    raw = pc.utf8_trim_whitespace(column)
    if np.asarray(pc.equal(raw, "")).any():
        raise ValueError("empty Location")
    if csv_errors.holds_line_ends(raw):
        raise ValueError("a quoted Location runs over line ends")  # the whole-file reader names the line
    return location_codes(raw)


def split_csv(
    path: Path, spill_dir: Path, *, location: str | None = None, split_periods: bool = True
) -> list[SpilledRecording] | None:
    """Spill the recordings of a CSV export into ``spill_dir``, one block in memory at a time.

    None when a block does not parse or check cleanly but the whole file does (e.g. integers
    written as ``12.0``): read that file whole. A bad file raises the whole-file parser's error.
    """
    path = Path(path)
    try:
        return _split(path, spill_dir, location, split_periods)
    except (pa.ArrowInvalid, ValueError, InputError):
        options: dict[str, Any] = {"split_periods": split_periods}
        if location is not None:
            options["location"] = location
        reader.read([path], **options)  # raises, naming the line and column, if the file is bad
        return None


def _split(path: Path, spill_dir: Path, location: str | None, split_periods: bool) -> list[SpilledRecording]:
    first, by_lower, wanted, types = _layout(path)
    loc_col, gt_col, frame_col = by_lower["location"], by_lower["global_time"], by_lower["frame_id"]
    # pass 1: the epochs of every location, and how many rows each holds
    epochs_of: dict[str, np.ndarray] = {}
    counts_of: dict[str, np.ndarray] = {}
    for batch in _blocks(path, [loc_col, gt_col, frame_col], types):
        codes, names = _locations(batch.column(loc_col))
        epoch = batch.column(gt_col).to_numpy() - GLOBAL_TIME_PER_FRAME * batch.column(frame_col).to_numpy()
        for i, name in enumerate(names):
            seen, count = np.unique(epoch[codes == i], return_counts=True)
            if name in epochs_of:
                seen, where = np.unique(np.r_[epochs_of[name], seen], return_inverse=True)
                count = np.bincount(where.ravel(), weights=np.r_[counts_of[name], count]).astype(np.int64)
            epochs_of[name], counts_of[name] = seen, count
    if not epochs_of:
        raise ValueError("no rows")
    if location is not None:
        location = normalise_location(location)
        if location not in epochs_of:
            raise InputError(
                path,
                f"no rows of location {location!r}",
                column="Location",
                expected=f"one of {sorted(epochs_of)}",
            )
        # as reader.read: the periods of the rows kept only
        epochs_of, counts_of = {location: epochs_of[location]}, {location: counts_of[location]}
    if few_rows(np.array([int(c.sum()) for c in counts_of.values()])) is not None:
        raise ValueError("a location of a row or two")  # reader.read names its line
    all_epochs = np.unique(np.concatenate(list(epochs_of.values())))
    cluster, period_start = clusters(all_epochs)
    if not split_periods:
        cluster, period_start = np.zeros_like(cluster), all_epochs[:1]
    else:  # a period of a row or two is a bad cell: reader.read names its line
        per_period = np.zeros(int(cluster[-1]) + 1, dtype=np.int64)
        for loc, seen in epochs_of.items():
            np.add.at(per_period, cluster[np.searchsorted(all_epochs, seen)], counts_of[loc])
        if few_rows(per_period) is not None:
            raise ValueError("a recording period of a row or two")
    # recordings: (location, period) in location order, periods ranked in time
    locations = sorted(epochs_of) if location is None else [location]
    recordings: dict[tuple[str, int], SpilledRecording] = {}
    for loc in locations:
        periods = np.unique(cluster[np.searchsorted(all_epochs, epochs_of[loc])])
        for rank, p in enumerate(periods.tolist(), start=1):
            name = recording_name(loc, path, rank, periods.size)
            spill = spill_dir / f"{path.stem}-{len(recordings):04d}.arrow"
            recordings[(loc, p)] = SpilledRecording(
                name, str(path), str(spill), loc, int(period_start[p]), 0, rank, int(periods.size)
            )
    # pass 2: every used column, each block's rows to their recording's spill
    spill_dir.mkdir(parents=True, exist_ok=True)
    writers: dict[tuple[str, int], pa.ipc.RecordBatchFileWriter] = {}
    start: dict[tuple[str, int], int] = {}
    used = [n for n in (*USED_COLUMNS, "direction") if n in by_lower]
    header = [c.strip() for c in first.lstrip("\ufeff").rstrip("\r").split(",")]
    try:
        for batch in _blocks(path, wanted, types):
            codes, names = _locations(batch.column(loc_col))
            columns = {n: batch.column(by_lower[n]).to_numpy() for n in USED_COLUMNS}
            if not all(np.isfinite(v).all() for v in columns.values()):
                raise ValueError("a value that is not a finite number")
            columns = checked_ranges(path, columns, header, header=True)
            if "direction" in by_lower:
                columns["direction"] = batch.column(by_lower["direction"]).to_numpy(zero_copy_only=False)
            epoch = columns["global_time"] - GLOBAL_TIME_PER_FRAME * columns["frame_id"]
            period = cluster[np.searchsorted(all_epochs, epoch)]
            for i, loc in enumerate(names):
                if location is not None and loc != location:
                    continue
                in_loc = codes == i
                for p in np.unique(period[in_loc]).tolist():
                    rows = np.flatnonzero(in_loc & (period == p))
                    key = (loc, p)
                    part = pa.record_batch({n: pa.array(columns[n][rows]) for n in used})
                    if key not in writers:
                        writers[key] = pa.ipc.new_file(recordings[key].spill, part.schema)
                    writers[key].write_batch(part)
                    gt_min = int(columns["global_time"][rows].min())
                    start[key] = min(start.get(key, gt_min), gt_min)
    finally:
        for writer in writers.values():
            writer.close()
    _check_spills([recordings[key] for key in recordings if key in start])
    spilled = [
        SpilledRecording(**{**asdict(rec), "start": start[key]})
        for key, rec in recordings.items()
        if key in start
    ]
    return sorted(spilled, key=lambda rec: rec.name)  # reader.read's order (location "us" after "us-101")


def _spilled_columns(rec: SpilledRecording, names: list[str] | None = None) -> dict[str, np.ndarray]:
    """The columns ``names`` (default: all) of a spilled recording [n]."""
    with pa.memory_map(rec.spill) as source:
        table = pa.ipc.open_file(source).read_all()
    return {n: table.column(n).to_numpy() for n in (table.column_names if names is None else names)}


def _check_spills(spilled: list[SpilledRecording]) -> None:
    """ValueError (reader.read then names the line) where the spills, one or two at a time, break
    what reader.read checks across a whole file: a freeway vehicle driving backwards, a row or two
    of a vehicle put by its Global_Time in another period than its neighbouring frame."""
    for rec in spilled:
        if is_freeway(rec.location):
            c = _spilled_columns(rec, ["vehicle_id", "frame_id", "local_y"])
            zeros = np.zeros(c["frame_id"].size, dtype=np.int64)
            if wrong_way(zeros, zeros, c["vehicle_id"], c["frame_id"], c["local_y"]) is not None:
                raise ValueError("a vehicle driving backwards on a one-way freeway")
    for loc in sorted({rec.location for rec in spilled}):
        periods = [rec for rec in spilled if rec.location == loc]
        if len(periods) < 2:
            continue
        # only vehicles with a row or two in some period can be strays: their rows in every period
        few: list[np.ndarray] = []
        for rec in periods:
            ids, count = np.unique(_spilled_columns(rec, ["vehicle_id"])["vehicle_id"], return_counts=True)
            few.append(ids[count <= MAX_STRAY_ROWS])
        suspects = np.unique(np.concatenate(few))
        if not suspects.size:
            continue
        parts = []
        for p, rec in enumerate(periods):
            c = _spilled_columns(rec, ["vehicle_id", "frame_id"])
            keep = np.isin(c["vehicle_id"], suspects)
            parts.append((c["vehicle_id"][keep], c["frame_id"][keep], np.full(int(keep.sum()), p)))
        vehicle, frame, period = (np.concatenate(x) for x in zip(*parts, strict=True))
        if stray_pair(np.zeros(vehicle.size, dtype=np.int64), vehicle, frame, period) is not None:
            raise ValueError("a row of a vehicle in another period than its neighbouring frame")


def read_spilled(rec: SpilledRecording) -> pa.Table:
    """One spilled recording as a validated track table, as reader.read gives that recording."""
    columns = _spilled_columns(rec)
    n = columns["vehicle_id"].size
    columns.setdefault("direction", np.full(n, np.nan))
    columns["recording"] = np.zeros(n, dtype=np.int64)
    path = Path(rec.source)
    meta = recording_meta(path, rec.location, "column", rec.epoch, rec.start, rec.period, rec.n_periods)
    return to_track_table(columns, [rec.name], {rec.name: meta}, [rec.source])  # validated there
