"""Read tracked objects from MCAP drive logs into a track table.

Supported object topics: ``foxglove.SceneUpdate`` (protobuf or JSON; cube entities, entity id =
track id) and, in ROS 2 logs (CDR), ``autoware_perception_msgs/msg/TrackedObjects`` and
``visualization_msgs/msg/MarkerArray`` (cube markers, id = track id). Transforms from
``tf2_msgs/msg/TFMessage`` (``/tf``, ``/tf_static``), ``foxglove.FrameTransform(s)`` and
``nav_msgs/msg/Odometry`` move objects in moving frames into a fixed one (see
:mod:`lanecast.io_adapters.logs.tracked_objects`).

The file is walked record by record with every CRC checked (chunks, data section, summary); a
truncated file, a corrupt chunk or an unknown schema raises :class:`LogError` with the byte offset.
With ``salvage=True`` damaged chunks are skipped (resynchronising on the next intact chunk) and the
loss is reported on stderr and in :class:`ReadStats`.

Size: the record walk (CRCs, chunk indexes, salvage) and the per-schema decoding are two concerns,
kept in one file this wave while the hostile-input work (issue 13) hardens both; the cut is
``_walk`` and its helpers into ``logs/mcap_walk.py`` behind a small decoder protocol.
"""

from __future__ import annotations

import json
import mmap
import struct
import sys
import zlib
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa

from lanecast.io_adapters.contracts import track_table
from lanecast.io_adapters.errors import LogError
from lanecast.io_adapters.logs import frame_transforms, log_assembly, ros_types
from lanecast.io_adapters.logs import log_conventions as conv
from lanecast.io_adapters.logs import scene_update_wire as wire
from lanecast.io_adapters.logs import tracked_objects as to

FORMAT = "mcap"
MAGIC = b"\x89MCAP0\r\n"

OP_HEADER, OP_FOOTER, OP_SCHEMA, OP_CHANNEL, OP_MESSAGE, OP_CHUNK = 0x01, 0x02, 0x03, 0x04, 0x05, 0x06
OP_MESSAGE_INDEX, OP_STATISTICS, OP_METADATA, OP_DATA_END = 0x07, 0x0B, 0x0C, 0x0F
_MAX_OP = 0x10

SCENE_UPDATE = "foxglove.SceneUpdate"
FRAME_TRANSFORMS = ("foxglove.FrameTransform", "foxglove.FrameTransforms")
OBJECT_TYPES = (SCENE_UPDATE, ros_types.TRACKED_OBJECTS, ros_types.MARKER_ARRAY)
SUPPORTED = (
    "foxglove.SceneUpdate (protobuf or jsonschema), autoware_perception_msgs/msg/TrackedObjects or "
    "visualization_msgs/msg/MarkerArray (ros2msg/cdr)"
)
_ROS_NAMES = {
    "autoware_perception_msgs/TrackedObjects": ros_types.TRACKED_OBJECTS,
    "visualization_msgs/MarkerArray": ros_types.MARKER_ARRAY,
    "tf2_msgs/TFMessage": ros_types.TF_MESSAGE,
    "nav_msgs/Odometry": ros_types.ODOMETRY,
    "std_msgs/String": ros_types.STRING,
}

_OP_NAMES = {OP_SCHEMA: "Schema", OP_CHANNEL: "Channel", OP_MESSAGE: "Message", OP_METADATA: "Metadata"}
# Records read with fixed-size fields: the least length their fields take.
_FIXED_SIZE = {OP_DATA_END: 4, OP_STATISTICS: 8, OP_FOOTER: 20, OP_CHUNK: 28}
_MSG_HEAD = struct.Struct("<HIQQ")
_REC_HEAD = struct.Struct("<BQ")
_LEN = struct.Struct("<Q")


# Topics lanecast writes into annotated logs (forecasts); never read back as tracked objects.
OWN_TOPIC_PREFIX = conv.OWN_TOPIC_PREFIX


