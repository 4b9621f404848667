"""Bulk-encoded forecast messages against the per-object encoders they replaced (kept here as the oracle).

Protobuf and CDR must be byte-identical to what the foxglove protobuf classes and rosbags'
serializer make of the same message; JSON must decode to the same documents (it is also compared
byte for byte: both sides write Python's shortest float text).
"""

from __future__ import annotations

import functools
import json
from dataclasses import dataclass
from typing import Any

import numpy as np
import pyarrow as pa
import pytest

from lanecast.io_adapters.contracts.windows import MANEUVERS
from lanecast.io_adapters.logs import forecast_messages as fm

# ------------------------------------------------------------------- the per-object encoders (oracle)


@dataclass(frozen=True)
class _Line:
    points: list[list[float]]  # [P][3] (x, y, z)
    rgba: tuple[float, float, float, float]


@dataclass(frozen=True)
class _Entity:
    id: str
    metadata: list[tuple[str, str]]
    lines: list[_Line]


def _entities(frame: fm.ForecastFrame) -> list[_Entity]:
    """The drawing of a frame, independent of the encoding (arrays converted once per frame)."""
    m, k = frame.track_id.size, frame.alt_prob.shape[1]
    has_origin = ~np.isnan(frame.origin).any(axis=1)  # [M]
    start = np.where(has_origin, 0, 1).tolist()  # without an origin the line starts at the first point
    origin = np.where(has_origin[:, None], frame.origin, 0.0)
    main_xy = np.concatenate([origin[:, None, :], frame.points], axis=1)  # [M, 6, 2]
    main_pts = np.concatenate([main_xy, np.zeros((m, fm.N_STEPS + 1, 1))], axis=-1).tolist()  # [M][6][3]
    alt_xy = np.concatenate(
        [np.broadcast_to(origin[:, None, None, :], (m, k, 1, 2)), frame.alt_points], axis=2
    )
    alt_pts = np.concatenate([alt_xy, np.zeros((m, k, fm.N_STEPS + 1, 1))], axis=-1).tolist()  # [M][K][6][3]
    main = fm.dominant_maneuver(frame.maneuver)  # [M]
    alt = fm.dominant_maneuver(frame.alt_maneuver)  # [M, K]
    main_rgba = [(*c, fm.MAIN_ALPHA) for c in fm.COLOURS[main].tolist()]
    alt_rgba = [[(*c, fm.ALT_ALPHA) for c in row] for row in fm.COLOURS[alt].tolist()]
    ids = frame.track_id.astype(str).tolist()
    names = [fm.LABELS[j] for j in main.tolist()]
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
    return json.dumps([fm.LABELS[j] for j in row])


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


def prediction_dict(frame: fm.ForecastFrame) -> dict[str, Any]:
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
    flags = frame.out_of_distribution
    ood = [None] * m if flags is None else [None if f < 0 else bool(f) for f in flags.tolist()]
    targets = [
        {
            "track_id": tid,
            "origin": origin[i] if has_origin[i] else None,
            "x": xs[i],
            "y": ys[i],
            "maneuver": maneuver[i],
            "maneuver_probs": probs[i],
            "out_of_distribution": ood[i],
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


def scene_update_dict(frame: fm.ForecastFrame) -> dict[str, Any]:
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
                        "thickness": fm.LINE_THICKNESS_M,
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
                "models": [],
            }
        )
    return {"deletions": [], "entities": entities}


def scene_update_protobuf(frame: fm.ForecastFrame) -> bytes:
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
            lp.thickness = fm.LINE_THICKNESS_M
            lp.scale_invariant = False
            for x, y, z in line.points:
                lp.points.add(x=x, y=y, z=z)
            lp.color.r, lp.color.g, lp.color.b, lp.color.a = line.rgba
    return msg.SerializeToString()


def scene_update_cdr(frame: fm.ForecastFrame) -> bytes:
    store = fm.ros2_typestore()
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
        T[fm.SCENE_UPDATE_ROS2],
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
                    thickness=fm.LINE_THICKNESS_M,
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
    return bytes(store.serialize_cdr(Update(deletions=[], entities=entities), fm.SCENE_UPDATE_ROS2))


def string_cdr(text: str) -> bytes:
    store = fm.ros2_typestore()
    return bytes(store.serialize_cdr(store.types[fm.STRING_ROS2](data=text), fm.STRING_ROS2))


# ------------------------------------------------------------------------------------------- tests


