"""Copy a drive log record for record into a new log while merging extra messages in log-time order.

- MCAP → MCAP: every schema, channel (with its original id), message (original bytes, log and
  publish time, sequence), attachment and metadata record is streamed through ``mcap``'s low-level
  reader (CRCs validated) into a chunked zstd MCAP with a summary and indexes; the header's profile
  is kept. Only the index/summary records are regenerated.
- ROS 2 bag directory → ROS 2 bag (rosbags): every connection (type, definition, hash, QoS) and
  message (bytes and time) plus the extra topics.
- ROS 1 bag → MCAP: every connection becomes a ``ros1msg`` schema and ``ros1`` channel, every
  message keeps its bytes and time.

Extra messages are ``(log_time_ns, extra channel index, payload)`` sorted by time; each is written
just before the first original message with a later log time, so the output stays in log-time order
wherever the input was. Memory is bounded: one chunk in and one chunk out at a time.
"""

from __future__ import annotations

import io
import os
import struct
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, BinaryIO

from mcap.exceptions import McapError
from mcap.records import Attachment, Channel, Header, Message, Metadata, Schema
from mcap.stream_reader import CRCValidationError, StreamReader
from mcap.writer import CompressionType, IndexType, Writer

from lanecast.io_adapters.annotations.forecast_messages import ChannelSpec
from lanecast.io_adapters.errors import LogError

ExtraMessage = tuple[int, int, bytes]  # (log_time_ns, index into the extra channels, payload)
Progress = Callable[[int, int], None]  # (messages copied since last call, input bytes since last call)
LIBRARY = "lanecast (mcap-python)"
CHUNK_SIZE = 4 * 1024 * 1024
_PROGRESS_EVERY = 2000


@dataclass
class CopyStats:
    """What a copy wrote: original records copied and extra messages merged."""

    schemas: int = 0
    channels: int = 0
    messages: int = 0
    attachments: int = 0
    metadata: int = 0
    added: int = 0
    bytes_in: int = 0
    bytes_out: int = 0
    profile: str = ""
    extra_channel_ids: list[int] = field(default_factory=list)

    def as_dict(self) -> dict[str, Any]:
        return {k: v for k, v in self.__dict__.items() if k != "extra_channel_ids"}


class _IdWriter(Writer):
    """``mcap.writer.Writer`` that registers schemas and channels under given ids (the original ones).

    ``Writer`` numbers them 1, 2, … itself; keeping a log's ids means reaching its (private) tables,
    which is checked at construction so that an mcap release that renames them fails loudly here.
    """

    def __init__(self, output: BinaryIO, **kwargs: Any) -> None:
        super().__init__(output, **kwargs)
        for name in (
            "_Writer__schemas",
            "_Writer__channels",
            "_Writer__statistics",
            "_Writer__chunk_builder",
        ):
            if not hasattr(self, name):
                raise RuntimeError(f"mcap.writer.Writer has no {name}: this mcap version is not supported")

    def _private(self, name: str) -> Any:
        return getattr(self, f"_Writer__{name}")

    def _maybe_finalize(self) -> None:
        self._private("maybe_finalize_chunk")()

    def put_extra(
        self, channels: Sequence[ChannelSpec], schema_ids: list[int], channel_ids: list[int]
    ) -> None:
        """Register the extra channels (and their schemas) under the given ids."""
        for spec, sid, cid in zip(channels, schema_ids, channel_ids, strict=True):
            self.put_schema(
                Schema(id=sid, name=spec.schema_name, encoding=spec.schema_encoding, data=spec.schema_data)
            )
            self.put_channel(
                Channel(
                    id=cid,
                    topic=spec.topic,
                    message_encoding=spec.message_encoding,
                    schema_id=sid,
                    metadata={},
                )
            )

    def put_schema(self, schema: Schema) -> bool:
        """Register ``schema`` under its own id; False if that id is already registered identically."""
        return self._put("schema", schema, self._private("chunk_builder").add_schema)

    def put_channel(self, channel: Channel) -> bool:
        """Register ``channel`` under its own id; False if that id is already registered identically."""
        return self._put("channel", channel, self._private("chunk_builder").add_channel)

    def _put(self, kind: str, record: Any, add_to_chunk: Any) -> bool:
        table: dict[int, Any] = self._private(f"{kind}s")
        if record.id in table:
            if table[record.id] != record:
                raise ValueError(f"{kind} id {record.id} is defined twice with different content")
            return False
        table[record.id] = record
        statistics = self._private("statistics")
        setattr(statistics, f"{kind}_count", getattr(statistics, f"{kind}_count") + 1)
        add_to_chunk(record)
        self._maybe_finalize()
        return True


