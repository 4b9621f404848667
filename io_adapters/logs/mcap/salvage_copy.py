"""Copy a damaged MCAP drive log (``annotate --salvage``) into a new one, merging extra messages.

:func:`copy_mcap_salvaged` is :func:`~lanecast.io_adapters.logs.mcap.copy.copy_mcap` for a
log that ``mcap``'s reader cannot stream: the records come from the checked walk of
:mod:`lanecast.io_adapters.logs.mcap.walk` with salvage, which skips what is damaged exactly as the
track reader does (a chunk that fails its CRC, or uses a channel no intact record defines), and a
:class:`_CopySink` writes every intact record in file order, the extra messages merged in log-time
order. The output is a complete MCAP with a summary made from what it holds.
"""

from __future__ import annotations

import mmap
import os
import struct
from collections.abc import Sequence
from pathlib import Path
from typing import Any, BinaryIO

from mcap.records import Channel, Schema

from lanecast.io_adapters.errors import LogError
from lanecast.io_adapters.logs.forecast_messages import ChannelSpec
from lanecast.io_adapters.logs.mcap.copy import (
    CHUNK_SIZE,
    LIBRARY,
    CopyStats,
    IdWriter,
    McapSummaryInfo,
    Merge,
    MergedCopy,
    check_new_topics,
    summary_info,
    zstd_writer,
)
from lanecast.io_adapters.logs.mcap.records import (
    MSG_HEAD,
    OP_CHANNEL,
    OP_MESSAGE,
    OP_SCHEMA,
    REC_HEAD,
    read_schema,
    read_string,
    read_string_map,
)
from lanecast.io_adapters.logs.mcap.walk import (
    LogDamage,
    ReadStats,
    walk,
)

_INTACT = "a chunk whose records define every channel and schema they use"


class _CopySink:
    """A record sink that copies what the checked walk hands it into an MCAP writer (annotate
    --salvage): every intact chunk's records and every intact top-level record, in file order, the
    extra messages merged. A chunk whose records do not hold together (a message on a channel
    never defined) is refused whole before any of it is written (the walk then skips it)."""

    def __init__(
        self,
        src: Path,
        writer: IdWriter,
        copying: MergedCopy,
        reserved: tuple[set[int], set[int]],
        extra: Sequence[ChannelSpec],
    ) -> None:
        self.offset = 0
        self.extra = extra
        self.stats = ReadStats()
        self.src, self.writer, self.copying, self.reserved = src, writer, copying, reserved
        self.schemas: dict[int, Schema] = {}
        self.channels: dict[int, Channel] = {}

    def records(self, buf: Any, start: int, end: int, in_chunk: bool, hint: Any = None) -> int:
        parsed: list[Schema | Channel | tuple[int, int, int, int, bytes]] = []
        pos = start
        while pos < end:
            if pos + 9 > end:
                raise ValueError(f"record header at {pos - start} runs past the end")
            op, length = REC_HEAD.unpack_from(buf, pos)
            body, nxt = pos + 9, pos + 9 + length
            if nxt > end:
                raise ValueError(f"record at {pos - start} declares {length} bytes, only {end - body} left")
            if op == OP_SCHEMA:
                sid, rec = read_schema(buf, body, nxt)
                parsed.append(Schema(id=sid, name=rec.name, encoding=rec.encoding, data=rec.data))
            elif op == OP_CHANNEL:
                parsed.append(_channel(buf, body, nxt))
            elif op == OP_MESSAGE:
                if length < MSG_HEAD.size:
                    raise ValueError(f"a Message record of {length} bytes, shorter than its header")
                cid, seq, log_time, publish_time = MSG_HEAD.unpack_from(buf, body)
                parsed.append((cid, seq, log_time, publish_time, bytes(buf[body + MSG_HEAD.size : nxt])))
            pos = nxt
        self._check(parsed)
        count = 0
        for item in parsed:
            if isinstance(item, Schema):
                self._put_schema(item)
            elif isinstance(item, Channel):
                self._put_channel(item)
            else:
                cid, seq, log_time, publish_time, data = item
                self.copying.before(log_time)
                self.writer.add_message(cid, log_time, data, publish_time, seq)
                self.copying.copied()
                count += 1
        return count

    def _check(self, parsed: list[Schema | Channel | tuple[int, int, int, int, bytes]]) -> None:
        """LogDamage (the chunk is lost) for a message on a channel, or a channel of a schema, defined
        neither before nor earlier in the chunk, or an id given other content."""
        schemas, channels = dict(self.schemas), dict(self.channels)
        for item in parsed:
            if isinstance(item, Schema):
                if schemas.get(item.id, item) != item:
                    raise LogDamage(
                        self.offset, f"schema {item.id} defined again with other content", "", True
                    )
                schemas[item.id] = item
            elif isinstance(item, Channel):
                if channels.get(item.id, item) != item:
                    raise LogDamage(
                        self.offset, f"channel {item.id} defined again with other content", "", True
                    )
                if item.schema_id and item.schema_id not in schemas:
                    raise LogDamage(
                        self.offset,
                        f"channel {item.id} refers to schema {item.schema_id}, never defined",
                        "",
                        True,
                    )
                channels[item.id] = item
            elif item[0] not in channels:
                raise LogDamage(
                    self.offset, f"message on channel {item[0]}, which was never defined", "", True
                )

    def _put_schema(self, schema: Schema) -> None:
        if schema.id in self.reserved[0]:
            raise LogError(
                self.src, f"schema id {schema.id} clashes with a forecast schema id", offset=self.offset
            )
        self.schemas[schema.id] = schema
        self.writer.put_schema(schema)

    def _put_channel(self, channel: Channel) -> None:
        if channel.id in self.reserved[1]:
            raise LogError(
                self.src, f"channel id {channel.id} clashes with a forecast channel id", offset=self.offset
            )
        check_new_topics(self.src, [channel.topic], self.extra)
        self.channels[channel.id] = channel
        self.writer.put_channel(channel)

    def metadata(self, buf: Any, pos: int, end: int) -> None:
        name, pos = read_string(buf, pos, end)
        values, _ = read_string_map(buf, pos, end)
        self.writer.add_metadata(name, values)
        self.copying.stats.metadata += 1

    def attachment(self, buf: Any, body: int, end: int) -> None:
        log_time, create_time = struct.unpack_from("<QQ", buf, body)
        name, pos = read_string(buf, body + 16, end)
        media_type, pos = read_string(buf, pos, end)
        (n,) = struct.unpack_from("<Q", buf, pos)
        self.writer.add_attachment(create_time, log_time, name, media_type, bytes(buf[pos + 8 : pos + 8 + n]))
        self.copying.stats.attachments += 1


