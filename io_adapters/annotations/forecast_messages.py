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
sequence, else straight: straight blue, left green, right orange, unknown (baselines) grey — and the top-K alternatives as
fainter lines (alpha 0.35). Entity metadata holds the maneuver and the probabilities as JSON text.
"""

from __future__ import annotations

import functools
import json
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from importlib import resources
from typing import Any, Literal

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc

from lanecast.io_adapters.contracts.windows import MANEUVERS
from lanecast.io_adapters.errors import InputError
from lanecast.io_adapters.logs.mcap_writer import scene_update_jsonschema

FORECAST_TOPIC = "/lanecast/forecast"
PREDICTION_TOPIC = "/lanecast/prediction"
Encoding = Literal["protobuf", "json", "cdr"]
ENCODINGS: tuple[str, ...] = ("protobuf", "json", "cdr")

LABELS: tuple[str, ...] = (*MANEUVERS, "unknown")  # maneuver names by index; index -1: unknown
# RGB per maneuver index: straight blue, left green, right orange.
COLOURS: np.ndarray = np.array(
    [[0.20, 0.55, 1.00], [0.10, 0.80, 0.25], [1.00, 0.45, 0.10], [0.60, 0.60, 0.60]]
)  # straight blue, left green, right orange, unknown (index -1) grey
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

    ``frame_id``: the log's fixed frame, or one per recording.

    Origins come from ``origin_x``/``origin_y`` when present, else from ``tracks`` (interpolated at
    t0), else they are NaN and the line starts at the first predicted point.
    """
    for name in ("recording", "track_id", "t0_ns", "x", "y", "maneuver_probs", "maneuver"):
        if name not in forecasts.column_names:
            raise InputError(None, "forecasts table lacks a column", column=name)
    n = forecasts.num_rows
    if n == 0:
        return
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
    cuts = np.flatnonzero((np.diff(t0) != 0) | (np.diff(rec_code) != 0)) + 1
    lifetime_ns = round(lifetime_s * 1e9)
    for lo, hi in zip(np.r_[0, cuts], np.r_[cuts, n], strict=True):
        yield ForecastFrame(
            t0_ns=int(t0[lo]),
            recording=str(rec_names[rec_code[lo]]),
            frame_id=frame_id
            if isinstance(frame_id, str)
            else frame_id.get(str(rec_names[rec_code[lo]]), "map"),
            horizon_s=horizon,
            track_id=tid[lo:hi],
            origin=origin[lo:hi],
            points=points[lo:hi],
            probs=probs[lo:hi],
            maneuver=maneuver[lo:hi],
            alt_points=alt_points[lo:hi],
            alt_prob=alt_prob[lo:hi],
            alt_maneuver=alt_maneuver[lo:hi],
            lifetime_ns=lifetime_ns,
        )


# ------------------------------------------------------------------------------------ neutral scene


def dominant_maneuver(maneuver: np.ndarray) -> np.ndarray:
    """The first non-straight maneuver of each predicted sequence, else 0 (straight). [..., 5] -> [...]."""
    lane_change = maneuver != 0
    first = np.argmax(lane_change, axis=-1)
    picked = np.take_along_axis(maneuver, first[..., None], axis=-1)[..., 0]
    return np.where(lane_change.any(axis=-1), picked, 0)


@dataclass(frozen=True)
class _Line:
    points: list[list[float]]  # [P][3] (x, y, z)
    rgba: tuple[float, float, float, float]


@dataclass(frozen=True)
class _Entity:
    id: str
    metadata: list[tuple[str, str]]
    lines: list[_Line]


def _entities(frame: ForecastFrame) -> list[_Entity]:
    """The drawing of a frame, independent of the encoding (arrays converted once per frame)."""
    m, k = frame.track_id.size, frame.alt_prob.shape[1]
    has_origin = ~np.isnan(frame.origin).any(axis=1)  # [M]
    start = np.where(has_origin, 0, 1).tolist()  # without an origin the line starts at the first point
    origin = np.where(has_origin[:, None], frame.origin, 0.0)
    main_xy = np.concatenate([origin[:, None, :], frame.points], axis=1)  # [M, 6, 2]
    main_pts = np.concatenate([main_xy, np.zeros((m, N_STEPS + 1, 1))], axis=-1).tolist()  # [M][6][3]
    alt_xy = np.concatenate(
        [np.broadcast_to(origin[:, None, None, :], (m, k, 1, 2)), frame.alt_points], axis=2
    )
    alt_pts = np.concatenate([alt_xy, np.zeros((m, k, N_STEPS + 1, 1))], axis=-1).tolist()  # [M][K][6][3]
    main = dominant_maneuver(frame.maneuver)  # [M]
    alt = dominant_maneuver(frame.alt_maneuver)  # [M, K]
    main_rgba = [(*c, MAIN_ALPHA) for c in COLOURS[main].tolist()]
    alt_rgba = [[(*c, ALT_ALPHA) for c in row] for row in COLOURS[alt].tolist()]
    ids = frame.track_id.astype(str).tolist()
    names = [LABELS[j] for j in main.tolist()]
    sequences = [_sequence_json(tuple(row)) for row in frame.maneuver.tolist()]
    probs = _json_rows(np.round(frame.probs, 4))
    top_k = _json_rows(np.round(frame.alt_prob, 4))
    horizon = json.dumps(frame.horizon_s.tolist())
    entities = []
    for i in range(m):
        s = start[i]
        lines = [_Line(main_pts[i][s:], main_rgba[i])]
        lines += [_Line(alt_pts[i][j][s:], alt_rgba[i][j]) for j in range(k)]
        metadata = [
            ("track_id", ids[i]),
            ("maneuver", names[i]),
            ("maneuver_sequence", sequences[i]),
            ("maneuver_probs", probs[i]),
            ("horizon_s", horizon),
            ("top_k_probs", top_k[i]),
        ]
        entities.append(_Entity(ids[i], metadata, lines))
    return entities


