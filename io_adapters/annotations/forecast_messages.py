"""Forecasts as log messages: ``foxglove.SceneUpdate`` on /lanecast/forecast and JSON on /lanecast/prediction.

A forecasts table (``lanecast.workflows.forecast.forecast_table``: one row per target and forecast time t0:
``recording``, ``track_id``, ``t0_ns``, ``x``, ``y`` (5 predicted positions, source frame, m),
``maneuver_probs`` (5×3, null for baselines), ``maneuver`` (5, null for baselines), optionally
``horizon_s`` (5), ``origin_x``/``origin_y`` (the target's centre at t0; else interpolated from the
tracks) and the top-K alternatives ``alt_x``/``alt_y`` (K×5), ``alt_probs`` (K), ``alt_maneuvers``
(K×5)) is grouped by (t0, recording) into :class:`ForecastFrame` s; each frame becomes one message
per topic, encoded as the log needs:

- ``protobuf``: ``foxglove.SceneUpdate`` (schema = serialized FileDescriptorSet), for plain MCAP;
- ``json``: Foxglove's JSON encoding of ``foxglove.SceneUpdate`` (schema encoding ``jsonschema``);
- ``cdr``: ROS 2 ``foxglove_msgs/msg/SceneUpdate`` (schema encoding ``ros2msg``), for ROS 2 logs.

/lanecast/prediction is JSON with lanecast's own JSON schema (:data:`PREDICTION_SCHEMA`); in ROS 2
logs it is a ``std_msgs/msg/String`` whose ``data`` is that same JSON text.

Drawing: one entity per target (id = track id), a LINE_STRIP from the target's position at t0 through
the 5 predicted points, coloured by the maneuver it predicts — the first lane change in the predicted
sequence, else straight: straight grey, left blue, right orange, unknown (baselines) purple, the colours
of the reports (``MANEUVER_COLOURS`` of the windows contract) — and the top-K alternatives as
fainter lines (alpha 0.35). Entity metadata holds the maneuver and the probabilities as JSON text.

Size: one module because every encoding (protobuf, JSON, CDR, the prediction JSON) renders the same
:class:`ForecastFrame` with the same colours and entity layout, and they are read side by side. The
natural cut, one module per wire format beside the frame grouping, waits until this wave's other
changes to it (issues 10, 11) have landed.
"""

from __future__ import annotations

import dataclasses
import functools
import json
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from importlib import resources
from typing import Any, Literal

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc

from lanecast.io_adapters.annotations import byte_rows as br
from lanecast.io_adapters.annotations.byte_rows import ByteRows
from lanecast.io_adapters.contracts.windows import MANEUVER_COLOURS, MANEUVERS, NEIGHBOUR_ROWS, UNKNOWN_COLOUR
from lanecast.io_adapters.errors import InputError
from lanecast.io_adapters.logs.mcap_writer import scene_update_jsonschema

FORECAST_TOPIC = "/lanecast/forecast"
PREDICTION_TOPIC = "/lanecast/prediction"
#: What-if forecasts (``lanecast annotate --explain``): per target, the forecast with one neighbour removed.
EXPLAIN_TOPIC = "/lanecast/explain"
#: The neighbour slots a what-if removes, by index.
WHAT_IF_SLOTS: tuple[str, ...] = NEIGHBOUR_ROWS
Encoding = Literal["protobuf", "json", "cdr"]
ENCODINGS: tuple[str, ...] = ("protobuf", "json", "cdr")

LABELS: tuple[str, ...] = (*MANEUVERS, "unknown")  # maneuver names by index; index -1: unknown
#: RGB per maneuver index (the windows contract's colours, as in the reports); index -1: unknown.
COLOURS: np.ndarray = np.array([*MANEUVER_COLOURS, UNKNOWN_COLOUR])
MAIN_ALPHA = 1.0
ALT_ALPHA = 0.35
LINE_THICKNESS_M = 0.3
N_STEPS = 5

