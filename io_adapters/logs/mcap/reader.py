"""Read tracked objects from MCAP drive logs into a track table.

Supported object topics: ``foxglove.SceneUpdate`` (protobuf or JSON; cube entities, entity id =
track id) and, in ROS 2 logs (CDR), ``autoware_perception_msgs/msg/TrackedObjects`` and
``visualization_msgs/msg/MarkerArray`` (cube markers, id = track id). Transforms from
``tf2_msgs/msg/TFMessage`` (``/tf``, ``/tf_static``), ``foxglove.FrameTransform(s)`` and
``nav_msgs/msg/Odometry`` move objects in moving frames into a fixed one (see
:mod:`lanecast.io_adapters.logs.coordinate_frames`). The file's records come from the checked walk
of :mod:`lanecast.io_adapters.logs.mcap.walk` (``salvage=True`` skips damaged chunks and reports
the loss); this module dispatches them by channel to a decoder per schema: protobuf SceneUpdates in
batches (:class:`~lanecast.io_adapters.logs.foxglove.scene_update_decode.SceneUpdateBatch`, decoded on
the free cores' threads while the walk goes on: :mod:`lanecast.io_adapters.cores`), the others one
message at a time, and assembles the table with :mod:`lanecast.io_adapters.logs.assembly`.
"""

from __future__ import annotations

import json
import mmap
import sys
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
from mcap.opcode import Opcode

from lanecast.io_adapters.contracts import track_table
from lanecast.io_adapters.cores import default_threads
from lanecast.io_adapters.errors import LogError
from lanecast.io_adapters.logs import assembly as log_assembly
from lanecast.io_adapters.logs import conventions as conv
from lanecast.io_adapters.logs import coordinate_frames as frame_transforms
from lanecast.io_adapters.logs import object_columns as to
from lanecast.io_adapters.logs.foxglove import scene_update_decode as wire
from lanecast.io_adapters.logs.mcap.definitions import Definitions, parsed
from lanecast.io_adapters.logs.mcap.errors import NotMcap
from lanecast.io_adapters.logs.mcap.index import verified_offsets
from lanecast.io_adapters.logs.mcap.records import (
    MAGIC,
    MSG_HEAD,
    ChannelRecord,
    RecordOverrun,
    SchemaRecord,
    read_channel,
    read_ints,
    read_schema,
    read_string,
    read_string_map,
    records,
)
from lanecast.io_adapters.logs.mcap.walk import ReadStats, walk
from lanecast.io_adapters.logs.messages import ros_types

FORMAT = "mcap"
_ONLY = "of the chunk's records (a chunk holds only Schema, Channel and Message records)"
MAX_LOG_TIME = 2**63 - 1  # ns: time_ns is int64 (MCAP's log times are uint64)
SCENE_UPDATE = "foxglove.SceneUpdate"
FRAME_TRANSFORMS = ("foxglove.FrameTransform", "foxglove.FrameTransforms")
OBJECT_TYPES = (SCENE_UPDATE, *ros_types.TRACKED_OBJECT_TYPES, ros_types.MARKER_ARRAY)
SUPPORTED = f"foxglove.SceneUpdate (protobuf or jsonschema), {ros_types.OBJECT_MESSAGES} (ros2msg/cdr)"
_ROS_NAMES = {
    "autoware_perception_msgs/TrackedObjects": ros_types.TRACKED_OBJECTS,
    "autoware_auto_perception_msgs/TrackedObjects": ros_types.TRACKED_OBJECTS_AUTO,
    "visualization_msgs/MarkerArray": ros_types.MARKER_ARRAY,
    "tf2_msgs/TFMessage": ros_types.TF_MESSAGE,
    "nav_msgs/Odometry": ros_types.ODOMETRY,
    "std_msgs/String": ros_types.STRING,
}


# Topics lanecast writes into annotated logs (forecasts); never read back as tracked objects.
OWN_TOPIC_PREFIX = conv.OWN_TOPIC_PREFIX


def sniff(path: str | Path) -> bool:
    """True for a file that starts with the MCAP magic."""
    path = Path(path)
    if not path.is_file():
        return False
    with path.open("rb") as f:
        return f.read(8) == MAGIC