@functools.lru_cache(maxsize=1024)
def _sequence_json(row: tuple[int, ...]) -> str:
    return json.dumps([LABELS[j] for j in row])


def _json_rows(values: np.ndarray) -> list[str]:
    """One JSON text per row of ``values`` [M, ...] (NaN as null); finite rows take a fast path
    (Python's text of a list of finite floats is JSON)."""
    if np.isfinite(values).all():
        return [str(row) for row in values.tolist()]
    return [json.dumps(_nan_to_none(row)) for row in values]


def _nan_to_none(values: np.ndarray | np.floating) -> Any:
    """Nested lists (or a float) with NaN as None: JSON has no NaN."""
    arr = np.asarray(values, dtype=np.float64)
    nan = np.isnan(arr)
    if nan.all():
        return None
    if nan.any():
        boxed = arr.astype(object)
        boxed[nan] = None
        return boxed.tolist()
    return arr.tolist()


def prediction_dict(frame: ForecastFrame) -> dict[str, Any]:
    """The /lanecast/prediction document of a frame (follows :data:`PREDICTION_SCHEMA`)."""
    m, k = frame.track_id.size, frame.alt_prob.shape[1]
    has_origin = ~np.isnan(frame.origin).any(axis=1)
    origin = frame.origin.tolist()
    xs, ys = frame.points[..., 0].tolist(), frame.points[..., 1].tolist()
    maneuver = frame.maneuver.tolist()
    if np.isfinite(frame.probs).all() and np.isfinite(frame.alt_prob).all():
        probs, alt_prob = frame.probs.tolist(), frame.alt_prob.reshape(-1).tolist()
    else:
        probs = [_nan_to_none(p) for p in frame.probs]
        alt_prob = [_nan_to_none(p) for p in frame.alt_prob.reshape(-1)]
    alt_x, alt_y = frame.alt_points[..., 0].tolist(), frame.alt_points[..., 1].tolist()
    alt_maneuver = frame.alt_maneuver.tolist()
    targets = [
        {
            "track_id": tid,
            "origin": origin[i] if has_origin[i] else None,
            "x": xs[i],
            "y": ys[i],
            "maneuver": maneuver[i],
            "maneuver_probs": probs[i],
            "alternatives": [
                {
                    "prob": alt_prob[i * k + j],
                    "x": alt_x[i][j],
                    "y": alt_y[i][j],
                    "maneuver": alt_maneuver[i][j],
                }
                for j in range(k)
            ],
        }
        for i, tid in zip(range(m), frame.track_id.tolist(), strict=True)
    ]
    return {
        "recording": frame.recording,
        "frame_id": frame.frame_id,
        "t0_ns": frame.t0_ns,
        "horizon_s": frame.horizon_s.tolist(),
        "maneuver_names": list(MANEUVERS),
        "targets": targets,
    }


def _sec_nsec(ns: int) -> tuple[int, int]:
    return ns // 1_000_000_000, ns % 1_000_000_000


# ------------------------------------------------------------------------------------------- JSON


def scene_update_dict(frame: ForecastFrame) -> dict[str, Any]:
    """Foxglove's JSON form of the frame's ``foxglove.SceneUpdate``."""
    sec, nsec = _sec_nsec(frame.t0_ns)
    lsec, lnsec = _sec_nsec(frame.lifetime_ns)
    identity = {
        "position": {"x": 0.0, "y": 0.0, "z": 0.0},
        "orientation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0},
    }
    entities = []
    for e in _entities(frame):
        entities.append(
            {
                "timestamp": {"sec": sec, "nsec": nsec},
                "frame_id": frame.frame_id,
                "id": e.id,
                "lifetime": {"sec": lsec, "nsec": lnsec},
                "frame_locked": False,
                "metadata": [{"key": k, "value": v} for k, v in e.metadata],
                "arrows": [],
                "cubes": [],
                "spheres": [],
                "cylinders": [],
                "lines": [
                    {
                        "type": 0,
                        "pose": identity,
                        "thickness": LINE_THICKNESS_M,
                        "scale_invariant": False,
                        "points": [{"x": x, "y": y, "z": z} for x, y, z in line.points],
                        "color": dict(zip("rgba", line.rgba, strict=True)),
                        "colors": [],
                        "indices": [],
                    }
                    for line in e.lines
                ],
                "triangles": [],
                "texts": [],
                "lanecast.models": [],
            }
        )
    return {"deletions": [], "entities": entities}


