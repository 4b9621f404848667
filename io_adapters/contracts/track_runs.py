"""Runs of rows that belong together (a track, a recording, a gap-free stretch of frames) and what
is computed along them: the one place where lanecast finds track boundaries, differentiates along a
track and finds lane changes (docs/design.md §1).

Every function takes columns [n] whose rows are sorted so that each run is contiguous (a track
table is sorted by recording, track_id, frame) and works column-wise: no loop over rows.
"""

from __future__ import annotations

import numpy as np


def run_starts(*keys: np.ndarray) -> np.ndarray:
    """bool [n]: True on the first row of every run, i.e. where any of ``keys`` [n] differs from the
    previous row (and on row 0).

    A gap-free run of frames is a run of ``(…, track, frame - arange(n))``: the difference is
    constant exactly while the frames step by one.
    """
    n = keys[0].shape[0] if keys else 0
    new = np.ones(n, dtype=bool)
    if n > 1:
        new[1:] = False
        for key in keys:
            new[1:] |= key[1:] != key[:-1]
    return new


def run_bounds(*keys: np.ndarray) -> np.ndarray:
    """int64 [R + 1]: the first row of each run, then n; ``bounds[i]:bounds[i + 1]`` is run i."""
    new = run_starts(*keys)
    return np.concatenate([np.flatnonzero(new), [new.size]]).astype(np.int64)


def run_groups(bounds: np.ndarray, max_rows: int) -> np.ndarray:
    """int64 [G + 1]: consecutive whole runs grouped, at most ``max_rows`` rows a group (a longer
    run is a group of its own), as indices into the runs of ``bounds`` (:func:`run_bounds`): group
    g is runs ``groups[g]:groups[g + 1]``, rows ``bounds[groups[g]]:bounds[groups[g + 1]]``."""
    runs = bounds.size - 1
    groups = [0]
    while groups[-1] < runs:
        last = int(np.searchsorted(bounds, bounds[groups[-1]] + max_rows, side="right")) - 1
        groups.append(min(max(last, groups[-1] + 1), runs))
    return np.asarray(groups, dtype=np.int64)


def row_extent(new: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(first row, last row) of each row's run, int64 [n] each (inclusive), from ``run_starts``."""
    n = new.size
    starts = np.flatnonzero(new)
    length = np.diff(np.append(starts, n))
    first = np.repeat(starts, length)
    ends = np.append(starts[1:], n) if n else starts  # no rows: no runs
    last = np.repeat(ends - 1, length)
    return first.astype(np.int64), last.astype(np.int64)


def along_track_derivative(
    values: np.ndarray,
    t: np.ndarray,
    first: np.ndarray,
    last: np.ndarray,
    *,
    span: int = 1,
    t_unit: float = 1.0,
) -> np.ndarray:
    """d values / d t along each track, float64 [n].

    ``values`` and ``t`` [n] (any numeric time: seconds, frames, ns; ``t_unit`` converts its
    differences to seconds), ``first``/``last`` [n] each row's track extent (``row_extent``). The
    difference over ±``span`` rows clipped to the track: central inside it (over 2·span rows, a
    light smoothing), one-sided at its ends, 0 for a single-row track. Gaps in time are fine: the
    difference is divided by the actual time between the two rows.
    """
    i = np.arange(values.shape[0])
    lo = np.maximum(i - span, first)
    hi = np.minimum(i + span, last)
    dt = (t[hi] - t[lo]).astype(np.float64) * t_unit
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(dt > 0, (values[hi] - values[lo]) / np.where(dt > 0, dt, 1.0), 0.0)


def lane_change_starts(new_track: np.ndarray, lane: np.ndarray, known: np.ndarray) -> np.ndarray:
    """bool [n]: rows whose lane differs from the previous row of the same track, both lanes known.

    The row marked is the first one in the new lane (docs/design.md §1, §2).
    ``new_track`` from ``run_starts``; ``lane`` [n] any value where ``known`` [n] is False.
    """
    change = np.zeros(lane.shape[0], dtype=bool)
    if lane.shape[0] > 1:
        change[1:] = ~new_track[1:] & known[1:] & known[:-1] & (lane[1:] != lane[:-1])
    return change