class _LogDecoder:
    """Decodes the supported topics of one MCAP into TopicData and Transforms."""

    def __init__(self, path: Path, topic: str | None, threads: int = 1) -> None:
        self.path = path
        self.topic = topic
        # threads that decode protobuf SceneUpdates while the walk goes on (None: the walk's own)
        self.pool = ThreadPoolExecutor(threads, thread_name_prefix="lanecast-decode") if threads > 1 else None
        self.threads = threads
        self.defs = Definitions()
        self.schemas: dict[int, SchemaRecord] = self.defs.schemas
        self.channels: dict[int, ChannelRecord] = self.defs.channels
        self.handlers: dict[int, Callable[[Any, int], None] | None] = {}
        self.topics: dict[str, log_assembly.TopicData] = {}
        self.transforms = frame_transforms.Transforms()
        self.log_meta: dict[str, Any] | None = None
        self.stats = ReadStats()
        self.offset = 0  # offset of the record being decoded (for errors)
        self.foreign: dict[str, LogError] = {}  # the --topic's channels that hold no objects

    # -- records
    def metadata(self, buf: Any, pos: int, end: int) -> None:
        """A Metadata record whose body is buf[pos:end]."""
        name, pos = read_string(buf, pos, end)
        values, _ = read_string_map(buf, pos, end)
        if name == conv.META_NAME and conv.META_NAME in values:
            self.log_meta = conv.parse_log_metadata(self.path, values[conv.META_NAME])

    # -- message dispatch
    def handler(self, cid: int) -> Callable[[Any, int], None] | None:
        if cid in self.handlers:
            return self.handlers[cid]
        ch = self.defs.channel_of(self.offset, cid)
        h = self._make_handler(ch)
        self.handlers[cid] = h
        return h

    def _make_handler(self, ch: ChannelRecord) -> Callable[[Any, int], None] | None:
        schema = self.schemas.get(ch.schema_id) if ch.schema_id else None
        name = schema.name if schema else ""
        name = _ROS_NAMES.get(name, name)
        if self.topic is not None and ch.topic == self.topic and name not in OBJECT_TYPES:
            # the error if no other channel of the topic holds objects (a topic may have several)
            self.foreign.setdefault(
                ch.topic,
                LogError(
                    self.path,
                    f"topic {ch.topic!r} has schema {name or '(none)'!r} "
                    f"({schema.encoding if schema else 'no schema'}), which holds no tracked objects",
                    offset=self.offset,
                    expected=SUPPORTED,
                ),
            )
            return None
        if name == SCENE_UPDATE:
            return self._scene_update(ch, schema)
        if name in FRAME_TRANSFORMS:
            return self._frame_transforms(ch, name)
        if (
            schema is None
            or ch.encoding not in ("cdr", "ros1")
            or not name.startswith(tuple({n.split("/")[0] for n in _ROS_NAMES.values()}))
        ):
            return None
        # ROS 2 messages are CDR; ROS 1 messages in MCAP (an annotated ROS 1 bag) keep ROS 1's encoding
        ros = 1 if ch.encoding == "ros1" else 2
        store = ros_types.store_for(name, schema.data.decode("utf-8", "replace"), ros)
        deserialize = store.deserialize_ros1 if ch.encoding == "ros1" else store.deserialize_cdr
        if name in (*ros_types.TRACKED_OBJECT_TYPES, ros_types.MARKER_ARRAY):
            if (
                self.topic is not None
                and ch.topic != self.topic
                and not ch.topic == self.topic + conv.MARKER_SUFFIX
            ):
                return None
            add = to.add_tracked_objects if name in ros_types.TRACKED_OBJECT_TYPES else to.add_marker_array
            cols = self._columns(ch.topic, name)

            def ros_objects(data: Any, log_time: int) -> None:
                add(cols, deserialize(data, name), log_time)

            return ros_objects
        transforms = self.transforms
        if name == ros_types.TF_MESSAGE:
            return lambda data, _t: transforms.add_tf(deserialize(data, name), ch.topic)
        if name == ros_types.ODOMETRY:
            return lambda data, _t: transforms.add_odometry(deserialize(data, name), ch.topic)
        if name == ros_types.STRING and ch.topic == conv.META_TOPIC:

            def meta(data: Any, _t: int) -> None:
                self.log_meta = conv.parse_log_metadata(self.path, deserialize(data, name).data)

            return meta
        return None

    def _columns(self, topic: str, msgtype: str) -> to.ObjectColumns:
        data = self.topics.get(topic)
        if data is None:
            data = self.topics[topic] = log_assembly.TopicData(topic, msgtype)
        return data.columns

    def _frame_transforms(self, ch: ChannelRecord, name: str) -> Callable[[Any, int], None] | None:
        """foxglove.FrameTransform(s) in protobuf or JSON: transforms between frames."""
        add, topic = self.transforms.add_frame_transform, ch.topic
        many = name.endswith("s")
        if ch.encoding == "json":

            def from_json(data: Any, _t: int) -> None:
                doc = json.loads(bytes(data))
                for tr in doc.get("transforms", []) if many else [doc]:
                    add(tr, topic)

            return from_json
        if ch.encoding != "protobuf":
            return None
        from foxglove_schemas_protobuf.FrameTransform_pb2 import FrameTransform
        from foxglove_schemas_protobuf.FrameTransforms_pb2 import FrameTransforms

        msg = FrameTransforms() if many else FrameTransform()

        def from_protobuf(data: Any, _t: int) -> None:
            msg.ParseFromString(bytes(data))
            for tr in msg.transforms if many else [msg]:  # type: ignore[union-attr]
                add(tr, topic)

        return from_protobuf

    def _scene_update(
        self, ch: ChannelRecord, schema: SchemaRecord | None
    ) -> Callable[[Any, int], None] | None:
        if self.topic is not None and ch.topic != self.topic:
            return None
        if self.topic is None and ch.topic.startswith(OWN_TOPIC_PREFIX):
            return None  # lanecast's own forecasts in an annotated log are not tracked objects
        if ch.encoding == "protobuf":
            return wire.SceneUpdateBatch(self._columns(ch.topic, SCENE_UPDATE), self.pool, self.threads - 1)
        if ch.encoding == "json":
            cols = self._columns(ch.topic, SCENE_UPDATE)
            loads = json.loads
            add_json = to.add_scene_update_json
            return lambda data, log_time: add_json(cols, loads(bytes(data)), log_time)
        raise LogError(
            self.path,
            f"topic {ch.topic!r}: foxglove.SceneUpdate with message encoding {ch.encoding!r} "
            f"(schema encoding {schema.encoding if schema else 'none'!r}) cannot be decoded",
            offset=self.offset,
            expected="protobuf or json",
        )

    # -- chunk contents
    def records(self, buf: Any, start: int, end: int, in_chunk: bool, hint: np.ndarray | None = None) -> int:
        """Decode Schema/Channel/Message records in buf[start:end]; return the message count.

        ``hint``: the record offsets the chunk's MessageIndex records list (checked before use).
        """
        if in_chunk and start == 0:
            count = self._batched_chunk(buf, end, hint)
            if count is not None:
                return count
            self.defs.check_chunk(parsed(buf, 0, end, read_schema, read_channel), self.offset)
        count = 0
        unpack_msg, message = MSG_HEAD.unpack_from, Opcode.MESSAGE
        handler, handlers, defs = self.handler, self.handlers, self.defs
        spans: dict[wire.SceneUpdateBatch, tuple[list[int], list[int], list[int]]] = {}
        for op, pos, body, nxt in records(buf, start, end):
            if op == message:
                if nxt - body < MSG_HEAD.size:
                    raise ValueError(f"a Message record of {nxt - body} bytes, shorter than its header")
                cid, _seq, log_time, _pub = unpack_msg(buf, body)
                if log_time > MAX_LOG_TIME:
                    raise LogError(
                        self.path,
                        f"a message's log time {log_time} ns is after what lanecast's int64 times hold (2262)",
                        offset=self.offset if in_chunk else pos,  # the chunk, or the record itself
                        expected=f"log times up to {MAX_LOG_TIME} ns",
                    )
                h = handlers[cid] if cid in handlers else handler(cid)
                if h is not None:
                    if type(h) is wire.SceneUpdateBatch:
                        lists = spans.get(h)
                        if lists is None:
                            lists = spans[h] = ([], [], [])
                        lists[0].append(body + 22 - start)
                        lists[1].append(nxt - start)
                        lists[2].append(log_time)
                    else:
                        self._call(h, cid, buf[body + 22 : nxt], log_time)
                count += 1
            elif op == Opcode.SCHEMA:
                defs.schema(self.offset, *read_schema(buf, body, nxt))
            elif op == Opcode.CHANNEL:
                defs.channel(self.offset, *read_channel(buf, body, nxt))
            elif (
                in_chunk and op <= Opcode.DATA_END
            ):  # 0x00 or one the spec keeps out of chunks (later: skipped)
                raise ValueError(f"a record of opcode {op:#04x} at byte {pos - start} {_ONLY}")
        if spans:
            data = buf.obj if in_chunk and start == 0 else bytes(buf[start:end])
            for batch, lists in spans.items():
                try:
                    batch.add(self.offset, data, lists)
                except (ValueError, IndexError) as exc:
                    raise self._undecodable(exc) from exc
        return count

    def _batched_chunk(self, buf: Any, end: int, hint: np.ndarray | None) -> int | None:
        """The message count of a chunk buf[:end] holding only Message records on channels decoded
        in batches, whose spans go to the batches; None (nothing done) for any other chunk.

        The record offsets are the chunk's MessageIndex offsets (``hint``) where they check out as
        the exact chain of records, else those of the record walk; the record headers are then
        read with numpy.
        """
        data = buf.obj
        raw = np.frombuffer(data, dtype=np.uint8)
        at = verified_offsets(raw, end, hint) if hint is not None else None
        if at is None:
            try:
                positions = [pos for _op, pos, _body, _nxt in records(buf, 0, end)]
            except RecordOverrun:
                return None
            if not positions:
                return None
            at = np.asarray(positions, dtype=np.int64)
        nxt = np.append(at[1:], end)
        if (raw[at] != Opcode.MESSAGE).any() or (nxt - at < 9 + 22).any():
            return None
        cids = read_ints(raw, at + 9, "<u2")
        handlers: dict[int, wire.SceneUpdateBatch | None] = {}
        for cid in np.unique(cids).tolist():
            h = self.handlers[cid] if cid in self.handlers else self.handler(cid)
            if h is not None and type(h) is not wire.SceneUpdateBatch:
                return None
            handlers[cid] = h
        times = read_ints(raw, at + 9 + 6, "<u8")
        if (times > MAX_LOG_TIME).any():
            return None  # the record walk names the message
        times = times.astype(np.int64)
        for cid, h in handlers.items():
            if h is None:
                continue
            sel = cids == cid if len(handlers) > 1 else slice(None)
            try:
                h.add(self.offset, data, (at[sel] + 9 + 22, nxt[sel], times[sel]))
            except (ValueError, IndexError) as exc:
                raise self._undecodable(exc) from exc
        return int(at.size)

    def finish(self) -> None:
        """Decode what the batches still hold."""
        for h in self.handlers.values():
            if type(h) is wire.SceneUpdateBatch:
                try:
                    h.finish()
                except (ValueError, IndexError) as exc:
                    raise self._undecodable(exc) from exc

    def _undecodable(self, exc: Exception) -> LogError:
        return LogError(
            self.path,
            f"protobuf foxglove.SceneUpdate messages cannot be decoded: {exc}",
            offset=getattr(exc, "offset", self.offset),
            expected="valid foxglove.SceneUpdate protobuf messages",
        )

    def _call(self, h: Callable[[Any, int], None], cid: int, data: Any, log_time: int) -> None:
        try:
            h(data, log_time)
        except LogError:
            raise
        except Exception as exc:  # a message its schema cannot decode
            ch = self.channels[cid]
            schema = self.schemas.get(ch.schema_id)
            raise LogError(
                self.path,
                f"topic {ch.topic!r}: message at log time {log_time} cannot be decoded: {_why(exc)}",
                offset=self.offset,
                expected=f"a valid {schema.name if schema else ch.encoding} message",
            ) from exc