# --------------------------------------------------------------------------------------- protobuf


def _scene_update_protobuf(frame: ForecastFrame) -> bytes:
    from foxglove_schemas_protobuf.LinePrimitive_pb2 import LinePrimitive
    from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate

    msg = SceneUpdate()
    sec, nsec = _sec_nsec(frame.t0_ns)
    lsec, lnsec = _sec_nsec(frame.lifetime_ns)
    for e in _entities(frame):
        ent = msg.entities.add()
        ent.timestamp.seconds, ent.timestamp.nanos = sec, nsec
        ent.frame_id = frame.frame_id
        ent.id = e.id
        ent.lifetime.seconds, ent.lifetime.nanos = lsec, lnsec
        ent.frame_locked = False
        for k, v in e.metadata:
            kv = ent.metadata.add()
            kv.key, kv.value = k, v
        for line in e.lines:
            lp = ent.lines.add()
            lp.type = LinePrimitive.LINE_STRIP
            lp.pose.orientation.w = 1.0
            lp.thickness = LINE_THICKNESS_M
            lp.scale_invariant = False
            for x, y, z in line.points:
                lp.points.add(x=x, y=y, z=z)
            lp.color.r, lp.color.g, lp.color.b, lp.color.a = line.rgba
    return msg.SerializeToString()


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


def _scene_update_cdr(frame: ForecastFrame) -> bytes:
    store = ros2_typestore()
    T = store.types
    Time, Duration = T["builtin_interfaces/msg/Time"], T["builtin_interfaces/msg/Duration"]
    Pose, Point, Quat = (
        T["geometry_msgs/msg/Pose"],
        T["geometry_msgs/msg/Point"],
        T["geometry_msgs/msg/Quaternion"],
    )
    Color, KV = T["foxglove_msgs/msg/Color"], T["foxglove_msgs/msg/KeyValuePair"]
    Line, Entity, Update = (
        T["foxglove_msgs/msg/LinePrimitive"],
        T["foxglove_msgs/msg/SceneEntity"],
        T[SCENE_UPDATE_ROS2],
    )
    sec, nsec = _sec_nsec(frame.t0_ns)
    lsec, lnsec = _sec_nsec(frame.lifetime_ns)
    identity = Pose(position=Point(x=0.0, y=0.0, z=0.0), orientation=Quat(x=0.0, y=0.0, z=0.0, w=1.0))
    no_indices = np.zeros(0, dtype=np.uint32)
    entities = [
        Entity(
            timestamp=Time(sec=sec, nanosec=nsec),
            frame_id=frame.frame_id,
            id=e.id,
            lifetime=Duration(sec=lsec, nanosec=lnsec),
            frame_locked=False,
            metadata=[KV(key=k, value=v) for k, v in e.metadata],
            arrows=[],
            cubes=[],
            spheres=[],
            cylinders=[],
            lines=[
                Line(
                    type=0,
                    pose=identity,
                    thickness=LINE_THICKNESS_M,
                    scale_invariant=False,
                    points=[Point(x=x, y=y, z=z) for x, y, z in line.points],
                    color=Color(r=line.rgba[0], g=line.rgba[1], b=line.rgba[2], a=line.rgba[3]),
                    colors=[],
                    indices=no_indices,
                )
                for line in e.lines
            ],
            triangles=[],
            texts=[],
            models=[],
        )
        for e in _entities(frame)
    ]
    return bytes(store.serialize_cdr(Update(deletions=[], entities=entities), SCENE_UPDATE_ROS2))


def _string_cdr(text: str) -> bytes:
    store = ros2_typestore()
    return bytes(store.serialize_cdr(store.types[STRING_ROS2](data=text), STRING_ROS2))


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


def encode_frame(frame: ForecastFrame, encoding: str) -> tuple[bytes, bytes]:
    """(/lanecast/forecast payload, /lanecast/prediction payload) of one frame in ``encoding``."""
    prediction = json.dumps(prediction_dict(frame), separators=(",", ":"))
    if encoding == "protobuf":
        return _scene_update_protobuf(frame), prediction.encode()
    if encoding == "json":
        return json.dumps(scene_update_dict(frame), separators=(",", ":")).encode(), prediction.encode()
    if encoding == "cdr":
        return _scene_update_cdr(frame), _string_cdr(prediction)
    raise InputError(None, f"unknown forecast encoding {encoding!r}", expected=f"one of {ENCODINGS}")