def _channel(buf: Any, body: int, end: int) -> Channel:
    """The Channel record whose body is buf[body:end] (with its metadata, which the copy keeps)."""
    if body + 4 > end:
        raise ValueError("a Channel record too short for its ids")
    cid, sid = struct.unpack_from("<HH", buf, body)
    topic, pos = read_string(buf, body + 4, end)
    encoding, pos = read_string(buf, pos, end)
    metadata, _ = read_string_map(buf, pos, end)
    return Channel(id=cid, topic=topic, message_encoding=encoding, schema_id=sid, metadata=metadata)


def copy_mcap_salvaged(
    src: Path,
    out: BinaryIO,
    merge: Merge | None = None,
    *,
    chunk_size: int = CHUNK_SIZE,
    info: McapSummaryInfo | None = None,
    digest: Any = None,
) -> CopyStats:
    """:func:`copy_mcap` of a damaged MCAP (annotate --salvage): the records of every intact chunk
    and every intact top-level record, through the reader's checked walk with salvage, which skips
    what is damaged exactly as the track reader does (which reports the loss). The output is a
    complete MCAP with a summary made from what it holds."""
    src = Path(src)
    merge = merge or Merge()
    info = info or summary_info(src)
    check_new_topics(src, info.topics, merge.channels)
    stats = CopyStats(profile=info.profile)
    top = (info.max_schema_id, info.max_channel_id) if info.has_summary else None
    n = len(merge.channels)
    schema_ids = [top[0] + 1 + i if top else 0xFFFF - i for i in range(n)]
    channel_ids = [top[1] + 1 + i if top else 0xFFFF - i for i in range(n)]
    stats.extra_channel_ids = channel_ids
    writer = zstd_writer(out, chunk_size)
    copying = MergedCopy(
        merge, stats, lambda item: writer.add_message(channel_ids[item[1]], item[0], item[2], item[0], 0)
    )
    writer.start(profile=info.profile, library=LIBRARY)
    writer.put_extra(merge.channels, schema_ids, channel_ids)
    sink = _CopySink(src, writer, copying, (set(schema_ids), set(channel_ids)), merge.channels)
    with open(src, "rb") as f:
        stats.bytes_in = os.fstat(f.fileno()).st_size
        with mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) as mm:
            walk(mm, src, sink, True)
            if digest is not None:
                digest.update(mm)
    stats.schemas, stats.channels = len(sink.schemas), len(sink.channels)
    copying.before(None)
    writer.finish()
    copying.done()
    stats.bytes_out = out.tell()
    return stats