def _why(exc: Exception) -> str:
    """What an exception from decoding a message says, readable: a KeyError's or a TypeError's
    text alone ('0', "'str' object has no attribute 'get'") does not say a field is wrong."""
    if isinstance(exc, (KeyError, IndexError, TypeError, AttributeError)):
        return f"a field is missing or of the wrong type ({type(exc).__name__}: {exc})"
    if isinstance(exc, RecursionError):
        return "nested too deeply"
    return str(exc)


def read_log(
    path: str | Path,
    *,
    topic: str | None = None,
    salvage: bool = False,
    fixed_frames: Sequence[str] | None = None,
    crcs_checked_later: bool = False,
) -> tuple[pa.Table, ReadStats]:
    """One MCAP file → (validated track table, read statistics).

    ``topic`` picks one object topic (default: every supported topic); ``salvage`` skips damaged
    chunks instead of raising; ``fixed_frames`` overrides the frame ids taken as fixed
    (default map, odom, world, road); ``crcs_checked_later``: the caller reads the same bytes again
    with their CRCs checked before anything it makes is kept (annotate), so this pass skips them.
    """
    path = Path(path)
    dec = _LogDecoder(path, topic, default_threads())
    try:
        with path.open("rb") as f:
            if path.stat().st_size == 0:
                raise NotMcap(path, "the file is empty", offset=0, expected="an MCAP file")
            with mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) as mm:
                walk(mm, path, dec, salvage, crcs=salvage or not crcs_checked_later)
                dec.finish()
    except OSError as exc:
        raise LogError(path, f"cannot read the file: {exc}") from exc
    except LogError:
        if crcs_checked_later and not salvage:  # damage found without the CRCs: a CRC may name it
            read_log(path, topic=topic, fixed_frames=fixed_frames)
        raise
    finally:
        if dec.pool is not None:
            dec.pool.shutdown(cancel_futures=True)
    if salvage and (dec.stats.chunks_lost or dec.stats.damage):
        print(f"lanecast: {path}: {dec.stats.summary()}", file=sys.stderr)
    elif dec.stats.index:
        print(f"lanecast: {path}: {dec.stats.index_note()}", file=sys.stderr)
    return _table(path, dec, topic, fixed_frames), dec.stats


