"""Copy an MCAP drive log record for record into a new one while merging extra messages in log-time order.

Every schema, channel (with its original id), message (original bytes, log and publish time,
sequence), attachment and metadata record is streamed through ``mcap``'s low-level reader (CRCs
validated) into a chunked zstd MCAP with a summary and indexes; the header's profile is kept. Only
the index/summary records are regenerated. What to add is a :class:`Merge`: extra channels and
their messages ``(log_time_ns, extra channel index, payload)`` sorted by time; each is written just
before the first original message with a later log time (:class:`MergedCopy`, shared with the ROS
bag copies of :mod:`lanecast.io_adapters.logs.rosbag.copy`), so the output stays in log-time
order wherever the input was. Memory is bounded: one chunk in and one chunk out at a time. A
damaged log (``annotate --salvage``) is copied by :mod:`~lanecast.io_adapters.logs.mcap.salvage_copy` instead.
"""

from __future__ import annotations

import io
import os
import struct
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, BinaryIO

from mcap.exceptions import McapError
from mcap.records import Attachment, Channel, DataEnd, Header, Message, Metadata, Schema
from mcap.stream_reader import CRCValidationError, StreamReader
from mcap.writer import CompressionType, IndexType, Writer

from lanecast.io_adapters.errors import LogError
from lanecast.io_adapters.logs.forecast_messages import ChannelSpec
from lanecast.io_adapters.logs.mcap.errors import IndexMismatch
from lanecast.io_adapters.logs.mcap.walk import check_file

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


class IdWriter(Writer):
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
                    metadata=dict(spec.metadata),
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


@dataclass(frozen=True)
class CopyOptions:
    """How a log is copied (by :func:`copy_mcap` and the salvage copy alike): ``chunk_size`` of the
    output's chunks; ``info``: the log's :func:`summary_info` when the caller has it already;
    ``digest`` (a ``hashlib`` object): fed every byte of the source as it is copied, so that a
    checksum costs no second read."""

    chunk_size: int = CHUNK_SIZE
    info: McapSummaryInfo | None = None
    digest: Any = None


DEFAULT_COPY = CopyOptions()


def check_records(path: Path) -> None:
    """The McapError naming the offset of the first damaged record of MCAP ``path`` (the reader's
    checked walk), or of the first index record that disagrees with the data section, for a copy
    the mcap library refused with a message and no offset; returns if there is neither."""
    for offset, problem in check_file(path):
        if offset is not None:
            raise IndexMismatch(
                path,
                f"an index record the mcap library cannot read: {problem}",
                offset=offset,
                expected="index records that agree with the data section (lanecast convert reads this log)",
            )


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
        check_records(path)  # the reader's walk names what is wrong where
        raise LogError(path, f"cannot read the MCAP header: {type(exc).__name__}: {exc}", offset=8) from exc
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


def check_new_topics(path: Path, existing: Iterable[str], channels: Sequence[ChannelSpec]) -> None:
    """A log that already has one of the topics to add (an annotated log) is refused."""
    clash = sorted({spec.topic for spec in channels} & set(existing))
    if clash:
        raise LogError(
            path, f"the log already has topic(s) {clash}", expected="a log that is not yet annotated"
        )


@dataclass(frozen=True)
class Merge:
    """What a copy adds to the log, and whom it tells how far it is (the options every copy takes).

    ``channels``: the extra channels; ``extra``: their messages ``(log_time_ns, channel index,
    payload)`` sorted by time; ``progress``: called with (messages, input bytes) since its last call.
    """

    channels: Sequence[ChannelSpec] = ()
    extra: Iterable[ExtraMessage] = ()
    progress: Progress | None = None


class MergedCopy:
    """The bookkeeping every copy shares: extra messages written just before the first original
    message with a later log time, counts in :class:`CopyStats`, progress every few thousand
    messages."""

    def __init__(self, merge: Merge, stats: CopyStats, write_extra: Callable[[ExtraMessage], None]) -> None:
        self.extras = iter(merge.extra)
        self.pending = next(self.extras, None)
        self.progress = merge.progress
        self.stats = stats
        self.write_extra = write_extra
        self.since_messages = 0
        self.since_bytes_at = 0

    def before(self, log_time: int | None) -> None:
        """Write the extra messages logged before ``log_time`` (all that are left when None)."""
        while self.pending is not None and (log_time is None or self.pending[0] < log_time):
            self.write_extra(self.pending)
            self.stats.added += 1
            self.pending = next(self.extras, None)

    def copied(self, position: Callable[[], int] | None = None) -> None:
        """Count one original message copied; ``position``: the input's byte offset, if known."""
        self.stats.messages += 1
        self.since_messages += 1
        if self.progress is not None and self.since_messages >= _PROGRESS_EVERY:
            at = position() if position is not None else self.since_bytes_at
            self.progress(self.since_messages, at - self.since_bytes_at)
            self.since_messages, self.since_bytes_at = 0, at

    def done(self) -> None:
        """Report the rest of the progress (up to the whole input)."""
        if self.progress is not None:
            self.progress(self.since_messages, self.stats.bytes_in - self.since_bytes_at)


