"""Conventions of the drive logs lanecast writes and reads back: topics, metadata, frame groups.

Documented here, used by the MCAP and ROS bag writers and checked by the readers:

- one topic per recording: ``/tracked_objects`` for a single recording, ``/tracked_objects/<name>``
  for several, the recording's name as a ROS name (``highd-01-upper`` → ``highd_01_upper``: the
  topic says which recording and driving direction it holds); in ROS bags each has a
  ``<topic>/markers`` MarkerArray companion. Readers map topics to recordings through the metadata,
  so logs with other topic names (``/tracked_objects/r0`` …) read the same.
- the log's metadata (MCAP metadata record ``lanecast``; in ROS bags a ``std_msgs/msg/String`` on
  ``/lanecast/metadata``, and rosbag2 ``custom_data``) holds a JSON document: ``source_format``,
  ``frame_rate``, ``units``, ``time_offset_ns`` (below) and per recording ``topic``, ``frame_rate``, ``coordinate_frame``, the
  frame origin (``frame0``, ``time0_ns``) or an explicit frame list, ``source_files`` and ``extra``
  (parsed and checked by :func:`parse_log_metadata`); in the ROS bags lanecast writes, whose
  formats have no checksum of their own, also a digest of their messages (:class:`PayloadDigest`).
- the log's clock: a track table's times count from its recording's start, but a recording whose
  start is known (``start_time_ns`` in its metadata: highD's recordingMeta, ``lanecast simulate``)
  is written at that date, not at 1 January 1970: every time in the log is the table's plus
  ``time_offset_ns`` (the earliest start among the recordings; 0 and left out when none is known).
  The readers subtract it, so a table read back is the table written; the annotation adds it to
  the forecasts it writes and the report takes it from the forecasts it reads.
- SceneUpdate: one message per frame, entity id = track id, one cube (centre, yaw, length × width ×
  1.5 m), entity metadata ``class``, ``lane_id`` (absent = null), ``vx``, ``vy``, ``ax``, ``ay`` (float32
  in their shortest decimal form: the same kinematics as the ROS bags carry, so the same table
  scores the same in either; a log without ``ax``/``ay`` gets them as velocity differences).
- Autoware TrackedObjects: UUID = the track id as 8 little-endian bytes then 8 zero bytes; twist and
  acceleration in the object's body frame (Autoware's convention); the class as the Autoware label.
  The MarkerArray companion: cube marker per object, id = track id, ``ns`` = lanecast's class
  string, ``text`` = ``lane_id=<n>`` (empty = null): this is where the lane and the exact class
  round-trip.
"""

from __future__ import annotations

import hashlib
import re
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa

from lanecast.io_adapters import json_fields as jf
from lanecast.io_adapters.contracts import track_table
from lanecast.io_adapters.contracts.track_runs import run_bounds
from lanecast.io_adapters.errors import LogError

FIXED_FRAMES: frozenset[str] = frozenset({"map", "odom", "world", "road"})

#: what a ROS 2 bag directory holds (a new bag replaces a directory holding only these)
BAG_FILES: tuple[str, ...] = ("metadata.yaml", "*.mcap", "*.db3", "*.db3-*")


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


def ros_name(name: str) -> str:
    """``name`` as one token of a ROS name: letters, digits and ``_``, not starting with a digit."""
    token = re.sub(r"_+", "_", re.sub(r"[^A-Za-z0-9_]", "_", name)).strip("_") or "recording"
    return f"r_{token}" if token[0].isdigit() else token


def recording_topics(names: list[str]) -> dict[str, str]:
    """Recording name → topic in a log lanecast writes (see the module docstring); names that read
    alike as ROS names get ``_2``, ``_3`` … in order."""
    if len(names) == 1:
        return {names[0]: TRACK_TOPIC}
    topics: dict[str, str] = {}
    taken: set[str] = set()
    for name in names:
        token, n = ros_name(name), 1
        while (topic := f"{TRACK_TOPIC}/{token}" + (f"_{n}" if n > 1 else "")) in taken:
            n += 1
        topics[name] = topic
        taken.add(topic)
    return topics


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


#: the recording's extra naming its start on the Unix clock (ns), where known
START_KEY = "start_time_ns"
#: the recording's extra, in a table read from a log, naming the log's ``time_offset_ns``
OFFSET_KEY = "log_time_offset_ns"


def log_time_offset(table: pa.Table | pa.Schema) -> int:
    """What a log adds to the table's times: the earliest known start of its recordings (ns), else 0."""
    starts = [
        rec.extra[START_KEY]
        for rec in track_table.read_meta(table).recordings.values()
        if isinstance(rec.extra.get(START_KEY), int) and 0 < rec.extra[START_KEY] < 2**62
    ]
    return min(starts, default=0)


def read_offset(table: pa.Table | pa.Schema) -> int:
    """The ``time_offset_ns`` of the log a table was read from (0 for other tables)."""
    offsets = [rec.extra.get(OFFSET_KEY, 0) for rec in track_table.read_meta(table).recordings.values()]
    return int(max((o for o in offsets if isinstance(o, int)), default=0))


def shifted(table: pa.Table, offset: int, column: str = "time_ns") -> pa.Table:
    """``table`` with ``offset`` ns added to its times ``column`` (its field and metadata kept)."""
    if not offset:
        return table
    i = table.schema.get_field_index(column)
    times = table.column(i).to_numpy() + np.int64(offset)
    return table.set_column(i, table.schema.field(i), pa.array(times, pa.int64()))


def log_metadata(
    table: pa.Table, topics: Mapping[str, str], groups: Mapping[str, FrameGroups], time_offset_ns: int = 0
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
    doc: dict[str, Any] = {
        "version": 1,
        "source_format": meta.source_format,
        "source_files": meta.source_files,
        "frame_rate": meta.frame_rate,
        "units": track_table.UNITS,
        "recordings": recordings,
    }
    if time_offset_ns:
        doc["time_offset_ns"] = int(time_offset_ns)
    return doc


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
        if jf.get(doc, "time_offset_ns", "", "count", 0) >= 2**62:
            raise jf.FieldError(
                "time_offset_ns", f"{doc['time_offset_ns']}", "a time before the year 2116 (ns)"
            )
        recording_of_topic: dict[str, str] = {}
        for name, spec in jf.get(doc, "recordings", "", "object", {}).items():
            where = f"recordings.{name}"
            jf.check(spec, where, "object")
            topic = jf.get(spec, "topic", where, "str")
            if topic in recording_of_topic:  # its rows would be read twice, once per recording
                raise jf.FieldError(
                    f"{where}.topic",
                    f"{topic!r}, the topic of recording {recording_of_topic[topic]!r} too",
                    "one topic per recording",
                )
            recording_of_topic[topic] = name
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
