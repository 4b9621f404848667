"""Checks of parsed NGSIM cells: each cell a finite number (integers whole), values in range, and
lengths in NGSIM's feet; InputError at the first bad cell in file order, naming line and column.

``columns`` hold the used columns [n] (lower-case names) in file order; ``names`` are the file's
column names (the header, or TXT_COLUMNS); ``header`` says the first line is a header.
"""

from __future__ import annotations

import csv
import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from lanecast.io_adapters.contracts import track_table
from lanecast.io_adapters.datasets.csv_errors import REPEATED_HEADER, is_header, line_spans, row_line, shown
from lanecast.io_adapters.datasets.ngsim.columns import FEET, FRAME_NS, INTEGER_COLUMNS
from lanecast.io_adapters.errors import InputError

NAN_LITERALS = ("nan", "na", "n/a", "null", "#n/a", "")
EXACT_FLOAT_INT = 2**53  # integers read through float64 are exact only below this
MAX_FRAME_ID = 2**62 // FRAME_NS  # time_ns = Frame_ID * 1e8 stays well inside int64
INT32_MAX = 2**31 - 1
FLOAT32_MAX = float(np.finfo(np.float32).max)
MAX_POSITION_FT = 1e9  # Local_X/Local_Y beyond this are no road (NGSIM's are below 1e4)
MAX_SIZE_FT = 1000.0  # v_Length, v_Width: the longest road trains are under 200 ft
MIN_MEDIAN_CAR_FT = (
    8.0  # ft: no car is shorter (a Smart Fortwo is 8.8 ft); a file whose median car is, is in metres
)


def integral(columns: dict[str, np.ndarray]) -> bool:
    """Every integer column holds whole numbers."""
    return all(np.array_equal(columns[n], np.round(columns[n])) for n in INTEGER_COLUMNS)


def _line(path: Path, row: int, header: bool) -> int:
    return row_line(path, row, header=header, whitespace=not header)


def check_values(path: Path, columns: dict[str, np.ndarray], names: Sequence[str], *, header: bool) -> None:
    """Raise InputError at the first cell (row-major) of ``columns`` that is not a finite number
    (float64, NaN where a cell did not parse); the cell's text is read back from its line."""
    first_row, first_col = None, ""
    for name in columns:
        values = columns[name]
        bad = ~np.isfinite(values)
        if name in INTEGER_COLUMNS:
            bad |= np.isfinite(values) & (values != np.round(values))
        if bad.any():
            row = int(np.flatnonzero(bad)[0])
            if first_row is None or row < first_row:
                first_row, first_col = row, name
    if first_row is None:
        return
    data = path.read_bytes()
    line = _line(path, first_row, header)
    starts, ends = line_spans(data)
    text = data[starts[line - 1] : ends[line - 1]].decode("utf-8", errors="replace")
    cells = next(csv.reader([text])) if header else text.split()  # "40,5" is one cell
    if is_header(cells, names):  # the CSV's header line, or the .txt columns' names, again
        raise InputError(
            path,
            REPEATED_HEADER
            if header
            else "column names in the data (a header line; two files joined into one?)",
            line=line,
            expected="one header line, at line 1" if header else "18 numbers a line, no header",
        )
    index = [n.lower() for n in names].index(first_col)
    cell = cells[index].strip() if index < len(cells) else ""
    if cell == "":
        problem = "empty cell"
    elif cell.lower() in NAN_LITERALS:
        problem = f"missing value {shown(cell)}"
    elif cell.lower().lstrip("+-") in {"inf", "infinity"}:
        problem = f"infinite value {shown(cell)}"
    elif math.isfinite(columns[first_col][first_row]):
        problem = f"{shown(cell)} is not a whole number"
    else:
        problem = f"{shown(cell)} is not a finite number"
    expected = "an integer" if first_col in INTEGER_COLUMNS else "a finite number"
    raise InputError(path, problem, line=line, column=names[index], expected=expected)