PREDICTION_SCHEMA: dict[str, Any] = {
    "$schema": "http://json-schema.org/draft-07/schema#",
    "title": "lanecast.Prediction",
    "description": "lanecast forecasts at one time t0: per target, positions at t0 + horizon_s in frame_id "
    "(m) and maneuver probabilities (straight, left, right) per horizon step",
    "type": "object",
    "required": ["recording", "frame_id", "t0_ns", "horizon_s", "targets"],
    "properties": {
        "recording": {"type": "string"},
        "frame_id": {"type": "string"},
        "t0_ns": {"type": "integer"},
        "horizon_s": {"type": "array", "items": {"type": "number"}},
        "maneuver_names": {"type": "array", "items": {"type": "string"}},
        "targets": {
            "type": "array",
            "items": {
                "type": "object",
                "required": ["track_id", "x", "y", "maneuver", "maneuver_probs"],
                "properties": {
                    "track_id": {"type": "integer"},
                    "origin": {"type": ["array", "null"], "items": {"type": "number"}},
                    "x": {"type": "array", "items": {"type": "number"}},
                    "y": {"type": "array", "items": {"type": "number"}},
                    "maneuver": {"type": "array", "items": {"type": "integer", "minimum": -1, "maximum": 2}},
                    "maneuver_probs": {
                        "type": ["array", "null"],
                        "items": {"type": "array", "items": {"type": ["number", "null"]}},
                    },
                    "out_of_distribution": {
                        "type": ["boolean", "null"],
                        "description": "the target's state (speed, acceleration) lies outside the model's "
                        "training distribution: treat the forecast with caution (null: unknown)",
                    },
                    "alternatives": {
                        "type": "array",
                        "items": {
                            "type": "object",
                            "properties": {
                                "prob": {"type": ["number", "null"]},
                                "x": {"type": "array", "items": {"type": "number"}},
                                "y": {"type": "array", "items": {"type": "number"}},
                                "maneuver": {"type": "array", "items": {"type": "integer"}},
                            },
                        },
                    },
                },
            },
        },
    },
}


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


@dataclass(frozen=True)
class ChannelSpec:
    """What a writer registers for one forecast topic."""

    topic: str
    schema_name: str
    schema_encoding: str
    schema_data: bytes
    message_encoding: str
    ros_msgtype: str | None = None  # for rosbags writers (cdr only)


# --------------------------------------------------------------------------------------------- table


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
    for name in ("recording", "track_id", "t0_ns", "x", "y", "maneuver_probs", "maneuver"):
        if name not in forecasts.column_names:
            raise InputError(None, "forecasts table lacks a column", column=name)
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
    probs = _fixed_lists(forecasts, "maneuver_probs", (N_STEPS, 3), np.float64, fill=np.nan)
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
    if "removed_slot" in forecasts.column_names:  # what-if forecasts (lanecast annotate --explain)
        removed = forecasts.column("removed_slot").to_numpy(zero_copy_only=False).astype(np.int64)
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


# ------------------------------------------------------------------------------------ neutral scene


def dominant_maneuver(maneuver: np.ndarray) -> np.ndarray:
    """The first non-straight maneuver of each predicted sequence, else 0 (straight). [..., 5] -> [...]."""
    lane_change = maneuver != 0
    first = np.argmax(lane_change, axis=-1)
    picked = np.take_along_axis(maneuver, first[..., None], axis=-1)[..., 0]
    return np.where(lane_change.any(axis=-1), picked, 0)


@dataclass(frozen=True)
class _Drawing:
    """The drawing of a batch, independent of the encoding: N entities of L = 1 + K lines of 6 points.

    Line 0 is the main forecast, lines 1… the alternatives; point 0 of a line is the target's
    position at t0, dropped (``keep`` False) where it is unknown so that the line starts at the
    first predicted point. ``metadata``: (key, text per entity), in the entity's order.
    """

    row_frame: np.ndarray  # int64 [N]: frame of each entity
    ids: ByteRows  # [N] track ids as text
    xy: np.ndarray  # float64 [N, L, 6, 2]
    keep: np.ndarray  # bool [N, L, 6]
    rgba: np.ndarray  # float64 [N, L, 4]
    metadata: list[tuple[str, ByteRows]]


def _drawing(batch: ForecastBatch) -> _Drawing:
    n, k = batch.track_id.size, batch.alt_prob.shape[1]
    row_frame = np.repeat(np.arange(batch.n_frames), np.diff(batch.bounds))
    has_origin = ~np.isnan(batch.origin).any(axis=1)
    origin = np.where(has_origin[:, None], batch.origin, 0.0)
    lines = np.concatenate([batch.points[:, None], batch.alt_points], axis=1)  # [N, L, 5, 2]
    start = np.broadcast_to(origin[:, None, None, :], (n, k + 1, 1, 2))
    xy = np.concatenate([start, lines], axis=2)
    keep = np.ones((n, k + 1, N_STEPS + 1), bool)
    keep[:, :, 0] = has_origin[:, None]
    main = dominant_maneuver(batch.maneuver)  # [N]
    alt = dominant_maneuver(batch.alt_maneuver)  # [N, K]
    rgba = np.concatenate(
        [
            np.concatenate([COLOURS[main], np.full((n, 1), MAIN_ALPHA)], axis=-1)[:, None],
            np.concatenate([COLOURS[alt], np.full((n, k, 1), ALT_ALPHA)], axis=-1),
        ],
        axis=1,
    )
    ids = br.json_ints(batch.track_id)
    if batch.removed is not None:  # one entity per what-if: "<track id> without <slot>"
        suffix = np.array([f" without {slot}".encode() for slot in WHAT_IF_SLOTS], dtype="S")
        ids = ByteRows.from_strings(np.char.add(batch.track_id.astype("S"), suffix[batch.removed]))
    labels = ByteRows.from_strings(np.array(LABELS, dtype="S"))
    horizon = json.dumps(batch.horizon_s.tolist()).encode()
    metadata = [
        ("track_id", ids),
        ("maneuver", labels.take(main % len(LABELS))),
        ("maneuver_sequence", _sequence_texts(batch.maneuver)),
        ("maneuver_probs", _probability_texts(np.round(batch.probs, 4), batch.bounds, row_frame)),
        ("horizon_s", ByteRows.constant(horizon, n)),
        ("top_k_probs", _probability_texts(np.round(batch.alt_prob, 4), batch.bounds, row_frame)),
    ]
    if batch.removed is not None:
        slots = ByteRows.from_strings(np.array([s.encode() for s in WHAT_IF_SLOTS], dtype="S"))
        metadata += [
            ("target_track_id", br.json_ints(batch.track_id)),
            ("removed", slots.take(batch.removed)),
        ]
    return _Drawing(row_frame, ids, xy, keep, rgba, metadata)