def sniff(path: str | Path) -> bool:
    """True for a file that starts with the MCAP magic."""
    path = Path(path)
    if not path.is_file():
        return False
    with path.open("rb") as f:
        return f.read(8) == MAGIC


@dataclass
class ReadStats:
    """What a read saw and, with salvage, what it lost."""

    chunks: int = 0
    chunks_lost: int = 0
    messages: int = 0
    messages_lost: int | None = 0
    damage: list[str] = field(default_factory=list)

    def summary(self) -> str:
        lost = "an unknown number of" if self.messages_lost is None else f"{self.messages_lost:,}"
        return (
            f"salvaged {self.messages:,} messages from {self.chunks - self.chunks_lost:,} intact chunks; "
            f"lost {self.chunks_lost:,} chunks with {lost} messages"
            + (f" ({'; '.join(self.damage)})" if self.damage else "")
        )


class _Damage(Exception):
    """A damaged record (internal): offset and message, turned into LogError or salvaged."""

    def __init__(self, offset: int, message: str, expected: str, resync: bool) -> None:
        super().__init__(message)
        self.offset, self.message, self.expected, self.resync = offset, message, expected, resync


def _string(buf: Any, pos: int, end: int) -> tuple[str, int]:
    """The length-prefixed UTF-8 string at buf[pos] that must end by ``end`` (its record's end)."""
    if pos + 4 > end:
        raise ValueError("a string length runs past the record")
    (n,) = struct.unpack_from("<I", buf, pos)
    stop = pos + 4 + n
    if stop > end:
        raise ValueError(f"a string of {n} bytes runs past the record")
    try:
        return bytes(buf[pos + 4 : stop]).decode(), stop
    except UnicodeDecodeError as exc:
        raise ValueError(f"a string that is not UTF-8 ({exc.reason} at byte {exc.start})") from exc


def _string_map(buf: Any, pos: int, end: int) -> tuple[dict[str, str], int]:
    if pos + 4 > end:
        raise ValueError("a map length runs past the record")
    (n,) = struct.unpack_from("<I", buf, pos)
    stop = pos + 4 + n
    if stop > end:
        raise ValueError(f"a map of {n} bytes runs past the record")
    pos += 4
    out = {}
    while pos < stop:
        k, pos = _string(buf, pos, stop)
        v, pos = _string(buf, pos, stop)
        out[k] = v
    return out, stop


@dataclass
class _Schema:
    name: str
    encoding: str
    data: bytes


@dataclass
class _Channel:
    topic: str
    schema_id: int
    encoding: str


class _ProtobufBatch:
    """Protobuf SceneUpdate messages of one topic, decoded together (vectorised) per ~8 MB of data.

    Holds the decompressed bytes of the chunks it has spans in until it is flushed, never more.
    (Larger batches cost no less: the decoder works through them in cache-sized entity groups.)
    """

    LIMIT = 8 << 20

    def __init__(self, columns: to.ObjectColumns) -> None:
        self.columns = columns
        self.pieces: list[tuple[int, bytes, Any, Any, Any]] = []
        self.size = 0

    def __call__(self, data: Any, log_time: int) -> None:
        """One message on its own (the walk hands over whole chunks through :meth:`add` instead)."""
        raw = bytes(data)
        self.add(-1, raw, ([0], [len(raw)], [log_time]))

    def add(self, offset: int, data: bytes, spans: tuple[Any, Any, Any]) -> None:
        """Messages data[starts[i]:ends[i]] at log times[i], from the record at file offset ``offset``."""
        self.pieces.append((offset, data, *spans))
        self.size += len(data)
        if self.size >= self.LIMIT:
            self.flush()

    def flush(self) -> None:
        """Decode what is held; a ValueError raised carries the ``offset`` of the record at fault."""
        if not self.pieces:
            return
        pieces, self.pieces, self.size = self.pieces, [], 0
        try:
            self._decode(pieces)
        except (ValueError, IndexError) as exc:
            for piece in pieces:  # find the record that holds the bad message
                try:
                    wire.scene_update_block(*_piece_arrays([piece]))
                except (ValueError, IndexError):
                    setattr(exc, "offset", piece[0])  # noqa: B010
                    break
            raise

    def _decode(self, pieces: list[tuple[int, bytes, Any, Any, Any]]) -> None:
        args = _piece_arrays(pieces)
        self.columns.add_block(wire.scene_update_block(*args), int(args[1].size))


