"""Window tensors (docs/design.md §2): gather history, neighbours and future of every window at once.

A window at t0 of target T takes T's 30 history frames (t0-2.9 s … t0) and, at every history
frame k, whoever occupies each neighbour slot at that frame, with its state at that frame. All in
the window frame (:func:`frame_heading`): origin T's centre at t0, x along the road, y to its left. Channels
x, y, speed |v| and longitudinal acceleration (a projected on the vehicle's own heading). Absent
neighbours are 0 with ``present`` False. Everything is fancy indexing into row arrays: rows of a
track are consecutive and sorted by frame, so T's frame t0+d is row r0+d inside a gap-free run.
"""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from lanecast.io_adapters.contracts.track_runs import row_extent, run_starts
from lanecast.io_adapters.contracts.windows import HISTORY, HORIZONS, ROWS, TARGET_ROW
from lanecast.pipeline.neighbour_columns import SLOTS, Columns

FUTURE = 50  # frames at 10 Hz after t0 that the targets need
HORIZON_STEP = 10  # frames between future steps (1 s)
SLOT_ROWS = np.array([ROWS.index(s) for s in SLOTS])  # tensor row of each neighbour slot
CHUNK = 512  # windows per gather chunk (temporaries of ~1 MB stay in cache)
ROW_BLOCK = 8192  # rows per block of per_row_features (temporaries of ~0.5 MB)
WORKERS = min(2, os.cpu_count() or 1)  # threads for the CPU-bound stages (see make_windows)
MIN_CHORD_M = 3.0  # a shorter displacement gives no reliable direction (tracker noise ~0.1-0.3 m)
LONG_CHORD_FRAMES = 100  # 10 s: the fallback chord for a target that barely moved in its history


def runs(cols: Columns) -> tuple[np.ndarray, np.ndarray]:
    """Gap-free run lengths around each row: (back, fwd) int64 [n], the number of consecutive
    frames of the row's track ending at / starting at the row (both count the row itself)."""
    idx = np.arange(cols.n)
    run_first, run_last = row_extent(run_starts(cols.rec, cols.track, cols.frame - idx))
    return idx - run_first + 1, run_last - idx + 1


def window_rows(
    cols: Columns,
    *,
    stride: int = 10,
    require_future: bool = True,
    t0_frames: np.ndarray | None = None,
    back: np.ndarray | None = None,
    fwd: np.ndarray | None = None,
) -> np.ndarray:
    """The t0 row of every window, int64 [W], in row order.

    A row qualifies when its track has the 30 history frames without a gap (and the 50 future ones
    if ``require_future``). Windows start at the first qualifying frame of every gap-free run and
    then every ``stride`` frames, unless ``t0_frames`` (int64 10 Hz frame numbers) picks them.
    """
    if back is None or fwd is None:
        back, fwd = runs(cols)
    ok = back >= HISTORY
    if require_future:
        ok &= fwd >= FUTURE + 1
    if t0_frames is None:
        ok &= (back - HISTORY) % max(int(stride), 1) == 0
    else:
        ok &= np.isin(cols.frame, np.asarray(t0_frames, dtype=np.int64))
    return np.flatnonzero(ok)


@dataclass
class WindowArrays:
    """Gathered windows: see lanecast.io_adapters.contracts.windows.Windows for the meaning of each array."""

    inputs: np.ndarray  # float32 [W, 4, 8, 30]
    present: np.ndarray  # bool [W, 8, 30]
    future: np.ndarray  # float32 [W, 5, 2]
    maneuver: np.ndarray  # int64 [W, 5]
    origin: np.ndarray  # float64 [W, 3]: x, y, heading of the window frame in the source frame


def speed_and_lon_acc(cols: Columns) -> tuple[np.ndarray, np.ndarray]:
    """Speed |v| and acceleration along the vehicle's own heading, float64 [n] each."""
    return np.hypot(cols.vx, cols.vy), cols.ax * np.cos(cols.heading) + cols.ay * np.sin(cols.heading)