@functools.lru_cache(maxsize=1024)
def _sequence_json(code: int) -> bytes:
    """JSON of the maneuver names of a sequence coded base 4 (digit i = step i's maneuver, 3 = unknown)."""
    return json.dumps([LABELS[(code >> (2 * i)) & 3] for i in range(N_STEPS)]).encode()


def _sequence_texts(maneuver: np.ndarray) -> ByteRows:
    """``["straight", "left", …]`` per row of maneuver [N, 5] (-1: "unknown")."""
    codes = ((maneuver % len(LABELS)) << (2 * np.arange(N_STEPS))).sum(axis=1)
    unique, inverse = np.unique(codes, return_inverse=True)
    table = np.array([_sequence_json(int(c)) for c in unique.tolist()] or [b""], dtype="S")
    return ByteRows.from_strings(table).take(inverse.reshape(-1))


def _probability_texts(values: np.ndarray, bounds: np.ndarray, row_frame: np.ndarray) -> ByteRows:
    """Python's text of each row of ``values`` [N, ...] as a (nested) list, ``", "`` between items.

    As the metadata always wrote it: in a frame that holds a NaN, NaN is ``null`` and a row of
    NaN only (or no values) is ``null`` itself.
    """
    n = values.shape[0]
    flat = values.reshape(n, -1)
    text = _four_decimals(flat.reshape(-1))
    rows = flat.size
    for width in reversed(values.shape[1:]):
        rows //= max(width, 1)
        text = br.json_lists(text, rows if width else n, width, b", ")
    nan_rows = np.isnan(flat).all(axis=1)  # True for rows without values too
    if n and (frame_nan := np.add.reduceat(~np.isfinite(flat).all(axis=1), bounds[:-1]) > 0).any():
        null = nan_rows & frame_nan[row_frame]
        text = br.concat(n, text.blank(~null), ByteRows.constant(b"null", n).blank(null))
    return text


@functools.cache
def _four_decimal_table() -> ByteRows:
    """Python's text of k / 10,000 for k = 0 … 10,000 (the probabilities as the metadata rounds them)."""
    return br.json_numbers(np.arange(10_001) / 10_000)


def _four_decimals(values: np.ndarray) -> ByteRows:
    """Like ``br.json_numbers`` for values rounded to 4 decimals in [0, 1] (a table look-up), NaN → null."""
    k = np.rint(values * 10_000)
    exact = (k >= 0) & (k <= 10_000) & (k / 10_000 == values)
    if not (exact | np.isnan(values)).all():
        return br.json_numbers(values)
    text = _four_decimal_table().take(np.where(exact, k, 0).astype(np.int64))
    nan = ~exact
    if nan.any():
        text = br.concat(len(values), text.blank(exact), ByteRows.constant(b"null", len(values)).blank(nan))
    return text


def _sec_nsec(ns: np.ndarray | int) -> tuple[np.ndarray, np.ndarray]:
    sec, nsec = np.divmod(np.asarray(ns, np.int64), 1_000_000_000)
    return np.atleast_1d(sec), np.atleast_1d(nsec)


# ------------------------------------------------------------------------------ /lanecast/prediction


