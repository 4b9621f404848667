"""Resample every track to 10 Hz (docs/design.md §2): one vectorised pass over all tracks at once.

Per recording and track, every numeric column is linearly interpolated onto the multiples of 0.1 s
of ``time_ns`` that lie inside the track's time span; ``heading`` is interpolated along the shorter
arc (unwrapped); categorical columns (``lane_id``, the neighbour ids, ``object_class``) take the
value of the nearest-earlier original sample. Output ``frame = time_ns / 0.1 s`` exactly.

Gaps: where consecutive samples of a track are more than ``gap_factor`` native frame periods apart
the track is cut into segments and nothing is interpolated across the gap; the 10 Hz track then
simply has no rows in the gap, and windows (which need consecutive frames) never span it.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pyarrow as pa

from lanecast.io_adapters.contracts import track_table
from lanecast.io_adapters.errors import TrackTableError

RATE_HZ = 10.0
GAP_FACTOR = 1.5
_LINEAR = ("x", "y", "vx", "vy", "ax", "ay", "length", "width")


def step_ns(rate_hz: float) -> int:
    """The grid step in integer nanoseconds (10 Hz -> 100,000,000)."""
    return round(1e9 / rate_hz)


def segment_starts(
    rec_code: np.ndarray, track: np.ndarray, time_ns: np.ndarray, period_ns: np.ndarray, gap_factor: float
) -> np.ndarray:
    """Rows that start a gap-free segment of a track: bool [n].

    rec_code, track, time_ns int64 [n] sorted by (recording, track, time); period_ns float [n] is
    the native frame period of each row's recording.
    """
    n = track.size
    start = np.ones(n, dtype=bool)
    if n > 1:
        same = (rec_code[1:] == rec_code[:-1]) & (track[1:] == track[:-1])
        gap = (time_ns[1:] - time_ns[:-1]) > gap_factor * period_ns[1:]
        start[1:] = ~same | gap
    return start


def resample_indices(
    time_ns: np.ndarray, seg_start: np.ndarray, step: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Grid points of every segment and where they fall between the original samples.

    time_ns int64 [n] (increasing within each segment), seg_start bool [n].
    Returns (k int64 [m]: grid index, time = k * step; j int64 [m]: the nearest-earlier original row;
    w float64 [m]: interpolation weight of row j+1, 0 where the grid point hits row j or j is the
    segment's last row).
    """
    n = time_ns.size
    first = np.flatnonzero(seg_start)
    last = np.append(first[1:], n) - 1
    k0 = -((-time_ns[first]) // step)  # ceil
    k1 = time_ns[last] // step  # floor
    counts = np.maximum(k1 - k0 + 1, 0)
    seg_of = np.repeat(np.arange(first.size), counts)
    within = np.arange(seg_of.size) - np.repeat(np.cumsum(counts) - counts, counts)
    k = k0[seg_of] + within
    grid = k * step
    # Lay the segments end to end on one increasing axis so a single searchsorted finds every j.
    span = time_ns[last] - time_ns[first] + 1
    offset = np.cumsum(span) - span
    seg_of_row = np.cumsum(seg_start) - 1
    mono = time_ns - time_ns[first][seg_of_row] + offset[seg_of_row]
    query = grid - time_ns[first][seg_of] + offset[seg_of]
    j = np.searchsorted(mono, query, side="right") - 1
    j1 = np.minimum(j + 1, last[seg_of])
    dt = (time_ns[j1] - time_ns[j]).astype(np.float64)
    w = np.divide((grid - time_ns[j]).astype(np.float64), dt, out=np.zeros(k.size), where=dt > 0)
    return k, j, w


def wrap_angle(a: np.ndarray) -> np.ndarray:
    """Angles to [-pi, pi)."""
    return (a + np.pi) % (2 * np.pi) - np.pi


def resample(
    table: pa.Table,
    rate_hz: float = RATE_HZ,
    gap_factor: float = GAP_FACTOR,
    *,
    meta: track_table.TableMeta | None = None,
) -> pa.Table:
    """A track table at ``rate_hz`` (same schema; metadata frame_rate = rate_hz per recording).

    The recording's native rate (metadata) defines the gap threshold; the native rate is kept in
    each recording's ``extra["native_frame_rate"]``. ``meta``: the table's metadata when the caller
    has parsed it already.
    """
    return resample_with_physics(table, rate_hz, gap_factor, meta=meta)[0]


def resample_with_physics(
    table: pa.Table,
    rate_hz: float = RATE_HZ,
    gap_factor: float = GAP_FACTOR,
    *,
    meta: track_table.TableMeta | None = None,
) -> tuple[pa.Table, dict[str, np.ndarray]]:
    """:func:`resample`, and its interpolated physical columns as computed (float64 [m] each: x, y,
    heading, vx, vy, ax, ay, length, width), so that the stages use them directly instead of reading
    them back from the table's float32 columns."""
    meta = meta or track_table.read_meta(table)
    step = step_ns(rate_hz)
    uniq, rec_code = track_table.recording_codes(table)
    missing = [name for name in uniq if name not in meta.recordings]
    if missing:
        raise TrackTableError(f"recordings {missing} have no entry in the table metadata")
    period = np.array([1e9 / meta.recordings[str(name)].frame_rate for name in uniq], dtype=np.float64)
    time_ns = table.column("time_ns").to_numpy()
    track = table.column("track_id").to_numpy()
    seg_start = segment_starts(
        rec_code, track, time_ns, period[rec_code] if uniq.size else period, gap_factor
    )
    if table.num_rows == 0:
        k = j = np.zeros(0, dtype=np.int64)
        w = np.zeros(0)
    else:
        k, j, w = resample_indices(time_ns, seg_start, step)
    j1 = np.minimum(j + 1, max(table.num_rows - 1, 0))
    physics: dict[str, np.ndarray] = {}
    for name in _LINEAR:
        v = table.column(name).to_numpy().astype(np.float64)
        vj = v[j]
        physics[name] = vj + w * (v[j1] - vj) if v.size else vj
    h = table.column("heading").to_numpy().astype(np.float64)
    hj = h[j]
    physics["heading"] = wrap_angle(hj + w * wrap_angle(h[j1] - hj)) if h.size else hj
    columns = {
        "frame": pa.array(k, pa.int64()),
        "time_ns": pa.array(k * step, pa.int64()),
        **{name: pa.array(values) for name, values in physics.items()},
    }
    # the other columns (ids, lanes, classes) take the nearest-earlier sample's value
    taken = table.select([n for n in table.column_names if n not in columns]).take(pa.array(j, pa.int64()))
    out = pa.Table.from_arrays(
        [columns[f.name].cast(f.type) if f.name in columns else taken.column(f.name) for f in table.schema],
        schema=table.schema,
    )
    recordings = {
        name: replace(
            rec,
            frame_rate=float(rate_hz),
            extra={**rec.extra, "native_frame_rate": rec.extra.get("native_frame_rate", rec.frame_rate)},
        )
        for name, rec in meta.recordings.items()
    }
    new_meta = replace(meta, recordings=recordings)
    return out.replace_schema_metadata({track_table.META_KEY: new_meta.to_json().encode()}), physics