def per_row_features(
    cols: Columns, neighbour_rows: np.ndarray, block: int = ROW_BLOCK
) -> tuple[np.ndarray, np.ndarray]:
    """What every row contributes to a window, before the window's own transform.

    Returns (features float32 [4, 8, n], present bool [8, n]): for each tensor row (FL … RR, T
    itself included) the vehicle's position relative to this row's vehicle in the source frame
    (computed in float64, so small and exact in float32), its speed and its longitudinal
    acceleration; zeros where the slot is empty. Row-last so that a window's 30 consecutive
    history rows are 30 contiguous values. Computed ``block`` rows at a time, so that the
    temporaries stay in cache.
    """
    n = cols.n
    speed, lon_acc = speed_and_lon_acc(cols)
    features = np.empty((4, len(ROWS), n), dtype=np.float32)
    present = np.empty((len(ROWS), n), dtype=bool)
    for lo in range(0, n, block):
        hi = min(lo + block, n)
        own = np.arange(lo, hi)
        vehicles = np.empty((len(ROWS), hi - lo), dtype=np.int64)
        vehicles[SLOT_ROWS] = neighbour_rows[lo:hi].T
        vehicles[TARGET_ROW] = own
        here = np.greater_equal(vehicles, 0, out=present[:, lo:hi])
        v = np.where(here, vehicles, own[None, :])  # an empty slot reads the row itself: 0 offset
        f = features[:, :, lo:hi]
        np.subtract(cols.x[v], cols.x[None, lo:hi], out=f[0], casting="same_kind")  # float64, then float32
        np.subtract(cols.y[v], cols.y[None, lo:hi], out=f[1], casting="same_kind")
        f[2] = speed[v]
        f[3] = lon_acc[v]
        f *= here[None]
    return features, present


def frame_heading(cols: Columns, t0_rows: np.ndarray) -> np.ndarray:
    """Rotation of each window frame in its source frame, float64 [W] rad (docs/design.md §2).

    The frame's x axis is the direction of the road, never T's instantaneous heading (a few
    degrees off the road during a lane change, which swings a 5 s future by metres):
    - road-frame recordings (highD, US-101, I-80, simulations): 0, a translation only;
    - world-frame logs and arterials: T's direction of travel over its history, the chord from
      t0-2.9 s to t0; where T moved less than ``MIN_CHORD_M`` in it (queues), the chord over up to
      10 s of gap-free past; where even that is short (T stood still), the circular mean of its
      heading over the history. Causal: only the history decides, as at inference.
    ``t0_rows`` int64 [W] must have 30 gap-free history rows (see :func:`window_rows`).
    """
    t0 = np.asarray(t0_rows, dtype=np.int64)
    out = np.zeros(t0.size, dtype=np.float64)
    world = ~cols.road_frame[cols.rec[t0]]
    if not world.any():
        return out
    t = t0[world]
    first = t - (HISTORY - 1)
    dx, dy = cols.x[t] - cols.x[first], cols.y[t] - cols.y[first]
    short = np.hypot(dx, dy) < MIN_CHORD_M
    if short.any():
        back, _ = runs(cols)
        far = t - np.minimum(back[t] - 1, LONG_CHORD_FRAMES)
        dx = np.where(short, cols.x[t] - cols.x[far], dx)
        dy = np.where(short, cols.y[t] - cols.y[far], dy)
    still = np.hypot(dx, dy) < MIN_CHORD_M
    hist = first[:, None] + np.arange(HISTORY)[None, :]  # [w, 30]
    mean_heading = np.arctan2(np.sin(cols.heading[hist]).sum(1), np.cos(cols.heading[hist]).sum(1))
    out[world] = np.where(still, mean_heading, np.arctan2(dy, dx))
    return out


