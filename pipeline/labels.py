"""Maneuver labels (docs/design.md §2): 0 straight, 1 left, 2 right, -1 unknown, per row of a 10 Hz table.

A lane change happens where ``lane_id`` changes between two consecutive rows of a track (both
known); the change's instant is the first row in the new lane. Every row of that track within
±``window_s`` (2 s, inclusive) of the instant is a lane change; its direction is the sign of the
target's lateral displacement across the change over ±``span_s`` (1 s), to the left (+y) = 1.
"Lateral" is relative to the road: in a road frame it is plain +y; in any other frame it is
relative to the chord of the track over ±``reference_s`` (3 s), which follows the road through
the change. (Not relative to the target's own heading at the change: during a lane change that
heading already points across the lanes, so the displacement along it has no lateral part and
its sign would be noise.) All spans are clipped to the track. Where changes are closer than
2 s the nearer one wins. Rows with no lane id and no change near them are unknown (-1), so a table
without lane ids has unknown maneuvers everywhere (documented fallback; its neighbours come from
lateral bands).
"""

from __future__ import annotations

import numpy as np

from lanecast.io_adapters.contracts.track_runs import lane_change_starts, row_extent, run_starts
from lanecast.pipeline.neighbour_columns import Columns

STRAIGHT, LEFT, RIGHT, UNKNOWN = 0, 1, 2, -1
WINDOW_S = 2.0
SPAN_S = 1.0
REFERENCE_S = 3.0


def track_bounds(cols: Columns) -> tuple[np.ndarray, np.ndarray]:
    """(first row, last row) of each row's track, int64 [n] each."""
    return row_extent(run_starts(cols.rec, cols.track))


def lane_changes(
    cols: Columns, rate_hz: float = 10.0, span_s: float = SPAN_S, reference_s: float = REFERENCE_S
) -> tuple[np.ndarray, np.ndarray]:
    """Rows where the lane id changes (first row in the new lane) and the direction of each
    (1 left, 2 right, 0 if there is no lateral displacement). int64 [c] each."""
    new_track = run_starts(cols.rec, cols.track)
    first, last = row_extent(new_track)
    rows = np.flatnonzero(lane_change_starts(new_track, cols.lane, cols.lane_known))
    m = max(round(span_s * rate_hz), 1)
    before = np.maximum(rows - m, first[rows])
    after = np.minimum(rows + m - 1, last[rows])
    dx = cols.x[after] - cols.x[before]
    dy = cols.y[after] - cols.y[before]
    r = max(round(reference_s * rate_hz), 1)
    ref_before = np.maximum(rows - r, first[rows])
    ref_after = np.minimum(rows + r - 1, last[rows])
    chord = np.arctan2(cols.y[ref_after] - cols.y[ref_before], cols.x[ref_after] - cols.x[ref_before])
    h = np.where(cols.road_frame[cols.rec[rows]], 0.0, chord)  # road frame: +x is the direction of travel
    lateral = -np.sin(h) * dx + np.cos(h) * dy
    direction = np.where(lateral > 0, LEFT, np.where(lateral < 0, RIGHT, STRAIGHT)).astype(np.int64)
    return rows, direction


def row_labels(cols: Columns, rate_hz: float = 10.0, window_s: float = WINDOW_S) -> np.ndarray:
    """Maneuver label of every row, int64 [n] (see the module docstring)."""
    n = cols.n
    first, last = track_bounds(cols)
    rows, direction = lane_changes(cols, rate_hz)
    labels = np.where(cols.lane_known, STRAIGHT, UNKNOWN).astype(np.int64)
    if rows.size == 0:
        return labels
    idx = np.arange(n)
    is_change = np.zeros(n, dtype=bool)
    is_change[rows] = True
    dir_of_row = np.zeros(n, dtype=np.int64)
    dir_of_row[rows] = direction
    prev = np.maximum.accumulate(np.where(is_change, idx, -1))
    nxt = np.minimum.accumulate(np.where(is_change, idx, n)[::-1])[::-1]
    prev_ok = prev >= first
    next_ok = nxt <= last
    reach = window_s * rate_hz + 1e-9
    d_prev = np.where(prev_ok, cols.frame - cols.frame[np.maximum(prev, 0)], np.inf)
    d_next = np.where(next_ok, cols.frame[np.minimum(nxt, n - 1)] - cols.frame, np.inf)
    use_prev = (d_prev <= d_next) & (d_prev <= reach)
    use_next = ~use_prev & (d_next <= reach)
    labels[use_prev] = dir_of_row[prev[use_prev]]
    labels[use_next] = dir_of_row[nxt[use_next]]
    return labels
