"""Decoded drive-log messages ⇄ track-table columns: the part the MCAP and bag adapters share.

Reading: a decoder appends every object of a message to an :class:`ObjectColumns` (flat Python
lists, no message kept; protobuf SceneUpdates are decoded many messages at a time straight from the
wire format by :mod:`lanecast.io_adapters.logs.scene_update_wire`), transforms (``/tf``, foxglove
FrameTransforms, odometry) go into :class:`Transforms`, and :func:`assemble` turns everything into
one track table: objects in moving frames moved into the fixed frame their transform chain reaches
(map, odom, world, road, or a frame named in lanecast's metadata), heading from the quaternion yaw
(from the velocity where there is no orientation), velocities and accelerations from the message
where it has them, else from differences (positions, then velocities), frame indices on the topic's
timeline at its nominal rate (median message interval, snapped to a whole rate within 1 %).
Recordings: one per object topic, named after the file stem (``<stem>-<topic>`` when a log has
several), or the names stored in lanecast's metadata.

Conventions of the logs lanecast writes (documented here, used by both writers):

- one topic per recording: ``/tracked_objects`` for a single recording, ``/tracked_objects/r<i>``
  for several; in ROS bags each has a ``<topic>/markers`` MarkerArray companion.
- the log's metadata (MCAP metadata record ``lanecast``; in ROS bags a ``std_msgs/msg/String`` on
  ``/lanecast/metadata``, and rosbag2 ``custom_data``) holds a JSON document: ``source_format``,
  ``frame_rate``, ``units`` and per recording ``topic``, ``frame_rate``, ``coordinate_frame``, the
  frame origin (``frame0``, ``time0_ns``) or an explicit frame list, ``source_files`` and ``extra``.
- SceneUpdate: one message per frame, entity id = track id, one cube (centre, yaw, length × width ×
  1.5 m), entity metadata ``class``, ``lane_id`` (absent = null), ``vx``, ``vy`` (float32 in their
  shortest decimal form); accelerations are not written (read back as velocity differences;
  ``ax``/``ay`` keys are read where a log has them).
- Autoware TrackedObjects: UUID = the track id as 8 little-endian bytes then 8 zero bytes; twist and
  acceleration in the object's body frame (Autoware's convention); the class as the Autoware label.
  The MarkerArray companion: cube marker per object, id = track id, ``ns`` = lanecast's class
  string, ``text`` = ``lane_id=<n>`` (empty = null): this is where the lane and the exact class
  round-trip.

Size: reading (decoders, transforms, :func:`assemble`) and the conventions of the logs lanecast
writes (topics, metadata, frame groups) share the column helpers above; they stay together this
wave while the hostile-input work (issue 13) edits both; the cut is the writing conventions into
their own module.
"""

from __future__ import annotations

import hashlib
import math
import sys
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
import pyarrow as pa

from lanecast.io_adapters import json_fields as jf
from lanecast.io_adapters.contracts import track_table
from lanecast.io_adapters.contracts.track_runs import (
    along_track_derivative,
    row_extent,
    run_bounds,
    run_starts,
)
from lanecast.io_adapters.errors import FrameError, LogError

FIXED_FRAMES: frozenset[str] = frozenset({"map", "odom", "world", "road"})
META_NAME = "lanecast"
META_TOPIC = "/lanecast/metadata"
OWN_TOPIC_PREFIX = "/lanecast/"  # topics lanecast writes (metadata, forecasts): never objects
TRACK_TOPIC = "/tracked_objects"
MARKER_SUFFIX = "/markers"
BOX_HEIGHT = 1.5  # m, height of the cubes written (the table has no height)

# Autoware ObjectClassification labels.
AUTOWARE_LABELS: dict[int, str] = {
    0: "unknown",
    1: "car",
    2: "truck",
    3: "bus",
    4: "trailer",
    5: "motorcycle",
    6: "bicycle",
    7: "pedestrian",
}
LABEL_OF_CLASS: dict[str, int] = {v: k for k, v in AUTOWARE_LABELS.items()}
KNOWN_CLASSES = frozenset(AUTOWARE_LABELS.values()) | {"van", "motorbike"}

# Per-row numeric slots of ObjectColumns.floats, in order.
_FLOATS = ("x", "y", "qx", "qy", "qz", "qw", "length", "width", "vx", "vy", "ax", "ay", "lane")
_NF = len(_FLOATS)
NAN = math.nan
MAX_STAMP_SEC = (2**63 - 1) // 1_000_000_000 - 1  # the last second whose nanoseconds fit int64


def track_id_of(text: str) -> int:
    """A track id from an entity id string: the int64 it spells, else a stable 56-bit hash."""
    try:
        value = int(text)
        if -(2**63) <= value < 2**63:
            return value
    except ValueError:
        pass
    return int.from_bytes(hashlib.blake2b(text.encode(), digest_size=7).digest(), "little")


