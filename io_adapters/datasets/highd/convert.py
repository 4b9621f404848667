"""highD tracks → track-table columns: each recording split by ``drivingDirection`` into
``highd-NN-upper`` (direction 1, drives towards −x in the image) and ``highd-NN-lower`` (direction 2,
towards +x), each in its road frame (docs/design.md §1: x along the direction of travel, y left).

* highD ``x, y`` are the bounding box's top-left corner in image-like coordinates (y down),
  ``width`` is the extent along x (vehicle length), ``height`` along y (vehicle width);
  the centre is ``(x + width/2, y + height/2)``.
* lower (+x travel): road = ``(x_img, −y_img)``; upper (−x travel): road = ``(−x_img, +y_img)``
  (the y-up frame turned by 180°). Velocities and accelerations map the same way.

The checks run first (checks.py, meta_checks.py), on the whole file or on a block of whole tracks.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from datetime import datetime
from typing import Any

import numpy as np
import pyarrow as pa

from lanecast.io_adapters.contracts import track_schema, track_table
from lanecast.io_adapters.contracts.track_runs import run_bounds, run_groups
from lanecast.io_adapters.cores import map_columns
from lanecast.io_adapters.datasets.highd import checks, meta_checks
from lanecast.io_adapters.datasets.highd.columns import (
    DIRECTION_NAMES,
    LOWER,
    NEIGHBOURS,
    TRACKS_COLUMNS,
    UPPER,
)
from lanecast.io_adapters.datasets.highd.meta import Meta
from lanecast.io_adapters.datasets.highd.sniff import Recording
from lanecast.io_adapters.datasets.highd.start_time import NOTE, start_ns

HEADING_MIN_SPEED = 0.5  # m/s: below it the heading is 0 (direction of travel)


def road_frame(direction: np.ndarray, u: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Image-frame (y down) vectors ``(u, v)`` [N] → the road frame of each row's drivingDirection:
    lower ``(u, −v)``, upper ``(−u, +v)``; the same for positions, velocities and accelerations."""
    sign = np.where(direction == LOWER, 1.0, -1.0)
    return sign * u + 0.0, -sign * v + 0.0  # + 0.0: no negative zeros


def heading_from_velocity(vx: np.ndarray, vy: np.ndarray, min_speed: float = HEADING_MIN_SPEED) -> np.ndarray:
    """``atan2(vy, |vx|)`` where the speed exceeds ``min_speed`` (m/s), else 0. Arrays ``[N]``.

    Every vehicle travels along +x of its road frame: a negative ``vx`` is measurement noise of a
    (nearly) standing vehicle, not a vehicle turned round, and must not flip its heading."""
    moving = np.hypot(vx, vy) > min_speed
    return np.where(moving, np.arctan2(vy, np.abs(vx)), 0.0) + 0.0


def road_lane_markings(raw: list[float], direction: int) -> list[float]:
    """Raw image-y lane markings → road-frame y (m), sorted ascending (right to left)."""
    sign = 1.0 if direction == UPPER else -1.0
    return sorted(float(sign * v) for v in raw)


@dataclass(frozen=True)
class CheckedTracks:
    """A recording's tracks (or a block of whole tracks) after every check: the columns of
    ``TRACKS_COLUMNS`` sorted by (id, frame) [N], each row's tracksMeta row and drivingDirection
    [N], and the lower-cased class names with each tracksMeta row's code into them."""

    cols: dict[str, np.ndarray]
    row_meta: np.ndarray
    direction: np.ndarray
    class_names: list[str]
    class_codes: np.ndarray
    frame_rate: float


def check_tracks(
    rec: Recording, meta: Meta, meta_table: pa.Table, tracks: pa.Table, *, all_tracks: bool = True
) -> CheckedTracks:
    """The parsed ``tracks`` rows, checked: the whole file, or with ``all_tracks`` False a block of
    whole tracks (whose errors name rows of the block)."""
    tracks_path = rec.path("tracks")
    # each column copied out of the parser's blocks into one array, the columns on the free cores
    arrays = map_columns(lambda name: tracks.column(name).to_numpy(), TRACKS_COLUMNS)
    raw = dict(zip(TRACKS_COLUMNS, arrays, strict=True))
    cols, source_row = checks.dedupe(tracks_path, raw)
    checks.report_dropped(tracks_path, tracks.num_rows, source_row, all_tracks)
    checks.check_ranges(tracks_path, cols, source_row, meta.frame_rate)
    row_meta, direction = meta_checks.check_meta(rec, meta_table, cols, source_row, all_tracks)
    meta_checks.check_direction(rec, cols, row_meta, direction)
    meta_checks.check_speed_units(rec, cols, source_row, meta.frame_rate)
    checks.check_lanes(tracks_path, meta, cols, source_row)
    class_names, class_codes = meta_checks.classes(meta_table, rec)
    return CheckedTracks(cols, row_meta, direction, class_names, class_codes, meta.frame_rate)