def _table(path: Path, dec: _LogDecoder, topic: str | None, fixed_frames: Sequence[str] | None) -> pa.Table:
    found = {t: d for t, d in dec.topics.items() if len(d.columns)}
    if topic is not None and topic not in dec.topics:
        if topic in dec.foreign:
            raise dec.foreign[topic]
        listing = _listing(dec)
        raise LogError(path, f"topic {topic!r} is not in the log (topics: {listing})", expected=SUPPORTED)
    if not found:
        raise LogError(
            path,
            f"no supported topic with tracked objects (topics: {_listing(dec)})",
            expected=f"a topic of type {SUPPORTED}",
        )
    extra: dict[str, Any] = {}
    if dec.stats.index:
        extra["index_disagrees"] = dec.stats.index
    if dec.stats.damage:
        extra["salvage"] = {
            "chunks_lost": dec.stats.chunks_lost,
            "messages_lost": dec.stats.messages_lost,
            "damage": dec.stats.damage,
        }
    return log_assembly.assemble(
        path,
        found,
        dec.transforms,
        dec.log_meta,
        source_format=FORMAT,
        topic=topic,
        fixed_frames=fixed_frames or conv.FIXED_FRAMES,
        extra=extra,
    )


def _listing(dec: _LogDecoder) -> str:
    items = []
    for ch in dec.channels.values():
        s = dec.schemas.get(ch.schema_id)
        items.append(f"{ch.topic} [{s.name if s else ch.encoding}]")
    return ", ".join(sorted(items)) or "none"


def read(paths: Sequence[str | Path] | str | Path, **options: Any) -> pa.Table:
    """MCAP files → one validated track table (options: topic, salvage, fixed_frames,
    crcs_checked_later)."""
    if isinstance(paths, (str, Path)):
        paths = [paths]
    tables = [read_log(p, **options)[0] for p in paths]
    return tables[0] if len(tables) == 1 else track_table.concat(tables, [str(p) for p in paths])