def uuid_to_track_id(uuid: Any) -> int:
    """A track id from a 16-byte UUID: lanecast's own (8 LE bytes + 8 zeros) exactly, else a hash."""
    raw = bytes(np.asarray(uuid, dtype=np.uint8))
    if raw[8:] == bytes(8):
        return int.from_bytes(raw[:8], "little", signed=True)
    return int.from_bytes(hashlib.blake2b(raw, digest_size=7).digest(), "little")


def track_id_to_uuid(track_id: int) -> np.ndarray:
    """uint8[16]: the track id in 8 little-endian bytes, then zeros."""
    return np.frombuffer(int(track_id).to_bytes(8, "little", signed=True) + bytes(8), dtype=np.uint8).copy()


def yaw_of(qx: np.ndarray, qy: np.ndarray, qz: np.ndarray, qw: np.ndarray) -> np.ndarray:
    """Yaw (rad, about z) of quaternions; arrays of shape [n]. NaN for the zero quaternion (no
    orientation given), so that the heading comes from the velocity instead."""
    yaw = np.arctan2(2.0 * (qw * qz + qx * qy), 1.0 - 2.0 * (qy * qy + qz * qz))
    return np.where((qx == 0) & (qy == 0) & (qz == 0) & (qw == 0), np.nan, yaw)


