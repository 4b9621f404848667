"""A straightforward per-window implementation of the windows stage, as research code writes it.

Kept only as the benchmark's baseline and as an independent check of lanecast's vectorised stage
(benchmarks/bench_windows.py compares both, value by value). It loops over windows in Python and
looks rows up in pandas: per window, the target's history by frame, then per neighbour slot the
ids over the history and each neighbour's rows at those frames. It takes a 10 Hz table whose
neighbour id columns are filled (highD / the simulator), i.e. lanecast's ``neighbours="source"``.

It follows the windows contract of docs/design.md §2, written out again without lanecast's code:
- the window frame has its origin at T's centre at t0 and its x axis along the road: in a
  road-frame recording the recording's own axes (a translation only); elsewhere T's direction of
  travel over its history (the chord t0 - 2.9 s -> t0; if T moved less than 3 m, the chord over
  up to 10 s of gap-free past; if even that is under 3 m, the circular mean of T's heading over
  the history);
- a neighbour more than the neighbour range (100 m) ahead of or behind T at that history frame
  (along x in a road frame, else along T's heading at that frame) is no neighbour;
- a maneuver label's direction is T's lateral displacement across the lane change (±1 s around
  it), lateral relative to the road: +y in a road frame, else relative to the chord of the track
  over ±3 s around the change.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np
import pandas as pd

SLOT_COLUMNS = {  # tensor row -> source column (row 4 is the target)
    0: "left_preceding_id",
    1: "preceding_id",
    2: "right_preceding_id",
    3: "left_alongside_id",
    5: "right_alongside_id",
    6: "left_following_id",
    7: "right_following_id",
}
NEIGHBOUR_RANGE_M = 100.0
MIN_CHORD_M = 3.0
LONG_CHORD_FRAMES = 100


class Track:
    """One track: its frame-indexed rows and whether its recording is in a road frame."""

    def __init__(self, rows: pd.DataFrame, road_frame: bool) -> None:
        self.rows = rows
        self.road_frame = road_frame


def prepare(table_10hz: pd.DataFrame, coordinate_frames: Mapping[str, str]) -> dict[tuple[str, int], Track]:
    """One frame-indexed track per (recording, track); ``coordinate_frames``: recording -> its
    coordinate frame as the track table's metadata states it (``"road"`` or a world frame)."""
    df = table_10hz.copy()
    df["recording"] = df["recording"].astype(str)
    df["speed"] = np.hypot(df["vx"].astype(float), df["vy"].astype(float))
    heading = df["heading"].astype(float)
    df["lon_acc"] = df["ax"].astype(float) * np.cos(heading) + df["ay"].astype(float) * np.sin(heading)
    return {
        (str(key[0]), int(key[1])): Track(  # type: ignore[call-overload]
            g.set_index("frame"), coordinate_frames[str(key[0])] == "road"
        )
        for key, g in df.groupby(["recording", "track_id"], sort=False)
    }


def frame_heading(track: Track, t0: int) -> float:
    """Rotation of the window frame at ``t0`` in the source frame (rad)."""
    if track.road_frame:
        return 0.0
    rows = track.rows
    end: Any = rows.loc[t0]
    start: Any = rows.loc[t0 - 29]
    dx, dy = float(end["x"] - start["x"]), float(end["y"] - start["y"])
    if math.hypot(dx, dy) < MIN_CHORD_M:
        back = 0  # gap-free frames before t0, at most 10 s
        while back < LONG_CHORD_FRAMES and (t0 - back - 1) in rows.index:
            back += 1
        far: Any = rows.loc[t0 - back]
        dx, dy = float(end["x"] - far["x"]), float(end["y"] - far["y"])
    if math.hypot(dx, dy) < MIN_CHORD_M:
        hist = rows.loc[t0 - 29 : t0, "heading"].astype(float)
        return math.atan2(float(np.sin(hist).sum()), float(np.cos(hist).sum()))
    return math.atan2(dy, dx)


