"""Tracked objects of decoded drive-log messages, as columns: the part all log decoders share.

A decoder appends every object of a message to an :class:`ObjectColumns` (flat Python lists, no
message kept): Autoware ``TrackedObjects``, ``MarkerArray`` cube markers and JSON SceneUpdates one
message at a time here, protobuf SceneUpdates many messages at a time straight from the wire format
(:mod:`lanecast.io_adapters.logs.foxglove.scene_update_decode`) as blocks of arrays. Strings (classes, frame
ids) travel as :class:`Categorical` codes; track ids come from entity ids, marker ids or Autoware
UUIDs. Transforms go to :mod:`lanecast.io_adapters.logs.coordinate_frames`, and
:mod:`lanecast.io_adapters.logs.assembly` turns the columns into one track table.
"""

from __future__ import annotations

import hashlib
import math
from collections.abc import Iterable, Mapping
from typing import Any

import numpy as np
import pyarrow as pa

from lanecast.io_adapters import json_fields as jf
from lanecast.io_adapters.logs.conventions import AUTOWARE_LABELS

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


#: Squared norm an orientation quaternion may have (float32 rounding, sloppy normalisation); the
#: zero quaternion means "no orientation". Anything else is damage: (0, 0, 1e300, 1) turned a car by
#: 90 degrees and rotated its velocity with it, silently.
UNIT_NORM2 = (0.9, 1.1)


def check_quaternion(qx: float, qy: float, qz: float, qw: float) -> None:
    """ValueError unless (qx, qy, qz, qw) is a unit quaternion (within UNIT_NORM2) or all zero."""
    n2 = qx * qx + qy * qy + qz * qz + qw * qw
    if n2 != 0.0 and not UNIT_NORM2[0] <= n2 <= UNIT_NORM2[1]:  # NaN and inf fail too
        raise ValueError(
            f"orientation quaternion (x, y, z, w) = ({qx:g}, {qy:g}, {qz:g}, {qw:g}) is not a unit "
            f"quaternion (norm {math.sqrt(n2) if math.isfinite(n2) else n2:g}; expected norm 1, or all zero for none)"
        )


def check_quaternions(qx: np.ndarray, qy: np.ndarray, qz: np.ndarray, qw: np.ndarray) -> None:
    """:func:`check_quaternion` over arrays [n] (one pass; the first bad one is named)."""
    with np.errstate(over="ignore", invalid="ignore"):
        n2 = qx * qx + qy * qy + qz * qz + qw * qw
    bad = (n2 != 0.0) & ~((n2 >= UNIT_NORM2[0]) & (n2 <= UNIT_NORM2[1]))
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        check_quaternion(float(qx[i]), float(qy[i]), float(qz[i]), float(qw[i]))


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
    append whole blocks of arrays (:meth:`add_blocks`).
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

    def add_blocks(self, blocks: list[dict[str, Any]], messages: int) -> None:
        """Blocks of arrays [n] named like ``_FLOATS`` (a ``yaw`` instead of the quaternion) plus
        time_ns, msg_time, track_id, and ``classes``/``frame_ids`` as :class:`Categorical`, from
        ``messages`` messages (kept apart until :meth:`arrays` joins everything once)."""
        self.blocks.extend(blocks)
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


def message_stamps(stamps: np.ndarray, message: np.ndarray) -> np.ndarray:
    """Each row's message stamp [n]: the earliest object stamp of its message (``message`` [n]
    numbers the messages).

    A Foxglove entity's timestamp is the object's time; the log time is when the recorder got the
    message and may repeat or jitter. Frames follow this stamp, which equals the log time of every
    message lanecast writes (the frame's earliest object stamp).
    """
    if not stamps.size:
        return stamps
    first = np.full(int(message.max()) + 1, np.iinfo(np.int64).max, dtype=np.int64)
    np.minimum.at(first, message, stamps)
    return first[message]


# --------------------------------------------------------------------------------------- decoders


