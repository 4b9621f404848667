"""The track-run primitives every reader and stage shares (io_adapters/contracts/track_runs.py)."""

from __future__ import annotations

import numpy as np
import pytest

from lanecast.io_adapters.contracts.track_runs import (
    along_track_derivative,
    lane_change_starts,
    row_extent,
    run_bounds,
    run_groups,
    run_starts,
)
from lanecast.io_adapters.sim import sumo_highway


def test_per_track_gradient_by_hand() -> None:
    values = np.array([0.0, 1.0, 3.0, 5.0, 5.0, 2.0])
    new_track = np.array([True, False, False, True, False, True])
    first, last = row_extent(new_track)
    got = along_track_derivative(values, np.arange(6), first, last, t_unit=sumo_highway.STEP_S)
    # track 1: one-sided (1-0)/0.04, central (3-0)/0.08, one-sided (3-1)/0.04; track 2 constant; track 3 alone.
    assert got.tolist() == pytest.approx([25.0, 37.5, 50.0, 0.0, 0.0, 0.0])


def test_runs_of_several_keys_and_gap_free_frames() -> None:
    rec = np.array([0, 0, 0, 0, 1, 1])
    track = np.array([7, 7, 7, 8, 7, 7])
    frame = np.array([1, 2, 4, 4, 1, 2])
    assert run_starts(rec, track).tolist() == [True, False, False, True, True, False]
    assert run_bounds(rec, track).tolist() == [0, 3, 4, 6]
    gap_free = run_bounds(rec, track, frame - np.arange(frame.size))
    assert gap_free.tolist() == [0, 2, 3, 4, 6]  # the jump from frame 2 to 4 starts a run
    first, last = row_extent(run_starts(rec, track))
    assert first.tolist() == [0, 0, 0, 3, 4, 4]
    assert last.tolist() == [2, 2, 2, 3, 5, 5]
    assert run_bounds(np.zeros(0, np.int64)).tolist() == [0]


def test_derivative_spans_clip_to_the_track_and_divide_by_real_time() -> None:
    values = np.array([0.0, 2.0, 4.0, 10.0, 1.0])
    t_ns = np.array([0, 1, 3, 4, 0]) * 1_000_000_000  # a gap of 2 s inside track 1
    first, last = row_extent(np.array([True, False, False, False, True]))
    got = along_track_derivative(values, t_ns, first, last, span=2, t_unit=1e-9)
    assert got.tolist() == pytest.approx([4 / 3, 10 / 4, 10 / 4, 8 / 3, 0.0])


def test_lane_change_starts_need_both_lanes_known_and_the_same_track() -> None:
    new_track = np.array([True, False, False, False, True, False])
    lane = np.array([1, 2, 0, 3, 3, 4])
    known = np.array([True, True, False, True, True, True])
    assert np.flatnonzero(lane_change_starts(new_track, lane, known)).tolist() == [1, 5]


def test_run_groups_hold_whole_runs_of_at_most_max_rows_a_longer_run_alone() -> None:
    bounds = np.array([0, 5, 8, 11, 14])  # runs of 5, 3, 3 and 3 rows
    assert run_groups(bounds, 3).tolist() == [0, 1, 2, 3, 4]
    assert run_groups(bounds, 8).tolist() == [0, 2, 4]
    assert run_groups(bounds, 6).tolist() == [0, 1, 3, 4]
    assert run_groups(bounds, 100).tolist() == [0, 4]
    assert run_groups(np.array([0]), 10).tolist() == [0]  # no rows: no group