@dataclass(frozen=True)
class McapSummaryInfo:
    """What the copy needs to know before streaming: the profile, encodings and free ids."""

    profile: str
    message_encodings: frozenset[str]
    max_schema_id: int
    max_channel_id: int
    has_summary: bool
    topics: frozenset[str] = frozenset()


def summary_info(path: Path) -> McapSummaryInfo:
    """Profile, channel encodings and the highest ids of an MCAP, from its header and summary.

    A log whose summary cannot be read (truncated, no footer) is reported as having none; the
    stream copy then names the offset where it breaks.
    """
    from mcap.reader import make_reader

    errors = (McapError, CRCValidationError, struct.error, ValueError, UnicodeDecodeError)
    try:
        with open(path, "rb") as f:
            header = next(iter(StreamReader(f).records))
    except (*errors, StopIteration) as exc:
        raise LogError(path, f"cannot read the MCAP header: {exc}", offset=0) from exc
    except OSError as exc:
        raise LogError(path, f"cannot open: {exc.strerror}") from exc
    if not isinstance(header, Header):
        raise LogError(path, "the first MCAP record is not a header", offset=8)
    try:
        with open(path, "rb") as f:
            summary = make_reader(f, validate_crcs=True).get_summary()
    except errors:
        summary = None
    if summary is None:
        return McapSummaryInfo(header.profile, frozenset(), 0, 0, False)
    return McapSummaryInfo(
        header.profile,
        frozenset(c.message_encoding for c in summary.channels.values()),
        max(summary.schemas, default=0),
        max(summary.channels, default=0),
        True,
        frozenset(c.topic for c in summary.channels.values()),
    )


def _check_new_topics(path: Path, existing: Iterable[str], channels: Sequence[ChannelSpec]) -> None:
    """A log that already has one of the topics to add (an annotated log) is refused."""
    clash = sorted({spec.topic for spec in channels} & set(existing))
    if clash:
        raise LogError(
            path, f"the log already has topic(s) {clash}", expected="a log that is not yet annotated"
        )


def _merge_before(
    extras: Iterator[ExtraMessage],
    pending: ExtraMessage | None,
    log_time: int | None,
    emit: Callable[[ExtraMessage], None],
) -> ExtraMessage | None:
    """Emit extra messages with time < ``log_time`` (all when None); return the next pending one."""
    while pending is not None and (log_time is None or pending[0] < log_time):
        emit(pending)
        pending = next(extras, None)
    return pending


class _HashingRaw(io.RawIOBase):
    """An unbuffered file that hashes every block read from it: behind a ``BufferedReader`` the
    record stream's many small reads cost nothing extra, and the file is read once for the copy
    and its checksum."""

    def __init__(self, raw: io.FileIO, digest: Any) -> None:
        super().__init__()
        self.raw, self.digest = raw, digest

    def readable(self) -> bool:
        return True

    def readinto(self, buffer: Any) -> int:
        n = self.raw.readinto(buffer) or 0
        self.digest.update(memoryview(buffer)[:n])
        return n

    def tell(self) -> int:
        return self.raw.tell()


