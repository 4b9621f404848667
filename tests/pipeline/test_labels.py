"""Maneuver labels: a lane change at a known time with every label of the windows around it, right
changes, two changes close together, a 25 Hz source, a world frame, and tables without lane ids."""

from __future__ import annotations

import numpy as np
import pyarrow as pa
import pytest
from conftest import make_track_table

from lanecast.pipeline.labels import lane_changes, row_labels
from lanecast.pipeline.make_windows import make_windows
from lanecast.pipeline.neighbour_columns import columns


def track_table(
    y: np.ndarray, lane: np.ndarray, *, rate: float = 10.0, rotate: float = 0.0, steer: bool = False
) -> pa.Table:
    """One car at 30 m/s along x with lateral position ``y`` and ``lane`` per frame (NaN = unknown).

    ``steer``: the heading follows the motion (as in real data and SUMO), so that during a lane
    change it points across the lanes; otherwise it stays along the road.
    """
    n = y.size
    t = np.arange(n) / rate
    x = 30.0 * t
    c, s = np.cos(rotate), np.sin(rotate)
    along = rotate + (np.arctan2(np.gradient(y, t), 30.0) if steer else np.zeros(n))
    cols = {
        "track_id": np.full(n, 1),
        "frame": np.arange(n),
        "time_ns": np.rint(t * 1e9).astype(np.int64),
        "x": c * x - s * y,
        "y": s * x + c * y,
        "heading": along,
        "vx": np.full(n, 30.0 * c),
        "vy": np.full(n, 30.0 * s),
        "lane_id": lane,
    }
    return make_track_table(cols, rate=rate, coordinate_frame="road" if rotate == 0.0 else "odom")


def change_at(
    n: int, frame: int, direction: int = 1, *, start: int = 80, end: int = 120
) -> tuple[np.ndarray, np.ndarray]:
    """y moving one lane (3.75 m) left (+1) or right (-1) between ``start`` and ``end``; lane id
    2 -> 2 + direction from ``frame`` on."""
    f = np.arange(n)
    y = direction * 3.75 * np.clip((f - start) / (end - start), 0.0, 1.0)
    lane = np.where(f >= frame, 2 + direction, 2).astype(float)
    return y, lane


# Windows at t0 = 29, 39, …, 149 of a 200-frame track with a change at frame 100: step k of a
# window is at t0 + 10k and is a lane change iff |t0 + 10k - 100| <= 20.
EXPECTED_STEPS = {
    29: [0, 0, 0, 0, 0],
    39: [0, 0, 0, 0, 1],
    49: [0, 0, 0, 1, 1],
    59: [0, 0, 1, 1, 1],
    69: [0, 1, 1, 1, 1],
    79: [1, 1, 1, 1, 0],
    89: [1, 1, 1, 0, 0],
    99: [1, 1, 0, 0, 0],
    109: [1, 0, 0, 0, 0],
    119: [0, 0, 0, 0, 0],
    129: [0, 0, 0, 0, 0],
    139: [0, 0, 0, 0, 0],
    149: [0, 0, 0, 0, 0],
}


def test_row_labels_two_seconds_around_the_change() -> None:
    table = track_table(*change_at(200, 100))
    labels = row_labels(columns(table))
    expected = np.where(np.abs(np.arange(200) - 100) <= 20, 1, 0)
    np.testing.assert_array_equal(labels, expected)
    rows, direction = lane_changes(columns(table))
    np.testing.assert_array_equal(rows, [100])
    np.testing.assert_array_equal(direction, [1])


def test_every_window_label_around_a_left_change() -> None:
    windows = make_windows(track_table(*change_at(200, 100)), split="none")
    t0 = windows.index.column("t0_ns").to_numpy() // 100_000_000
    assert t0.tolist() == sorted(EXPECTED_STEPS)
    np.testing.assert_array_equal(windows.maneuver, np.array([EXPECTED_STEPS[f] for f in t0]))


