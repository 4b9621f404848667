"""Cross-checks of highD's ``NN_tracksMeta.csv`` and ``NN_recordingMeta.csv`` against the tracks:
the id sets, each vehicle's frames, its driving direction against its velocity, and its velocity
against the motion of its position at the stated frame rate (units). A disagreement names the line
of the row that states it.

``cols`` are the deduplicated tracks sorted by (id, frame) [N], ``source_row`` [N] their rows in
the file.
"""

from __future__ import annotations

import numpy as np
import pyarrow as pa

from lanecast.io_adapters.contracts.track_runs import run_bounds
from lanecast.io_adapters.datasets.csv_errors import row_line
from lanecast.io_adapters.datasets.highd.columns import DIRECTION_NAMES, LOWER, TRACKS_META_COLUMNS, UPPER
from lanecast.io_adapters.datasets.highd.sniff import Recording
from lanecast.io_adapters.errors import InputError

WRONG_WAY_MPS = 1.0  # a track whose mean speed along its road frame's x is below minus this drives backwards
MAX_SPEED_RATIO = 1.5  # mean xVelocity over the motion of x: further apart, one of them is in other units
MIN_UNITS_SPEED = 3.0  # m/s: slower tracks' ratio is noise (stop and go)
MIN_UNITS_SECONDS = 1.0  # s: shorter tracks' ratio is noise


def check_meta(
    rec: Recording,
    meta_table: pa.Table,
    cols: dict[str, np.ndarray],
    source_row: np.ndarray,
    all_tracks: bool = True,
) -> tuple[np.ndarray, np.ndarray]:
    """Map each track row to its tracksMeta row: ``(meta_row int64 [N], direction int64 [N])``;
    InputError on any disagreement (drivingDirection, id sets, initialFrame, finalFrame, numFrames).
    With ``all_tracks`` False (a block of the tracks) a meta id without rows is not refused."""
    meta_path, tracks_path = rec.path("tracksMeta"), rec.path("tracks")
    m = {
        name: meta_table.column(name).to_numpy()
        for name, kind in TRACKS_META_COLUMNS.items()
        if kind != "str"
    }
    direction = m["drivingDirection"]
    bad = np.flatnonzero((direction != UPPER) & (direction != LOWER))
    if bad.size:
        raise InputError(
            meta_path,
            f"drivingDirection is {direction[bad[0]]}",
            line=row_line(meta_path, int(bad[0])),
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
            line=row_line(meta_path, row),
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
            line=row_line(tracks_path, int(source_row[starts[k]])),
            column="id",
            expected=f"an id listed in {meta_path.name}",
        )
    unused = np.setdiff1d(meta_ids, track_ids) if all_tracks else meta_ids[:0]  # a block: some tracks
    if unused.size:
        raise InputError(
            meta_path,
            f"vehicle id {unused[0]} has no rows in {tracks_path.name}",
            line=row_line(meta_path, int(np.flatnonzero(meta_ids == unused[0])[0])),
            column="id",
            expected=f"an id present in {tracks_path.name}",
        )
    meta_rows = meta_order[pos]  # meta row of each track
    observed = {"initialFrame": frames[starts], "finalFrame": frames[ends - 1], "numFrames": ends - starts}
    for name, got in observed.items():
        stated = m[name][meta_rows]
        wrong = np.flatnonzero(stated != got)
        if wrong.size:
            k = int(wrong[0])
            raise InputError(
                meta_path,
                f"{name} {stated[k]} for vehicle {track_ids[k]} disagrees with {tracks_path.name} "
                f"(frames {frames[starts[k]]}..{frames[ends[k] - 1]}, {ends[k] - starts[k]} rows)",
                line=row_line(meta_path, int(meta_rows[k])),
                column=name,
                expected=f"{got[k]}",
            )
    row_meta = np.repeat(meta_rows, ends - starts)
    return row_meta, direction[row_meta]


def check_direction(
    rec: Recording, cols: dict[str, np.ndarray], row_meta: np.ndarray, direction: np.ndarray
) -> None:
    """Refuse a vehicle whose drivingDirection contradicts its xVelocity: in its road frame it would
    drive backwards (a tracksMeta row that disagrees with the tracks, never a real vehicle).
    ``row_meta`` and ``direction`` [N] per row (:func:`check_meta`)."""
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
            line=row_line(meta_path, int(row_meta[k])),
            column="drivingDirection",
            expected=f"{UPPER if d == LOWER else LOWER}, the direction the vehicle drives",
        )


def check_speed_units(
    rec: Recording, cols: dict[str, np.ndarray], source_row: np.ndarray, frame_rate: float
) -> None:
    """Refuse a vehicle whose mean xVelocity disagrees with the motion of its x over its frames at
    the recordingMeta's frameRate by more than MAX_SPEED_RATIO: velocities in km/h, positions in
    feet or a wrong frameRate, each converted as it came, give tracks whose x and vx disagree."""
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
        line=row_line(path, int(source_row[first])),
        column="xVelocity",
        expected=f"xVelocity (m/s) within a factor {MAX_SPEED_RATIO:g} of the motion of x (m): "
        "velocities in km/h, positions in feet or a wrong frameRate disagree",
    )


def classes(meta_table: pa.Table, rec: Recording) -> tuple[list[str], np.ndarray]:
    """Lower-cased class names (``Car`` → ``car``) as (dictionary, code int32 [M] per meta row);
    a class of blanks only is refused at its line of tracksMeta."""
    lowered = [
        ("" if name is None else str(name)).strip().lower() for name in meta_table.column("class").to_pylist()
    ]
    blank = [row for row, name in enumerate(lowered) if not name]
    if blank:
        path = rec.path("tracksMeta")
        raise InputError(
            path,
            "class is blank",
            line=row_line(path, blank[0]),
            column="class",
            expected="Car or Truck",
        )
    names = list(dict.fromkeys(lowered))  # in order of first appearance
    code = {name: i for i, name in enumerate(names)}
    return names, np.array([code[name] for name in lowered], dtype=np.int32)