def copy_mcap(
    src: Path,
    out: BinaryIO,
    *,
    channels: Sequence[ChannelSpec] = (),
    extra: Iterable[ExtraMessage] = (),
    progress: Progress | None = None,
    chunk_size: int = CHUNK_SIZE,
    info: McapSummaryInfo | None = None,
    digest: Any = None,
) -> CopyStats:
    """Stream every record of MCAP ``src`` into ``out`` (an open binary file), merging ``extra``.

    The extra channels get schema and channel ids above the log's own (from its summary; without a
    summary, ids counted down from 65535, and a clash with a later original id is an error).
    ``info``: the log's ``summary_info`` when the caller has it already; ``digest`` (a ``hashlib``
    object) is fed every byte of ``src`` as it is copied, so that a checksum costs no second read.
    """
    src = Path(src)
    info = info or summary_info(src)
    _check_new_topics(src, info.topics, channels)
    stats = CopyStats(profile=info.profile)
    if info.has_summary:
        schema_ids = [info.max_schema_id + 1 + i for i in range(len(channels))]
        channel_ids = [info.max_channel_id + 1 + i for i in range(len(channels))]
    else:
        schema_ids = [0xFFFF - i for i in range(len(channels))]
        channel_ids = [0xFFFF - i for i in range(len(channels))]
    stats.extra_channel_ids = channel_ids
    reserved_schemas, reserved_channels = set(schema_ids), set(channel_ids)
    writer = _IdWriter(
        out,
        chunk_size=chunk_size,
        compression=CompressionType.ZSTD,
        index_types=IndexType.ALL,
        enable_data_crcs=True,
    )
    extras = iter(extra)
    pending = next(extras, None)

    def emit(item: ExtraMessage) -> None:
        writer.add_message(channel_ids[item[1]], item[0], item[2], item[0], 0)
        stats.added += 1

    since_msgs = 0
    since_bytes_pos = 0
    with open(src, "rb", buffering=0) as raw:
        stats.bytes_in = os.fstat(raw.fileno()).st_size
        hashing = _HashingRaw(raw, digest) if digest is not None else None
        f = io.BufferedReader(hashing if hashing is not None else raw, buffer_size=1 << 20)
        try:
            for record in StreamReader(f, validate_crcs=True).records:
                if isinstance(record, Message):
                    pending = _merge_before(extras, pending, record.log_time, emit)
                    writer.add_message(
                        record.channel_id, record.log_time, record.data, record.publish_time, record.sequence
                    )
                    stats.messages += 1
                    since_msgs += 1
                    if progress is not None and since_msgs >= _PROGRESS_EVERY:
                        pos = f.tell()
                        progress(since_msgs, pos - since_bytes_pos)
                        since_msgs, since_bytes_pos = 0, pos
                elif isinstance(record, Header):
                    writer.start(profile=record.profile, library=LIBRARY)
                    writer.put_extra(channels, schema_ids, channel_ids)
                elif isinstance(record, Schema):
                    if record.id in reserved_schemas:
                        raise ValueError(f"schema id {record.id} clashes with a forecast schema id")
                    stats.schemas += writer.put_schema(record)
                elif isinstance(record, Channel):
                    if record.id in reserved_channels:
                        raise ValueError(f"channel id {record.id} clashes with a forecast channel id")
                    _check_new_topics(src, [record.topic], channels)
                    stats.channels += writer.put_channel(record)
                elif isinstance(record, Attachment):
                    writer.add_attachment(
                        record.create_time, record.log_time, record.name, record.media_type, record.data
                    )
                    stats.attachments += 1
                elif isinstance(record, Metadata):
                    writer.add_metadata(record.name, dict(record.metadata))
                    stats.metadata += 1
                # Chunk contents arrive decoded; indexes, statistics, summary offsets, data end and
                # footer are regenerated by the writer.
        except (McapError, CRCValidationError, struct.error, ValueError, UnicodeDecodeError) as exc:
            raise LogError(src, f"cannot copy the MCAP: {exc}", offset=f.tell()) from exc
        if hashing is not None:
            while f.read(1 << 20):  # the trailing magic the record stream leaves unread
                pass
        pending = _merge_before(extras, pending, None, emit)
        writer.finish()
        if progress is not None:
            progress(since_msgs, stats.bytes_in - since_bytes_pos)
    stats.bytes_out = out.tell()
    return stats