def quat_of_yaw(yaw: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(qz, qw) of a rotation by ``yaw`` about z (qx = qy = 0); arrays of shape [n]."""
    half = 0.5 * np.asarray(yaw, dtype=np.float64)
    return np.sin(half), np.cos(half)


def rotate(vx: np.ndarray, vy: np.ndarray, angle: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rotate 2D vectors [n] by ``angle`` [n] (rad, counter-clockwise)."""
    c, s = np.cos(angle), np.sin(angle)
    return c * vx - s * vy, s * vx + c * vy


class Categorical:
    """Strings as int32 codes [n] into ``names`` (how classes and frame ids travel, cheaply)."""

    __slots__ = ("codes", "names")

    def __init__(self, codes: np.ndarray, names: list[str]) -> None:
        self.codes = np.asarray(codes, dtype=np.int32)
        self.names = list(names)

    @classmethod
    def from_strings(cls, values: Iterable[str]) -> Categorical:
        lookup: dict[str, int] = {}
        codes = [lookup.setdefault(v, len(lookup)) for v in values]
        return cls(np.asarray(codes, dtype=np.int32), list(lookup))

    @classmethod
    def concat(cls, parts: list[Categorical]) -> Categorical:
        """One categorical of all parts, in order (categories merged)."""
        lookup: dict[str, int] = {}
        codes = []
        for p in parts:
            lut = np.asarray([lookup.setdefault(n, len(lookup)) for n in p.names], dtype=np.int32)
            codes.append(lut[p.codes] if p.codes.size else p.codes)
        return cls(np.concatenate(codes) if codes else np.zeros(0, np.int32), list(lookup))

    def take(self, idx: np.ndarray) -> Categorical:
        return Categorical(self.codes[idx], self.names)

    def strings(self) -> np.ndarray:
        return (
            np.asarray(self.names, dtype=object)[self.codes]
            if self.names
            else np.zeros(self.codes.size, object)
        )

    def where(self, mask: np.ndarray, other: Categorical) -> Categorical:
        """Values of ``other`` where mask [n] holds, else own."""
        merged = Categorical.concat([self, other])
        n = self.codes.size
        return Categorical(np.where(mask, merged.codes[n:], merged.codes[:n]), merged.names)

    def to_arrow(self) -> pa.DictionaryArray:
        return pa.DictionaryArray.from_arrays(
            pa.array(self.codes, pa.int32()), pa.array(self.names, pa.string())
        )


class ObjectColumns:
    """Objects of one topic, accumulated message by message (no message is kept).

    Per-message decoders append to flat lists: ints (time_ns, message stamp ns, track id), floats
    (see ``_FLOATS``; NaN = not in the message), the class and the frame id. Vectorised decoders
    append whole blocks of arrays (:meth:`add_block`).
    """

    __slots__ = ("blocks", "classes", "floats", "frame_ids", "ints", "messages", "velocity_in_body")

    def __init__(self) -> None:
        self.ints: list[int] = []
        self.floats: list[float] = []
        self.classes: list[str] = []
        self.frame_ids: list[str] = []
        self.blocks: list[dict[str, Any]] = []
        self.messages = 0
        self.velocity_in_body = False

    def add_block(self, block: dict[str, Any], messages: int) -> None:
        """Arrays [n] named like ``_FLOATS`` (a ``yaw`` instead of the quaternion) plus time_ns,
        msg_time, track_id, and
        ``classes``/``frame_ids`` as :class:`Categorical`."""
        self.blocks.append(block)
        self.messages += messages

    def __len__(self) -> int:
        return len(self.classes) + sum(int(b["track_id"].size) for b in self.blocks)

    def arrays(self) -> tuple[dict[str, np.ndarray], Categorical, Categorical]:
        """All rows as numpy columns [n], the classes and the frame ids."""
        ints = np.asarray(self.ints, dtype=np.int64).reshape(-1, 3)
        floats = np.asarray(self.floats, dtype=np.float64).reshape(-1, _NF)
        listed: dict[str, np.ndarray] = {
            "time_ns": ints[:, 0],
            "msg_time": ints[:, 1],
            "track_id": ints[:, 2],
        }
        for i, name in enumerate(_FLOATS):
            if not name.startswith("q"):
                listed[name] = floats[:, i]
        listed["yaw"] = yaw_of(floats[:, 2], floats[:, 3], floats[:, 4], floats[:, 5])
        parts = [listed, *self.blocks]
        cols = {k: np.concatenate([p[k] for p in parts]) if len(parts) > 1 else listed[k] for k in listed}
        classes = Categorical.concat(
            [Categorical.from_strings(self.classes)] + [b["classes"] for b in self.blocks]
        )
        frames = Categorical.concat(
            [Categorical.from_strings(self.frame_ids)] + [b["frame_ids"] for b in self.blocks]
        )
        return cols, classes, frames


# --------------------------------------------------------------------------------------- decoders


def add_scene_update_json(cols: ObjectColumns, doc: Mapping[str, Any], log_time: int) -> None:
    """Append the cube entities of a JSON-encoded ``foxglove.SceneUpdate``."""
    ints, floats, classes, frames = cols.ints, cols.floats, cols.classes, cols.frame_ids
    cols.messages += 1
    for e in doc.get("entities", ()):
        cubes = e.get("cubes")
        if not cubes:
            continue
        c = cubes[0]
        pose = c.get("pose", {})
        p = pose.get("position", {})
        q = pose.get("orientation", {})
        s = c.get("size", {})
        ts = e.get("timestamp") or {}
        sec, nsec = int(ts.get("sec", 0)), int(ts.get("nsec", 0))
        if not (0 <= sec <= MAX_STAMP_SEC and 0 <= nsec <= 999_999_999):
            raise ValueError(
                f"entity timestamp sec={sec}, nsec={nsec} out of range "
                f"(0 <= sec <= {MAX_STAMP_SEC}, 0 <= nsec <= 999999999 expected)"
            )
        t = sec * 1_000_000_000 + nsec or log_time
        meta = {kv.get("key"): kv.get("value") for kv in e.get("metadata", ())}
        ints += (t, log_time, track_id_of(str(e.get("id", ""))))
        floats += (
            float(p.get("x", 0.0)),
            float(p.get("y", 0.0)),
            float(q.get("x", 0.0)),
            float(q.get("y", 0.0)),
            float(q.get("z", 0.0)),
            float(q.get("w", 1.0)),
            float(s.get("x", 0.0)),
            float(s.get("y", 0.0)),
            *(float(meta[k]) if k in meta else NAN for k in ("vx", "vy", "ax", "ay", "lane_id")),
        )
        classes.append(str(meta.get("class", "unknown")))
        frames.append(str(e.get("frame_id", "")))


def _stamp(header: Any) -> int:
    return int(header.stamp.sec) * 1_000_000_000 + int(header.stamp.nanosec)


def add_tracked_objects(cols: ObjectColumns, msg: Any, log_time: int) -> None:
    """Append the objects of an Autoware ``TrackedObjects`` (twist/accel in the body frame)."""
    cols.messages += 1
    cols.velocity_in_body = True
    t = _stamp(msg.header) or log_time
    frame_id = msg.header.frame_id
    ints, floats, classes, frames = cols.ints, cols.floats, cols.classes, cols.frame_ids
    for o in msg.objects:
        k = o.kinematics
        pose = k.pose_with_covariance.pose
        p, q = pose.position, pose.orientation
        v = k.twist_with_covariance.twist.linear
        a = k.acceleration_with_covariance.accel.linear
        d = o.shape.dimensions
        label = max(o.classification, key=lambda c: c.probability).label if o.classification else 0
        ints += (t, t, uuid_to_track_id(o.object_id.uuid))
        # The pose's orientation is used whatever orientation_availability says: Autoware expresses
        # the twist in that orientation's frame.
        floats += (p.x, p.y, q.x, q.y, q.z, q.w, d.x, d.y, v.x, v.y, a.x, a.y, NAN)
        classes.append(AUTOWARE_LABELS.get(int(label), "unknown"))
        frames.append(frame_id)


def parse_marker_text(text: str) -> float:
    """The lane id in a marker's text (``lane_id=<n>``), NaN where absent."""
    for token in text.replace(";", " ").split():
        if token.startswith("lane_id="):
            try:
                return float(int(token[8:]))
            except ValueError:
                return NAN
    return NAN


def add_marker_array(cols: ObjectColumns, msg: Any, log_time: int) -> None:
    """Append the cube markers (type CUBE, action ADD) of a ``MarkerArray``: id = track id."""
    cols.messages += 1
    ints, floats, classes, frames = cols.ints, cols.floats, cols.classes, cols.frame_ids
    for m in msg.markers:
        if m.type != 1 or m.action != 0:
            continue
        p, q = m.pose.position, m.pose.orientation
        t = _stamp(m.header) or log_time
        ints += (t, t, int(m.id))
        floats += (p.x, p.y, q.x, q.y, q.z, q.w, m.scale.x, m.scale.y, NAN, NAN, NAN, NAN)
        floats.append(parse_marker_text(m.text))
        classes.append(m.ns)
        frames.append(m.header.frame_id)


@dataclass
class Transforms:
    """Planar poses of child frames in parent frames over time (from /tf, /tf_static, odometry)."""

    edges: dict[str, tuple[str, list[int], list[float]]] = field(
        default_factory=dict
    )  # child -> parent, t, xyyaw
    sources: set[str] = field(default_factory=set)

    def add(self, parent: str, child: str, t: int, x: float, y: float, q: Any, source: str) -> None:
        parent, child = parent.lstrip("/"), child.lstrip("/")
        entry = self.edges.get(child)
        if entry is None or entry[0] != parent:
            entry = (parent, [], [])
            self.edges[child] = entry
        entry[1].append(t)
        yaw = math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))
        entry[2].extend((x, y, yaw))
        self.sources.add(source)

    def add_tf(self, msg: Any, source: str) -> None:
        """A ``tf2_msgs/msg/TFMessage``."""
        for tr in msg.transforms:
            v = tr.transform.translation
            self.add(
                tr.header.frame_id,
                tr.child_frame_id,
                _stamp(tr.header),
                v.x,
                v.y,
                tr.transform.rotation,
                source,
            )

    def add_odometry(self, msg: Any, source: str) -> None:
        """A ``nav_msgs/msg/Odometry``: the pose of ``child_frame_id`` in ``header.frame_id``."""
        pose = msg.pose.pose
        self.add(
            msg.header.frame_id,
            msg.child_frame_id,
            _stamp(msg.header),
            pose.position.x,
            pose.position.y,
            pose.orientation,
            source,
        )

    def add_frame_transform(self, tr: Any, source: str) -> None:
        """A ``foxglove.FrameTransform`` (protobuf object, or its JSON document)."""
        if isinstance(tr, Mapping):
            ts, v, q = tr.get("timestamp") or {}, tr.get("translation") or {}, tr.get("rotation") or {}
            rotation = SimpleNamespace(**{k: float(q.get(k, 1.0 if k == "w" else 0.0)) for k in "xyzw"})
            t = int(ts.get("sec", 0)) * 1_000_000_000 + int(ts.get("nsec", 0))
            parent, child = str(tr.get("parent_frame_id", "")), str(tr.get("child_frame_id", ""))
            self.add(parent, child, t, float(v.get("x", 0.0)), float(v.get("y", 0.0)), rotation, source)
            return
        t = tr.timestamp.seconds * 1_000_000_000 + tr.timestamp.nanos
        self.add(
            tr.parent_frame_id, tr.child_frame_id, t, tr.translation.x, tr.translation.y, tr.rotation, source
        )

    def chain(self, frame: str, fixed: Iterable[str]) -> list[str] | None:
        """Frames from ``frame`` up to the first fixed frame, or None when the tree has no such path."""
        fixed = set(fixed)
        path = [frame]
        while path[-1] not in fixed:
            entry = self.edges.get(path[-1])
            if entry is None or entry[0] in path:
                return None
            path.append(entry[0])
        return path

    def to_fixed(
        self, path: list[str], t: np.ndarray, x: np.ndarray, y: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Points [n] at times t [n] in ``path[0]`` → (x, y, added yaw) in ``path[-1]`` (interpolated)."""
        yaw_total = np.zeros_like(x)
        for child in path[:-1]:
            _, times, xyyaw = self.edges[child]
            et = np.asarray(times, dtype=np.int64)
            poses = np.asarray(xyyaw, dtype=np.float64).reshape(-1, 3)
            order = np.argsort(et, kind="stable")
            et, poses = et[order], poses[order]
            tq = (t - et[0]).astype(np.float64)
            tr = (et - et[0]).astype(np.float64)
            ex = np.interp(tq, tr, poses[:, 0])
            ey = np.interp(tq, tr, poses[:, 1])
            eyaw = np.interp(tq, tr, np.unwrap(poses[:, 2]))
            x, y = rotate(x, y, eyaw)
            x, y = x + ex, y + ey
            yaw_total = yaw_total + eyaw
        return x, y, yaw_total


# ------------------------------------------------------------------------------------ assembling


@dataclass
class TopicData:
    """What was decoded from one topic."""

    topic: str
    msgtype: str
    columns: ObjectColumns = field(default_factory=ObjectColumns)


def nominal_rate(msg_times: np.ndarray) -> float:
    """The nominal rate (Hz) of a topic from its distinct message stamps [n] (median interval)."""
    stamps = np.unique(msg_times)
    if stamps.size < 2:
        return 10.0
    interval = float(np.median(np.diff(stamps)))
    rate = 1e9 / interval
    # Snap to a round rate where the log is within 1 % of one (25 Hz, 10 Hz, …).
    rounded = round(rate)
    return float(rounded) if rounded > 0 and abs(rate - rounded) < 0.01 * rate else rate


def frames_of(msg_times: np.ndarray, spec: Mapping[str, Any] | None) -> tuple[np.ndarray, float]:
    """Frame indices [n] of rows from their message stamps [n], and the frame rate.

    ``spec`` (from lanecast's metadata) gives ``frame_rate`` with ``frame0``/``time0_ns`` or an
    explicit ``frames`` list (one per distinct stamp); without it the rate is estimated and frame 0
    is the first message.
    """
    if spec is not None and "frames" in spec:
        stamps, inverse = np.unique(msg_times, return_inverse=True)
        listed = np.asarray(spec["frames"], dtype=np.int64)
        if listed.size == stamps.size:
            return listed[inverse], float(spec["frame_rate"])
    if spec is not None and "frame0" in spec:
        rate = float(spec["frame_rate"])
        t0, f0 = int(spec["time0_ns"]), int(spec["frame0"])
    else:
        rate = nominal_rate(msg_times)
        t0, f0 = (int(msg_times.min()) if msg_times.size else 0), 0
    frames = f0 + np.rint((msg_times - t0).astype(np.float64) * rate / 1e9).astype(np.int64)
    return frames, rate


def _merge_markers(main: dict[str, np.ndarray], classes: Categorical, markers: ObjectColumns) -> Categorical:
    """Take lane ids and class strings from a lanecast marker companion, matched on (stamp, id)."""
    if len(markers) == 0:
        return classes
    m, m_cls, _ = markers.arrays()
    n_main = main["msg_time"].size
    # Dense ranks of (stamp, id) over both sides make one sortable int64 key per row.
    _, rt = np.unique(np.concatenate([main["msg_time"], m["msg_time"]]), return_inverse=True)
    ids, ri = np.unique(np.concatenate([main["track_id"], m["track_id"]]), return_inverse=True)
    key = rt.astype(np.int64) * ids.size + ri
    q, mk = key[:n_main], key[n_main:]
    order = np.argsort(mk, kind="stable")
    mk_sorted = mk[order]
    idx = np.minimum(np.searchsorted(mk_sorted, q), max(order.size - 1, 0))
    hit = mk_sorted[idx] == q
    src = order[idx]
    main["lane"] = np.where(hit, m["lane"][src], main["lane"])
    return classes.where(hit, m_cls.take(src))


def assemble(
    path: Path,
    topics: Mapping[str, TopicData],
    transforms: Transforms,
    log_meta: Mapping[str, Any] | None,
    *,
    source_format: str,
    topic: str | None = None,
    fixed_frames: Iterable[str] = FIXED_FRAMES,
    extra: Mapping[str, Any] | None = None,
) -> pa.Table:
    """One track table from the decoded topics of one log (validated).

    With lanecast's metadata the recordings and their topics come from it (marker companions fill
    lanes and classes); otherwise every supported topic with objects is one recording, named after
    the file's stem (``<stem>-<topic>`` when there are several).
    """
    fixed = set(fixed_frames)
    recordings_meta = (log_meta or {}).get("recordings") or {}
    if recordings_meta:
        fixed |= {str(r.get("coordinate_frame")) for r in recordings_meta.values()}
    plan: list[tuple[str, str | None]]
    if topic is not None:
        plan = [(topic, None)]
        for name, spec in recordings_meta.items():
            if spec.get("topic") == topic:
                plan = [(topic, name)]
    elif recordings_meta:
        plan = [
            (spec["topic"], name) for name, spec in recordings_meta.items() if spec.get("topic") in topics
        ]
        # The metadata is the log's word, not the truth: a topic with objects that it does not name
        # (a renamed topic, an edited document) is read as a recording of its own, never dropped.
        claimed = {t for t, _ in plan}
        claimed |= {t + MARKER_SUFFIX for t in claimed}
        for t in sorted(set(topics) - claimed):
            if len(topics[t].columns):
                name = _fallback_name(path, t, set(recordings_meta))
                print(
                    f"lanecast: {path}: topic {t!r} has objects but no entry in the log's lanecast "
                    f"metadata; read as recording {name!r}",
                    file=sys.stderr,
                )
                plan.append((t, name))
    else:
        marker_topics = {t + MARKER_SUFFIX for t in topics}
        plan = [(t, None) for t in sorted(topics) if t not in marker_topics or len(topics) == 1]
    stem = path.stem if path.suffix else path.name
    multi = len(plan) > 1
    pieces: list[dict[str, np.ndarray]] = []
    piece_classes: list[Categorical] = []
    rec_names: list[str] = []
    recordings: dict[str, track_table.RecordingMeta] = {}
    for tp, name in plan:
        data = topics[tp]
        spec = recordings_meta.get(name) if name else None
        rec_name = name or (f"{stem}-{tp.strip('/').replace('/', '-')}" if multi else stem)
        cols, classes, frame_ids = data.columns.arrays()
        marker = topics.get(tp + MARKER_SUFFIX)
        if spec is not None and marker is not None and marker is not data:
            classes = _merge_markers(cols, classes, marker.columns)
        elif data.msgtype.endswith("MarkerArray"):
            known = np.asarray([n in KNOWN_CLASSES for n in classes.names] + [True], dtype=bool)
            unknown = ~known[classes.codes]
            classes = classes.where(unknown, Categorical(np.zeros(unknown.size, np.int32), ["unknown"]))
        frame_name = _to_fixed_frame(
            path, tp, cols, frame_ids, transforms, fixed, data.columns.velocity_in_body
        )
        frames, rate = frames_of(cols["msg_time"], spec)
        piece, order, dropped = _derive(cols, frames, data.columns.velocity_in_body)
        pieces.append(piece)
        piece_classes.append(classes.take(order))
        rec_names.append(rec_name)
        rec_extra: dict[str, Any] = dict(spec.get("extra", {})) if spec else {}
        rec_extra.update({"topic": tp, "message_type": data.msgtype, "messages": data.columns.messages})
        if dropped:
            rec_extra["duplicates_dropped"] = dropped
            print(
                f"lanecast: {path}: topic {tp!r}: {dropped:,} rows repeat a (track, frame) of an earlier "
                "row; kept the earliest by log time",
                file=sys.stderr,
            )
        if extra:
            rec_extra.update(extra)
        recordings[rec_name] = track_table.RecordingMeta(
            frame_rate=float(spec["frame_rate"]) if spec else rate,
            coordinate_frame=frame_name,
            source_files=list(spec.get("source_files", [])) if spec else [str(path)],
            extra=rec_extra,
        )
    columns: dict[str, Any] = (
        dict(pieces[0])
        if len(pieces) == 1
        else {k: np.concatenate([p[k] for p in pieces]) for k in pieces[0]}
    )
    columns["object_class"] = Categorical.concat(piece_classes).to_arrow()
    sizes = [p["track_id"].size for p in pieces]
    columns["recording"] = Categorical(np.repeat(np.arange(len(sizes)), sizes), rec_names).to_arrow()
    meta = track_table.TableMeta(
        source_format=str((log_meta or {}).get("source_format") or source_format),
        recordings=recordings,
        source_files=[str(path)],
    )
    table = track_table.build_table(columns, meta)
    track_table.validate(table, source=path)
    return table


def _fallback_name(path: Path, topic: str, taken: set[str]) -> str:
    """A recording name for a topic the log's metadata does not name, distinct from ``taken``."""
    stem = path.stem if path.suffix else path.name
    name = f"{stem}-{topic.strip('/').replace('/', '-')}"
    while name in taken:
        name += "-unlisted"
    return name


def _to_fixed_frame(
    path: Path,
    topic: str,
    cols: dict[str, np.ndarray],
    frame_ids: Categorical,
    transforms: Transforms,
    fixed: set[str],
    body: bool,
) -> str:
    """Move rows in moving frames into a fixed frame (in place); return the fixed frame's name.

    Velocities and accelerations given in the message frame's axes are rotated with it; body-frame
    ones (``body``) stay as they are (they turn with the heading later).
    """
    present = np.bincount(frame_ids.codes, minlength=len(frame_ids.names)) > 0
    distinct = sorted({frame_ids.names[i].lstrip("/") for i in np.flatnonzero(present)})
    names = [n.lstrip("/") for n in frame_ids.names]
    target: str | None = next((f for f in distinct if f in fixed), None)
    for frame in distinct:
        if frame in fixed:
            if target is not None and frame != target:
                raise FrameError(
                    f"{path}: topic {topic!r} mixes the fixed frames {target!r} and {frame!r}; "
                    "expected one fixed frame per topic"
                )
            continue
        chain = transforms.chain(frame, [target] if target else fixed)
        if chain is None:
            have = ", ".join(sorted(transforms.sources)) or "none"
            raise FrameError(
                f"{path}: topic {topic!r} has objects in frame {frame!r}, which is not a fixed frame "
                f"({', '.join(sorted(fixed))}), and the log has no transform from it to one "
                f"(transform topics found: {have}); expected /tf (tf2_msgs/msg/TFMessage or "
                f"foxglove.FrameTransform(s)) or an odometry topic (nav_msgs/msg/Odometry) linking "
                f"{frame!r} to a fixed frame"
            )
        target = chain[-1]
        rows = np.isin(frame_ids.codes, [i for i, n in enumerate(names) if n == frame])
        x, y, dyaw = transforms.to_fixed(chain, cols["msg_time"][rows], cols["x"][rows], cols["y"][rows])
        cols["x"][rows], cols["y"][rows] = x, y
        cols["yaw"][rows] += dyaw
        for a, b in () if body else (("vx", "vy"), ("ax", "ay")):
            va, vb = rotate(cols[a][rows], cols[b][rows], dyaw)
            cols[a][rows], cols[b][rows] = va, vb
    return target or "map"


def _row_order(track: np.ndarray, frame: np.ndarray, time_ns: np.ndarray) -> np.ndarray:
    """The order [n] sorting rows by (track, frame, time): one argsort of a combined integer key
    where (track, frame) pairs are distinct and the key fits, else a lexsort (a third of the speed)."""
    if track.size:
        t0, f0 = int(track.min()), int(frame.min())
        frames = int(frame.max()) - f0 + 1
        if (int(track.max()) - t0 + 1) * frames < 2**62:
            key = (track - t0) * frames + (frame - f0)
            order = np.argsort(key, kind="stable")  # rows come in message order: runs a merge sort uses
            ordered = key[order]
            if not (ordered[1:] == ordered[:-1]).any():
                return order
    return np.lexsort((time_ns, frame, track))


def _derive(
    cols: dict[str, np.ndarray], frames: np.ndarray, body: bool
) -> tuple[dict[str, np.ndarray], np.ndarray, int]:
    """Sort by (track, frame), drop duplicate (track, frame), derive heading, velocity, acceleration.

    Returns the columns, the row order applied (for the categoricals) and the duplicates dropped.
    """
    order = _row_order(cols["track_id"], frames, cols["time_ns"])
    track, frame = cols["track_id"][order], frames[order]
    keep = run_starts(track, frame)
    order = order[keep]
    dropped = int((~keep).sum())
    c = {k: v[order] for k, v in cols.items() if k != "msg_time"}
    track, frame = c["track_id"], frames[order]
    heading = c["yaw"]
    t = c["time_ns"]
    vx, vy = c["vx"], c["vy"]
    if body:
        vx, vy = rotate(vx, vy, np.nan_to_num(heading))
        ax, ay = rotate(c["ax"], c["ay"], np.nan_to_num(heading))
    else:
        ax, ay = c["ax"], c["ay"]
    first, last = row_extent(run_starts(track))

    def derivative(values: np.ndarray) -> np.ndarray:
        return along_track_derivative(values, t, first, last, t_unit=1e-9)

    missing_v = np.isnan(vx) | np.isnan(vy)
    if missing_v.any():
        vx = np.where(np.isnan(vx), derivative(c["x"]), vx)
        vy = np.where(np.isnan(vy), derivative(c["y"]), vy)
    if (np.isnan(ax) | np.isnan(ay)).any():
        ax = np.where(np.isnan(ax), derivative(vx), ax)
        ay = np.where(np.isnan(ay), derivative(vy), ay)
    no_yaw = np.isnan(heading)
    out = {
        "track_id": track,
        "frame": frame,
        "time_ns": t,
        "x": c["x"],
        "y": c["y"],
        "heading": np.where(no_yaw, np.arctan2(vy, vx), heading) if no_yaw.any() else heading,
        "vx": vx,
        "vy": vy,
        "ax": ax,
        "ay": ay,
        "length": c["length"],
        "width": c["width"],
        "lane_id": c["lane"],
    }
    return out, order, dropped


# ------------------------------------------------------------------------------------- writing


def recording_topics(names: list[str]) -> dict[str, str]:
    """Recording name → topic in a log lanecast writes (see the module docstring)."""
    if len(names) == 1:
        return {names[0]: TRACK_TOPIC}
    return {name: f"{TRACK_TOPIC}/r{i}" for i, name in enumerate(names)}


@dataclass
class FrameGroups:
    """Rows of one recording grouped into messages: one message per frame.

    ``order`` [n] sorts the recording's rows by (frame, track); ``starts`` [m+1] bounds message i
    as ``order[starts[i]:starts[i+1]]``; ``stamp`` [m] is the message time (earliest row time).
    """

    order: np.ndarray
    starts: np.ndarray
    stamp: np.ndarray
    frame: np.ndarray


def frame_groups(frame: np.ndarray, track: np.ndarray, time_ns: np.ndarray) -> FrameGroups:
    order = np.lexsort((track, frame))
    f = frame[order]
    starts = run_bounds(f)
    stamp = np.minimum.reduceat(time_ns[order], starts[:-1]) if f.size else np.zeros(0, np.int64)
    return FrameGroups(order, starts, stamp, f[starts[:-1]])


def message_plan(
    recording: np.ndarray, frame: np.ndarray, track: np.ndarray, time_ns: np.ndarray, names: list[str]
) -> tuple[dict[str, FrameGroups], np.ndarray]:
    """Frame groups per recording and all messages in log-time order: int64 [m, 3] (stamp, rec, group).

    Inputs are the table's columns [n]; ``names`` fixes the recording index ``rec``.
    """
    groups: dict[str, FrameGroups] = {}
    keys = []
    for i, name in enumerate(names):
        rows = np.flatnonzero(recording == name)
        g = frame_groups(frame[rows], track[rows], time_ns[rows])
        g.order = rows[g.order]
        groups[name] = g
        keys.append(np.stack([g.stamp, np.full(g.stamp.size, i), np.arange(g.stamp.size)], axis=1))
    allkeys = np.concatenate(keys) if keys else np.zeros((0, 3), np.int64)
    return groups, allkeys[np.lexsort((allkeys[:, 2], allkeys[:, 1], allkeys[:, 0]))]


def log_metadata(
    table: pa.Table, topics: Mapping[str, str], groups: Mapping[str, FrameGroups]
) -> dict[str, Any]:
    """The JSON document lanecast stores in the logs it writes (see the module docstring)."""
    meta = track_table.read_meta(table)
    recordings: dict[str, Any] = {}
    for name, rec in meta.recordings.items():
        if name not in topics:
            continue
        g = groups[name]
        spec: dict[str, Any] = {
            "topic": topics[name],
            "frame_rate": rec.frame_rate,
            "coordinate_frame": rec.coordinate_frame,
            "source_files": rec.source_files,
            "extra": rec.extra,
        }
        if g.frame.size:
            f0, t0 = int(g.frame[0]), int(g.stamp[0])
            predicted = f0 + np.rint((g.stamp - t0).astype(np.float64) * rec.frame_rate / 1e9).astype(
                np.int64
            )
            if np.array_equal(predicted, g.frame):
                spec.update(frame0=f0, time0_ns=t0)
            else:
                spec["frames"] = g.frame.tolist()
        recordings[name] = spec
    return {
        "version": 1,
        "source_format": meta.source_format,
        "source_files": meta.source_files,
        "frame_rate": meta.frame_rate,
        "units": track_table.UNITS,
        "recordings": recordings,
    }


#: Highest frame rate accepted from a log's lanecast metadata (Hz).
MAX_META_FRAME_RATE = 10_000.0


class PayloadDigest:
    """An order-free checksum of a log's messages: the sum (mod 2^128) of a hash of each message's
    topic, log time and payload. lanecast stores it in the metadata of the ROS bags it writes, whose
    formats (ROS 1, sqlite3) have no checksum of their own, and checks it on reading."""

    def __init__(self) -> None:
        self.total = 0
        self.count = 0

    def add(self, topic: str, log_time: int, payload: bytes | memoryview) -> None:
        h = hashlib.blake2b(digest_size=16)
        h.update(topic.encode() + b"\0" + int(log_time).to_bytes(8, "little", signed=True))
        h.update(payload)
        self.total = (self.total + int.from_bytes(h.digest(), "little")) % (1 << 128)
        self.count += 1

    def hexdigest(self) -> str:
        return f"{self.total:032x}"


def check_payload_digest(path: Path, log_meta: Mapping[str, Any] | None, digest: PayloadDigest) -> None:
    """LogError if the log's lanecast metadata states a payload digest its messages do not give."""
    expected = (log_meta or {}).get("payload_digest")
    if expected is None:
        return
    count = (log_meta or {}).get("payload_messages")
    if expected != digest.hexdigest() or (count is not None and count != digest.count):
        raise LogError(
            path,
            f"the messages do not match the checksum lanecast wrote in {META_TOPIC} "
            f"({digest.count:,} messages read, {count} written): the bag is damaged or was edited",
            expected="an intact bag",
        )


def parse_log_metadata(path: Path, text: str | bytes) -> dict[str, Any]:
    """lanecast's metadata document from a log, every field used checked for type and range.

    A log can carry anything under this name, so the document is input like any other: a wrong
    type, a missing key, deep nesting or text that is not JSON is a LogError naming the field.
    """
    what = "lanecast metadata"
    try:
        doc = jf.check(jf.loads(text, "lanecast"), "lanecast", "object")
        jf.get(doc, "source_format", "", "str|null", None)
        jf.get(doc, "source_files", "", "str_list", [])
        jf.get(doc, "payload_digest", "", "str", None)
        jf.get(doc, "payload_messages", "", "count", None)
        for name, spec in jf.get(doc, "recordings", "", "object", {}).items():
            where = f"recordings.{name}"
            jf.check(spec, where, "object")
            jf.get(spec, "topic", where, "str")
            rate = jf.get(spec, "frame_rate", where, "positive")
            if rate > MAX_META_FRAME_RATE:
                raise jf.FieldError(
                    f"{where}.frame_rate", f"{rate}", f"a rate up to {MAX_META_FRAME_RATE:g} Hz"
                )
            jf.get(spec, "coordinate_frame", where, "str", "map")
            jf.get(spec, "source_files", where, "str_list", [])
            jf.get(spec, "extra", where, "object", {})
            for key in ("frame0", "time0_ns"):
                jf.get(spec, key, where, "count", 0)
            if ("frame0" in spec) != ("time0_ns" in spec):
                raise jf.FieldError(
                    f"{where}.frame0", "frame0 and time0_ns not both given", "both or neither"
                )
            jf.get(spec, "frames", where, "int_list", [])
    except jf.FieldError as exc:
        raise LogError(path, f"{what}: {exc.reason}", column=exc.name, expected=exc.expected) from exc
    return doc


def table_columns(table: pa.Table) -> dict[str, np.ndarray]:
    """The columns the writers need as numpy arrays [n] (lane_id: NaN = null)."""
    out: dict[str, np.ndarray] = {
        name: table.column(name).to_numpy()
        for name in (
            "track_id",
            "frame",
            "time_ns",
            "x",
            "y",
            "heading",
            "vx",
            "vy",
            "ax",
            "ay",
            "length",
            "width",
        )
    }
    lane = table.column("lane_id").cast(pa.float64()).to_numpy(zero_copy_only=False)
    out["lane_id"] = np.asarray(lane, dtype=np.float64)
    out["recording"] = table.column("recording").cast(pa.string()).to_numpy(zero_copy_only=False)
    out["object_class"] = table.column("object_class").cast(pa.string()).to_numpy(zero_copy_only=False)
    return out
