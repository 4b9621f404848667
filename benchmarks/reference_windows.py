"""A straightforward per-window implementation of the windows stage, as research code writes it.

Kept only as the benchmark's baseline and as an independent check of lanecast's vectorised stage
(benchmarks/bench_windows.py compares both, value by value). It loops over windows in Python and
looks rows up in pandas: per window, the target's history by frame, then per neighbour slot the
ids over the history and each neighbour's rows at those frames. It takes a 10 Hz table whose
neighbour id columns are filled (highD / the simulator), i.e. lanecast's ``neighbours="source"``.
"""

from __future__ import annotations

import math
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


def prepare(table_10hz: pd.DataFrame) -> dict[tuple[str, int], pd.DataFrame]:
    """One frame-indexed DataFrame per (recording, track)."""
    df = table_10hz.copy()
    df["recording"] = df["recording"].astype(str)
    df["speed"] = np.hypot(df["vx"], df["vy"])
    df["lon_acc"] = df["ax"] * np.cos(df["heading"]) + df["ay"] * np.sin(df["heading"])
    return {
        (str(key[0]), int(key[1])): g.set_index("frame")  # type: ignore[call-overload]
        for key, g in df.groupby(["recording", "track_id"], sort=False)
    }


def lane_label(track: pd.DataFrame, frame: int) -> int:
    """Maneuver label of ``track`` at ``frame``: the nearest lane change within 2 s (20 frames)."""
    lane = track["lane_id"].to_numpy(dtype=float)
    frames = track.index.to_numpy()
    known = ~np.isnan(lane)
    idx = np.flatnonzero(known[1:] & known[:-1] & (lane[1:] != lane[:-1])) + 1
    if idx.size == 0 or np.abs(frames[idx] - frame).min() > 20:
        return 0 if known[np.searchsorted(frames, frame)] else -1
    d = np.abs(frames[idx] - frame)
    i = int(idx[np.argmin(d)])  # ties: the earlier change
    before, after = max(i - 10, 0), min(i + 9, len(frames) - 1)
    # Lateral = +y of the road frame (highD and the simulator are road-aligned), not relative to
    # the heading at the change, which during a lane change points across the lanes.
    dy = track["y"].iloc[after] - track["y"].iloc[before]
    return 1 if dy > 0 else (2 if dy < 0 else 0)


def window(
    tracks: dict[tuple[str, int], pd.DataFrame], recording: str, track_id: int, t0: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(inputs [4, 8, 30], present [8, 30], future [5, 2], maneuver [5]) of one window."""
    track = tracks[(recording, track_id)]
    frames = list(range(t0 - 29, t0 + 1))
    hist = track.loc[frames]
    origin: Any = track.loc[t0]
    c, s = math.cos(float(origin["heading"])), math.sin(float(origin["heading"]))
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
            if other is None:
                continue
            for k, f in enumerate(frames):
                if ids.loc[f] == nid and f in other.index:
                    put(row, k, other.loc[f])
    future = np.zeros((5, 2), dtype=np.float32)
    maneuver = np.zeros(5, dtype=np.int64)
    for step in range(5):
        state = track.loc[t0 + 10 * (step + 1)]
        dx, dy = state["x"] - origin["x"], state["y"] - origin["y"]
        future[step] = (c * dx + s * dy, -s * dx + c * dy)
        maneuver[step] = lane_label(track, t0 + 10 * (step + 1))
    return inputs, present, future, maneuver