def nested(values: np.ndarray, dtype: pa.DataType) -> pa.Array:
    """[N, a, b, …] as N rows of nested lists."""
    flat: pa.Array = pa.array(np.ascontiguousarray(values).reshape(-1), type=dtype)
    for size in reversed(values.shape[1:]):
        flat = pa.ListArray.from_arrays(
            pa.array(np.arange(len(flat) // size + 1, dtype=np.int32) * size), flat
        )
    return flat


def forecasts(seed: int, *, k: int = 3, baseline: bool = False) -> pa.Table:
    """A forecasts table: two recordings, ~25 forecast times, 1–30 targets each, some without origin."""
    rng = np.random.default_rng(seed)
    rows = []
    for rec in ("rec-a", "rec-b"):
        for t0 in rng.choice(np.arange(0, 60) * 500_000_000 + 1_700_000_000_000_000_000, 12, replace=False):
            m = int(rng.integers(1, 30))
            rows += [(rec, int(tid), int(t0)) for tid in rng.choice(5000, m, replace=False)]
    n = len(rows)
    probs = rng.dirichlet([8.0, 1.0, 1.0], size=(n, 5)) if not baseline else np.full((n, 5, 3), np.nan)
    probs[:3] = np.round(probs[:3], 2)  # short decimals, 0.0 and 1.0 exactly
    probs[3, 0] = [1.0, 0.0, 0.0]
    maneuver = probs.argmax(axis=2)
    origin = rng.normal(0, 300, (n, 2)) * 10.0 ** rng.integers(-3, 3, (n, 1))
    xy = origin[:, None, :] + np.cumsum(rng.normal(25, 3, (n, 5, 2)), axis=1)
    origin[rng.random(n) < 0.2] = np.nan
    origin[5] = [0.0, -0.0]
    xy[6, 0] = 0.0
    alt_prob = np.sort(rng.random((n, k)), axis=1)[:, ::-1]
    alt_maneuver = rng.integers(0, 3, (n, k, 5))
    alt_xy = xy[:, None] + rng.normal(0, 1, (n, k, 5, 2))
    columns = {
        "recording": pa.array([r[0] for r in rows]).dictionary_encode(),
        "track_id": pa.array([r[1] for r in rows], pa.int64()),
        "t0_ns": pa.array([r[2] for r in rows], pa.int64()),
        "horizon_s": nested(np.tile(np.arange(1.0, 6.0), (n, 1)), pa.float32()),
        "x": nested(xy[..., 0], pa.float64()),
        "y": nested(xy[..., 1], pa.float64()),
        "maneuver_probs": nested(probs, pa.float32())
        if not baseline
        else pa.nulls(n, pa.list_(pa.list_(pa.float32()))),
        "maneuver": nested(maneuver, pa.int8()) if not baseline else pa.nulls(n, pa.list_(pa.int8())),
        "origin_x": pa.array(origin[:, 0]),
        "origin_y": pa.array(origin[:, 1]),
    }
    if k:
        columns |= {
            "alt_probs": nested(alt_prob, pa.float32()),
            "alt_maneuvers": nested(alt_maneuver, pa.int8()),
            "alt_x": nested(alt_xy[..., 0], pa.float64()),
            "alt_y": nested(alt_xy[..., 1], pa.float64()),
        }
    return pa.table(columns)


CASES = {
    "stcnn top-3": {"seed": 1},
    "stcnn top-1": {"seed": 2, "k": 1},
    "no alternatives": {"seed": 3, "k": 0},
    "baseline": {"seed": 4, "baseline": True, "k": 0},
}


@pytest.mark.parametrize("case", list(CASES))
@pytest.mark.parametrize("encoding", fm.ENCODINGS)
def test_bulk_messages_equal_the_per_object_encoders(
    case: str, encoding: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(fm, "BULK_ROWS", 50)  # several bulk passes, frames never split
    table = forecasts(**CASES[case])  # type: ignore[arg-type]
    frame_id = {"rec-a": "map", "rec-b": ""}
    batch = fm.batch_from_table(table, frame_id=frame_id, lifetime_s=1.0)
    encoded = list(fm.encode_batch(batch, encoding))
    frames = list(fm.frames_from_table(table, frame_id=frame_id, lifetime_s=1.0))
    assert len(encoded) == len(frames) == 24
    assert sum(f.track_id.size for f in frames) == table.num_rows
    for (t0, scene, prediction), frame in zip(encoded, frames, strict=True):
        assert t0 == frame.t0_ns
        expected_prediction = json.dumps(prediction_dict(frame), separators=(",", ":"))
        if encoding == "protobuf":
            assert scene == scene_update_protobuf(frame)
            assert prediction == expected_prediction.encode()
        elif encoding == "json":
            assert json.loads(scene) == scene_update_dict(frame)
            assert scene == json.dumps(scene_update_dict(frame), separators=(",", ":")).encode()
            assert json.loads(prediction) == prediction_dict(frame)
        else:
            assert scene == scene_update_cdr(frame)
            assert prediction == string_cdr(expected_prediction)
        assert fm.encode_frame(frame, encoding) == (scene, prediction)


def test_protobuf_messages_decode_with_the_official_classes() -> None:
    from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate

    batch = fm.batch_from_table(forecasts(5), frame_id="odom", lifetime_s=2.5)
    (t0, scene, prediction), *_ = fm.encode_batch(batch, "protobuf")
    msg = SceneUpdate.FromString(scene)
    first = next(batch.frames())
    assert len(msg.entities) == first.track_id.size
    entity = msg.entities[0]
    assert entity.id == str(first.track_id[0]) and entity.frame_id == "odom"
    assert entity.timestamp.seconds * 10**9 + entity.timestamp.nanos == t0
    assert (entity.lifetime.seconds, entity.lifetime.nanos) == (2, 500_000_000)
    assert (
        len(entity.lines) == 4
        and [p.x for p in entity.lines[0].points][-5:] == first.points[0, :, 0].tolist()
    )
    assert dict((kv.key, kv.value) for kv in entity.metadata)["horizon_s"] == "[1.0, 2.0, 3.0, 4.0, 5.0]"
    assert json.loads(prediction)["targets"][0]["track_id"] == int(first.track_id[0])


def test_an_empty_forecasts_table_gives_no_messages() -> None:
    empty = forecasts(6).slice(0, 0)
    for encoding in fm.ENCODINGS:
        assert list(fm.encode_batch(fm.batch_from_table(empty, frame_id="map"), encoding)) == []


def test_maneuver_names_are_the_contract_names() -> None:
    assert fm.LABELS[: len(MANEUVERS)] == tuple(MANEUVERS)
