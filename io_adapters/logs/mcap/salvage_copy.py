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

from mcap.opcode import Opcode
from mcap.records import Channel, Schema

from lanecast.io_adapters.errors import LogError
from lanecast.io_adapters.logs.forecast_messages import ChannelSpec
from lanecast.io_adapters.logs.mcap.copy import (
    DEFAULT_COPY,
    LIBRARY,
    CopyOptions,
    CopyStats,
    IdWriter,
    Merge,
    MergedCopy,
    check_new_topics,
    finish_copy,
    start_copy,
)
from lanecast.io_adapters.logs.mcap.definitions import Definitions, parsed
from lanecast.io_adapters.logs.mcap.records import (
    MSG_HEAD,
    read_schema,
    read_string,
    read_string_map,
)
from lanecast.io_adapters.logs.mcap.walk import ReadStats, walk


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
        self.defs = Definitions()
        self.schemas: dict[int, Schema] = self.defs.schemas
        self.channels: dict[int, Channel] = self.defs.channels

    def records(self, buf: Any, start: int, end: int, in_chunk: bool, hint: Any = None) -> int:
        items = list(parsed(buf, start, end, _schema, _channel))
        self.defs.check_chunk(items, self.offset)
        count = 0
        for op, _pos, body, nxt, value in items:
            if op == Opcode.SCHEMA:
                self._put_schema(value[1])
            elif op == Opcode.CHANNEL:
                self._put_channel(value[1])
            else:
                cid, seq, log_time, publish_time = value
                self.copying.before(log_time)
                self.writer.add_message(
                    cid, log_time, bytes(buf[body + MSG_HEAD.size : nxt]), publish_time, seq
                )
                self.copying.copied()
                count += 1
        return count

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


def _schema(buf: Any, body: int, end: int) -> tuple[int, Schema]:
    sid, rec = read_schema(buf, body, end)
    return sid, Schema(id=sid, name=rec.name, encoding=rec.encoding, data=rec.data)


def _channel(buf: Any, body: int, end: int) -> tuple[int, Channel]:
    """The Channel record whose body is buf[body:end] (with its metadata, which the copy keeps)."""
    if body + 4 > end:
        raise ValueError("a Channel record too short for its ids")
    cid, sid = struct.unpack_from("<HH", buf, body)
    topic, pos = read_string(buf, body + 4, end)
    encoding, pos = read_string(buf, pos, end)
    metadata, _ = read_string_map(buf, pos, end)
    return cid, Channel(id=cid, topic=topic, message_encoding=encoding, schema_id=sid, metadata=metadata)


def copy_mcap_salvaged(
    src: Path, out: BinaryIO, merge: Merge | None = None, options: CopyOptions = DEFAULT_COPY
) -> CopyStats:
    """:func:`copy_mcap` of a damaged MCAP (annotate --salvage): the records of every intact chunk
    and every intact top-level record, through the reader's checked walk with salvage, which skips
    what is damaged exactly as the track reader does (which reports the loss). The output is a
    complete MCAP with a summary made from what it holds."""
    src = Path(src)
    merge = merge or Merge()
    info, stats, writer, copying, schema_ids, channel_ids = start_copy(src, out, merge, options)
    writer.start(profile=info.profile, library=LIBRARY)
    writer.put_extra(merge.channels, schema_ids, channel_ids)
    sink = _CopySink(src, writer, copying, (set(schema_ids), set(channel_ids)), merge.channels)
    with open(src, "rb") as f:
        stats.bytes_in = os.fstat(f.fileno()).st_size
        with mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) as mm:
            walk(mm, src, sink, True)
            if options.digest is not None:
                options.digest.update(mm)
    stats.schemas, stats.channels = len(sink.schemas), len(sink.channels)
    finish_copy(writer, copying, out)
    return stats