def add_scene_update_json(cols: ObjectColumns, doc: Any, log_time: int) -> None:
    """Append the cube entities of a JSON-encoded ``foxglove.SceneUpdate`` (message stamp: the
    earliest entity stamp, see :func:`message_stamps`). A field of the wrong type or a metadata
    value that is no number raises :class:`~lanecast.io_adapters.json_fields.FieldError` naming it
    (``entities[2].metadata.vx``)."""
    ints, floats, classes, frames = cols.ints, cols.floats, cols.classes, cols.frame_ids
    cols.messages += 1
    first = len(ints)
    jf.check(doc, "SceneUpdate", "object")
    for i, e in enumerate(jf.get(doc, "entities", "", "list", [])):
        where = f"entities[{i}]"
        jf.check(e, where, "object")
        cubes = jf.get(e, "cubes", where, "list", [])
        if not cubes:
            continue
        cube = jf.check(cubes[0], f"{where}.cubes[0]", "object")
        pose = jf.get(cube, "pose", f"{where}.cubes[0]", "object", {})
        p = jf.get(pose, "position", f"{where}.cubes[0].pose", "object", {})
        q = jf.get(pose, "orientation", f"{where}.cubes[0].pose", "object", {})
        s = jf.get(cube, "size", f"{where}.cubes[0]", "object", {})
        ts = jf.get(e, "timestamp", where, "object|null", None) or {}
        sec, nsec = (_whole_number(ts, key, f"{where}.timestamp") for key in ("sec", "nsec"))
        if not (0 <= sec <= MAX_STAMP_SEC and 0 <= nsec <= 999_999_999):
            raise jf.FieldError(
                f"{where}.timestamp",
                f"sec={sec}, nsec={nsec} out of range",
                f"0 <= sec <= {MAX_STAMP_SEC}, 0 <= nsec <= 999999999",
            )
        t = sec * 1_000_000_000 + nsec or log_time
        meta = _entity_metadata(e, where)
        entity_id = jf.get(e, "id", where, "str", "")
        ints += (t, log_time, track_id_of(entity_id))
        at = f"{where}.cubes[0]"
        pos = [float(jf.get(p, k, f"{at}.pose.position", "number", 0.0)) for k in ("x", "y")]
        quat = [
            float(jf.get(q, k, f"{at}.pose.orientation", "number", 1.0 if k == "w" else 0.0))
            for k in ("x", "y", "z", "w")
        ]
        size = [float(jf.get(s, k, f"{at}.size", "number", 0.0)) for k in ("x", "y")]
        check_quaternion(*quat)
        floats += (*pos, *quat, *size, *(_metadata_number(meta, k, where) for k in _NUMERIC_METADATA))
        classes.append(meta.get("class", "unknown"))
        frames.append(jf.get(e, "frame_id", where, "str", ""))
    if len(ints) > first:
        ints[first + 1 :: 3] = [min(ints[first::3])] * ((len(ints) - first) // 3)


_NUMERIC_METADATA = ("vx", "vy", "ax", "ay", "lane_id")


def _whole_number(doc: Mapping[str, Any], key: str, where: str) -> int:
    """An integer field of any size (its range is checked by the caller, which names the stamp)."""
    value = doc.get(key, 0)
    if not isinstance(value, int) or isinstance(value, bool):
        raise jf.FieldError(f"{where}.{key}", repr(value), "an integer")
    return value


def _entity_metadata(entity: Mapping[str, Any], where: str) -> dict[str, str]:
    """An entity's metadata list (``[{"key": …, "value": …}]``) as a dict of strings."""
    meta: dict[str, str] = {}
    for k, kv in enumerate(jf.get(entity, "metadata", where, "list", [])):
        at = f"{where}.metadata[{k}]"
        jf.check(kv, at, "object")
        meta[jf.get(kv, "key", at, "str")] = jf.get(kv, "value", at, "str", "")
    return meta


def _metadata_number(meta: Mapping[str, str], key: str, where: str) -> float:
    """A numeric metadata value (text, e.g. "12.5"); NaN where absent."""
    if key not in meta:
        return NAN
    try:
        value = float(meta[key])
    except ValueError:
        raise jf.FieldError(f"{where}.metadata.{key}", f"{meta[key]!r}", "a number as text") from None
    if math.isinf(value):  # "nan" is unknown, as an absent value is
        raise jf.FieldError(f"{where}.metadata.{key}", f"{meta[key]!r}", "a finite number as text")
    return value


def stamp_ns(header: Any) -> int:
    return int(header.stamp.sec) * 1_000_000_000 + int(header.stamp.nanosec)


def add_tracked_objects(cols: ObjectColumns, msg: Any, log_time: int) -> None:
    """Append the objects of an Autoware ``TrackedObjects`` (twist/accel in the body frame)."""
    cols.messages += 1
    cols.velocity_in_body = True
    t = stamp_ns(msg.header) or log_time
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
        check_quaternion(q.x, q.y, q.z, q.w)
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
        check_quaternion(q.x, q.y, q.z, q.w)
        t = stamp_ns(m.header) or log_time
        ints += (t, t, int(m.id))
        floats += (p.x, p.y, q.x, q.y, q.z, q.w, m.scale.x, m.scale.y, NAN, NAN, NAN, NAN)
        floats.append(parse_marker_text(m.text))
        classes.append(m.ns)
        frames.append(m.header.frame_id)
