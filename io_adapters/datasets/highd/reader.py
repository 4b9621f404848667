"""highD reader: ``NN_tracks.csv`` + ``NN_tracksMeta.csv`` + ``NN_recordingMeta.csv`` → track table.

One highD recording is three CSV files sharing a prefix in one directory. Each recording is split
by ``drivingDirection`` into two track-table recordings, ``highd-NN-upper`` (direction 1, drives
towards −x in the image) and ``highd-NN-lower`` (direction 2, towards +x), each in its road frame
(docs/design.md §1: x along the direction of travel, y to the left):

* highD ``x, y`` are the bounding box's top-left corner in image-like coordinates (y down),
  ``width`` is the extent along x (vehicle length), ``height`` along y (vehicle width);
  the centre is ``(x + width/2, y + height/2)``.
* lower (+x travel): road = ``(x_img, −y_img)``; upper (−x travel): road = ``(−x_img, +y_img)``
  (the y-up frame turned by 180°). Velocities and accelerations map the same way.

Parsing is vectorised (pyarrow.csv with explicit column types). Only after the fast parse or a
check fails does a second, equally vectorised pass locate the offending line, so that every error
names the file, the 1-based line (header = line 1), the column and what was expected.

Size: one reader, most of it the line-exact diagnosis of bad files that the format needs
(the line finder itself is shared: ``datasets/csv_errors.py``).
"""

from __future__ import annotations

import difflib
import errno
import os
import re
import sys
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.csv as pacsv

from lanecast.io_adapters.contracts import track_table
from lanecast.io_adapters.contracts.track_runs import run_bounds
from lanecast.io_adapters.datasets.csv_errors import (
    REPEATED_HEADER,
    check_field_counts,
    check_one_line_per_row,
    check_parseable,
    check_text,
    is_header,
    read_first_line,
    record_lines,
    shown,
)
from lanecast.io_adapters.errors import InputError
from lanecast.io_adapters.files import COMPRESSED_SUFFIXES, NOT_REGULAR, progress

FORMAT = "highd"

KINDS = ("tracks", "tracksMeta", "recordingMeta")
_NAME = re.compile(r"^(?P<prefix>.+)_(?P<kind>tracks|tracksMeta|recordingMeta)\.csv$")

# Required columns and their parse types ("int", "float", "str"), per file kind.
TRACKS_COLUMNS: dict[str, str] = {
    "frame": "int",
    "id": "int",
    "x": "float",
    "y": "float",
    "width": "float",
    "height": "float",
    "xVelocity": "float",
    "yVelocity": "float",
    "xAcceleration": "float",
    "yAcceleration": "float",
    "precedingId": "int",
    "followingId": "int",
    "leftPrecedingId": "int",
    "leftAlongsideId": "int",
    "leftFollowingId": "int",
    "rightPrecedingId": "int",
    "rightAlongsideId": "int",
    "rightFollowingId": "int",
    "laneId": "int",
}
TRACKS_META_COLUMNS: dict[str, str] = {
    "id": "int",
    "initialFrame": "int",
    "finalFrame": "int",
    "numFrames": "int",
    "class": "str",
    "drivingDirection": "int",
}
RECORDING_META_COLUMNS: dict[str, str] = {
    "id": "int",
    "frameRate": "float",
    "locationId": "int",
    "speedLimit": "float",
    "upperLaneMarkings": "str",
    "lowerLaneMarkings": "str",
}
_COLUMNS_BY_KIND = {
    "tracks": TRACKS_COLUMNS,
    "tracksMeta": TRACKS_META_COLUMNS,
    "recordingMeta": RECORDING_META_COLUMNS,
}
# highD neighbour columns → track-table neighbour columns (0 in highD means "none").
NEIGHBOURS: dict[str, str] = dict(
    zip(
        (
            "precedingId",
            "followingId",
            "leftPrecedingId",
            "leftAlongsideId",
            "leftFollowingId",
            "rightPrecedingId",
            "rightAlongsideId",
            "rightFollowingId",
        ),
        track_table.NEIGHBOUR_COLUMNS,
        strict=True,
    )
)
UPPER, LOWER = 1, 2  # highD drivingDirection values
DIRECTION_NAMES = {UPPER: "upper", LOWER: "lower"}
HEADING_MIN_SPEED = 0.5  # m/s: below it the heading is 0 (direction of travel)

_ARROW_TYPES = {"int": pa.int64(), "float": pa.float64(), "str": pa.string()}
_EXPECTED = {"int": "an integer within int64", "float": "a number", "str": "a non-empty value"}
_NULL_TOKENS = tuple(pacsv.ConvertOptions().null_values)
_INT_RE = r"^\s*-?\d+\s*$"  # pyarrow reads no "+3" as int64
_FLOAT_RE = r"^\s*[-+]?(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?\s*$|^\s*[-+]?(inf|Inf|INF|infinity|Infinity)\s*$"


@dataclass(frozen=True)
class Recording:
    """The three files of one highD recording (``prefix`` is the ``NN`` of ``NN_tracks.csv``)."""

    directory: Path
    prefix: str

    def path(self, kind: str) -> Path:
        return self.directory / f"{self.prefix}_{kind}.csv"

    @property
    def paths(self) -> list[Path]:
        return [self.path(kind) for kind in KINDS]


# --------------------------------------------------------------------------------------------
# sniff / locate