def copy_ros1_to_mcap(
    src: Path,
    out: BinaryIO,
    *,
    channels: Sequence[ChannelSpec] = (),
    extra: Iterable[ExtraMessage] = (),
    progress: Progress | None = None,
    chunk_size: int = CHUNK_SIZE,
) -> CopyStats:
    """Every connection and message of ROS 1 bag ``src`` into an MCAP (no profile: the extra
    channels may use other encodings), merging ``extra`` in log-time order."""
    from rosbags.rosbag1 import Reader
    from rosbags.rosbag1.reader import ReaderError

    src = Path(src)
    stats = CopyStats(profile="")
    writer = _IdWriter(
        out,
        chunk_size=chunk_size,
        compression=CompressionType.ZSTD,
        index_types=IndexType.ALL,
        enable_data_crcs=True,
    )
    writer.start(profile="", library=LIBRARY)
    extras = iter(extra)
    pending = next(extras, None)
    try:
        with Reader(src) as reader:
            stats.bytes_in = src.stat().st_size
            _check_new_topics(src, [c.topic for c in reader.connections], channels)
            schema_of: dict[tuple[str, str], int] = {}
            channel_of: dict[int, int] = {}
            for conn in reader.connections:
                msgtype = conn.msgtype.replace("/msg/", "/")
                key = (msgtype, conn.msgdef.data)
                if key not in schema_of:
                    schema_of[key] = len(schema_of) + 1
                    writer.put_schema(
                        Schema(
                            id=schema_of[key],
                            name=msgtype,
                            encoding="ros1msg",
                            data=conn.msgdef.data.encode(),
                        )
                    )
                    stats.schemas += 1
                meta = {"md5sum": conn.digest}
                ext = conn.ext
                if getattr(ext, "callerid", None):
                    meta["callerid"] = str(ext.callerid)  # type: ignore[union-attr]
                if getattr(ext, "latching", None):
                    meta["latching"] = str(ext.latching)  # type: ignore[union-attr]
                cid = len(channel_of) + 1
                channel_of[conn.id] = cid
                writer.put_channel(
                    Channel(
                        id=cid,
                        topic=conn.topic,
                        message_encoding="ros1",
                        schema_id=schema_of[key],
                        metadata=meta,
                    )
                )
                stats.channels += 1
            base_schema, base_channel = len(schema_of), len(channel_of)
            channel_ids = [base_channel + 1 + i for i in range(len(channels))]
            stats.extra_channel_ids = channel_ids
            writer.put_extra(channels, [base_schema + 1 + i for i in range(len(channels))], channel_ids)

            def emit(item: ExtraMessage) -> None:
                writer.add_message(channel_ids[item[1]], item[0], item[2], item[0], 0)
                stats.added += 1

            since = 0
            for conn, timestamp, data in reader.messages():
                pending = _merge_before(extras, pending, timestamp, emit)
                writer.add_message(channel_of[conn.id], timestamp, bytes(data), timestamp, 0)
                stats.messages += 1
                since += 1
                if progress is not None and since >= _PROGRESS_EVERY:
                    progress(since, 0)
                    since = 0
            pending = _merge_before(extras, pending, None, emit)
    except ReaderError as exc:
        raise LogError(src, f"cannot read the ROS 1 bag: {exc}") from exc
    writer.finish()
    if progress is not None:
        progress(since, stats.bytes_in)
    stats.bytes_out = out.tell()
    return stats


def ros2_custom_data(bag: Path) -> dict[str, str]:
    """The ``custom_data`` of a ROS 2 bag's metadata.yaml (string keys and values; empty if none)."""
    from ruamel.yaml import YAML  # rosbags' own YAML library

    try:
        doc = YAML(typ="safe").load((Path(bag) / "metadata.yaml").read_text())
        custom = doc["rosbag2_bagfile_information"].get("custom_data") or {}
    except Exception as exc:  # any YAML or shape problem: rosbags' reader reports it first anyway
        raise LogError(bag, f"cannot read metadata.yaml's custom_data: {exc}") from exc
    if not isinstance(custom, dict):
        raise LogError(bag, "metadata.yaml's custom_data is not a mapping", expected="key: value strings")
    return {str(k): str(v) for k, v in custom.items()}