def test_right_change_is_label_2() -> None:
    windows = make_windows(track_table(*change_at(200, 100, direction=-1)), split="none")
    t0 = windows.index.column("t0_ns").to_numpy() // 100_000_000
    np.testing.assert_array_equal(windows.maneuver, 2 * np.array([EXPECTED_STEPS[f] for f in t0]))


def test_direction_in_a_world_frame_follows_the_heading() -> None:
    """Driving at 2.0 rad in a log frame, a move to the vehicle's left is still label 1."""
    table = track_table(*change_at(200, 100), rotate=2.0)
    np.testing.assert_array_equal(lane_changes(columns(table))[1], [1])
    windows = make_windows(table, split="none")
    t0 = windows.index.column("t0_ns").to_numpy() // 100_000_000
    np.testing.assert_array_equal(windows.maneuver, np.array([EXPECTED_STEPS[f] for f in t0]))


def test_two_close_changes_the_nearer_wins() -> None:
    """Left at frame 100, back right at 130: 80…115 left (115 is a tie, the earlier wins), 116…150 right."""
    f = np.arange(220)
    y = np.interp(f, [0, 90, 110, 120, 140, 219], [0, 0, 3.75, 3.75, 0, 0])
    lane = np.where((f >= 100) & (f < 130), 3, 2).astype(float)
    labels = row_labels(columns(track_table(y, lane)))
    expected = np.zeros(220, dtype=np.int64)
    expected[80:116] = 1
    expected[116:151] = 2
    np.testing.assert_array_equal(labels, expected)


def test_change_in_a_25hz_source() -> None:
    """At 25 Hz the lane id changes at frame 251 (10.04 s); at 10 Hz the first frame in the new lane
    is 10.1 s (frame 101), so frames 81…121 are the lane change."""
    n = 500
    f = np.arange(n)
    y = 3.75 * np.clip((f - 200) / 100, 0, 1)
    lane = np.where(f >= 251, 3, 2).astype(float)
    windows = make_windows(track_table(y, lane, rate=25.0), split="none", stride=1)
    t0 = windows.index.column("t0_ns").to_numpy() // 100_000_000
    step_frames = t0[:, None] + 10 * np.arange(1, 6)[None, :]
    expected = np.where(np.abs(step_frames - 101) <= 20, 1, 0)
    np.testing.assert_array_equal(windows.maneuver, expected)
    assert windows.maneuver.max() == 1


def test_no_lane_ids_gives_unknown_labels() -> None:
    y, _ = change_at(200, 100)
    windows = make_windows(track_table(y, np.full(200, np.nan)), split="none")
    assert len(windows) == 13
    assert np.all(windows.maneuver == -1)
    assert windows.manifest["label_distribution"]["unknown"] == 13 * 5


def test_partly_unknown_lanes() -> None:
    """Rows without a lane id are unknown unless a change is near; a change needs both ids known."""
    y, lane = change_at(200, 100)
    lane[150:] = np.nan
    labels = row_labels(columns(track_table(y, lane)))
    assert np.all(labels[150:] == -1)
    np.testing.assert_array_equal(labels[:150], np.where(np.abs(np.arange(150) - 100) <= 20, 1, 0))


@pytest.mark.parametrize("rotate", [0.0, 0.7, -2.5])
@pytest.mark.parametrize("direction", [1, -1])
def test_direction_is_right_when_the_heading_points_across_the_lanes(rotate: float, direction: int) -> None:
    """A constant-rate lane change (SUMO's) with the heading along the motion: the displacement
    along the heading at the change has no lateral part, yet the label must say left or right."""
    y, lane = change_at(200, 100, direction)
    table = track_table(y, lane, rotate=rotate, steer=True)
    rows, dirs = lane_changes(columns(table))
    assert rows.tolist() == [100]
    assert dirs.tolist() == [1 if direction == 1 else 2]
    labels = row_labels(columns(table))
    assert set(labels[80:121].tolist()) == {1 if direction == 1 else 2}
    assert set(labels[:80].tolist()) == set(labels[121:].tolist()) == {0}