def _header_names(path: Path, limit: int = 65536) -> list[str]:
    """The column names of the first line of ``path`` (stripped of blanks, quotes and a BOM)."""
    text = read_first_line(path, limit).decode("utf-8-sig", errors="replace")
    if not text.strip():
        return []
    return [name.strip().strip('"') for name in text.split(",")]


def _looks_like(path: Path, kind: str) -> bool:
    """Header shares at least half of the required columns of ``kind`` (tolerates a misnamed one)."""
    try:
        names = set(_header_names(path))
    except OSError:
        return False
    required = _COLUMNS_BY_KIND[kind]
    return len(names & set(required)) * 2 >= len(required)


def _named_files(directory: Path, *, regular: bool = True) -> list[tuple[Path, re.Match[str]]]:
    """The regular files of ``directory`` named as highD's (NN_tracks.csv, …), with their match
    (``regular=False``: any entry but a directory: a FIFO or a link to nothing too)."""
    named = ((p, _NAME.match(p.name)) for p in sorted(directory.glob("*_*.csv")))
    return [(p, m) for p, m in named if m is not None and (p.is_file() if regular else not p.is_dir())]


def _with_companions(path: Path, prefix: str) -> bool:
    """All three files of recording ``prefix`` are beside ``path``."""
    return all((path.parent / f"{prefix}_{kind}.csv").is_file() for kind in KINDS)


def sniff(path: Path) -> bool:
    """A highD file (by name ``NN_tracks.csv`` etc., and its header or its two companion files) or
    a directory holding one: a recording whose file is damaged (empty, UTF-16, another separator)
    is still highD, for the reader to name what is wrong with it."""
    path = Path(path)
    if path.is_dir():  # any of a recording's files: one missing is the reader's to name
        return any(
            _looks_like(p, m.group("kind")) or _with_companions(p, m.group("prefix"))
            for p, m in _named_files(path)
        )
    match = _NAME.match(path.name)
    return (
        match is not None
        and path.is_file()
        and (_looks_like(path, match.group("kind")) or _with_companions(path, match.group("prefix")))
    )


def recordings(paths: Sequence[str | Path]) -> list[Recording]:
    """The distinct recordings named by ``paths`` (any of their three files, or directories)."""
    found: dict[tuple[Path, str], Recording] = {}
    for raw in paths:
        path = Path(raw)
        match = _NAME.match(path.name)
        if path.is_dir() and match is None:
            # Every recording any of whose three files is here (a FIFO or a link to nothing under
            # its name too): one whose tracks file is missing or no file is refused naming it, not
            # left out.
            prefixes = sorted({m.group("prefix") for _, m in _named_files(path, regular=False)})
            if not prefixes:
                raise InputError(path, "no highD recording in this directory", expected="NN_tracks.csv files")
            candidates = [Recording(path, prefix) for prefix in prefixes]
        else:
            if match is None:
                raise InputError(
                    path,
                    "not a highD file name",
                    expected="NN_tracks.csv, NN_tracksMeta.csv or NN_recordingMeta.csv",
                )
            if not path.is_file():
                raise InputError(path, not_a_file(path), expected=f"the highD {match.group('kind')} CSV file")
            candidates = [Recording(path.parent, match.group("prefix"))]
        for rec in candidates:
            found.setdefault((rec.directory.resolve(), rec.prefix), rec)
    return list(found.values())


def _loops(path: Path) -> bool:
    try:
        os.stat(path)
    except OSError as exc:
        return exc.errno == errno.ELOOP
    return False


def not_a_file(path: Path) -> str:
    """Why ``path``, which is no regular file, cannot be read: missing (and, where a compressed copy
    lies beside it, which), a directory, or a FIFO, socket or device (which nothing may open)."""
    if path.is_dir():
        return "a directory, not a file"
    if path.exists():
        return NOT_REGULAR
    if path.is_symlink():
        return "a symbolic link loop" if _loops(path) else "a symbolic link to a missing file"
    packed = [path.with_name(path.name + s) for s in COMPRESSED_SUFFIXES]
    found = [p.name for p in packed if p.is_file()]
    return f"no such file ({found[0]} beside it is compressed: decompress it)" if found else "no such file"


# --------------------------------------------------------------------------------------------
# CSV parsing with precise errors