def copy_ros2_bag(
    src: Path,
    dst: Path,
    *,
    channels: Sequence[ChannelSpec] = (),
    extra: Iterable[ExtraMessage] = (),
    typestore: Any = None,
    progress: Progress | None = None,
) -> CopyStats:
    """Every connection and message of ROS 2 bag directory ``src`` into a new bag ``dst`` (which must
    not exist; same storage plugin, the same ``custom_data`` in metadata.yaml), merging ``extra`` on
    CDR topics registered from ``typestore``."""
    from rosbags.rosbag2 import Reader, Writer
    from rosbags.rosbag2.errors import ReaderError
    from rosbags.rosbag2.writer import StoragePlugin

    src = Path(src)
    stats = CopyStats(profile="ros2")
    try:
        with Reader(src) as reader:
            stats.bytes_in = sum(p.stat().st_size for p in src.rglob("*") if p.is_file())
            _check_new_topics(src, [c.topic for c in reader.connections], channels)
            plugin = StoragePlugin.MCAP if any(src.glob("*.mcap")) else StoragePlugin.SQLITE3
            writer = Writer(dst, version=9, storage_plugin=plugin)
            for key, value in ros2_custom_data(src).items():
                writer.set_custom_data(key, value)
            writer.open()
            try:
                out_conn = {}
                for conn in reader.connections:
                    ext = conn.ext
                    out_conn[conn.id] = writer.add_connection(
                        conn.topic,
                        conn.msgtype,
                        msgdef=conn.msgdef.data,
                        rihs01=conn.digest,
                        serialization_format=ext.serialization_format,  # type: ignore[union-attr]
                        offered_qos_profiles=ext.offered_qos_profiles,  # type: ignore[union-attr]
                    )
                    stats.channels += 1
                extra_conns = [
                    writer.add_connection(
                        spec.topic, spec.ros_msgtype or spec.schema_name, typestore=typestore
                    )
                    for spec in channels
                ]
                stats.extra_channel_ids = [c.id for c in extra_conns]

                def emit(item: ExtraMessage) -> None:
                    writer.write(extra_conns[item[1]], item[0], item[2])
                    stats.added += 1

                extras = iter(extra)
                pending = next(extras, None)
                since = 0
                for conn, timestamp, data in reader.messages():
                    pending = _merge_before(extras, pending, timestamp, emit)
                    writer.write(out_conn[conn.id], timestamp, data)
                    stats.messages += 1
                    since += 1
                    if progress is not None and since >= _PROGRESS_EVERY:
                        progress(since, 0)
                        since = 0
                pending = _merge_before(extras, pending, None, emit)
            finally:
                writer.close()
    except ReaderError as exc:
        raise LogError(src, f"cannot read the ROS 2 bag: {exc}") from exc
    compress_bag_storage(dst)
    if progress is not None:
        progress(since, stats.bytes_in)
    stats.bytes_out = sum(p.stat().st_size for p in dst.rglob("*") if p.is_file())
    return stats


def compress_bag_storage(bag: Path) -> None:
    """Rewrite the MCAP files of ROS 2 bag directory ``bag`` chunked, zstd-compressed and with CRCs.

    rosbags' MCAP storage plugin writes uncompressed chunks with every CRC 0: 5 minutes of traffic
    as TrackedObjects + MarkerArray made a 345 MB bag. The copy keeps every record (schemas,
    channels, messages, metadata: ``metadata.yaml`` stays valid) and makes it about 50× smaller (6.5 MB) and
    checkable. Each file is replaced only once its copy is complete.
    """
    for item in sorted(Path(bag).glob("*.mcap")):
        tmp = item.with_name(f".{item.name}.zstd-tmp")
        try:
            with open(tmp, "wb") as out:
                copy_mcap(item, out)
            os.replace(tmp, item)
        finally:
            tmp.unlink(missing_ok=True)