def checked_ranges(
    path: Path, columns: dict[str, np.ndarray], names: Sequence[str], *, header: bool
) -> dict[str, np.ndarray]:
    """The columns with the integer ones as int64, after refusing values that parse but cannot be
    right: integers read through float64 beyond 2^53, a Frame_ID whose time overflows, a
    Global_Time beyond 2^53 ms, a negative neighbour id, a size that is not positive, a negative
    speed, a Lane_ID that is negative or outside int32, a value beyond float32 or the track table's
    bounds, lengths in metres."""
    out = dict(columns)
    bad_rows: list[tuple[int, str, str]] = []

    def flag(name: str, bad: np.ndarray, expected: str) -> None:
        rows = np.flatnonzero(bad)
        if rows.size:
            bad_rows.append((int(rows[0]), name, expected))

    for name in INTEGER_COLUMNS:
        if out[name].dtype.kind == "f":
            flag(
                name,
                np.abs(out[name]) >= EXACT_FLOAT_INT,
                "an integer written without a fraction, or below 2^53",
            )
    if not bad_rows:
        for name in INTEGER_COLUMNS:
            out[name] = out[name].astype(np.int64)
        flag("vehicle_id", out["vehicle_id"] < 0, "a vehicle id >= 0")  # NGSIM numbers from 1
        for name in ("preceding", "following"):
            flag(name, out[name] < 0, "a vehicle id >= 0 (0 means no vehicle)")
        flag("frame_id", (out["frame_id"] < 0) | (out["frame_id"] > MAX_FRAME_ID), f"0 to {MAX_FRAME_ID}")
        flag(
            "global_time", (out["global_time"] < 0) | (out["global_time"] >= EXACT_FLOAT_INT), "0 to 2^53 ms"
        )
        # NGSIM numbers lanes from 1 (0 and >= 10 on the arterials' intersections and bays); a
        # negative one on a row or two would be two lane changes that never happened
        flag("lane_id", (out["lane_id"] < 0) | (out["lane_id"] > INT32_MAX), "a lane id >= 0 within int32")
        size = f"> 0 and <= {MAX_SIZE_FT:g} ft"  # no road vehicle is longer than a few hundred feet
        flag("v_length", ~((out["v_length"] > 0) & (out["v_length"] <= MAX_SIZE_FT)), f"a length {size}")
        flag("v_width", ~((out["v_width"] > 0) & (out["v_width"] <= MAX_SIZE_FT)), f"a width {size}")
        flag("v_vel", ~(out["v_vel"] >= 0), "a speed >= 0 ft/s")
        for name in ("v_length", "v_width", "v_vel", "v_acc"):  # float32 in the table
            flag(name, np.abs(out[name]) > FLOAT32_MAX / FEET, "a value within float32")
        limit = track_table.MAX_POSITION_M / FEET  # the track table's bounds (track_table.RANGES), in feet
        flag("v_vel", np.abs(out["v_vel"]) > limit, f"a speed within ±{limit:.4g} ft/s")
        flag("v_acc", np.abs(out["v_acc"]) > limit, f"an acceleration within ±{limit:.4g} ft/s^2")
        for name in ("local_x", "local_y"):  # differences over 0.1 s must stay float32 speeds
            flag(name, np.abs(out[name]) > MAX_POSITION_FT, f"a position within ±{MAX_POSITION_FT:g} ft")
    if not bad_rows:
        _check_feet(path, out, names, header=header)
        return out
    row, name, expected = min(bad_rows)
    column = next(n for n in names if n.strip().lower() == name)
    raise InputError(
        path,
        f"{column} is {columns[name][row]}",
        line=_line(path, row, header),
        column=column,
        expected=expected,
    )


def _check_feet(path: Path, columns: dict[str, np.ndarray], names: Sequence[str], *, header: bool) -> None:
    """Refuse a file whose vehicle lengths are metres, not NGSIM's feet: cars (``v_Class`` 2; all
    vehicles if none is) shorter than ``MIN_MEDIAN_CAR_FT`` at the median would be read 3.3 times
    too small, and their positions and speeds with them. InputError at the first such car's line."""
    length = columns["v_length"]
    cars = columns["v_class"] == 2
    pool = cars if cars.any() else np.ones(length.size, dtype=bool)
    median = float(np.median(length[pool])) if pool.any() else MIN_MEDIAN_CAR_FT
    if median >= MIN_MEDIAN_CAR_FT:
        return
    row = int(np.flatnonzero(pool & (length < MIN_MEDIAN_CAR_FT))[0])
    raise InputError(
        path,
        f"the median {'car' if cars.any() else 'vehicle'} length is {median:g}, no car is under "
        f"{MIN_MEDIAN_CAR_FT:g} ft: lengths (and so positions and speeds) look like metres",
        line=_line(path, row, header),
        column=next(n for n in names if n.strip().lower() == "v_length"),
        expected=f"NGSIM's feet (cars of {MIN_MEDIAN_CAR_FT:g} ft and more)",
    )
