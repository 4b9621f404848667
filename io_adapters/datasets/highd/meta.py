"""highD's ``NN_recordingMeta.csv``: the one row of a recording's frame rate, location, speed
limit and lane markings, each checked where it is read (a wrong frame rate or marking would be
applied to every track of the recording)."""

from __future__ import annotations

import csv
import itertools
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path

import numpy as np

from lanecast.io_adapters.contracts import track_table
from lanecast.io_adapters.datasets.csv_errors import row_line
from lanecast.io_adapters.datasets.highd.columns import LOWER, RECORDING_META_COLUMNS, UPPER
from lanecast.io_adapters.datasets.highd.parse import read_csv
from lanecast.io_adapters.datasets.highd.sniff import NAME
from lanecast.io_adapters.datasets.highd.start_time import recording_start
from lanecast.io_adapters.errors import InputError


@dataclass
class Meta:
    """Parsed recordingMeta of one recording."""

    recording_id: int
    frame_rate: float
    location_id: int
    speed_limit: float
    markings: dict[int, list[float]]  # drivingDirection → raw image y of the lane markings
    start: datetime | None = None  # local start (start_time.recording_start), None where not given


def _markings(path: Path, text: str | None, column: str, line: int) -> list[float]:
    """``"8.51;12.59;16.43"`` → [8.51, 12.59, 16.43] (a handful of values, not rows)."""
    if text is None or not text.strip():
        return []
    try:
        values = [float(v) for v in text.split(";") if v.strip()]
    except ValueError as exc:
        raise InputError(
            path,
            f"lane markings {text!r} are not numbers",
            line=line,
            column=column,
            expected="';'-separated y values in metres",
        ) from exc
    if not all(np.isfinite(values)):
        raise InputError(path, f"lane markings {text!r} are not finite", line=line, column=column)
    if (np.diff(values) <= 0).any():  # lanes between them: none, or upside down
        raise InputError(
            path,
            f"lane markings {text!r} are not in increasing order",
            line=line,
            column=column,
            expected="y values increasing from the top of the image (highD numbers lanes in that order)",
        )
    return values


def _check_recording_id(path: Path, recording_id: int, line: int) -> None:
    """recordingMeta's ``id`` is the ``NN`` of its file name (as highD and ``lanecast simulate``
    write them): another one is a file of another recording put under this name, whose frame rate
    and lane markings would be applied to this recording's tracks. A name with no number is not
    checked."""
    match = NAME.match(path.name)
    prefix = match.group("prefix") if match is not None else ""
    if prefix.isdigit() and int(prefix) != recording_id:
        raise InputError(
            path,
            f"recording id {recording_id} disagrees with the file name's {prefix} "
            "(a recordingMeta of another recording?)",
            line=line,
            column="id",
            expected=f"{int(prefix)}",
        )


def read_recording_meta(path: Path) -> Meta:
    """The checked recordingMeta of ``path``: exactly one row, its id that of the file name, a
    plausible frame rate, lane markings as increasing numbers."""
    table = read_csv(
        path, RECORDING_META_COLUMNS, "recordingMeta", frozenset({"upperLaneMarkings", "lowerLaneMarkings"})
    )
    if table.num_rows != 1:
        raise InputError(
            path, f"{table.num_rows} data rows", line=row_line(path, 1), expected="exactly one data row"
        )
    row = {name: table.column(name)[0].as_py() for name in RECORDING_META_COLUMNS}
    when = _when(path)
    line = row_line(path, 0)
    _check_recording_id(path, int(row["id"]), line)
    if not track_table.plausible_frame_rate(row["frameRate"]):
        raise InputError(
            path,
            f"frame rate {row['frameRate']:g} Hz",
            line=line,
            column="frameRate",
            expected=f"highD's 25 Hz, or any rate {track_table.FRAME_RATES}",
        )
    return Meta(
        recording_id=int(row["id"]),
        frame_rate=float(row["frameRate"]),
        location_id=int(row["locationId"]),
        speed_limit=float(row["speedLimit"]),
        markings={
            UPPER: _markings(path, row["upperLaneMarkings"], "upperLaneMarkings", line),
            LOWER: _markings(path, row["lowerLaneMarkings"], "lowerLaneMarkings", line),
        },
        start=recording_start(when.get("month"), when.get("weekDay"), when.get("startTime")),
    )


def _when(path: Path) -> dict[str, str]:
    """The optional ``month``, ``weekDay`` and ``startTime`` cells of the one-row file (empty where
    the file has no such column)."""
    with path.open(encoding="utf-8", errors="replace", newline="") as fh:
        rows = list(itertools.islice(csv.reader(fh), 2))
    if len(rows) < 2:
        return {}
    return {k: v for k, v in zip(rows[0], rows[1], strict=False) if k in ("month", "weekDay", "startTime")}
