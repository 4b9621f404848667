"""The record walk of an MCAP file: every record checked, chunks decompressed, damage located.

:func:`walk` goes through the top-level records of a whole file (an mmap) with every CRC checked
(chunks, data section, summary) and hands Schema, Channel, Message and Metadata records, and the
decompressed records of each chunk, to a :class:`RecordSink` (the decoder of
:mod:`lanecast.io_adapters.logs.mcap.reader`). A truncated file, a corrupt chunk or a bad record
raises :class:`LogError` with the byte offset; with ``salvage`` damaged chunks are skipped
(resynchronising on the next intact chunk) and the loss is counted in :class:`ReadStats`. Chunk
sizes are bounded before any allocation, so a chunk that lies about its size costs no more memory
than it declares.

The data section is the truth: the summary and the indexes (chunk indexes, message indexes,
summary offsets, the footer's offsets, the summary's copies of schemas and channels) are checked
against the records the walk found, and where they disagree :attr:`ReadStats.index` says how
(the read is the linear scan, right whatever the index says; tools that seek by it are not). A
Statistics message count that differs is refused: it says messages are missing. The records'
layouts are in :mod:`mcap_records`, the summary and index checks in :mod:`mcap_index`.
"""

from __future__ import annotations

import struct
import zlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from lanecast.io_adapters.errors import LogError
from lanecast.io_adapters.logs.mcap.index import (
    Layout,
    index_count,
    index_offsets,
    message_index_problem,
    summary_definition,
)
from lanecast.io_adapters.logs.mcap.records import (
    FIXED_SIZE,
    MAGIC,
    MAX_OP,
    MSG_HEAD,
    OP_ATTACHMENT,
    OP_CHANNEL,
    OP_CHUNK,
    OP_CHUNK_INDEX,
    OP_DATA_END,
    OP_FOOTER,
    OP_MESSAGE,
    OP_METADATA,
    OP_NAMES,
    OP_SCHEMA,
    OP_STATISTICS,
    OP_SUMMARY_OFFSET,
    REC_HEAD,
    ChannelRecord,
    SchemaRecord,
    check_attachment,
    chunk_payload,
    crc32_of,
    read_channel,
    read_schema,
)


@dataclass
class ReadStats:
    """What a read saw and, with salvage, what it lost."""

    chunks: int = 0
    chunks_lost: int = 0
    messages: int = 0
    messages_lost: int | None = 0
    damage: list[str] = field(default_factory=list)
    index: list[str] = field(default_factory=list)  # where the summary or an index disagrees with the data

    def index_note(self) -> str:
        """One line on an index that disagrees with the data section (empty if none does)."""
        if not self.index:
            return ""
        more = f" (and {len(self.index) - 1} more)" if len(self.index) > 1 else ""
        return (
            f"the file's index disagrees with its data section: {self.index[0]}{more}; "
            "read by a linear scan of the data section (tools that seek by the index read this log differently)"
        )

    def summary(self) -> str:
        lost = "an unknown number of" if self.messages_lost is None else f"{self.messages_lost:,}"
        return (
            f"salvaged {self.messages:,} messages from {self.chunks - self.chunks_lost:,} intact chunks; "
            f"lost {self.chunks_lost:,} chunks with {lost} messages"
            + (f" ({'; '.join(self.damage)})" if self.damage else "")
        )


class LogDamage(Exception):
    """A damaged record (internal): offset and message, turned into LogError or salvaged."""

    def __init__(self, offset: int, message: str, expected: str, resync: bool) -> None:
        super().__init__(message)
        self.offset, self.message, self.expected, self.resync = offset, message, expected, resync


def redefined(offset: int, kind: str, ident: int, before: object, now: object) -> LogDamage:
    """A Schema or Channel record giving a known id other content (the messages after it would be
    read as another topic or type): MCAP ids are unique in a file, a repeat repeats the content."""
    return LogDamage(
        offset,
        f"{kind} {ident} defined again with other content ({now}; before: {before})",
        f"one {kind} per id (a repeated {kind.capitalize()} record the same as the first)",
        False,
    )


