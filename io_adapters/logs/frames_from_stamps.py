"""Frames of a drive log's messages from their stamps: the topic's nominal rate, the grid laid
through the stamps, and a frame index per message (docs/design.md §1: logs keep their stamps).

A recorder's or a sensor's clock jitters, so the rate is estimated robustly and snapped to a whole
one, the grid goes through the stamps' mean phase, and a stamp jittered past half a period moves
to the free frame beside it rather than sharing a frame with its neighbour (a row lost).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np


def nominal_rate(msg_times: np.ndarray) -> float:
    """The nominal rate (Hz) of a topic from its distinct message stamps [n] (median interval).

    Snapped to a whole rate (25 Hz, 10 Hz, …) where the median is within 1 % of one, or within 5 %
    of one on whose grid as many consecutive stamps lie one frame apart as on the median's: stamps
    that jitter by tens of milliseconds bend the median (a 10 Hz topic stamped ±30 ms measured
    10.14 Hz), and an unsnapped rate drifts off the grid until messages share frames (and rows of a
    track are lost as repeats).
    """
    stamps = np.unique(msg_times)
    if stamps.size < 2:
        return 10.0
    rate = 1e9 / float(np.median(np.diff(stamps)))
    rounded = round(rate)
    if rounded > 0 and abs(rate - rounded) < 0.01 * rate:
        return float(rounded)
    wholes = sorted({math.floor(rate), math.ceil(rate)}, key=lambda r: abs(r - rate))
    candidates = [float(r) for r in wholes if r > 0 and abs(rate - r) < 0.05 * rate] + [rate]
    return min(candidates, key=lambda r: _off_grid(stamps, r))  # the first of equals: a whole rate


def grid_origin(stamps: np.ndarray, rate: float) -> int:
    """The time (ns) of frame 0 on a ``rate`` grid through sorted distinct ``stamps`` [n]: the first
    stamp moved by the stamps' mean phase on the grid (a circular mean), so that a first message
    stamped late or early does not push every other message to the edge of its frame."""
    if stamps.size == 0:
        return 0
    phase = (stamps - stamps[0]).astype(np.float64) * rate / 1e9
    angle = np.angle(np.exp(2j * np.pi * phase).mean())
    return int(stamps[0]) + round(angle / (2 * np.pi) * 1e9 / rate)


def _grid_frames(times: np.ndarray, origin: int, rate: float) -> np.ndarray:
    return np.rint((times - origin).astype(np.float64) * rate / 1e9).astype(np.int64)


def _off_grid(stamps: np.ndarray, rate: float) -> int:
    """How many consecutive pairs of the sorted distinct ``stamps`` [n] do not lie one frame apart
    on a ``rate`` grid (both on one frame: a row lost as a repeat; frames skipped: a gap made)."""
    frames = spread_frames((stamps - grid_origin(stamps, rate)).astype(np.float64) * rate / 1e9)
    return int(np.count_nonzero(np.diff(frames) != 1))


def frames_of(
    msg_times: np.ndarray, spec: Mapping[str, Any] | None, tracks: np.ndarray | None = None
) -> tuple[np.ndarray, float]:
    """Frame indices [n] of rows from their message stamps [n], and the frame rate.

    ``spec`` (from lanecast's metadata) gives ``frame_rate`` with ``frame0``/``time0_ns`` or an
    explicit ``frames`` list (one per distinct stamp); without it the rate is estimated, the grid
    is laid through the stamps (:func:`grid_origin`) and frame 0 is the first message's. Two
    stamps that fall on one frame and hold the same track (``tracks`` [n], the rows' track ids)
    are a stamp jittered past half a period: one moves to the free frame beside it
    (:func:`spread_frames`).
    """
    if spec is not None and "frames" in spec:
        stamps, inverse = np.unique(msg_times, return_inverse=True)
        listed = np.asarray(spec["frames"], dtype=np.int64)
        if listed.size == stamps.size:
            return listed[inverse], float(spec["frame_rate"])
    if spec is not None and "frame0" in spec:
        rate = float(spec["frame_rate"])
        return int(spec["frame0"]) + _grid_frames(msg_times, int(spec["time0_ns"]), rate), rate
    rate = nominal_rate(msg_times)
    stamps, inverse = np.unique(msg_times, return_inverse=True)
    exact = (stamps - grid_origin(stamps, rate)).astype(np.float64) * rate / 1e9
    per_stamp = spread_frames(exact, _shares_track(inverse.reshape(-1), tracks, stamps.size))
    frames = per_stamp[inverse.reshape(-1)]
    return frames - (frames.min() if frames.size else 0), rate


def spread_frames(exact: np.ndarray, movable: np.ndarray | None = None) -> np.ndarray:
    """Frames [n] (int64) of sorted distinct stamps at ``exact`` [n] frames from the grid origin:
    each the nearest whole frame, except that a stamp sharing a frame with the one before it takes
    the next frame (or the one before it the previous) where that is free and within
    :data:`SPREAD` of a period of it. A clock jittering by nearly half a period, or a grid laid a
    little off, puts two messages on one frame and none on its neighbour; a message recorded twice
    (stamps close together) stays on its frame. ``movable`` [n]: bool, True where stamp i may be
    separated from stamp i - 1 (default: all).
    """
    out = np.rint(exact).astype(np.int64)
    clash = np.flatnonzero(out[1:] <= out[:-1])
    if not clash.size:
        return out
    for i in range(int(clash[0]) + 1, out.size):
        if out[i] > out[i - 1] or (movable is not None and not movable[i]):
            continue
        if out[i - 1] + 1 - exact[i] <= SPREAD and (i + 1 == out.size or out[i + 1] > out[i - 1] + 1):
            out[i] = out[i - 1] + 1
        elif (
            exact[i - 1] - (out[i] - 1) <= SPREAD
            and out[i - 1] == out[i]
            and (i < 2 or out[i - 2] < out[i] - 1)
        ):
            out[i - 1] = out[i] - 1
        elif out[i - 1] + 1 - exact[i] <= SPREAD:  # the next frame is taken: the stamps after move on
            out[i] = out[i - 1] + 1
    return out


#: How far (in periods) a stamp may lie from the frame it is moved to by :func:`spread_frames`.
SPREAD = 0.7


def _shares_track(inverse: np.ndarray, tracks: np.ndarray | None, n: int) -> np.ndarray | None:
    """bool [n]: True where distinct stamp i holds a track that stamp i - 1 holds too (rows: their
    stamp's index ``inverse`` and ``tracks``); None without tracks (every pair movable)."""
    if tracks is None:
        return None
    out = np.zeros(n, dtype=bool)
    if not tracks.size:
        return out
    _, track = np.unique(tracks, return_inverse=True)
    width = int(track.max()) + 1
    key = inverse.astype(np.int64) * width + track.reshape(-1)  # one integer per (stamp, track)
    hit = np.isin(key - width, key) & (inverse > 0)  # (stamp i - 1, same track) exists
    out[inverse[hit]] = True
    return out