def prediction_texts(batch: ForecastBatch) -> list[bytes]:
    """The /lanecast/prediction JSON document of each frame (:data:`PREDICTION_SCHEMA`), compact.

    Text equal to ``json.dumps(document, separators=(",", ":"))``; NaN (baselines) is null, a
    target's probabilities that are all NaN are null. Built as text templates filled column-wise
    (:func:`_fill_rows`): the cost is CPython formatting the numbers, as in ``json.dumps``, without
    a dict per target.
    """
    n, k = batch.track_id.size, batch.alt_prob.shape[1]
    if n == 0:
        return []
    has_origin = ~np.isnan(batch.origin).any(axis=1)
    origin = np.asarray(_fill_rows(["[", ",", "]"], _number_texts(batch.origin)), dtype=object)
    origin[~has_origin] = "null"
    steps = _fill_rows(["[", ",", ",", "]"], _number_texts(batch.probs.reshape(n * N_STEPS, 3)))
    probs = np.asarray(
        _fill_rows(["[", *[","] * (N_STEPS - 1), "]"], np.asarray(steps, dtype=object).reshape(n, N_STEPS)),
        dtype=object,
    )
    probs[np.isnan(batch.probs.reshape(n, -1)).all(axis=1)] = "null"
    list5 = [*[","] * (N_STEPS - 1), "]"]
    literals = ['{"track_id":', ',"origin":', ',"x":[', *list5[:-1], '],"y":[', *list5[:-1]]
    literals += ['],"maneuver":[', *list5[:-1], '],"maneuver_probs":', ',"out_of_distribution":']
    literals += [',"alternatives":[']
    columns = [
        _int_texts(batch.track_id[:, None]),
        origin[:, None],
        _number_texts(batch.points[..., 0]),
        _number_texts(batch.points[..., 1]),
        _int_texts(batch.maneuver),
        probs[:, None],
        _flag_texts(batch.out_of_distribution, n)[:, None],
    ]
    for j in range(k):
        literals[-1] += ("," if j else "") + '{"prob":'
        literals += [',"x":[', *list5[:-1], '],"y":[', *list5[:-1], '],"maneuver":[', *list5[:-1]]
        columns += [
            _number_texts(batch.alt_prob[:, j : j + 1]),
            _number_texts(batch.alt_points[:, j, :, 0]),
            _number_texts(batch.alt_points[:, j, :, 1]),
            _int_texts(batch.alt_maneuver[:, j]),
        ]
        literals.append("]}")
    literals[-1] += "]}"
    targets = _fill_rows(literals, np.concatenate(columns, axis=1))
    horizon = json.dumps(batch.horizon_s.tolist(), separators=(",", ":"))
    names = json.dumps(list(MANEUVERS), separators=(",", ":"))
    return [
        (
            f'{{"recording":{json.dumps(r)},"frame_id":{json.dumps(i)},"t0_ns":{t},'
            f'"horizon_s":{horizon},"maneuver_names":{names},"targets":[' + ",".join(targets[lo:hi]) + "]}"
        ).encode()
        for r, i, t, lo, hi in zip(
            batch.recording,
            batch.frame_id,
            batch.t0_ns.tolist(),
            batch.bounds[:-1].tolist(),
            batch.bounds[1:].tolist(),
            strict=True,
        )
    ]


def _number_texts(values: np.ndarray) -> np.ndarray:
    """Python's ``repr`` of each float64 of values [N, M] (NaN → ``null``): object [N, M]."""
    flat = np.asarray(values, np.float64)
    texts = np.array(list(map(float.__repr__, flat.ravel().tolist())), dtype=object)
    texts[np.isnan(flat.ravel())] = "null"
    return texts.reshape(flat.shape)


def _int_texts(values: np.ndarray) -> np.ndarray:
    """Decimal text of each integer of values [N, M]: object [N, M]."""
    flat = np.asarray(values, np.int64)
    return np.array(list(map(str, flat.ravel().tolist())), dtype=object).reshape(flat.shape)


def _fill_rows(literals: list[str], tokens: np.ndarray) -> list[str]:
    """One text per row: literals[0] tokens[i, 0] literals[1] … tokens[i, M-1] literals[M].

    tokens: object [N, M] of str, M + 1 literals. One ``str.join`` over all rows, cut at a
    separator byte that JSON text never holds unescaped (U+0001).
    """
    n, m = tokens.shape
    if len(literals) != m + 1:
        raise ValueError(f"{len(literals)} literals for {m} tokens")
    cells = np.empty((n, 2 * m + 2), dtype=object)
    cells[:, 0 : 2 * m : 2] = np.array(literals[:m], dtype=object)
    cells[:, 1 : 2 * m : 2] = tokens
    cells[:, 2 * m] = literals[m]
    cells[:, 2 * m + 1] = "\x01"
    return "".join(cells.ravel().tolist()).split("\x01")[:n]