def check_chunk_definitions(
    buf: Any, end: int, schemas: dict[int, SchemaRecord], channels: dict[int, ChannelRecord], offset: int
) -> None:
    """Check the records of a chunk buf[:end] (at file ``offset``), given the ``schemas`` and
    ``channels`` defined before it, before any is decoded: with salvage a damaged chunk
    is skipped whole, so none of its messages may reach the table before the damage is found.

    ValueError for a record that does not fit; LogDamage for a message on a channel (or a
    channel of a schema) defined neither before nor earlier in the chunk, or a Schema/Channel
    record giving a known id other content.
    """
    schemas, channels = dict(schemas), dict(channels)  # the chunk's own definitions added to copies
    pos = 0
    while pos < end:
        if pos + 9 > end:
            raise ValueError(f"record header at {pos} runs past the end")
        op, length = REC_HEAD.unpack_from(buf, pos)
        body, nxt = pos + 9, pos + 9 + length
        if nxt > end:
            raise ValueError(f"record at {pos} declares {length} bytes, only {end - body} left")
        if op == OP_MESSAGE:
            if length < MSG_HEAD.size:
                raise ValueError(f"a Message record of {length} bytes, shorter than its header")
            (cid,) = struct.unpack_from("<H", buf, body)
            ch = channels.get(cid)
            if ch is None:
                raise LogDamage(
                    offset,
                    f"message at byte {pos} of the chunk on channel {cid}, which was never defined",
                    "a Channel record first",
                    True,
                )
            if ch.schema_id and ch.schema_id not in schemas:
                raise LogDamage(
                    offset,
                    f"topic {ch.topic!r} refers to schema {ch.schema_id}, which the file does not define",
                    "a Schema record for every channel",
                    True,
                )
        elif op == OP_SCHEMA:
            sid, schema = read_schema(buf, body, nxt)
            if sid in schemas and schemas[sid] != schema:
                raise redefined(offset, "schema", sid, schemas[sid], schema)
            schemas[sid] = schema
        elif op == OP_CHANNEL:
            cid, channel = read_channel(buf, body, nxt)
            if cid in channels and channels[cid] != channel:
                raise redefined(offset, "channel", cid, channels[cid], channel)
            channels[cid] = channel
        pos = nxt


def _resync(buf: Any, start: int, size: int) -> int | None:
    """The offset of the next intact Chunk record at or after start, else None."""
    pos = start
    while True:
        pos = buf.find(bytes([OP_CHUNK]), pos, size)
        if pos < 0 or pos + 9 > size:
            return None
        (length,) = struct.unpack_from("<Q", buf, pos + 1)
        end = pos + 9 + length
        if 40 <= length and end <= size and (end == size or 0 < buf[end] < MAX_OP):
            try:
                chunk_payload(buf, pos + 9, end)
                return pos
            except Exception:
                pass
        pos += 1


class RecordSink(Protocol):
    """What :func:`walk` hands the records it reads to (the MCAP decoder)."""

    offset: int  # file offset of the top-level record being handed over (for errors)
    stats: ReadStats

    def records(self, buf: Any, start: int, end: int, in_chunk: bool, hint: np.ndarray | None = None) -> int:
        """Schema/Channel/Message records in buf[start:end] (a chunk's records when ``in_chunk``;
        ``hint``: the record offsets its MessageIndex lists); returns the messages seen."""
        ...

    def metadata(self, buf: Any, pos: int, end: int) -> None:
        """A Metadata record whose body is buf[pos:end]."""
        ...


class CountingSink:
    """A record sink that decodes nothing and counts messages: the walk alone checks every record
    and the count against the summary's Statistics (a log checked, not read)."""

    offset = 0

    def __init__(self) -> None:
        self.stats = ReadStats()

    def records(self, buf: Any, start: int, end: int, in_chunk: bool, hint: Any = None) -> int:
        count, pos = 0, start
        while pos + 9 <= end:
            op, length = REC_HEAD.unpack_from(buf, pos)
            count += op == OP_MESSAGE
            pos += 9 + length
        return count

    def metadata(self, buf: Any, pos: int, end: int) -> None:
        pass