def gather(
    cols: Columns,
    neighbour_rows: np.ndarray,
    labels: np.ndarray,
    t0_rows: np.ndarray,
    fwd: np.ndarray,
    chunk: int = CHUNK,
    workers: int = 1,
    out: tuple[np.ndarray, np.ndarray] | None = None,
) -> WindowArrays:
    """Build the tensors of the windows at rows ``t0_rows`` [W].

    neighbour_rows int64 [n, 7] (slot order, -1 none), labels int64 [n], fwd int64 [n] (from
    :func:`runs`). A window's history is the 30 consecutive rows t0-29 … t0 of its target, so it
    reads 30 consecutive values of every per-row feature (a sliding-window view); a neighbour's
    position in the window frame is (its offset from T at that frame) + (T's displacement since
    t0), rotated into the window frame (:func:`frame_heading`). Works ``chunk`` windows at a time so that the temporaries
    stay in cache, on ``workers`` threads (default 1: the stage is bound by faulting in its output
    memory, which threads contend for). ``out``: preallocated (inputs, present) to fill.
    """
    features, row_present = per_row_features(cols, neighbour_rows)
    t0 = np.asarray(t0_rows, dtype=np.int64)
    w = t0.size
    h0 = frame_heading(cols, t0)
    cos0, sin0 = np.cos(h0), np.sin(h0)
    rotated = h0 != 0
    if out is None:
        inputs = np.empty((w, 4, len(ROWS), HISTORY), dtype=np.float32)
        present = np.empty((w, len(ROWS), HISTORY), dtype=bool)
    else:
        inputs, present = out  # preallocated [W, 4, 8, 30] float32 and [W, 8, 30] bool
    if cols.n >= HISTORY:
        f_view = np.lib.stride_tricks.sliding_window_view(features, HISTORY, axis=2)  # [4, 8, n-29, 30]
        p_view = np.lib.stride_tricks.sliding_window_view(row_present, HISTORY, axis=1)  # [8, n-29, 30]
        x_view = np.lib.stride_tricks.sliding_window_view(cols.x, HISTORY)  # [n-29, 30]
        y_view = np.lib.stride_tricks.sliding_window_view(cols.y, HISTORY)

    def fill(b0: int) -> None:
        b1 = min(b0 + chunk, w)
        first = t0[b0:b1] - (HISTORY - 1)  # the window's oldest row
        f = f_view[:, :, first]  # [4, 8, B, 30]
        here = p_view[:, first]  # [8, B, 30]
        # T's displacement since t0 (float64, then small enough for float32)
        dx = (x_view[first] - x_view[first, -1:]).astype(np.float32)  # [B, 30]
        dy = (y_view[first] - y_view[first, -1:]).astype(np.float32)
        px = f[0] + dx
        py = f[1] + dy
        out = inputs[b0:b1].transpose(1, 2, 0, 3)  # [4, 8, B, 30] view of the output
        if rotated[b0:b1].any():
            c = cos0[b0:b1, None].astype(np.float32)
            s = sin0[b0:b1, None].astype(np.float32)
            np.multiply(c * px + s * py, here, out=out[0])
            np.multiply(c * py - s * px, here, out=out[1])
        else:  # road frames: the window frame is T's position, not rotated (cos 1, sin 0)
            np.multiply(px, here, out=out[0])
            np.multiply(py, here, out=out[1])
        out[2] = f[2]
        out[3] = f[3]
        present[b0:b1] = here.transpose(1, 0, 2)

    starts = range(0, w, chunk)
    if workers > 1 and len(starts) > 1:
        # numpy releases the GIL in indexing and arithmetic: chunks fill disjoint slices in parallel
        with ThreadPoolExecutor(max_workers=workers) as pool:
            list(pool.map(fill, starts))
    else:
        for b0 in starts:
            fill(b0)
    steps = np.arange(1, HORIZONS + 1) * HORIZON_STEP
    known = fwd[t0][:, None] > steps[None, :]  # [W, 5]
    fr = np.where(known, t0[:, None] + steps[None, :], t0[:, None])
    fdx = cols.x[fr] - cols.x[t0][:, None]
    fdy = cols.y[fr] - cols.y[t0][:, None]
    c1, s1 = cos0[:, None], sin0[:, None]
    future = np.stack([c1 * fdx + s1 * fdy, c1 * fdy - s1 * fdx], axis=-1)
    future[~known] = np.nan
    maneuver = np.where(known, labels[fr], -1).astype(np.int64)
    origin = np.stack([cols.x[t0], cols.y[t0], h0], axis=1)
    return WindowArrays(inputs, present, future.astype(np.float32), maneuver, origin)
