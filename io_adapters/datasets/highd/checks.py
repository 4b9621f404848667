"""Checks of the parsed highD tracks: repeated rows, values that parse but cannot be right, and lane
ids outside highD's numbering; each refused at its line of ``NN_tracks.csv``.

The columns come sorted by (id, frame) with ``source_row`` [N], each row's index in the file, so that
an error names the first bad row in file order.
"""

from __future__ import annotations

import sys
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from lanecast.io_adapters.contracts import track_table
from lanecast.io_adapters.datasets.csv_errors import record_lines, row_line
from lanecast.io_adapters.datasets.highd.columns import LOWER, NEIGHBOURS, TRACKS_COLUMNS, UPPER
from lanecast.io_adapters.datasets.highd.meta import Meta
from lanecast.io_adapters.errors import InputError

INT32_MAX = 2**31 - 1
FLOAT32_MAX = float(np.finfo(np.float32).max)  # sizes, velocities, accelerations are float32
MAX_POSITION_M = 1e9  # highD positions are image metres (below 1e3)
MAX_SIZE_M = 300.0  # width (length) and height (width): no road vehicle is longer than ~60 m
MAX_TIME_NS = 2**62  # time_ns = frame / frameRate * 1e9 must stay well inside int64


def dedupe(path: Path, cols: dict[str, np.ndarray]) -> tuple[dict[str, np.ndarray], np.ndarray]:
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
            lines = record_lines(path.read_bytes())[0][1:]
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


def report_dropped(path: Path, rows: int, kept: np.ndarray, lines_known: bool) -> None:
    """Say on stderr how many rows repeated an earlier (id, frame) identically and were dropped
    (a repair, never silent); ``kept`` [N] the file rows kept of ``rows``; with ``lines_known``
    (the whole file was parsed) the first dropped row's line is named."""
    dropped = rows - kept.size
    if not dropped:
        return
    where = ""
    if lines_known:
        first = int(np.flatnonzero(np.isin(np.arange(rows), kept, invert=True))[0])
        where = f" (the first at line {row_line(path, first)})"
    print(
        f"lanecast: {path}: dropped {dropped:,} row(s) repeating an earlier (id, frame) with the same "
        f"values{where}",
        file=sys.stderr,
    )


def check_ranges(path: Path, cols: dict[str, np.ndarray], source_row: np.ndarray, frame_rate: float) -> None:
    """Values that parse but cannot be right, refused at their line: a negative frame, a frame whose
    time overflows ``time_ns``, a negative neighbour id, a size that is not positive, a laneId
    outside int32, a value beyond float32 or the track table's bounds. ``cols`` [N] in any order,
    ``source_row`` [N]."""
    max_frame = MAX_TIME_NS / 1e9 * frame_rate
    frames = f"a frame from 0 to {max_frame:.4g} (frame / frameRate {frame_rate:g} Hz in ns within int64)"
    size = f"> 0 and <= {MAX_SIZE_M:g} m"
    checks = (
        ("frame", (cols["frame"] < 0) | (cols["frame"] > max_frame), frames),
        # highD numbers vehicles from 1: 0 is "no vehicle" in the neighbour columns (precedingId, …)
        ("id", cols["id"] < 1, "a vehicle id >= 1 (0 means no vehicle in the neighbour columns)"),
        *((n, cols[n] < 0, "a vehicle id >= 0 (0 means no vehicle)") for n in NEIGHBOURS),
        ("width", ~((cols["width"] > 0) & (cols["width"] <= MAX_SIZE_M)), f"a length {size}"),
        ("height", ~((cols["height"] > 0) & (cols["height"] <= MAX_SIZE_M)), f"a width {size}"),
        ("laneId", (cols["laneId"] < -INT32_MAX) | (cols["laneId"] > INT32_MAX), "a lane id within int32"),
        *(
            (n, np.abs(cols[n]) > MAX_POSITION_M, f"a position within ±{MAX_POSITION_M:g} m")
            for n in ("x", "y")
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
        raise InputError(path, f"{name} is {value}", line=row_line(path, row), column=name, expected=expected)


def last_lane_id(markings: Mapping[int, Sequence[float]]) -> int | None:
    """The largest laneId highD gives with these lane markings, None when a direction has fewer than two.

    highD numbers the areas across the road from the top of the image: 1 the upper road edge, 2 … U
    the lanes between the U upperLaneMarkings, U + 1 the median, U + 2 … U + L the lower lanes,
    U + L + 1 the lower road edge."""
    upper, lower = len(markings[UPPER]), len(markings[LOWER])
    return upper + lower + 1 if upper >= 2 and lower >= 2 else None


def check_lanes(path: Path, meta: Meta, cols: dict[str, np.ndarray], source_row: np.ndarray) -> None:
    """Refuse a laneId that is no area of highD's numbering (-1, 0, 10**6): lane-change labels come
    from changes of laneId (pipeline/labels.py), so one such row would be a lane change that never
    happened. A road edge, the median or the other carriageway's lane is kept: a real recording may
    place a vehicle there (a breakdown on the shoulder, a box across a marking)."""
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
        line=row_line(path, int(source_row[k])),
        column="laneId",
        expected=expected,
    )