def _flag_texts(flags: np.ndarray | None, n: int) -> np.ndarray:
    """JSON ``true`` / ``false`` / ``null`` per row from int8 flags [n] (1, 0, -1; None: all null): object [n]."""
    if flags is None:
        return np.full(n, "null", dtype=object)
    return np.array(["null", "false", "true"], dtype=object)[np.asarray(flags, np.int64) + 1]


def prediction_dict(frame: ForecastFrame) -> dict[str, Any]:
    """The /lanecast/prediction document of a frame (follows :data:`PREDICTION_SCHEMA`)."""
    doc: dict[str, Any] = json.loads(prediction_texts(ForecastBatch.of(frame))[0])
    return doc


# ------------------------------------------------------------------------------------------- JSON


def _json_string_rows(values: list[str]) -> ByteRows:
    """JSON string literals (quotes included) of a few values, e.g. one per frame."""
    return ByteRows.from_strings(np.array([json.dumps(v).encode() for v in values] or [b'""'], dtype="S"))


def scene_update_json(batch: ForecastBatch, drawing: _Drawing) -> list[bytes]:
    """Foxglove's JSON form of each frame's ``foxglove.SceneUpdate`` (compact, one row per frame)."""
    n, lines_per = drawing.xy.shape[0], drawing.xy.shape[1]
    f = batch.n_frames
    m = n * lines_per
    xy = drawing.xy.reshape(m * (N_STEPS + 1), 2)
    points = br.concat(
        len(xy), b'{"x":', br.json_numbers(xy[:, 0]), b',"y":', br.json_numbers(xy[:, 1]), b',"z":0.0}'
    )
    keep = drawing.keep.reshape(m, N_STEPS + 1)
    comma = keep & (np.cumsum(keep, axis=1) > 1)  # before every kept point but the line's first
    points = br.concat(
        len(xy), ByteRows.constant(b",", len(xy)).blank(comma.reshape(-1)), points.blank(keep.reshape(-1))
    ).group_every(N_STEPS + 1)
    rgba = drawing.rgba.reshape(m, 4)
    identity = b'{"position":{"x":0.0,"y":0.0,"z":0.0},"orientation":{"x":0.0,"y":0.0,"z":0.0,"w":1.0}}'
    lines = br.concat(
        m,
        b'{"type":0,"pose":' + identity + b',"thickness":' + repr(LINE_THICKNESS_M).encode(),
        b',"scale_invariant":false,"points":[',
        points,
        b'],"color":{"r":',
        br.json_numbers(rgba[:, 0]),
        b',"g":',
        br.json_numbers(rgba[:, 1]),
        b',"b":',
        br.json_numbers(rgba[:, 2]),
        b',"a":',
        br.json_numbers(rgba[:, 3]),
        b'},"colors":[],"indices":[]}',
    )
    metadata: list[br.Column] = []
    for i, (key, value) in enumerate(drawing.metadata):
        metadata += [(b"," if i else b"") + b'{"key":' + json.dumps(key).encode() + b',"value":"']
        metadata += [br.escape_quotes(value), b'"}']
    sec, nsec = _sec_nsec(batch.t0_ns)
    lsec, lnsec = _sec_nsec(batch.lifetime_ns)
    stamp = br.concat(f, b'{"timestamp":{"sec":', br.json_ints(sec), b',"nsec":', br.json_ints(nsec), b"}")
    entities = br.concat(
        n,
        stamp.take(drawing.row_frame),
        b',"frame_id":',
        _json_string_rows(batch.frame_id).take(drawing.row_frame),
        b',"id":"',
        drawing.ids,
        f'","lifetime":{{"sec":{int(lsec[0])},"nsec":{int(lnsec[0])}}},"frame_locked":false,"metadata":['.encode(),
        *metadata,
        b'],"arrows":[],"cubes":[],"spheres":[],"cylinders":[],"lines":',
        br.json_lists(lines, n, lines_per),
        b',"triangles":[],"texts":[],"models":[]}',
    )
    return [b'{"deletions":[],"entities":[' + body + b"]}" for body in entities.join(batch.bounds, b",")]


# --------------------------------------------------------------------------------------- protobuf

# Constant parts of a LINE_STRIP (type 0 is the default: not written): pose = identity orientation,
# thickness. Field numbers from foxglove's LinePrimitive, SceneEntity and SceneUpdate .proto files.
_PB_POSE = br.length_delimited(2, br.length_delimited(2, br.doubles(4, np.ones(1)))).join()[0]
_PB_THICKNESS = br.doubles(3, np.array([LINE_THICKNESS_M])).join()[0]


def _pb_time(sec: np.ndarray, nsec: np.ndarray) -> ByteRows:
    """google.protobuf.Timestamp/Duration payloads (seconds 1, nanos 2; zeros not written)."""
    return br.concat(len(sec), br.int_field(1, sec), br.int_field(2, nsec))