def _data_lines(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """1-based line numbers and field counts of the data records of ``path`` (error path only):
    ``lines[i]`` is the line of the i-th row pyarrow parses (the header excluded)."""
    lines, fields = record_lines(path.read_bytes())
    return lines[1:], fields[1:]


def _read_csv(
    path: Path, columns: Mapping[str, str], what: str, may_be_empty: frozenset[str] = frozenset()
) -> pa.Table:
    """Parse the required ``columns`` of a highD CSV with explicit types; InputError on bad input.

    Checks: file present and non-empty, every required column in the header, cells parse as their
    type, no empty/NaN cell, floats finite, at least one data row.
    """
    if not path.is_file():
        raise InputError(path, f"missing {what} file", expected=f"{path.name} beside the other files")
    if path.stat().st_size == 0:
        raise InputError(path, "empty file", line=1, expected=f"a {what} header line")
    try:
        with path.open("rb") as fh:
            check_text(path, fh.read(4096), f"a highD {what} CSV")
        names = _header_names(path)
    except OSError as exc:
        raise InputError(path, f"cannot read: {exc}") from exc
    if not names:
        raise InputError(path, "empty header line", line=1, expected=f"a {what} header line")
    if len(names) == 1 and (";" in names[0] or "\t" in names[0]):
        sep = "';'" if ";" in names[0] else "tabs"
        raise InputError(path, f"the header is separated by {sep}", line=1, expected="comma-separated fields")
    if "recordingId" in names and "id" not in names:
        raise InputError(
            path,
            "a recording of highD's sister datasets (inD, rounD, exiD, uniD: columns recordingId, "
            "trackId, xCenter), whose format and road geometry lanecast does not read",
            line=1,
            expected=f"a highD {what} CSV, whose vehicles and recordings are numbered in a column 'id'",
        )
    for name in columns:
        if name not in names:
            close = difflib.get_close_matches(name, names, n=1)
            hint = f"; found {close[0]!r}" if close else ""
            raise InputError(
                path,
                f"no column {name!r} in the header{hint}",
                line=1,
                column=name,
                expected=f"the highD {what} column {name!r}",
            )
        if names.count(name) > 1:
            raise InputError(path, f"column {name!r} appears twice", line=1, column=name)
    read_options = pacsv.ReadOptions(column_names=names, skip_rows=1)
    convert = pacsv.ConvertOptions(
        column_types={name: _ARROW_TYPES[kind] for name, kind in columns.items()},
        include_columns=list(columns),
        strings_can_be_null=True,
    )
    try:
        table = pacsv.read_csv(path, read_options=read_options, convert_options=convert)
    except pa.ArrowInvalid as exc:
        _diagnose(path, names, columns)
        if _data_lines(path)[0].size == 0:  # a header with no line end: "Could not skip initial 1 rows"
            raise InputError(path, "no data rows", line=2, expected=f"at least one {what} row") from exc
        raise InputError(path, f"cannot parse as CSV: {exc}", expected=f"a highD {what} file") from exc
    except OSError as exc:
        raise InputError(path, f"cannot read: {exc}") from exc
    if table.num_rows == 0:
        raise InputError(path, "no data rows", line=2, expected=f"at least one {what} row")
    check_one_line_per_row(path, table)
    _check_cells(path, table, names, {k: v for k, v in columns.items() if k not in may_be_empty})
    return table


def _diagnose(path: Path, names: list[str], columns: Mapping[str, str]) -> None:
    """After a failed fast parse: find the first bad line (field count or cell) and raise there."""
    data = path.read_bytes()
    check_field_counts(path, data, names)
    lines = record_lines(data)[0][1:]
    try:
        table = pacsv.read_csv(
            path,
            read_options=pacsv.ReadOptions(column_names=names, skip_rows=1),
            convert_options=pacsv.ConvertOptions(
                column_types={name: pa.string() for name in columns},
                include_columns=list(columns),
                strings_can_be_null=False,
                quoted_strings_can_be_null=False,
            ),
        )
    except pa.ArrowInvalid:
        check_parseable(path, data)
        return  # not a cell problem: the caller reports pyarrow's own message
    first_bad: tuple[int, str] | None = None
    for name in names:
        kind = columns.get(name)
        if kind not in ("int", "float"):
            continue
        cells = table.column(name)
        ok = pc.or_(
            pc.match_substring_regex(cells, _INT_RE if kind == "int" else _FLOAT_RE),
            pc.is_in(cells, value_set=pa.array(_NULL_TOKENS)),
        )
        if kind == "int":  # digits that do not fit int64 (pyarrow's parse fails on them too)
            ok = pc.and_(ok, pc.invert(pc.match_substring_regex(cells, r"\d{19}")))
        bad = np.flatnonzero(~np.asarray(ok))
        if bad.size and (first_bad is None or bad[0] < first_bad[0]):
            first_bad = (int(bad[0]), name)
    if first_bad is not None:
        row, name = first_bad
        kind = columns[name]
        value = table.column(name)[row].as_py()
        if is_header([table.column(n)[row].as_py() for n in columns], list(columns)):
            raise InputError(
                path, REPEATED_HEADER, line=int(lines[row]), expected="one header line, at line 1"
            )
        raise InputError(
            path,
            f"cell {shown(value)} is not {_EXPECTED[kind]}",
            line=int(lines[row]),
            column=name,
            expected=_EXPECTED[kind],
        )


def _check_cells(path: Path, table: pa.Table, names: list[str], columns: Mapping[str, str]) -> None:
    """Empty/NaN cells (parsed as null) and non-finite floats, reported at their line."""
    first_bad: tuple[int, str, str] | None = None
    for name in names:
        kind = columns.get(name)
        if kind is None:
            continue
        column = table.column(name)
        bad = np.zeros(0, dtype=np.int64)
        message = "empty or NaN cell"
        if column.null_count:
            bad = np.flatnonzero(np.asarray(pc.is_null(column)))
        elif kind == "float":
            bad = np.flatnonzero(~np.isfinite(column.to_numpy()))
            message = "infinite value"
        if bad.size and (first_bad is None or bad[0] < first_bad[0]):
            first_bad = (int(bad[0]), name, message)
    if first_bad is not None:
        row, name, message = first_bad
        lines, _ = _data_lines(path)
        expected = "a finite number" if columns[name] == "float" else _EXPECTED[columns[name]]
        raise InputError(path, message, line=int(lines[row]), column=name, expected=expected)


def _line(path: Path, row: int) -> int:
    """The 1-based line of data row ``row`` of ``path`` (error path only)."""
    lines, _ = _data_lines(path)
    return int(lines[row])


# --------------------------------------------------------------------------------------------
# one recording


@dataclass
class _Meta:
    """Parsed recordingMeta of one recording."""

    recording_id: int
    frame_rate: float
    location_id: int
    speed_limit: float
    markings: dict[int, list[float]]  # drivingDirection → raw image y of the lane markings


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
    """recordingMeta's ``id`` is the ``NN`` of its file name (``NN_recordingMeta.csv``, as highD and
    ``lanecast simulate`` write them): another one is a file of another recording put under this
    name, whose frame rate and lane markings would be applied to this recording's tracks. A name
    with no number (``highway_recordingMeta.csv``) is not checked."""
    match = _NAME.match(path.name)
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


def _read_recording_meta(path: Path) -> _Meta:
    table = _read_csv(
        path, RECORDING_META_COLUMNS, "recordingMeta", frozenset({"upperLaneMarkings", "lowerLaneMarkings"})
    )
    if table.num_rows != 1:
        raise InputError(
            path, f"{table.num_rows} data rows", line=_line(path, 1), expected="exactly one data row"
        )
    row = {name: table.column(name)[0].as_py() for name in RECORDING_META_COLUMNS}
    line = _line(path, 0)
    _check_recording_id(path, int(row["id"]), line)
    if not track_table.plausible_frame_rate(row["frameRate"]):
        raise InputError(
            path,
            f"frame rate {row['frameRate']:g} Hz",
            line=line,
            column="frameRate",
            expected=f"highD's 25 Hz, or any rate {track_table.FRAME_RATES}",
        )
    return _Meta(
        recording_id=int(row["id"]),
        frame_rate=float(row["frameRate"]),
        location_id=int(row["locationId"]),
        speed_limit=float(row["speedLimit"]),
        markings={
            UPPER: _markings(path, row["upperLaneMarkings"], "upperLaneMarkings", line),
            LOWER: _markings(path, row["lowerLaneMarkings"], "lowerLaneMarkings", line),
        },
    )


def _numpy(table: pa.Table, columns: Mapping[str, str]) -> dict[str, np.ndarray]:
    return {name: table.column(name).to_numpy() for name, kind in columns.items() if kind != "str"}


def _dedupe(path: Path, cols: dict[str, np.ndarray]) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """Sort the tracks by (id, frame); drop identical duplicate rows, refuse differing ones.

    Returns the sorted columns and ``source_row int64 [N]``, each kept row's index in the file.
    """
    ids, frames = cols["id"], cols["frame"]
    n = ids.size
    order = np.arange(n)
    in_order = (ids[1:] > ids[:-1]) | ((ids[1:] == ids[:-1]) & (frames[1:] >= frames[:-1]))
    if not in_order.all():
        order = np.lexsort((frames, ids))  # stable: the first occurrence in the file comes first
        cols = {name: values[order] for name, values in cols.items()}
        ids, frames = cols["id"], cols["frame"]
    duplicate = (ids[1:] == ids[:-1]) & (frames[1:] == frames[:-1])
    if not duplicate.any():
        return cols, order
    for name in TRACKS_COLUMNS:  # header order of highD, which is the order listed
        values = cols[name]
        differs = duplicate & (values[1:] != values[:-1])
        if differs.any():
            i = int(np.flatnonzero(differs)[0])  # the sort is stable: order[i] < order[i + 1]
            lines, _ = _data_lines(path)
            first, second = int(lines[order[i]]), int(lines[order[i + 1]])
            raise InputError(
                path,
                f"duplicate (id, frame) = ({ids[i]}, {frames[i]}) with a different {name!r} than line "
                f"{first} ({values[i + 1]} vs {values[i]})",
                line=second,
                column=name,
                expected="one row per (id, frame)",
            )
    keep = np.ones(n, dtype=bool)
    keep[1:] = ~duplicate
    return {name: values[keep] for name, values in cols.items()}, order[keep]


def _report_dropped(path: Path, rows: int, kept: np.ndarray, lines_known: bool) -> None:
    """Say on stderr how many rows repeated an earlier (id, frame) identically and were dropped
    (a repair, never silent); ``kept`` [N] the file rows kept of ``rows``; with ``lines_known``
    (the whole file was parsed) the first dropped row's line is named."""
    dropped = rows - kept.size
    if not dropped:
        return
    where = ""
    if lines_known:
        first = int(np.flatnonzero(np.isin(np.arange(rows), kept, invert=True))[0])
        where = f" (the first at line {_line(path, first)})"
    print(
        f"lanecast: {path}: dropped {dropped:,} row(s) repeating an earlier (id, frame) with the same "
        f"values{where}",
        file=sys.stderr,
    )


INT32_MAX = 2**31 - 1
FLOAT32_MAX = float(np.finfo(np.float32).max)  # sizes, velocities, accelerations are float32
MAX_POSITION_M = 1e9  # highD positions are image metres (below 1e3)
MAX_SIZE_M = 300.0  # width (length) and height (width): no road vehicle is longer than ~60 m
MAX_TIME_NS = 2**62  # time_ns = frame / frameRate * 1e9 must stay well inside int64


def _check_ranges(path: Path, cols: dict[str, np.ndarray], source_row: np.ndarray, frame_rate: float) -> None:
    """Values that parse but cannot be right, refused at their line: a negative frame, a frame whose
    time overflows ``time_ns``, a size that is not positive, a laneId outside int32.

    ``cols`` are the tracks (arrays [N], any order), ``source_row`` [N] their rows in the file.
    """
    max_frame = MAX_TIME_NS / 1e9 * frame_rate
    frames = f"a frame from 0 to {max_frame:.4g} (frame / frameRate {frame_rate:g} Hz in ns within int64)"
    checks = (
        ("frame", (cols["frame"] < 0) | (cols["frame"] > max_frame), frames),
        # highD numbers vehicles from 1: 0 is "no vehicle" in the neighbour columns (precedingId, …)
        ("id", cols["id"] < 1, "a vehicle id >= 1 (0 means no vehicle in the neighbour columns)"),
        (
            "width",
            ~((cols["width"] > 0) & (cols["width"] <= MAX_SIZE_M)),
            f"a length > 0 and <= {MAX_SIZE_M:g} m",
        ),
        (
            "height",
            ~((cols["height"] > 0) & (cols["height"] <= MAX_SIZE_M)),
            f"a width > 0 and <= {MAX_SIZE_M:g} m",
        ),
        ("laneId", (cols["laneId"] < -INT32_MAX) | (cols["laneId"] > INT32_MAX), "a lane id within int32"),
        *(
            (name, np.abs(cols[name]) > MAX_POSITION_M, f"a position within ±{MAX_POSITION_M:g} m")
            for name in ("x", "y")
        ),
        *(
            (name, np.abs(cols[name]) > FLOAT32_MAX, "a value within float32")
            for name in ("width", "height", "xVelocity", "yVelocity", "xAcceleration", "yAcceleration")
        ),
        *(  # the track table's bounds (track_table.RANGES), here at the line of the CSV
            (
                name,
                np.abs(cols[name]) > track_table.MAX_POSITION_M,
                f"{what} within ±{track_table.MAX_POSITION_M:g}",
            )
            for name, what in (
                ("xVelocity", "a speed (m/s)"),
                ("yVelocity", "a speed (m/s)"),
                ("xAcceleration", "an acceleration (m/s^2)"),
                ("yAcceleration", "an acceleration (m/s^2)"),
            )
        ),
    )
    first: tuple[int, str, str] | None = None
    for name, bad, expected in checks:
        rows = source_row[bad]
        if rows.size and (first is None or int(rows.min()) < first[0]):
            first = (int(rows.min()), name, expected)
    if first is not None:
        row, name, expected = first
        value = cols[name][np.flatnonzero(source_row == row)[0]]
        raise InputError(path, f"{name} is {value}", line=_line(path, row), column=name, expected=expected)


def _check_meta(
    rec: Recording,
    meta_table: pa.Table,
    cols: dict[str, np.ndarray],
    source_row: np.ndarray,
    all_tracks: bool = True,
) -> tuple[np.ndarray, np.ndarray]:
    """Cross-check tracksMeta against the tracks; map each track row to its meta row.

    ``cols`` are the deduplicated tracks sorted by (id, frame), ``source_row [N]`` their rows in
    the file. Returns ``(meta_row int64 [N], direction int64 [N])``; raises InputError on any
    disagreement (id sets, initialFrame, finalFrame, numFrames, drivingDirection).
    """
    meta_path, tracks_path = rec.path("tracksMeta"), rec.path("tracks")
    m = _numpy(meta_table, TRACKS_META_COLUMNS)
    direction = m["drivingDirection"]
    bad = np.flatnonzero((direction != UPPER) & (direction != LOWER))
    if bad.size:
        row = int(bad[0])
        raise InputError(
            meta_path,
            f"drivingDirection is {direction[row]}",
            line=_line(meta_path, row),
            column="drivingDirection",
            expected="1 (upper lanes, towards −x) or 2 (lower lanes, towards +x)",
        )
    meta_ids = m["id"]
    meta_order = np.argsort(meta_ids, kind="stable")
    sorted_ids = meta_ids[meta_order]
    repeated = np.flatnonzero(sorted_ids[1:] == sorted_ids[:-1])
    if repeated.size:
        row = int(meta_order[repeated[0] + 1])
        raise InputError(
            meta_path,
            f"vehicle id {meta_ids[row]} appears twice",
            line=_line(meta_path, row),
            column="id",
            expected="one row per vehicle",
        )
    ids, frames = cols["id"], cols["frame"]
    bounds = run_bounds(ids)
    starts, ends = bounds[:-1], bounds[1:]
    track_ids = ids[starts]
    pos = np.minimum(np.searchsorted(sorted_ids, track_ids), sorted_ids.size - 1)
    unknown = np.flatnonzero(sorted_ids[pos] != track_ids)
    if unknown.size:
        k = int(unknown[0])
        raise InputError(
            tracks_path,
            f"vehicle id {track_ids[k]} has no row in {meta_path.name}",
            line=_line(tracks_path, int(source_row[starts[k]])),
            column="id",
            expected=f"an id listed in {meta_path.name}",
        )
    unused = np.setdiff1d(meta_ids, track_ids) if all_tracks else meta_ids[:0]  # a block: some tracks
    if unused.size:
        row = int(np.flatnonzero(meta_ids == unused[0])[0])
        raise InputError(
            meta_path,
            f"vehicle id {unused[0]} has no rows in {tracks_path.name}",
            line=_line(meta_path, row),
            column="id",
            expected=f"an id present in {tracks_path.name}",
        )
    meta_rows = meta_order[pos]  # meta row of each track
    observed = {
        "initialFrame": frames[starts],
        "finalFrame": frames[ends - 1],
        "numFrames": ends - starts,
    }
    for name, got in observed.items():
        stated = m[name][meta_rows]
        wrong = np.flatnonzero(stated != got)
        if wrong.size:
            k = int(wrong[0])
            row = int(meta_rows[k])
            raise InputError(
                meta_path,
                f"{name} {stated[k]} for vehicle {track_ids[k]} disagrees with {tracks_path.name} "
                f"(frames {frames[starts[k]]}..{frames[ends[k] - 1]}, {ends[k] - starts[k]} rows)",
                line=_line(meta_path, row),
                column=name,
                expected=f"{got[k]}",
            )
    row_meta = np.repeat(meta_rows, ends - starts)
    return row_meta, direction[row_meta]


WRONG_WAY_MPS = 1.0  # a track whose mean speed along its road frame's x is below minus this drives backwards


def _check_direction(
    rec: Recording, cols: dict[str, np.ndarray], row_meta: np.ndarray, direction: np.ndarray
) -> None:
    """Refuse a vehicle whose drivingDirection contradicts its xVelocity: in its road frame it would
    drive backwards (a tracksMeta row that disagrees with the tracks, never a real vehicle).

    ``cols`` sorted by (id, frame), ``row_meta`` and ``direction`` [N] per row (``_check_meta``)."""
    starts = run_bounds(cols["id"])[:-1]
    sign = np.where(direction[starts] == LOWER, 1.0, -1.0)
    mean_vx = np.add.reduceat(cols["xVelocity"], starts) / np.diff(np.append(starts, row_meta.size))
    wrong = np.flatnonzero(sign * mean_vx < -WRONG_WAY_MPS)
    if wrong.size:
        k = int(starts[wrong[0]])
        meta_path, d = rec.path("tracksMeta"), int(direction[k])
        raise InputError(
            meta_path,
            f"drivingDirection {d} ({DIRECTION_NAMES[d]} lanes, towards {'+' if d == LOWER else '−'}x) for "
            f"vehicle {cols['id'][k]}, but its mean xVelocity in {rec.path('tracks').name} is "
            f"{mean_vx[wrong[0]]:.2f} m/s",
            line=_line(meta_path, int(row_meta[k])),
            column="drivingDirection",
            expected=f"{UPPER if d == LOWER else LOWER}, the direction the vehicle drives",
        )


MAX_SPEED_RATIO = 1.5  # mean xVelocity over the motion of x: further apart, one of them is in other units
MIN_UNITS_SPEED = 3.0  # m/s: slower tracks' ratio is noise (stop and go)
MIN_UNITS_SECONDS = 1.0  # s: shorter tracks' ratio is noise


def _check_speed_units(
    rec: Recording, cols: dict[str, np.ndarray], source_row: np.ndarray, frame_rate: float
) -> None:
    """Refuse a vehicle whose mean xVelocity disagrees with the motion of its x over its frames at
    the recordingMeta's frameRate by more than MAX_SPEED_RATIO: velocities in km/h, positions in
    feet or a wrong frameRate, each converted as it came, give tracks whose x and vx disagree.

    ``cols`` sorted by (id, frame) [N], ``source_row`` [N] their rows in the file."""
    bounds = run_bounds(cols["id"])
    starts, last = bounds[:-1], bounds[1:] - 1
    frame, x = cols["frame"], cols["x"]
    seconds = (frame[last] - frame[starts]) / frame_rate
    motion = (x[last] - x[starts]) / np.where(seconds > 0, seconds, 1.0)
    mean_vx = np.add.reduceat(cols["xVelocity"], starts) / (last - starts + 1)
    judged = (seconds >= MIN_UNITS_SECONDS) & (np.maximum(np.abs(motion), np.abs(mean_vx)) >= MIN_UNITS_SPEED)
    ratio = mean_vx / np.where(motion != 0, motion, np.nan)
    wrong = np.flatnonzero(judged & ~((ratio >= 1 / MAX_SPEED_RATIO) & (ratio <= MAX_SPEED_RATIO)))
    if not wrong.size:
        return
    k = int(wrong[np.argmin(source_row[starts[wrong]])])  # the first such track in the file
    first = int(starts[k])
    path = rec.path("tracks")
    raise InputError(
        path,
        f"vehicle {cols['id'][first]}: xVelocity averages {mean_vx[k]:.2f} m/s but its x moves "
        f"{motion[k]:.2f} m/s over frames {frame[first]}..{frame[last[k]]} at the recordingMeta's "
        f"frameRate {frame_rate:g} Hz",
        line=_line(path, int(source_row[first])),
        column="xVelocity",
        expected=f"xVelocity (m/s) within a factor {MAX_SPEED_RATIO:g} of the motion of x (m): "
        "velocities in km/h, positions in feet or a wrong frameRate disagree",
    )


def last_lane_id(markings: Mapping[int, Sequence[float]]) -> int | None:
    """The largest laneId highD gives with these lane markings, None when a direction has fewer than two.

    highD numbers the areas across the road from the top of the image: 1 the upper road edge, 2 … U
    the lanes between the U upperLaneMarkings, U + 1 the median, U + 2 … U + L the lower lanes,
    U + L + 1 the lower road edge."""
    upper, lower = len(markings[UPPER]), len(markings[LOWER])
    return upper + lower + 1 if upper >= 2 and lower >= 2 else None


def _check_lanes(path: Path, meta: _Meta, cols: dict[str, np.ndarray], source_row: np.ndarray) -> None:
    """Refuse a laneId that is no area of highD's numbering (-1, 0, 10**6): lane-change labels come
    from changes of laneId (pipeline/labels.py), so one such row would be a lane change that never
    happened. A road edge, the median or the other carriageway's lane is kept: a real recording may
    place a vehicle there (a breakdown on the shoulder, a box across a marking), and refusing the
    whole recording for it would lose it. ``cols``, ``source_row`` [N]."""
    last = last_lane_id(meta.markings)
    lane = cols["laneId"]
    bad = np.flatnonzero((lane < 1) | (lane > (INT32_MAX if last is None else last)))
    if not bad.size:
        return
    k = int(bad[np.argmin(source_row[bad])])  # the first in the file
    if last is None:
        expected = "a lane id >= 1 (highD numbers lanes from the top of the image)"
    else:
        expected = (
            f"a highD lane id, 1 to {last} (road edges, lanes and median numbered from the top of the "
            f"image across the recordingMeta's {len(meta.markings[UPPER])} upper and "
            f"{len(meta.markings[LOWER])} lower lane markings)"
        )
    raise InputError(
        path,
        f"laneId is {lane[k]} for vehicle {cols['id'][k]}",
        line=_line(path, int(source_row[k])),
        column="laneId",
        expected=expected,
    )


def _classes(meta_table: pa.Table, path: Path) -> tuple[list[str], np.ndarray]:
    """Lower-cased class names (``Car`` → ``car``) as (dictionary, code int32 [M] per meta row);
    a class of blanks only is refused at its line of ``path`` (tracksMeta)."""
    lowered = pc.utf8_lower(pc.utf8_trim_whitespace(meta_table.column("class").combine_chunks()))
    blank = np.flatnonzero(np.asarray(pc.equal(lowered, "")))
    if blank.size:
        raise InputError(
            path, "class is blank", line=_line(path, int(blank[0])), column="class", expected="Car or Truck"
        )
    encoded = pc.dictionary_encode(lowered)
    return encoded.dictionary.to_pylist(), encoded.indices.to_numpy().astype(np.int32)


def road_frame(direction: np.ndarray, u: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Image-frame (y down) vectors ``(u, v)`` → the road frame of each row's driving direction.

    All arrays ``[N]``; ``direction`` is highD's drivingDirection (1 upper, 2 lower). Lower
    (+x travel): ``(u, −v)``; upper (−x travel): ``(−u, +v)``. The same for positions,
    velocities and accelerations (a fixed rotation/reflection, no offset).
    """
    sign = np.where(direction == LOWER, 1.0, -1.0)
    return sign * u + 0.0, -sign * v + 0.0  # + 0.0: no negative zeros


def heading_from_velocity(vx: np.ndarray, vy: np.ndarray, min_speed: float = HEADING_MIN_SPEED) -> np.ndarray:
    """``atan2(vy, |vx|)`` where the speed exceeds ``min_speed`` (m/s), else 0. Arrays ``[N]``.

    Each recording is one driving direction in its own road frame, so every vehicle travels along
    +x: a negative ``vx`` is measurement noise of a (nearly) standing vehicle, not a vehicle turned
    round, and must not flip its heading (and with it the sign of its longitudinal acceleration)."""
    moving = np.hypot(vx, vy) > min_speed
    return np.where(moving, np.arctan2(vy, np.abs(vx)), 0.0) + 0.0


def road_lane_markings(raw: Sequence[float], direction: int) -> list[float]:
    """Raw image-y lane markings → road-frame y (m), sorted ascending (right to left)."""
    sign = 1.0 if direction == UPPER else -1.0
    return sorted(float(sign * v) for v in raw)


def _read_one(
    rec: Recording, name_prefix: str
) -> tuple[dict[str, Any], dict[str, track_table.RecordingMeta]]:
    """Columns (numpy, with ``recording`` as names + codes) and metadata of one highD recording."""
    for kind in KINDS:
        if not rec.path(kind).is_file():
            reason = not_a_file(rec.path(kind))
            what = f"{'tracks' if kind == 'tracks' else 'companion'} file of highD recording {rec.prefix!r}"
            raise InputError(
                rec.path(kind),
                f"missing {what}{reason.removeprefix('no such file')}"
                if reason.startswith("no such file")
                else f"{what}: {reason}",
                expected=f"a file {rec.path(kind).name}"
                + (f" beside {rec.path('tracks').name}" if kind != "tracks" else ""),
            )
    meta = _read_recording_meta(rec.path("recordingMeta"))
    meta_table = _read_csv(rec.path("tracksMeta"), TRACKS_META_COLUMNS, "tracksMeta")
    tracks = _read_csv(rec.path("tracks"), TRACKS_COLUMNS, "tracks")
    return convert_tracks(rec, name_prefix, meta, meta_table, tracks)


def convert_tracks(
    rec: Recording,
    name_prefix: str,
    meta: _Meta,
    meta_table: pa.Table,
    tracks: pa.Table,
    *,
    all_tracks: bool = True,
) -> tuple[dict[str, Any], dict[str, track_table.RecordingMeta]]:
    """:func:`_read_one` after parsing: the parsed ``tracks`` rows (the whole file, or with
    ``all_tracks`` False a block of whole tracks, whose errors name rows of the block, as
    io_adapters/datasets/highd/stream.py reads a long file) converted."""
    tracks_path = rec.path("tracks")
    cols, source_row = _dedupe(tracks_path, _numpy(tracks, TRACKS_COLUMNS))
    _report_dropped(tracks_path, tracks.num_rows, source_row, all_tracks)
    _check_ranges(tracks_path, cols, source_row, meta.frame_rate)
    row_meta, direction = _check_meta(rec, meta_table, cols, source_row, all_tracks)
    _check_direction(rec, cols, row_meta, direction)
    _check_speed_units(rec, cols, source_row, meta.frame_rate)
    _check_lanes(tracks_path, meta, cols, source_row)
    class_names, class_codes = _classes(meta_table, rec.path("tracksMeta"))

    length, width = cols["width"], cols["height"]
    x, y = road_frame(direction, cols["x"] + length / 2, cols["y"] + width / 2)
    vx, vy = road_frame(direction, cols["xVelocity"], cols["yVelocity"])
    ax, ay = road_frame(direction, cols["xAcceleration"], cols["yAcceleration"])
    names = [f"{name_prefix}-{rec.prefix}-{DIRECTION_NAMES[d]}" for d in (UPPER, LOWER)]
    out: dict[str, Any] = {
        "recording_names": names,
        "recording_codes": (direction == LOWER).astype(np.int32),  # index into names
        "class_names": class_names,
        "class_codes": class_codes[row_meta],
        "track_id": cols["id"],
        "frame": cols["frame"],
        "time_ns": np.rint(cols["frame"] / meta.frame_rate * 1e9).astype(np.int64),
        "x": x,
        "y": y,
        "heading": heading_from_velocity(vx, vy),
        "vx": vx,
        "vy": vy,
        "ax": ax,
        "ay": ay,
        "length": length,
        "width": width,
        "lane_id": cols["laneId"],
    }
    for source, target in NEIGHBOURS.items():
        out[target] = cols[source]  # 0 (none) becomes null in _concat
    files = [str(p) for p in rec.paths]
    present = set(np.unique(direction).tolist())
    recs: dict[str, track_table.RecordingMeta] = {}
    for d, name in zip((UPPER, LOWER), names, strict=True):
        if d not in present:
            continue
        sign = 1.0 if d == LOWER else -1.0
        recs[name] = track_table.RecordingMeta(
            frame_rate=meta.frame_rate,
            coordinate_frame="road",
            source_files=files,
            extra={
                "dataset": "highD",
                "recording_id": meta.recording_id,
                "location_id": meta.location_id,
                "speed_limit_mps": meta.speed_limit if meta.speed_limit > 0 else None,
                "driving_direction": d,
                "direction": DIRECTION_NAMES[d],
                "lane_markings_y": road_lane_markings(meta.markings[d], d),
                "lane_markings_raw": meta.markings[d],
                "road_from_image": [[sign, 0.0], [0.0, -sign]],
            },
        )
    return out, recs


# --------------------------------------------------------------------------------------------
# public entry point


def read(paths: Sequence[str | Path], *, recording_prefix: str = "highd", **_: Any) -> pa.Table:
    """Read highD recordings (any of their files, or directories of them) into one track table.

    Each recording ``NN`` gives ``{recording_prefix}-NN-upper`` and ``-lower`` (only those with
    vehicles). Other options (e.g. ``topic``, meant for logs) are ignored. The table is validated.
    """
    if isinstance(paths, (str, Path)):
        paths = [paths]
    recs = recordings(paths)
    parts = []
    recording_meta: dict[str, track_table.RecordingMeta] = {}
    for rec in progress(recs, desc="highD", total=len(recs), unit="recording"):
        columns, metas = _read_one(rec, recording_prefix)
        clash = set(metas) & set(recording_meta)
        if clash:
            raise InputError(
                rec.path("tracks"),
                f"recording name {sorted(clash)[0]!r} is given by two inputs",
                expected="highD recordings with distinct numbers",
            )
        recording_meta.update(metas)
        parts.append(columns)
    table = track_table.build_table(
        _concat(parts),
        track_table.TableMeta(FORMAT, recording_meta, [f for rec in recs for f in map(str, rec.paths)]),
    )
    track_table.validate(table, source=", ".join(str(p) for p in paths))
    return table


def _dictionary(parts: list[dict[str, Any]], names_key: str, codes_key: str) -> pa.DictionaryArray:
    """Merge per-recording (names, codes) pairs into one dictionary array (no per-row strings)."""
    merged: list[str] = []
    chunks = []
    for part in parts:
        remap = np.empty(len(part[names_key]), dtype=np.int32)
        for i, name in enumerate(part[names_key]):
            if name not in merged:
                merged.append(name)
            remap[i] = merged.index(name)
        chunks.append(remap[part[codes_key]])
    return pa.DictionaryArray.from_arrays(
        pa.array(np.concatenate(chunks).astype(np.int32)), pa.array(merged, type=pa.string())
    )


def _concat(parts: list[dict[str, Any]]) -> dict[str, Any]:
    skip = {"recording_names", "recording_codes", "class_names", "class_codes"}
    columns: dict[str, Any] = {
        name: np.concatenate([p[name] for p in parts]) if len(parts) > 1 else parts[0][name]
        for name in parts[0]
        if name not in skip
    }
    for name in track_table.NEIGHBOUR_COLUMNS:
        ids = columns[name]
        columns[name] = pa.array(ids, mask=ids == 0, type=pa.int64())  # highD 0 = no neighbour
    columns["recording"] = _dictionary(parts, "recording_names", "recording_codes")
    columns["object_class"] = _dictionary(parts, "class_names", "class_codes")
    return columns