def walk(buf: Any, path: Path, dec: RecordSink, salvage: bool) -> None:
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
    statistics_at = 0
    layout = Layout()
    while pos < size:
        dec.offset = pos
        skip_to: int | None = None
        try:
            if pos + 9 > size:
                raise LogDamage(pos, "the file is truncated inside a record header", complete, True)
            op, length = REC_HEAD.unpack_from(buf, pos)
            body, nxt = pos + 9, pos + 9 + length
            if op == 0 or (MAX_OP <= op < 0x80):
                raise LogDamage(pos, f"invalid record opcode {op:#04x}", "an MCAP record", True)
            if nxt > size:
                if ends_with_magic:
                    raise LogDamage(
                        pos,
                        f"corrupt record: opcode {op:#04x} declares {length} bytes, past the end",
                        "a valid record length",
                        True,
                    )
                raise LogDamage(
                    pos,
                    f"the file is truncated: a record (opcode {op:#04x}) declares {length} bytes but the file "
                    f"ends {size - body} bytes later",
                    complete,
                    True,
                )
            if data_end_seen and op != OP_FOOTER:
                layout.summary_records[pos] = op
            if op == OP_CHUNK:
                stats.chunks += 1
                if body + 16 <= nxt:
                    layout.chunks[pos] = (length, *struct.unpack_from("<QQ", buf, body))
                try:
                    data = chunk_payload(buf, body, nxt)
                    hint = index_offsets(buf, nxt, size)
                    in_chunk = dec.records(memoryview(data), 0, len(data), True, hint)
                    stats.messages += in_chunk
                    problem = message_index_problem(buf, pos, nxt, size, data, in_chunk, layout)
                    if problem:
                        stats.index.append(problem)
                except LogDamage as dmg:  # an intact chunk whose records lack something: it is lost
                    skip_to = nxt  # its CRC held, so its length did: the walk goes on after it
                    raise LogDamage(pos, f"corrupt chunk: {dmg.message}", dmg.expected, True) from dmg
                except (ValueError, struct.error, zlib.error) as exc:
                    raise LogDamage(
                        pos, f"corrupt chunk: {exc}", "an intact zstd/lz4 chunk with a matching CRC", True
                    ) from exc
                except Exception as exc:
                    if type(exc).__module__.startswith(("zstandard", "lz4")):
                        raise LogDamage(
                            pos, f"corrupt chunk: {exc}", "an intact zstd/lz4 chunk", True
                        ) from exc
                    raise
            elif op in FIXED_SIZE and length < FIXED_SIZE[op]:
                raise LogDamage(
                    pos,
                    f"corrupt record: opcode {op:#04x} declares {length} bytes, fewer than its fields",
                    f"at least {FIXED_SIZE[op]} bytes",
                    False,
                )
            elif data_end_seen and op in (OP_SCHEMA, OP_CHANNEL):  # the data section's, repeated
                problem = summary_definition(buf, pos, body, nxt, op, dec)
                if problem:
                    layout.notes.append(problem)
            elif op == OP_CHUNK_INDEX and data_end_seen:
                layout.chunk_index(buf, pos, body, nxt)
            elif op == OP_SUMMARY_OFFSET and data_end_seen:
                layout.summary_offset(buf, pos, body, nxt)
            elif op in (OP_SCHEMA, OP_CHANNEL, OP_MESSAGE, OP_METADATA):
                try:
                    if op == OP_METADATA:
                        dec.metadata(buf, body, nxt)
                    else:
                        stats.messages += dec.records(buf, pos, nxt, False)
                except (ValueError, struct.error) as exc:
                    raise LogDamage(
                        pos, f"corrupt {OP_NAMES[op]} record: {exc}", f"a valid {OP_NAMES[op]} record", True
                    ) from exc
            elif op == OP_ATTACHMENT:  # copied by annotate: its fields must hold, its CRC match
                try:
                    check_attachment(buf, body, nxt)
                    copy_attachment = getattr(dec, "attachment", None)  # a sink that copies the log
                    if copy_attachment is not None:
                        copy_attachment(buf, body, nxt)
                except (ValueError, struct.error) as exc:
                    raise LogDamage(
                        pos, f"corrupt Attachment record: {exc}", "a valid Attachment record", True
                    ) from exc
            elif op == OP_DATA_END:
                data_end_seen = True
                layout.summary_start = nxt
                (crc,) = struct.unpack_from("<I", buf, body)
                if crc and crc32_of(buf, 0, pos) != crc:
                    skip_to = nxt
                    raise LogDamage(pos, "data section CRC mismatch", "an undamaged data section", False)
            elif op == OP_STATISTICS:
                (total_expected,) = struct.unpack_from("<Q", buf, body)
                statistics_at = pos
                if length >= 26:
                    (layout.statistics_chunks,) = struct.unpack_from("<I", buf, body + 22)
            elif op == OP_FOOTER:
                footer_seen = True
                summary_start, offset_start, summary_crc = struct.unpack_from("<QQI", buf, body)
                if summary_crc and summary_start and crc32_of(buf, summary_start, body + 16) != summary_crc:
                    total_expected = None
                    raise LogDamage(pos, "summary CRC mismatch", "an undamaged summary section", False)
                if data_end_seen:
                    stats.index += layout.problems(pos, summary_start, offset_start)
                if bytes(buf[nxt : nxt + 8]) != MAGIC:
                    raise LogDamage(
                        nxt, "the file does not end with the MCAP magic", "the closing magic", False
                    )
                break
            pos = nxt
        except LogDamage as dmg:
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
                lost, _ = index_count(buf, pos + 9 + length, size)
                if stats.messages_lost is not None:
                    stats.messages_lost = stats.messages_lost + lost if lost else None
                if skip_to is not None:
                    pos = skip_to
                    continue
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
    if total_expected is not None and footer_seen and total_expected != stats.messages:  # stale summary
        what = (
            f"the summary's Statistics record counts {total_expected:,} messages, but the data section "
            f"holds {stats.messages:,} (a chunk missing, repeated or added since the summary was written)"
        )
        if not salvage:
            raise LogError(
                path,
                what,
                offset=statistics_at,
                expected="a summary that matches the data section (--salvage reads the chunks there are)",
            )
        if not stats.damage:
            stats.damage.append(f"offset {statistics_at}: {what}")
    if salvage and total_expected is not None and footer_seen:
        stats.messages_lost = max(total_expected - stats.messages, 0)