def _pb_string(field: int, rows: ByteRows) -> ByteRows:
    """A proto3 string field per row; empty strings are not written."""
    return br.length_delimited(field, rows).blank(rows.lengths > 0)


@functools.cache
def _pb_key(key: str) -> bytes:
    """A KeyValuePair's key field (1)."""
    return br.length_delimited(1, ByteRows.constant(key.encode(), 1)).join()[0]


def scene_update_protobuf(batch: ForecastBatch, drawing: _Drawing) -> list[bytes]:
    """Each frame's ``foxglove.SceneUpdate`` serialized (protobuf wire format, one row per frame).

    Byte for byte what ``SceneUpdate.SerializeToString()`` writes for the same message: fields in
    number order, proto3 defaults (0, +0.0, false, "") omitted, sub-messages that were set kept.
    """
    n, lines_per = drawing.xy.shape[0], drawing.xy.shape[1]
    m = n * lines_per
    xy = drawing.xy.reshape(-1, 2)
    points = br.length_delimited(5, br.concat(len(xy), br.doubles(1, xy[:, 0]), br.doubles(2, xy[:, 1])))
    points = points.blank(drawing.keep.reshape(-1)).group_every(N_STEPS + 1)
    rgba = drawing.rgba.reshape(m, 4)
    color = br.length_delimited(6, br.concat(m, *(br.doubles(i + 1, rgba[:, i]) for i in range(4))))
    lines = br.length_delimited(11, br.concat(m, _PB_POSE, _PB_THICKNESS, points, color))
    sec, nsec = _sec_nsec(batch.t0_ns)
    lsec, lnsec = _sec_nsec(batch.lifetime_ns)
    frame_ids = ByteRows.from_strings(np.array([f.encode() for f in batch.frame_id] or [b""], dtype="S"))
    metadata = [
        br.length_delimited(
            6,
            br.concat(n, _pb_key(key), _pb_string(2, value)),
        )
        for key, value in drawing.metadata
    ]
    entities = br.length_delimited(
        2,
        br.concat(
            n,
            br.length_delimited(1, _pb_time(sec, nsec)).take(drawing.row_frame),
            _pb_string(2, frame_ids).take(drawing.row_frame),
            _pb_string(3, drawing.ids),
            br.length_delimited(4, _pb_time(lsec, lnsec)).join()[0],
            *metadata,
            lines.group_every(lines_per),
        ),
    )
    return entities.join(batch.bounds)


@functools.cache
def _protobuf_schema() -> bytes:
    from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate
    from mcap_protobuf.schema import build_file_descriptor_set

    return bytes(build_file_descriptor_set(SceneUpdate).SerializeToString())


# -------------------------------------------------------------------------------------------- CDR


