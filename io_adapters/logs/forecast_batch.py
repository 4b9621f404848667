"""Forecasts grouped by log time: the frames and batches every forecast encoder renders.

A forecasts table (``lanecast.io_adapters.contracts.forecasts``; without ``origin_x``/``origin_y``
the origins are interpolated from the tracks) is grouped by (t0, recording) into :class:`ForecastFrame` s, or kept column-wise as one
:class:`ForecastBatch` of many frames (what the bulk encoders take). Malformed columns raise
:class:`~lanecast.io_adapters.errors.InputError` naming the column.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc

from lanecast.io_adapters.contracts import forecasts as contract
from lanecast.io_adapters.contracts.forecasts import N_CLASSES, N_STEPS
from lanecast.io_adapters.contracts.windows import NEIGHBOUR_ROWS
from lanecast.io_adapters.errors import InputError

FORECAST_TOPIC = "/lanecast/forecast"


PREDICTION_TOPIC = "/lanecast/prediction"


#: What-if forecasts (``lanecast annotate --explain``): per target, the forecast with one neighbour removed.
EXPLAIN_TOPIC = "/lanecast/explain"


#: The neighbour slots a what-if removes, by index.
WHAT_IF_SLOTS: tuple[str, ...] = NEIGHBOUR_ROWS


@dataclass(frozen=True)
class ForecastFrame:
    """Every forecast of one log at one time t0 (M targets, K alternatives each)."""

    t0_ns: int
    recording: str
    frame_id: str
    horizon_s: np.ndarray  # float64 [5]
    track_id: np.ndarray  # int64 [M]
    origin: np.ndarray  # float64 [M, 2], NaN where unknown
    points: np.ndarray  # float64 [M, 5, 2]
    probs: np.ndarray  # float64 [M, 5, 3]
    maneuver: np.ndarray  # int64 [M, 5]
    alt_points: np.ndarray  # float64 [M, K, 5, 2]
    alt_prob: np.ndarray  # float64 [M, K]
    alt_maneuver: np.ndarray  # int64 [M, K, 5]
    lifetime_ns: int = 0
    removed: np.ndarray | None = None  # int64 [M]: what-ifs only, the neighbour slot removed (WHAT_IF_SLOTS)
    #: int8 [M]: 1 the target's state lies outside the model's training distribution, 0 inside, -1
    #: unknown (baselines); None: unknown for every target
    out_of_distribution: np.ndarray | None = None


@dataclass(frozen=True)
class ForecastBatch:
    """F forecast frames with their targets' rows concatenated: frame f is rows ``bounds[f]:bounds[f + 1]``.

    The arrays are those of :class:`ForecastFrame` over all N rows; what the bulk encoders take.
    """

    bounds: np.ndarray  # int64 [F + 1]
    t0_ns: np.ndarray  # int64 [F]
    recording: list[str]  # [F]
    frame_id: list[str]  # [F]
    horizon_s: np.ndarray  # float64 [5]
    track_id: np.ndarray  # int64 [N]
    origin: np.ndarray  # float64 [N, 2], NaN where unknown
    points: np.ndarray  # float64 [N, 5, 2]
    probs: np.ndarray  # float64 [N, 5, 3]
    maneuver: np.ndarray  # int64 [N, 5]
    alt_points: np.ndarray  # float64 [N, K, 5, 2]
    alt_prob: np.ndarray  # float64 [N, K]
    alt_maneuver: np.ndarray  # int64 [N, K, 5]
    lifetime_ns: int = 0
    removed: np.ndarray | None = None  # int64 [N]: what-ifs only, the neighbour slot removed (WHAT_IF_SLOTS)
    out_of_distribution: np.ndarray | None = None  # int8 [N]: 1 out, 0 in, -1 unknown (None: all unknown)

    @property
    def n_frames(self) -> int:
        return len(self.bounds) - 1

    @classmethod
    def empty(cls, lifetime_ns: int = 0) -> ForecastBatch:
        return cls(
            bounds=np.zeros(1, np.int64),
            t0_ns=np.zeros(0, np.int64),
            recording=[],
            frame_id=[],
            horizon_s=np.arange(1, N_STEPS + 1, dtype=np.float64),
            track_id=np.zeros(0, np.int64),
            origin=np.zeros((0, 2)),
            points=np.zeros((0, N_STEPS, 2)),
            probs=np.zeros((0, N_STEPS, 3)),
            maneuver=np.zeros((0, N_STEPS), np.int64),
            alt_points=np.zeros((0, 0, N_STEPS, 2)),
            alt_prob=np.zeros((0, 0)),
            alt_maneuver=np.zeros((0, 0, N_STEPS), np.int64),
            lifetime_ns=lifetime_ns,
        )

    @classmethod
    def of(cls, frame: ForecastFrame) -> ForecastBatch:
        """A batch of one frame."""
        return cls(
            bounds=np.array([0, frame.track_id.size], np.int64),
            t0_ns=np.array([frame.t0_ns], np.int64),
            recording=[frame.recording],
            frame_id=[frame.frame_id],
            **{name: getattr(frame, name) for name in _ROW_FIELDS},
            horizon_s=frame.horizon_s,
            lifetime_ns=frame.lifetime_ns,
            removed=frame.removed,
            out_of_distribution=frame.out_of_distribution,
        )

    def slice(self, first: int, last: int) -> ForecastBatch:
        """Frames ``first`` to ``last`` (exclusive) as a batch."""
        lo, hi = int(self.bounds[first]), int(self.bounds[last])
        return ForecastBatch(
            bounds=self.bounds[first : last + 1] - lo,
            t0_ns=self.t0_ns[first:last],
            recording=self.recording[first:last],
            frame_id=self.frame_id[first:last],
            horizon_s=self.horizon_s,
            **{name: getattr(self, name)[lo:hi] for name in _ROW_FIELDS},
            lifetime_ns=self.lifetime_ns,
            removed=None if self.removed is None else self.removed[lo:hi],
            out_of_distribution=None if self.out_of_distribution is None else self.out_of_distribution[lo:hi],
        )

    def frames(self) -> Iterator[ForecastFrame]:
        """The frames one by one (arrays are views)."""
        for f in range(self.n_frames):
            lo, hi = int(self.bounds[f]), int(self.bounds[f + 1])
            yield ForecastFrame(
                t0_ns=int(self.t0_ns[f]),
                recording=self.recording[f],
                frame_id=self.frame_id[f],
                horizon_s=self.horizon_s,
                **{name: getattr(self, name)[lo:hi] for name in _ROW_FIELDS},
                lifetime_ns=self.lifetime_ns,
                removed=None if self.removed is None else self.removed[lo:hi],
                out_of_distribution=None
                if self.out_of_distribution is None
                else self.out_of_distribution[lo:hi],
            )


_ROW_FIELDS = ("track_id", "origin", "points", "probs", "maneuver", "alt_points", "alt_prob", "alt_maneuver")


def _fixed_lists(
    table: pa.Table, name: str, shape: tuple[int, ...], dtype: type, fill: float | None = None
) -> np.ndarray:
    """A (nested) list column as an array of ``[rows, *shape]``; null rows get ``fill`` (an error
    when ``fill`` is None), other lengths raise InputError."""
    column: Any = table.column(name).combine_chunks()
    valid = np.asarray(column.is_valid().to_numpy(zero_copy_only=False), dtype=bool)
    if not valid.all():
        if fill is None:
            raise InputError(None, f"forecasts column {name!r} has null rows", column=name, expected="values")
        column = column.filter(pa.array(valid))
    values: Any = column
    while (
        pa.types.is_list(values.type)
        or pa.types.is_large_list(values.type)
        or pa.types.is_fixed_size_list(values.type)
    ):
        values = pc.list_flatten(values)
    flat: np.ndarray = np.asarray(values.to_numpy(zero_copy_only=False), dtype=dtype)
    rows = int(valid.sum())
    if flat.size != rows * int(np.prod(shape)):
        raise InputError(
            None,
            f"forecasts column {name!r} has {flat.size} values for {rows} rows",
            column=name,
            expected=f"{'×'.join(map(str, shape))} values per row",
        )
    out = np.full((table.num_rows, *shape), 0 if fill is None else fill, dtype=dtype)
    out[valid] = flat.reshape((rows, *shape))
    return out


def _origins_from_tracks(tracks: pa.Table, track_id: np.ndarray, t0_ns: np.ndarray) -> np.ndarray:
    """Target centre at t0 by linear interpolation within its track; NaN outside it. float64 [M, 2].

    tracks: a track table of one recording; track_id, t0_ns: int64 [M].
    """
    out = np.full((track_id.size, 2), np.nan)
    if tracks.num_rows == 0 or track_id.size == 0:
        return out
    tid = tracks.column("track_id").to_numpy()
    t = tracks.column("time_ns").to_numpy().astype(np.int64)
    order = np.lexsort((t, tid))
    tid, t = tid[order], t[order]
    xy = np.stack([tracks.column("x").to_numpy()[order], tracks.column("y").to_numpy()[order]], axis=-1)
    uniq, rank = np.unique(tid, return_inverse=True)
    base = int(min(t.min(), t0_ns.min()))
    span = int(max(t.max(), t0_ns.max())) - base + 1
    if uniq.size * span >= 2**62:
        raise InputError(
            None, "log too long to place forecasts on its tracks", expected="under 2^62 ns x tracks"
        )
    key = rank.astype(np.int64) * span + (t - base)  # increasing: rows sorted by (track, time)
    q_rank = np.searchsorted(uniq, track_id)
    known = (q_rank < uniq.size) & (uniq[np.minimum(q_rank, uniq.size - 1)] == track_id)
    q = np.minimum(q_rank, uniq.size - 1).astype(np.int64) * span + (t0_ns - base)
    hi = np.minimum(np.searchsorted(key, q, side="left"), t.size - 1)
    lo = np.maximum(hi - 1, 0)
    same_hi = rank[hi] == q_rank
    exact = same_hi & (t[hi] == t0_ns)
    inside = same_hi & (rank[lo] == q_rank) & (t[lo] <= t0_ns) & (t0_ns <= t[hi])
    lo = np.where(exact, hi, lo)
    dt = (t[hi] - t[lo]).astype(np.float64)
    w = np.where(dt > 0, (t0_ns - t[lo]) / np.where(dt > 0, dt, 1.0), 0.0)
    ok = known & (exact | inside)
    out[ok] = (xy[lo] + w[:, None] * (xy[hi] - xy[lo]))[ok]
    return out


def frames_from_table(
    forecasts: pa.Table,
    *,
    frame_id: str | Mapping[str, str],
    tracks: pa.Table | None = None,
    lifetime_s: float = 0.0,
) -> Iterator[ForecastFrame]:
    """Group a forecasts table by (t0, recording) (t0 ascending) into frames; targets by track id.

    ``frame_id``: the log's fixed frame, or one per recording. See :func:`batch_from_table`.
    """
    yield from batch_from_table(forecasts, frame_id=frame_id, tracks=tracks, lifetime_s=lifetime_s).frames()


def batch_from_table(
    forecasts: pa.Table,
    *,
    frame_id: str | Mapping[str, str],
    tracks: pa.Table | None = None,
    lifetime_s: float = 0.0,
) -> ForecastBatch:
    """A forecasts table as one batch of frames: rows sorted by (t0, recording, track id).

    ``frame_id``: the log's fixed frame, or one per recording.

    Origins come from ``origin_x``/``origin_y`` when present, else from ``tracks`` (interpolated at
    t0), else they are NaN and the line starts at the first predicted point.
    """
    contract.check_columns(forecasts)
    n = forecasts.num_rows
    if n == 0:
        return ForecastBatch.empty(lifetime_ns=round(lifetime_s * 1e9))
    t0 = forecasts.column("t0_ns").to_numpy().astype(np.int64)
    tid = forecasts.column("track_id").to_numpy().astype(np.int64)
    recording = forecasts.column("recording").cast(pa.string()).to_numpy(zero_copy_only=False).astype(str)
    rec_names, rec_code = np.unique(recording, return_inverse=True)
    order = np.lexsort((tid, rec_code, t0))
    forecasts = forecasts.take(pa.array(order))
    t0, tid, rec_code = t0[order], tid[order], rec_code[order]
    points = np.stack(
        [
            _fixed_lists(forecasts, "x", (N_STEPS,), np.float64),
            _fixed_lists(forecasts, "y", (N_STEPS,), np.float64),
        ],
        axis=-1,
    )
    # baselines give no maneuvers: NaN probabilities and maneuver -1 (drawn grey, "unknown")
    probs = _fixed_lists(forecasts, "maneuver_probs", (N_STEPS, N_CLASSES), np.float64, fill=np.nan)
    maneuver = _fixed_lists(forecasts, "maneuver", (N_STEPS,), np.int64, fill=-1)
    if "horizon_s" in forecasts.column_names:
        horizon = _fixed_lists(forecasts, "horizon_s", (N_STEPS,), np.float64)[0]
    else:
        horizon = np.arange(1, N_STEPS + 1, dtype=np.float64)
    if "origin_x" in forecasts.column_names and "origin_y" in forecasts.column_names:
        origin = np.stack(
            [
                forecasts.column(c).to_numpy(zero_copy_only=False).astype(np.float64)
                for c in ("origin_x", "origin_y")
            ],
            axis=-1,
        )
    elif tracks is not None and tracks.num_rows:
        origin = np.full((n, 2), np.nan)
        track_rec = tracks.column("recording").cast(pa.string())
        for code, name in enumerate(rec_names):  # per recording: track ids are unique only within one
            rows = rec_code == code
            mine = tracks.filter(pc.equal(track_rec, name))
            origin[rows] = _origins_from_tracks(mine, tid[rows], t0[rows])
    else:
        origin = np.full((n, 2), np.nan)
    if "alt_probs" in forecasts.column_names:
        k = len(forecasts.column("alt_probs")[0].as_py() or [])
        alt_prob = _fixed_lists(forecasts, "alt_probs", (k,), np.float64, fill=np.nan)
        alt_points = np.stack(
            [
                _fixed_lists(forecasts, "alt_x", (k, N_STEPS), np.float64),
                _fixed_lists(forecasts, "alt_y", (k, N_STEPS), np.float64),
            ],
            axis=-1,
        )
        if "alt_maneuvers" in forecasts.column_names:
            alt_maneuver = _fixed_lists(forecasts, "alt_maneuvers", (k, N_STEPS), np.int64, fill=-1)
        else:
            alt_maneuver = np.zeros((n, k, N_STEPS), dtype=np.int64)
    else:
        alt_prob = np.zeros((n, 0))
        alt_points = np.zeros((n, 0, N_STEPS, 2))
        alt_maneuver = np.zeros((n, 0, N_STEPS), dtype=np.int64)
    removed = None
    if contract.REMOVED_SLOT in forecasts.column_names:  # what-if forecasts (lanecast annotate --explain)
        removed = forecasts.column(contract.REMOVED_SLOT).to_numpy(zero_copy_only=False).astype(np.int64)
    ood = None
    if "out_of_distribution" in forecasts.column_names:
        column = forecasts.column("out_of_distribution")
        known = ~np.asarray(column.is_null())
        flagged = np.asarray(column.fill_null(False).to_numpy(zero_copy_only=False), dtype=bool)
        ood = np.where(known, flagged.astype(np.int8), np.int8(-1)).astype(np.int8)
    cuts = np.flatnonzero((np.diff(t0) != 0) | (np.diff(rec_code) != 0)) + 1
    bounds = np.r_[0, cuts, n].astype(np.int64)
    names = [str(rec_names[c]) for c in rec_code[bounds[:-1]].tolist()]
    return ForecastBatch(
        bounds=bounds,
        t0_ns=t0[bounds[:-1]],
        recording=names,
        frame_id=[frame_id if isinstance(frame_id, str) else frame_id.get(r, "map") for r in names],
        horizon_s=horizon,
        track_id=tid,
        origin=origin,
        points=points,
        probs=probs,
        maneuver=maneuver,
        alt_points=alt_points,
        alt_prob=alt_prob,
        alt_maneuver=alt_maneuver,
        lifetime_ns=round(lifetime_s * 1e9),
        removed=removed,
        out_of_distribution=ood,
    )
