"""Measurement errors of a video tracker, added to a simulated highD recording (training data).

Real trajectory datasets are measured, not simulated: positions carry slow errors (a box that drifts
along the vehicle over seconds) and frame-to-frame jitter, and their speeds and accelerations are
differentiated from those positions, so the derivative columns are far noisier than the positions
(NGSIM's accelerations swing by metres per second squared). A model trained only on SUMO's exact
states learns to trust speed and acceleration inputs that real data does not support. This module
makes a measured copy of a simulated recording: the same traffic, with errors on the box positions
and every velocity and acceleration column re-derived from the erroneous positions, as a tracker's
post-processing does.

Error model, per track (``level`` in metres):

* longitudinal: a slow error, a sum of three sinusoids with periods 2-10 s and random phases, std
  ``level``, plus white jitter of std ``level / 4``;
* lateral: the same with std ``level / 3`` each;
* standing vehicles (true speed below ``STANDING_MS``) keep the error they had when they stopped,
  without jitter: a dataset's tracker and smoothing hold a standing box still (NGSIM reports
  speed 0 for them), and a measured copy whose standing cars jitter teaches a network that speed
  0 never happens, so that on real data it predicts standing cars rolling backwards;
* velocities: the central difference of the positions over ±``DIFF_SPAN_S``; accelerations: the
  central difference of those velocities; both clipped to each track;
* or, for an *interpolating* tracker (NGSIM's: speeds held for frames, then jumping; accelerations 0,
  then saturating at ±11.2 ft/s²), positions measured only in some frames and linear between,
  velocities and accelerations forward differences.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.csv as pacsv

from lanecast.io_adapters.contracts.track_runs import row_extent, run_starts
from lanecast.io_adapters.sim.slow_signals import sinusoid_sum
from lanecast.io_adapters.sim.to_highd import file_names, write_highd

SLOW_PERIODS_S = (2.0, 10.0)
DIFF_SPAN_S = 0.2  # half-width of the difference that gives velocities and accelerations
STANDING_MS = 0.1  # a vehicle slower than this stands: its measured box stays still
NGSIM_MAX_ACC = 11.2 * 0.3048  # m/s²: NGSIM's accelerations saturate at ±11.2 ft/s²
KEYFRAME_RATE_MIN = 0.15  # lowest share of a track's frames an interpolating tracker measures


def slow_error(
    track_index: np.ndarray, time_s: np.ndarray, std: float, rng: np.random.Generator
) -> np.ndarray:
    """A smooth error per track, float64 [n], total std ``std``: a sinusoid sum with periods in
    ``SLOW_PERIODS_S``. ``track_index`` int [n] in 0 … T-1."""
    return sinusoid_sum(track_index, time_s, std, SLOW_PERIODS_S, rng)


def held_while_standing(error: np.ndarray, standing: np.ndarray, first: np.ndarray) -> np.ndarray:
    """``error`` float64 [n] with every standing row (``standing`` bool [n]) given the value of
    the last moving row before it in its track (the track's first row if none): the error a
    tracker keeps while the vehicle stands. ``first`` int [n]: first row of each row's track."""
    idx = np.arange(error.size)
    last_moving = np.maximum.accumulate(np.where(standing, -1, idx))
    return error[np.maximum(last_moving, first)]


def central_difference(
    values: np.ndarray, first: np.ndarray, last: np.ndarray, span: int, dt_s: float
) -> np.ndarray:
    """(values[i+span] - values[i-span]) / time, the rows clipped to [first, last] of row i's
    track; 0 on a one-row track. float64 [n]."""
    idx = np.arange(values.size)
    lo, hi = np.maximum(idx - span, first), np.minimum(idx + span, last)
    steps = np.maximum(hi - lo, 1)
    return np.where(hi > lo, (values[hi] - values[lo]) / (steps * dt_s), 0.0)


def keyframes(
    track_index: np.ndarray, first: np.ndarray, last: np.ndarray, rng: np.random.Generator
) -> np.ndarray:
    """Rows a tracker measured, bool [n]; the rows between are interpolated.

    NGSIM's speeds are held for several frames and then jump (its v_Acc is 0, then saturates):
    the video tracker detected a vehicle only in some frames and interpolated between them. Each
    track gets a detection rate ``p`` uniform in [``KEYFRAME_RATE_MIN``, 1]; a row is measured with
    probability ``p``; a track's first and last rows always are.
    """
    idx = np.arange(track_index.size)
    rate = rng.uniform(KEYFRAME_RATE_MIN, 1.0, size=int(track_index.max(initial=-1)) + 1)[track_index]
    return (rng.random(idx.size) < rate) | (idx == first) | (idx == last)


def interpolate_between(values: np.ndarray, measured: np.ndarray) -> np.ndarray:
    """``values`` float64 [n] linearly interpolated (in row steps) between the ``measured`` rows
    bool [n]; each track's first and last rows must be measured, so no track reads another's."""
    idx = np.arange(values.size)
    prev = np.maximum.accumulate(np.where(measured, idx, 0))
    nxt = np.minimum.accumulate(np.where(measured, idx, values.size - 1)[::-1])[::-1]
    span = np.maximum(nxt - prev, 1)
    weight = (idx - prev) / span
    return values[prev] * (1.0 - weight) + values[nxt] * weight


def forward_difference(values: np.ndarray, first: np.ndarray, last: np.ndarray, dt_s: float) -> np.ndarray:
    """(values[i+1] - values[i]) / dt within row i's track (the last row takes the backward
    difference); 0 on a one-row track. float64 [n]."""
    idx = np.arange(values.size)
    hi = np.minimum(idx + 1, last)
    lo = np.where(hi > idx, idx, np.maximum(idx - 1, first))
    return np.where(hi > lo, (values[hi] - values[lo]) / dt_s, 0.0)


def add_tracking_errors(
    tracks: pa.Table,
    frame_rate: float,
    level_m: float,
    seed: int,
    *,
    hold_standing: bool = True,
    interpolating: bool = False,
) -> pa.Table:
    """A highD ``tracks`` table (rows sorted by id, then frame) with tracker-like errors of ``level_m``
    on ``x``, ``y`` and velocities and accelerations re-derived from them (module docstring).
    ``hold_standing`` False: standing vehicles jitter like moving ones (a tracker without smoothing).
    ``interpolating``: the tracker measured only some frames (:func:`keyframes`) and interpolated
    between them; velocities and accelerations are forward differences, accelerations clipped to
    NGSIM's ±11.2 ft/s² (speeds held, then jumping; accelerations 0, then saturating).

    The lane, neighbour and headway columns keep their true values (a dataset's lane assignment
    comes from its own, smoothed processing)."""
    if level_m < 0:
        raise ValueError(f"level_m must be >= 0, not {level_m}")
    ids = tracks.column("id").to_numpy()
    frames = tracks.column("frame").to_numpy()
    first, last = row_extent(run_starts(ids))
    track_index = np.cumsum(run_starts(ids)) - 1
    time_s = frames / frame_rate
    rng = np.random.default_rng([int(seed), 0x7E5])
    x = tracks.column("x").to_numpy().astype(np.float64)
    y = tracks.column("y").to_numpy().astype(np.float64)
    speed = np.hypot(tracks.column("xVelocity").to_numpy(), tracks.column("yVelocity").to_numpy())
    standing = (speed < STANDING_MS) & hold_standing
    # highD's x runs along the road and y across it, whichever the direction.
    x_error = slow_error(track_index, time_s, level_m, rng) + rng.normal(0.0, level_m / 4, x.size)
    y_error = slow_error(track_index, time_s, level_m / 3, rng) + rng.normal(0.0, level_m / 3, y.size)
    x = x + held_while_standing(x_error, standing, first)
    y = y + held_while_standing(y_error, standing, first)
    dt = 1.0 / frame_rate
    if interpolating:
        measured = keyframes(track_index, first, last, rng)
        x, y = interpolate_between(x, measured), interpolate_between(y, measured)
        vx, vy = forward_difference(x, first, last, dt), forward_difference(y, first, last, dt)
        ax = np.clip(forward_difference(vx, first, last, dt), -NGSIM_MAX_ACC, NGSIM_MAX_ACC)
        ay = np.clip(forward_difference(vy, first, last, dt), -NGSIM_MAX_ACC, NGSIM_MAX_ACC)
    else:
        span = max(round(DIFF_SPAN_S * frame_rate), 1)
        vx = central_difference(x, first, last, span, dt)
        vy = central_difference(y, first, last, span, dt)
        ax = central_difference(vx, first, last, span, dt)
        ay = central_difference(vy, first, last, span, dt)
    replaced = {
        "x": np.round(x, 2),
        "y": np.round(y, 2),
        "xVelocity": np.round(vx, 2),
        "yVelocity": np.round(vy, 2),
        "xAcceleration": np.round(ax, 4),
        "yAcceleration": np.round(ay, 4),
    }
    for name, values in replaced.items():
        i = tracks.schema.get_field_index(name)
        tracks = tracks.set_column(i, name, pa.array(values + 0.0, type=tracks.schema.field(i).type))
    return tracks


def write_measured_copy(
    src_dir: Path,
    recording_id: int,
    out_dir: Path,
    new_id: int,
    level_m: float,
    seed: int,
    *,
    hold_standing: bool = True,
    interpolating: bool = False,
) -> Path:
    """Write recording ``recording_id`` of ``src_dir`` (highD CSVs) as recording ``new_id`` in
    ``out_dir`` with tracking errors of ``level_m`` (:func:`add_tracking_errors`); atomic."""
    names = file_names(recording_id)
    tables = {kind: pacsv.read_csv(Path(src_dir) / name) for kind, name in names.items()}
    rate = float(tables["recordingMeta"].column("frameRate")[0].as_py())
    tables["tracks"] = add_tracking_errors(
        tables["tracks"], rate, level_m, seed, hold_standing=hold_standing, interpolating=interpolating
    )
    meta = tables["recordingMeta"]
    i = meta.schema.get_field_index("id")
    tables["recordingMeta"] = meta.set_column(
        i, "id", pa.array([new_id] * meta.num_rows, meta.schema.field(i).type)
    )
    return write_highd(tables, out_dir, new_id, overwrite=True)