@functools.cache
def ros2_typestore() -> Any:
    """A rosbags ROS 2 typestore with every ``foxglove_msgs/msg/*`` type registered from the .msg files."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE)
    types: dict[str, Any] = {}
    folder = resources.files("lanecast.io_adapters") / "data" / "foxglove" / "ros2"
    for entry in sorted(folder.iterdir(), key=lambda p: p.name):
        if entry.name.endswith(".msg"):
            types.update(get_types_from_msg(entry.read_text(), f"foxglove_msgs/msg/{entry.name[:-4]}"))
    store.register(types)
    return store


SCENE_UPDATE_ROS2 = "foxglove_msgs/msg/SceneUpdate"
STRING_ROS2 = "std_msgs/msg/String"


CDR_HEADER = b"\x00\x01\x00\x00"  # XCDR1, little endian: what rosbags' serialize_cdr writes
_CDR_POSE = np.array([0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0], "<f8").tobytes()  # position 0, identity orientation
_CDR_LINE_HEAD = b"\x00"  # type LINE_STRIP (uint8)


class _CdrLayout:
    """Columns of N CDR serializations written side by side, with each row's position (mod 8) tracked.

    Alignment (padding with zeros to a multiple of the field's size, counted from the start of the
    payload after the 4-byte header) depends on what came before, so every row has its own cursor.
    ``build`` False only tracks positions (to learn a row's size for a given start).
    """

    def __init__(self, start: np.ndarray, build: bool = True) -> None:
        self.pos = np.asarray(start, np.int64).copy()
        self.n = len(self.pos)
        self.build = build
        self.columns: list[br.Column] = []

    def pad(self, align: int) -> None:
        padding = (-self.pos) % align
        if self.build and padding.any():
            self.columns.append(ByteRows.from_matrix(np.zeros((self.n, 8), np.uint8), padding))
        self.pos += padding

    def put(self, column: br.Column | None, size: np.ndarray | int) -> None:
        if self.build and column is not None:
            self.columns.append(column)
        self.pos += size

    def u32(self, value: int) -> None:
        self.pad(4)
        self.put(np.uint32(value).tobytes(), 4)

    def string(self, rows: ByteRows | None, lengths: np.ndarray) -> None:
        """A string: uint32 length with the NUL, the bytes, NUL."""
        self.pad(4)
        if self.build and rows is not None:
            self.put(br.concat(self.n, _u32_rows(lengths + 1), rows, b"\x00"), 5 + lengths)
        else:
            self.pos += 5 + lengths

    def rows(self) -> ByteRows:
        return br.concat(self.n, *self.columns)


def _u32_rows(values: np.ndarray) -> ByteRows:
    """Little-endian uint32 per row."""
    return br.fixed(np.asarray(values)[:, None], "<u4")


def _cdr_entities(batch: ForecastBatch, drawing: _Drawing, start: np.ndarray, build: bool) -> _CdrLayout:
    """The SceneEntity of every target, each starting at payload position ``start`` (mod 8)."""
    n, lines_per = drawing.xy.shape[0], drawing.xy.shape[1]
    sec, nsec = _sec_nsec(batch.t0_ns)
    lsec, lnsec = _sec_nsec(batch.lifetime_ns)
    frame_ids = ByteRows.from_strings(np.array([f.encode() for f in batch.frame_id] or [b""], dtype="S"))
    frame_ids = frame_ids.take(drawing.row_frame)
    out = _CdrLayout(start, build)
    out.pad(4)
    stamp = np.stack([sec.astype("<i4").view("<u4"), nsec.astype("<u4")], axis=1)[drawing.row_frame]
    out.put(ByteRows.from_matrix(stamp.view(np.uint8).reshape(n, 8), np.full(n, 8)) if build else None, 8)
    out.string(frame_ids, frame_ids.lengths)
    out.string(drawing.ids, drawing.ids.lengths)
    out.pad(4)
    out.put(
        np.array([lsec[0], lnsec[0]], "<i8").astype("<i4").tobytes() + b"\x00", 9
    )  # lifetime, frame_locked
    out.u32(len(drawing.metadata))
    for key, value in drawing.metadata:
        out.string(ByteRows.constant(key.encode(), n), np.full(n, len(key.encode())))
        out.string(value, value.lengths)
    for _ in range(4):  # arrows, cubes, spheres, cylinders
        out.u32(0)
    out.u32(lines_per)
    keep = drawing.keep
    for j in range(lines_per):
        out.put(_CDR_LINE_HEAD, 1)
        out.pad(8)
        out.put(
            _CDR_POSE + np.float64(LINE_THICKNESS_M).tobytes() + b"\x00", 65
        )  # pose, thickness, scale_invariant
        count = keep[:, j].sum(axis=1)
        out.pad(4)
        out.put(_u32_rows(count) if build else None, 4)
        out.pad(8)
        if build:
            xyz = np.zeros((n, N_STEPS + 1, 3), "<f8")
            xyz[..., :2] = drawing.xy[:, j]
            points = ByteRows.from_matrix(
                xyz.view(np.uint8).reshape(n * (N_STEPS + 1), 24), np.full(n * (N_STEPS + 1), 24)
            )
            out.put(points.blank(keep[:, j].reshape(-1)).group_every(N_STEPS + 1), 24 * count)
            rgba = np.ascontiguousarray(drawing.rgba[:, j], "<f8")
            out.put(ByteRows.from_matrix(rgba.view(np.uint8).reshape(n, 32), np.full(n, 32)), 32)
        else:
            out.put(None, 24 * count + 32)
        out.u32(0)  # colors
        out.u32(0)  # indices
    for _ in range(3):  # triangles, texts, models
        out.u32(0)
    return out


def scene_update_cdr(batch: ForecastBatch, drawing: _Drawing) -> list[bytes]:
    """Each frame's ROS 2 ``foxglove_msgs/msg/SceneUpdate`` as CDR (one row per frame).

    Byte for byte what rosbags' ``serialize_cdr`` writes. An entity's padding depends on where it
    starts (mod 8), which depends on every entity before it in its message: the start of each
    entity is found with a parallel prefix scan over the two possible residues (0 or 4).
    """
    n, f = drawing.xy.shape[0], batch.n_frames
    size0 = _cdr_entities(batch, drawing, np.zeros(n, np.int64), build=False).pos
    size4 = _cdr_entities(batch, drawing, np.full(n, 4, np.int64), build=False).pos - 4
    # state = start residue / 4 (0 or 1); after entity i: (state*4 + size_state) mod 8 / 4
    after = np.stack([(size0 % 8) // 4, ((4 + size4) % 8) // 4], axis=1)  # [N, 2]
    entering = np.empty((n, 2), np.int64)  # map from "state entering the previous entity" to mine
    entering[1:] = after[:-1]
    first = np.asarray(batch.bounds[:-1], np.int64)[np.diff(batch.bounds) > 0]
    entering[first] = 0  # the first entity of a message starts at payload offset 8
    scan = entering.copy()
    step = 1
    while step < n:  # inclusive prefix composition: scan[i] = entering[i] ∘ … ∘ entering[0]
        scan[step:] = np.take_along_axis(scan[step:], scan[:-step], axis=1)
        step *= 2
    start = scan[:, 0] * 4
    entities = _cdr_entities(batch, drawing, start, build=True).rows()
    counts = np.diff(batch.bounds)
    head = np.zeros((f, 12), np.uint8)
    head[:, :4] = np.frombuffer(CDR_HEADER, np.uint8)
    head[:, 8:] = counts.astype("<u4").view(np.uint8).reshape(f, 4)
    return [h.tobytes() + body for h, body in zip(head, entities.join(batch.bounds), strict=True)]


def strings_cdr(texts: list[bytes]) -> list[bytes]:
    """Each text as a ROS 2 ``std_msgs/msg/String`` in CDR (one header and length per message)."""
    return [CDR_HEADER + np.uint32(len(t) + 1).tobytes() + t + b"\x00" for t in texts]


# -------------------------------------------------------------------------------------------- API


def channel_specs(encoding: str) -> list[ChannelSpec]:
    """The two forecast channels (forecast, prediction) a log with ``encoding`` gets."""
    if encoding == "protobuf":
        scene = ChannelSpec(
            FORECAST_TOPIC, "foxglove.SceneUpdate", "protobuf", _protobuf_schema(), "protobuf"
        )
    elif encoding == "json":
        scene = ChannelSpec(
            FORECAST_TOPIC, "foxglove.SceneUpdate", "jsonschema", scene_update_jsonschema(), "json"
        )
    elif encoding == "cdr":
        store = ros2_typestore()
        scene_def, _ = store.generate_msgdef(SCENE_UPDATE_ROS2, ros_version=2)
        string_def, _ = store.generate_msgdef(STRING_ROS2, ros_version=2)
        scene = ChannelSpec(
            FORECAST_TOPIC, SCENE_UPDATE_ROS2, "ros2msg", scene_def.encode(), "cdr", SCENE_UPDATE_ROS2
        )
        pred = ChannelSpec(PREDICTION_TOPIC, STRING_ROS2, "ros2msg", string_def.encode(), "cdr", STRING_ROS2)
        return [scene, pred]
    else:
        raise InputError(None, f"unknown forecast encoding {encoding!r}", expected=f"one of {ENCODINGS}")
    pred = ChannelSpec(
        PREDICTION_TOPIC, "lanecast.Prediction", "jsonschema", json.dumps(PREDICTION_SCHEMA).encode(), "json"
    )
    return [scene, pred]


#: Targets encoded per bulk pass: bounds the memory of the encoded messages, not their speed.
BULK_ROWS = 20_000


def explain_channel_spec(encoding: str) -> ChannelSpec:
    """The /lanecast/explain channel: SceneUpdate as on /lanecast/forecast, one entity per what-if."""
    return dataclasses.replace(channel_specs(encoding)[0], topic=EXPLAIN_TOPIC)


def encode_batch(batch: ForecastBatch, encoding: str) -> Iterator[tuple[int, bytes, bytes]]:
    """(t0 in ns, /lanecast/forecast payload, /lanecast/prediction payload) of each frame, in order.

    Frames are encoded in bulk, up to :data:`BULK_ROWS` targets at a time.
    """
    if encoding not in ENCODINGS:
        raise InputError(None, f"unknown forecast encoding {encoding!r}", expected=f"one of {ENCODINGS}")
    first = 0
    while first < batch.n_frames:
        last = int(np.searchsorted(batch.bounds, batch.bounds[first] + BULK_ROWS, side="right")) - 1
        last = min(max(last, first + 1), batch.n_frames)
        part = batch.slice(first, last)
        drawing = _drawing(part)
        predictions = prediction_texts(part)
        if encoding == "protobuf":
            scenes = scene_update_protobuf(part, drawing)
        elif encoding == "json":
            scenes = scene_update_json(part, drawing)
        else:
            scenes = scene_update_cdr(part, drawing)
            predictions = strings_cdr(predictions)
        yield from zip(part.t0_ns.tolist(), scenes, predictions, strict=True)
        first = last


def encode_frame(frame: ForecastFrame, encoding: str) -> tuple[bytes, bytes]:
    """(/lanecast/forecast payload, /lanecast/prediction payload) of one frame in ``encoding``."""
    ((_, scene, prediction),) = encode_batch(ForecastBatch.of(frame), encoding)
    return scene, prediction