def zstd_writer(out: BinaryIO, chunk_size: int = CHUNK_SIZE) -> IdWriter:
    """An MCAP writer keeping record ids: zstd chunks of ``chunk_size``, every index, data CRCs."""
    return IdWriter(
        out,
        chunk_size=chunk_size,
        compression=CompressionType.ZSTD,
        index_types=IndexType.ALL,
        enable_data_crcs=True,
    )


def start_copy(
    src: Path, out: BinaryIO, merge: Merge, options: CopyOptions
) -> tuple[McapSummaryInfo, CopyStats, IdWriter, MergedCopy, list[int], list[int]]:
    """What every copy of an MCAP starts with: the log's summary (``options.info``, read if None)
    checked for the topics to add; schema and channel ids for the extra channels above the log's
    own (without a summary, counted down from 65535, and a clash with a later original id is an
    error); the writer and the merge of the extra messages."""
    info = options.info or summary_info(src)
    check_new_topics(src, info.topics, merge.channels)
    stats = CopyStats(profile=info.profile)
    n = len(merge.channels)
    schema_ids = [info.max_schema_id + 1 + i if info.has_summary else 0xFFFF - i for i in range(n)]
    channel_ids = [info.max_channel_id + 1 + i if info.has_summary else 0xFFFF - i for i in range(n)]
    stats.extra_channel_ids = channel_ids
    writer = zstd_writer(out, options.chunk_size)
    copying = MergedCopy(
        merge, stats, lambda item: writer.add_message(channel_ids[item[1]], item[0], item[2], item[0], 0)
    )
    return info, stats, writer, copying, schema_ids, channel_ids


def finish_copy(writer: IdWriter, copying: MergedCopy, out: BinaryIO) -> None:
    """Write the extra messages left, the summary and footer; report the rest of the progress."""
    copying.before(None)
    writer.finish()
    copying.done()
    copying.stats.bytes_out = out.tell()


def _not_reserved(kind: str, ident: int, reserved: list[int], has_summary: bool) -> None:
    """ValueError for a record of the log whose id is one given to an extra channel or its schema."""
    if ident in reserved:
        raise ValueError(
            f"{kind} id {ident} of the data section is one the summary left free for the forecasts "
            f"(its {kind}s end at {min(reserved) - 1}: a stale summary)"
            if has_summary
            else f"{kind} id {ident} clashes with a forecast {kind} id"
        )


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
    src: Path, out: BinaryIO, merge: Merge | None = None, options: CopyOptions = DEFAULT_COPY
) -> CopyStats:
    """Stream every record of MCAP ``src`` into ``out`` (an open binary file), merging ``merge``'s messages.

    The extra channels get schema and channel ids above the log's own (from its summary; without a
    summary, ids counted down from 65535, and a clash with a later original id is an error).
    """
    src = Path(src)
    merge = merge or Merge()
    info, stats, writer, copying, schema_ids, channel_ids = start_copy(src, out, merge, options)
    digest = options.digest
    with open(src, "rb", buffering=0) as raw:
        stats.bytes_in = os.fstat(raw.fileno()).st_size
        hashing = _HashingRaw(raw, digest) if digest is not None else None
        f = io.BufferedReader(hashing if hashing is not None else raw, buffer_size=1 << 20)
        try:
            for record in StreamReader(f, validate_crcs=True).records:
                if isinstance(record, Message):
                    copying.before(record.log_time)
                    writer.add_message(
                        record.channel_id, record.log_time, record.data, record.publish_time, record.sequence
                    )
                    copying.copied(f.tell)
                elif isinstance(record, Header):
                    writer.start(profile=record.profile, library=LIBRARY)
                    writer.put_extra(merge.channels, schema_ids, channel_ids)
                elif isinstance(record, Schema):
                    _not_reserved("schema", record.id, schema_ids, info.has_summary)
                    stats.schemas += writer.put_schema(record)
                elif isinstance(record, Channel):
                    _not_reserved("channel", record.id, channel_ids, info.has_summary)
                    check_new_topics(src, [record.topic], merge.channels)
                    stats.channels += writer.put_channel(record)
                elif isinstance(record, Attachment):
                    writer.add_attachment(
                        record.create_time, record.log_time, record.name, record.media_type, record.data
                    )
                    stats.attachments += 1
                elif isinstance(record, Metadata):
                    writer.add_metadata(record.name, dict(record.metadata))
                    stats.metadata += 1
                elif isinstance(record, DataEnd):
                    break  # the summary, which the writer makes anew from the data section
                # Chunk contents arrive decoded; indexes, statistics, summary offsets, data end and
                # footer are regenerated by the writer.
        except (McapError, CRCValidationError, struct.error, ValueError, UnicodeDecodeError) as exc:
            check_records(src)
            raise LogError(
                src, f"cannot copy the MCAP: {type(exc).__name__}: {exc}", offset=f.tell()
            ) from exc
        if hashing is not None:
            while f.read(1 << 20):  # the trailing magic the record stream leaves unread
                pass
        finish_copy(writer, copying, out)
    return stats