def track_columns(checked: CheckedTracks, rows: np.ndarray | None = None) -> dict[str, Any]:
    """The track-table columns (numpy; ``recording_codes`` index the names of
    :func:`recording_metas`, ``class_codes`` ``checked.class_names``) of ``rows`` [M] of
    ``checked``, in that order, or of all its rows."""
    cols = checked.cols if rows is None else {name: values[rows] for name, values in checked.cols.items()}
    direction = checked.direction if rows is None else checked.direction[rows]
    row_meta = checked.row_meta if rows is None else checked.row_meta[rows]
    length, width = cols["width"], cols["height"]
    x, y = road_frame(direction, cols["x"] + length / 2, cols["y"] + width / 2)
    vx, vy = road_frame(direction, cols["xVelocity"], cols["yVelocity"])
    ax, ay = road_frame(direction, cols["xAcceleration"], cols["yAcceleration"])
    out: dict[str, Any] = {
        "recording_codes": (direction == LOWER).astype(np.int32),  # index into names
        "class_codes": checked.class_codes[row_meta],
        "track_id": cols["id"],
        "frame": cols["frame"],
        "time_ns": np.rint(cols["frame"] / checked.frame_rate * 1e9).astype(np.int64),
        **{"x": x, "y": y, "heading": heading_from_velocity(vx, vy), "vx": vx, "vy": vy, "ax": ax, "ay": ay},
        "length": length,
        "width": width,
        "lane_id": cols["laneId"],
    }
    for source, target in NEIGHBOURS.items():
        out[target] = cols[source]  # 0 (none) becomes null in concat
    return out


def recording_metas(
    rec: Recording, name_prefix: str, meta: Meta, direction: np.ndarray
) -> tuple[list[str], dict[str, track_table.RecordingMeta]]:
    """The recording names ``[upper, lower]`` and the metadata of those with rows."""
    names = [f"{name_prefix}-{rec.prefix}-{DIRECTION_NAMES[d]}" for d in (UPPER, LOWER)]
    files = [str(p) for p in rec.paths]
    recs: dict[str, track_table.RecordingMeta] = {}
    for d, name in zip((UPPER, LOWER), names, strict=True):
        if not (direction == d).any():
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
                **_start_fields(meta.start),
            },
        )
    return names, recs


def convert_tracks(
    rec: Recording,
    name_prefix: str,
    meta: Meta,
    meta_table: pa.Table,
    tracks: pa.Table,
    *,
    all_tracks: bool = True,
) -> tuple[dict[str, Any], dict[str, track_table.RecordingMeta]]:
    """Checked and converted columns (numpy, ``recording`` and ``object_class`` as names + codes)
    and the recordings' metadata, of the parsed ``tracks`` rows: the whole file, or with
    ``all_tracks`` False a block of whole tracks (whose errors name rows of the block)."""
    checked = check_tracks(rec, meta, meta_table, tracks, all_tracks=all_tracks)
    names, recs = recording_metas(rec, name_prefix, meta, checked.direction)
    return {"recording_names": names, "class_names": checked.class_names, **track_columns(checked)}, recs


def direction_parts(
    checked: CheckedTracks, names: list[str], part_rows: int
) -> list[tuple[int, list[np.ndarray]]]:
    """The rows of ``checked`` in the track table's order, as ``(code, parts)`` per recording
    (``code`` indexes ``names``, ``[upper, lower]``; recordings in the order of their names), each
    recording's rows [M] cut into parts of whole tracks of at most ``part_rows`` rows (a longer
    track is a part of its own)."""
    out = []
    for code in sorted(range(2), key=names.__getitem__):
        rows = np.flatnonzero(checked.direction == (UPPER, LOWER)[code])
        if not rows.size:
            continue
        bounds = run_bounds(checked.cols["id"][rows])
        cuts = bounds[run_groups(bounds, part_rows)].tolist()
        out.append((code, [rows[lo:hi] for lo, hi in itertools.pairwise(cuts)]))
    return out


def _start_fields(start: datetime | None) -> dict[str, Any]:
    """The recording's start (drive logs written from it begin there), where recordingMeta gives it."""
    if start is None:
        return {}
    return {"start_time": start.isoformat(), "start_time_ns": start_ns(start), "start_time_note": NOTE}


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


def concat(parts: list[dict[str, Any]]) -> dict[str, Any]:
    """The track-table columns of the converted ``parts`` (:func:`convert_tracks`), in order."""
    skip = {"recording_names", "recording_codes", "class_names", "class_codes"}
    columns: dict[str, Any] = {
        name: np.concatenate([p[name] for p in parts]) if len(parts) > 1 else parts[0][name]
        for name in parts[0]
        if name not in skip
    }
    for name in track_table.NEIGHBOUR_COLUMNS:
        columns[name] = track_schema.neighbour_ids(columns[name])  # highD 0 = no neighbour
    columns["recording"] = _dictionary(parts, "recording_names", "recording_codes")
    columns["object_class"] = _dictionary(parts, "class_names", "class_codes")
    return columns