def _piece_arrays(
    pieces: list[tuple[int, bytes, Any, Any, Any]],
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """One buffer and the message spans [m] and log times [m] of several pieces."""
    base = np.cumsum([0] + [len(p[1]) for p in pieces[:-1]])
    buf = np.frombuffer(b"".join([*(p[1] for p in pieces), bytes(wire.PAD)]), dtype=np.uint8)
    starts = np.concatenate([np.asarray(p[2], dtype=np.int64) + b for p, b in zip(pieces, base, strict=True)])
    ends = np.concatenate([np.asarray(p[3], dtype=np.int64) + b for p, b in zip(pieces, base, strict=True)])
    times = np.concatenate([np.asarray(p[4], dtype=np.int64) for p in pieces])
    return buf, starts, ends, times


def _read(raw: np.ndarray, at: np.ndarray, dtype: str) -> np.ndarray:
    """Little-endian integers of type ``dtype`` at byte offsets at [n] of raw (uint8 [N]) → [n]."""
    size = np.dtype(dtype).itemsize
    every = np.ndarray((raw.size - size + 1,), dtype=dtype, buffer=raw, strides=(1,))
    return every[at]


class _LogDecoder:
    """Decodes the supported topics of one MCAP into TopicData and Transforms."""

    def __init__(self, path: Path, topic: str | None) -> None:
        self.path = path
        self.topic = topic
        self.schemas: dict[int, _Schema] = {}
        self.channels: dict[int, _Channel] = {}
        self.handlers: dict[int, Callable[[Any, int], None] | None] = {}
        self.topics: dict[str, log_assembly.TopicData] = {}
        self.transforms = frame_transforms.Transforms()
        self.log_meta: dict[str, Any] | None = None
        self.stats = ReadStats()
        self.offset = 0  # offset of the record being decoded (for errors)

    # -- records
    def schema(self, buf: Any, pos: int, end: int) -> None:
        """A Schema record whose body is buf[pos:end]."""
        if pos + 2 > end:
            raise ValueError("a Schema record too short for its id")
        (sid,) = struct.unpack_from("<H", buf, pos)
        name, pos = _string(buf, pos + 2, end)
        encoding, pos = _string(buf, pos, end)
        if pos + 4 > end:
            raise ValueError("the schema data length runs past the record")
        (n,) = struct.unpack_from("<I", buf, pos)
        if pos + 4 + n > end:
            raise ValueError(f"schema data of {n} bytes runs past the record")
        self.schemas[sid] = _Schema(name, encoding, bytes(buf[pos + 4 : pos + 4 + n]))

    def channel(self, buf: Any, pos: int, end: int) -> None:
        """A Channel record whose body is buf[pos:end]."""
        if pos + 4 > end:
            raise ValueError("a Channel record too short for its ids")
        cid, sid = struct.unpack_from("<HH", buf, pos)
        topic, pos = _string(buf, pos + 4, end)
        encoding, pos = _string(buf, pos, end)
        channel = _Channel(topic, sid, encoding)
        if self.channels.get(cid) == channel:
            return  # repeated (the summary repeats every channel)
        self.channels[cid] = channel
        old = self.handlers.pop(cid, None)
        if type(old) is _ProtobufBatch:
            old.flush()

    def metadata(self, buf: Any, pos: int, end: int) -> None:
        """A Metadata record whose body is buf[pos:end]."""
        name, pos = _string(buf, pos, end)
        values, _ = _string_map(buf, pos, end)
        if name == conv.META_NAME and conv.META_NAME in values:
            self.log_meta = conv.parse_log_metadata(self.path, values[conv.META_NAME])

    # -- message dispatch
    def handler(self, cid: int) -> Callable[[Any, int], None] | None:
        if cid in self.handlers:
            return self.handlers[cid]
        ch = self.channels.get(cid)
        if ch is None:
            raise _Damage(
                self.offset,
                f"message on channel {cid}, which was never defined",
                "a Channel record first",
                False,
            )
        h = self._make_handler(ch)
        self.handlers[cid] = h
        return h

    def _make_handler(self, ch: _Channel) -> Callable[[Any, int], None] | None:
        schema = self.schemas.get(ch.schema_id) if ch.schema_id else None
        if ch.schema_id and schema is None:
            raise _Damage(
                self.offset,
                f"topic {ch.topic!r} refers to schema {ch.schema_id}, which the file does not define",
                "a Schema record for every channel",
                False,
            )
        name = schema.name if schema else ""
        name = _ROS_NAMES.get(name, name)
        if self.topic is not None and ch.topic == self.topic and name not in OBJECT_TYPES:
            raise LogError(
                self.path,
                f"topic {ch.topic!r} has schema {name or '(none)'!r} "
                f"({schema.encoding if schema else 'no schema'}), which holds no tracked objects",
                offset=self.offset,
                expected=SUPPORTED,
            )
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
        store = ros_types.typestore(1 if ch.encoding == "ros1" else 2)
        deserialize = store.deserialize_ros1 if ch.encoding == "ros1" else store.deserialize_cdr
        if name in (ros_types.TRACKED_OBJECTS, ros_types.MARKER_ARRAY):
            if (
                self.topic is not None
                and ch.topic != self.topic
                and not ch.topic == self.topic + conv.MARKER_SUFFIX
            ):
                return None
            add = to.add_tracked_objects if name == ros_types.TRACKED_OBJECTS else to.add_marker_array
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

    def _frame_transforms(self, ch: _Channel, name: str) -> Callable[[Any, int], None] | None:
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

    def _scene_update(self, ch: _Channel, schema: _Schema | None) -> Callable[[Any, int], None] | None:
        if self.topic is not None and ch.topic != self.topic:
            return None
        if self.topic is None and ch.topic.startswith(OWN_TOPIC_PREFIX):
            return None  # lanecast's own forecasts in an annotated log are not tracked objects
        if ch.encoding == "protobuf":
            return _ProtobufBatch(self._columns(ch.topic, SCENE_UPDATE))
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
        pos = start
        count = 0
        unpack_head, unpack_msg = _REC_HEAD.unpack_from, _MSG_HEAD.unpack_from
        handler, handlers = self.handler, self.handlers
        spans: dict[_ProtobufBatch, tuple[list[int], list[int], list[int]]] = {}
        while pos < end:
            if pos + 9 > end:
                raise ValueError(f"record header at {pos - start} runs past the end")
            op, length = unpack_head(buf, pos)
            body = pos + 9
            nxt = body + length
            if nxt > end:
                raise ValueError(f"record at {pos - start} declares {length} bytes, only {end - body} left")
            if op == OP_MESSAGE:
                if length < _MSG_HEAD.size:
                    raise ValueError(f"a Message record of {length} bytes, shorter than its header")
                cid, _seq, log_time, _pub = unpack_msg(buf, body)
                h = handlers[cid] if cid in handlers else handler(cid)
                if h is not None:
                    if type(h) is _ProtobufBatch:
                        lists = spans.get(h)
                        if lists is None:
                            lists = spans[h] = ([], [], [])
                        lists[0].append(body + 22 - start)
                        lists[1].append(nxt - start)
                        lists[2].append(log_time)
                    else:
                        self._call(h, cid, buf[body + 22 : nxt], log_time)
                count += 1
            elif op == OP_SCHEMA:
                self.schema(buf, body, nxt)
            elif op == OP_CHANNEL:
                self.channel(buf, body, nxt)
            pos = nxt
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
        the exact chain of records, else one Python step per record; the record headers are then
        read with numpy.
        """
        data = buf.obj
        raw = np.frombuffer(data, dtype=np.uint8)
        at = _verified_offsets(raw, end, hint) if hint is not None else None
        if at is None:
            positions: list[int] = []
            append, unpack_len = positions.append, _LEN.unpack_from
            pos = 0
            try:
                while pos < end:
                    append(pos)
                    pos += 9 + unpack_len(buf, pos + 1)[0]
            except struct.error:
                return None
            if pos != end or not positions:
                return None
            at = np.asarray(positions, dtype=np.int64)
        nxt = np.append(at[1:], end)
        if (raw[at] != OP_MESSAGE).any() or (nxt - at < 9 + 22).any():
            return None
        cids = _read(raw, at + 9, "<u2")
        handlers: dict[int, _ProtobufBatch | None] = {}
        for cid in np.unique(cids).tolist():
            h = self.handlers[cid] if cid in self.handlers else self.handler(cid)
            if h is not None and type(h) is not _ProtobufBatch:
                return None
            handlers[cid] = h
        times = _read(raw, at + 9 + 6, "<u8").astype(np.int64)
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
            if type(h) is _ProtobufBatch:
                try:
                    h.flush()
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
                f"topic {ch.topic!r}: message at log time {log_time} cannot be decoded: {exc}",
                offset=self.offset,
                expected=f"a valid {schema.name if schema else ch.encoding} message",
            ) from exc


#: Largest chunk (uncompressed) read: a chunk's declared size is checked against it before any
#: allocation (MCAP writers make chunks of a few MB).
MAX_CHUNK_BYTES = 1 << 30


def _chunk_payload(buf: Any, body: int, end: int) -> bytes:
    """The decompressed, CRC-checked records of a Chunk record whose body is buf[body:end].

    The declared uncompressed size is bounded (:data:`MAX_CHUNK_BYTES`) and decompression stops
    one byte past it, so a chunk or an LZ4/zstd frame that lies about its size costs no more memory
    than the size the chunk declares.
    """
    if body + 28 > end:
        raise ValueError("a Chunk record too short for its header")
    _t0, _t1, size, crc = struct.unpack_from("<QQQI", buf, body)
    if size > MAX_CHUNK_BYTES:
        raise ValueError(
            f"the chunk declares {size:,} uncompressed bytes, more than the {MAX_CHUNK_BYTES:,} accepted"
        )
    compression, pos = _string(buf, body + 28, end)
    if pos + 8 > end:
        raise ValueError("the chunk's records length runs past the chunk")
    (n,) = struct.unpack_from("<Q", buf, pos)
    if pos + 8 + n > end:
        raise ValueError(f"chunk records ({n} bytes) run past the chunk")
    raw = buf[pos + 8 : pos + 8 + n]
    if compression == "zstd":
        import zstandard

        pieces = []
        try:
            with zstandard.ZstdDecompressor().stream_reader(bytes(raw), read_across_frames=True) as reader:
                wanted = size + 1
                while wanted > 0 and (piece := reader.read(wanted)):
                    pieces.append(piece)
                    wanted -= len(piece)
        except zstandard.ZstdError as exc:  # a damaged frame (flipped or missing bytes)
            raise ValueError(f"damaged zstd frame: {exc}") from exc
        data = b"".join(pieces)
    elif compression == "lz4":
        import lz4.frame

        try:
            data = lz4.frame.LZ4FrameDecompressor().decompress(bytes(raw), max_length=size + 1)
        except RuntimeError as exc:  # lz4 reports a damaged frame as RuntimeError
            raise ValueError(f"damaged LZ4 frame: {exc}") from exc
    elif compression == "":
        data = bytes(raw)
    else:
        raise ValueError(f"unknown compression {compression!r}")
    if len(data) != size:
        said = "more than" if len(data) > size else f"{len(data)} bytes,"
        raise ValueError(f"decompressed to {said} the {size} bytes the chunk says")
    if crc and zlib.crc32(data) != crc:
        raise ValueError(f"CRC mismatch (stored {crc:#010x}, computed {zlib.crc32(data):#010x})")
    return data


def _index_offsets(buf: Any, pos: int, size: int) -> np.ndarray | None:
    """Message offsets [n] (int64) listed by the MessageIndex records starting at pos, or None."""
    parts = []
    while pos + 15 <= size:
        op, length = _REC_HEAD.unpack_from(buf, pos)
        if op != OP_MESSAGE_INDEX or pos + 9 + length > size:
            break
        (n,) = struct.unpack_from("<I", buf, pos + 11)
        if n % 16 or 6 + n > length:
            return None
        pairs = np.frombuffer(buf, dtype="<u8", count=n // 8, offset=pos + 15)
        parts.append(pairs[1::2].astype(np.int64))
        del pairs  # no view of the mmap may outlive the read
        pos += 9 + length
    return np.concatenate(parts) if parts else None


def _verified_offsets(raw: np.ndarray, end: int, hint: np.ndarray) -> np.ndarray | None:
    """The sorted offsets ``hint`` if they are exactly the chain of records of raw[:end] (each record
    ends where the next starts, the first at 0, the last at end), else None."""
    if not hint.size:
        return None
    at = np.sort(hint)
    if at[0] != 0 or at[-1] + 9 > end:
        return None
    lengths = _read(raw, at + 1, "<u8")
    if (lengths > np.uint64(end)).any():
        return None
    if not (at + 9 + lengths.astype(np.int64) == np.append(at[1:], end)).all():
        return None
    return at


def _index_count(buf: Any, pos: int, size: int) -> tuple[int, int]:
    """Messages listed by the MessageIndex records starting at pos; returns (count, end)."""
    count = 0
    while pos + 9 <= size:
        op, length = _REC_HEAD.unpack_from(buf, pos)
        if op != OP_MESSAGE_INDEX or pos + 9 + length > size:
            break
        (n,) = struct.unpack_from("<I", buf, pos + 11)
        count += n // 16
        pos += 9 + length
    return count, pos


def _resync(buf: Any, start: int, size: int) -> int | None:
    """The offset of the next intact Chunk record at or after start, else None."""
    pos = start
    while True:
        pos = buf.find(bytes([OP_CHUNK]), pos, size)
        if pos < 0 or pos + 9 > size:
            return None
        (length,) = struct.unpack_from("<Q", buf, pos + 1)
        end = pos + 9 + length
        if 40 <= length and end <= size and (end == size or 0 < buf[end] < _MAX_OP):
            try:
                _chunk_payload(buf, pos + 9, end)
                return pos
            except Exception:
                pass
        pos += 1


def _walk(buf: Any, path: Path, dec: _LogDecoder, salvage: bool) -> None:
    """Walk the top-level records of buf (the whole file), decoding into dec.

    Damage raises LogError, or with ``salvage`` is recorded in ``dec.stats`` and skipped: a damaged
    chunk by resynchronising on the next intact chunk, a damaged index/summary by going on.
    """
    size = len(buf)
    stats = dec.stats
    if size == 0:
        raise LogError(path, "the file is empty", offset=0, expected="an MCAP file")
    if size < 8 and MAGIC.startswith(bytes(buf[:size])):
        raise LogError(
            path,
            f"the file is truncated: {size} bytes, inside the magic",
            offset=size,
            expected="an MCAP file",
        )
    if size < 8 or bytes(buf[:8]) != MAGIC:
        raise LogError(
            path, f"not an MCAP file (starts with {bytes(buf[:8])!r})", offset=0, expected="the MCAP magic"
        )
    ends_with_magic = size >= 16 and bytes(buf[size - 8 :]) == MAGIC
    complete = "a complete MCAP file ending with a footer and the magic"
    pos = 8
    footer_seen = data_end_seen = False
    total_expected: int | None = None
    while pos < size:
        dec.offset = pos
        skip_to: int | None = None
        try:
            if pos + 9 > size:
                raise _Damage(pos, "the file is truncated inside a record header", complete, True)
            op, length = _REC_HEAD.unpack_from(buf, pos)
            body, nxt = pos + 9, pos + 9 + length
            if op == 0 or (_MAX_OP <= op < 0x80):
                raise _Damage(pos, f"invalid record opcode {op:#04x}", "an MCAP record", True)
            if nxt > size:
                if ends_with_magic:
                    raise _Damage(
                        pos,
                        f"corrupt record: opcode {op:#04x} declares {length} bytes, past the end",
                        "a valid record length",
                        True,
                    )
                raise _Damage(
                    pos,
                    f"the file is truncated: a record (opcode {op:#04x}) declares {length} bytes but the file "
                    f"ends {size - body} bytes later",
                    complete,
                    True,
                )
            if op == OP_CHUNK:
                stats.chunks += 1
                try:
                    data = _chunk_payload(buf, body, nxt)
                    hint = _index_offsets(buf, nxt, size)
                    stats.messages += dec.records(memoryview(data), 0, len(data), True, hint)
                except (ValueError, struct.error, zlib.error) as exc:
                    raise _Damage(
                        pos, f"corrupt chunk: {exc}", "an intact zstd/lz4 chunk with a matching CRC", True
                    ) from exc
                except Exception as exc:
                    if type(exc).__module__.startswith(("zstandard", "lz4")):
                        raise _Damage(pos, f"corrupt chunk: {exc}", "an intact zstd/lz4 chunk", True) from exc
                    raise
            elif op in _FIXED_SIZE and length < _FIXED_SIZE[op]:
                raise _Damage(
                    pos,
                    f"corrupt record: opcode {op:#04x} declares {length} bytes, fewer than its fields",
                    f"at least {_FIXED_SIZE[op]} bytes",
                    False,
                )
            elif op in (OP_SCHEMA, OP_CHANNEL, OP_MESSAGE, OP_METADATA):
                try:
                    if op == OP_METADATA:
                        dec.metadata(buf, body, nxt)
                    else:
                        stats.messages += dec.records(buf, pos, nxt, False)
                except (ValueError, struct.error) as exc:
                    raise _Damage(
                        pos, f"corrupt {_OP_NAMES[op]} record: {exc}", f"a valid {_OP_NAMES[op]} record", True
                    ) from exc
            elif op == OP_DATA_END:
                data_end_seen = True
                (crc,) = struct.unpack_from("<I", buf, body)
                if crc and _crc32(buf, 0, pos) != crc:
                    skip_to = nxt
                    raise _Damage(pos, "data section CRC mismatch", "an undamaged data section", False)
            elif op == OP_STATISTICS:
                (total_expected,) = struct.unpack_from("<Q", buf, body)
            elif op == OP_FOOTER:
                footer_seen = True
                summary_start, _, summary_crc = struct.unpack_from("<QQI", buf, body)
                if summary_crc and summary_start and _crc32(buf, summary_start, body + 16) != summary_crc:
                    total_expected = None
                    raise _Damage(pos, "summary CRC mismatch", "an undamaged summary section", False)
                if bytes(buf[nxt : nxt + 8]) != MAGIC:
                    raise _Damage(
                        nxt, "the file does not end with the MCAP magic", "the closing magic", False
                    )
                break
            pos = nxt
        except _Damage as dmg:
            if not salvage:
                raise LogError(path, dmg.message, offset=dmg.offset, expected=dmg.expected) from dmg
            stats.damage.append(f"offset {dmg.offset}: {dmg.message}")
            if not dmg.resync:
                if skip_to is None:
                    break
                pos = skip_to
                continue
            if "corrupt chunk" in dmg.message:
                stats.chunks_lost += 1
                (length,) = struct.unpack_from("<Q", buf, pos + 1)
                lost, _ = _index_count(buf, pos + 9 + length, size)
                if stats.messages_lost is not None:
                    stats.messages_lost = stats.messages_lost + lost if lost else None
            elif not data_end_seen:
                if pos + 9 <= size and buf[pos] == OP_CHUNK:
                    stats.chunks += 1
                    stats.chunks_lost += 1
                stats.messages_lost = None
            resume = _resync(buf, pos + 1, size)
            if resume is None:
                break
            pos = resume
    if not footer_seen:
        if not salvage:
            raise LogError(
                path,
                f"the file is truncated: it ends at {size} bytes without a footer",
                offset=size,
                expected=complete,
            )
        if not data_end_seen:
            stats.messages_lost = None
        if not any("truncated" in d for d in stats.damage):
            stats.damage.append(f"offset {size}: the file ends without a footer (truncated)")
    if salvage and total_expected is not None and footer_seen:
        stats.messages_lost = max(total_expected - stats.messages, 0)


def _crc32(buf: Any, start: int, end: int, block: int = 1 << 24) -> int:
    """CRC-32 of ``buf[start:end]`` in blocks of views: slicing an mmap would copy the whole range."""
    crc = 0
    view = memoryview(buf)
    try:
        for lo in range(start, end, block):
            crc = zlib.crc32(view[lo : min(lo + block, end)], crc)
    finally:
        view.release()
    return crc


def read_log(
    path: str | Path,
    *,
    topic: str | None = None,
    salvage: bool = False,
    fixed_frames: Sequence[str] | None = None,
) -> tuple[pa.Table, ReadStats]:
    """One MCAP file → (validated track table, read statistics).

    ``topic`` picks one object topic (default: every supported topic); ``salvage`` skips damaged
    chunks instead of raising; ``fixed_frames`` overrides the frame ids taken as fixed
    (default map, odom, world, road).
    """
    path = Path(path)
    dec = _LogDecoder(path, topic)
    try:
        with path.open("rb") as f:
            if path.stat().st_size == 0:
                raise LogError(path, "the file is empty", offset=0, expected="an MCAP file")
            with mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) as mm:
                _walk(mm, path, dec, salvage)
                dec.finish()
    except OSError as exc:
        raise LogError(path, f"cannot read the file: {exc}") from exc
    if salvage and (dec.stats.chunks_lost or dec.stats.damage):
        print(f"lanecast: {path}: {dec.stats.summary()}", file=sys.stderr)
    return _table(path, dec, topic, fixed_frames), dec.stats


def _table(path: Path, dec: _LogDecoder, topic: str | None, fixed_frames: Sequence[str] | None) -> pa.Table:
    found = {t: d for t, d in dec.topics.items() if len(d.columns)}
    if topic is not None and topic not in dec.topics:
        listing = _listing(dec)
        raise LogError(path, f"topic {topic!r} is not in the log (topics: {listing})", expected=SUPPORTED)
    if not found:
        raise LogError(
            path,
            f"no supported topic with tracked objects (topics: {_listing(dec)})",
            expected=f"a topic of type {SUPPORTED}",
        )
    extra: dict[str, Any] = {}
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
    """MCAP files → one validated track table (options: topic, salvage, fixed_frames)."""
    if isinstance(paths, (str, Path)):
        paths = [paths]
    tables = [read_log(p, **options)[0] for p in paths]
    return tables[0] if len(tables) == 1 else track_table.concat(tables, [str(p) for p in paths])