def lane_label(track: Track, frame: int) -> int:
    """Maneuver label of ``track`` at ``frame``: the nearest lane change within 2 s (20 frames)."""
    rows = track.rows
    lane = rows["lane_id"].to_numpy(dtype=float)
    frames = rows.index.to_numpy()
    known = ~np.isnan(lane)
    idx = np.flatnonzero(known[1:] & known[:-1] & (lane[1:] != lane[:-1])) + 1
    if idx.size == 0 or np.abs(frames[idx] - frame).min() > 20:
        return 0 if known[np.searchsorted(frames, frame)] else -1
    d = np.abs(frames[idx] - frame)
    i = int(idx[np.argmin(d)])  # ties: the earlier change
    last = len(frames) - 1
    before, after = max(i - 10, 0), min(i + 9, last)
    dx = float(rows["x"].iloc[after] - rows["x"].iloc[before])
    dy = float(rows["y"].iloc[after] - rows["y"].iloc[before])
    # Lateral relative to the road, not to the heading at the change (which during a lane change
    # points across the lanes): +y in a road frame, else across the track's ±3 s chord.
    h = 0.0
    if not track.road_frame:
        ref_before, ref_after = max(i - 30, 0), min(i + 29, last)
        h = math.atan2(
            float(rows["y"].iloc[ref_after] - rows["y"].iloc[ref_before]),
            float(rows["x"].iloc[ref_after] - rows["x"].iloc[ref_before]),
        )
    lateral = -math.sin(h) * dx + math.cos(h) * dy
    return 1 if lateral > 0 else (2 if lateral < 0 else 0)


def within_range(target: Any, other: Any, road_frame: bool) -> bool:
    """Whether ``other`` is at most the neighbour range ahead or behind ``target`` (same frame)."""
    dx, dy = other["x"] - target["x"], other["y"] - target["y"]
    if road_frame:
        lon = dx
    else:
        h = float(target["heading"])
        lon = math.cos(h) * dx + math.sin(h) * dy
    return abs(lon) <= NEIGHBOUR_RANGE_M


def window(
    tracks: dict[tuple[str, int], Track], recording: str, track_id: int, t0: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(inputs [4, 8, 30], present [8, 30], future [5, 2], maneuver [5]) of one window."""
    track = tracks[(recording, track_id)]
    rows = track.rows
    frames = list(range(t0 - 29, t0 + 1))
    hist = rows.loc[frames]
    origin: Any = rows.loc[t0]
    h0 = frame_heading(track, t0)
    c, s = math.cos(h0), math.sin(h0)
    inputs = np.zeros((4, 8, 30), dtype=np.float32)
    present = np.zeros((8, 30), dtype=bool)

    def put(row: int, k: int, state: Any) -> None:
        dx, dy = state["x"] - origin["x"], state["y"] - origin["y"]
        inputs[:, row, k] = (c * dx + s * dy, -s * dx + c * dy, state["speed"], state["lon_acc"])
        present[row, k] = True

    for k, f in enumerate(frames):
        put(4, k, hist.loc[f])
    for row, column in SLOT_COLUMNS.items():
        ids = hist[column]
        for nid in ids.dropna().unique():
            other = tracks.get((recording, int(nid)))
            if other is None or int(nid) == track_id:
                continue
            for k, f in enumerate(frames):
                if ids.loc[f] == nid and f in other.rows.index:
                    state = other.rows.loc[f]
                    if within_range(hist.loc[f], state, track.road_frame):
                        put(row, k, state)
    future = np.zeros((5, 2), dtype=np.float32)
    maneuver = np.zeros(5, dtype=np.int64)
    for step in range(5):
        state = rows.loc[t0 + 10 * (step + 1)]
        dx, dy = state["x"] - origin["x"], state["y"] - origin["y"]
        future[step] = (c * dx + s * dy, -s * dx + c * dy)
        maneuver[step] = lane_label(track, t0 + 10 * (step + 1))
    return inputs, present, future, maneuver
