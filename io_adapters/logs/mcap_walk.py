"""The record walk of an MCAP file: every record checked, chunks decompressed, damage located.

:func:`walk` goes through the top-level records of a whole file (an mmap) with every CRC checked
(chunks, data section, summary) and hands Schema, Channel, Message and Metadata records, and the
decompressed records of each chunk, to a :class:`RecordSink` (the decoder of
:mod:`lanecast.io_adapters.logs.mcap_reader`). A truncated file, a corrupt chunk or a bad record
raises :class:`LogError` with the byte offset; with ``salvage`` damaged chunks are skipped
(resynchronising on the next intact chunk) and the loss is counted in :class:`ReadStats`. Chunk
sizes are bounded before any allocation, so a chunk that lies about its size costs no more memory
than it declares.

The data section is the truth: the summary and the indexes (chunk indexes, message indexes,
summary offsets, the footer's offsets, the summary's copies of schemas and channels) are checked
against the records the walk found, and where they disagree :attr:`ReadStats.index` says how
(the read is the linear scan, right whatever the index says; tools that seek by it are not). A
Statistics message count that differs is refused: it says messages are missing.
"""

from __future__ import annotations

import struct
import zlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from lanecast.io_adapters.errors import LogError

MAGIC = b"\x89MCAP0\r\n"


OP_HEADER, OP_FOOTER, OP_SCHEMA, OP_CHANNEL, OP_MESSAGE, OP_CHUNK = 0x01, 0x02, 0x03, 0x04, 0x05, 0x06


OP_MESSAGE_INDEX, OP_ATTACHMENT, OP_STATISTICS, OP_METADATA, OP_DATA_END = 0x07, 0x09, 0x0B, 0x0C, 0x0F


OP_CHUNK_INDEX, OP_SUMMARY_OFFSET = 0x08, 0x0E


_MAX_OP = 0x10


_OP_NAMES = {OP_SCHEMA: "Schema", OP_CHANNEL: "Channel", OP_MESSAGE: "Message", OP_METADATA: "Metadata"}


# Records read with fixed-size fields: the least length their fields take.
_FIXED_SIZE = {OP_DATA_END: 4, OP_STATISTICS: 8, OP_FOOTER: 20, OP_CHUNK: 28}


MSG_HEAD = struct.Struct("<HIQQ")


REC_HEAD = struct.Struct("<BQ")


LEN = struct.Struct("<Q")


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


def read_string(buf: Any, pos: int, end: int) -> tuple[str, int]:
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


def read_string_map(buf: Any, pos: int, end: int) -> tuple[dict[str, str], int]:
    if pos + 4 > end:
        raise ValueError("a map length runs past the record")
    (n,) = struct.unpack_from("<I", buf, pos)
    stop = pos + 4 + n
    if stop > end:
        raise ValueError(f"a map of {n} bytes runs past the record")
    pos += 4
    out = {}
    while pos < stop:
        k, pos = read_string(buf, pos, stop)
        v, pos = read_string(buf, pos, stop)
        out[k] = v
    return out, stop


@dataclass
class SchemaRecord:
    name: str
    encoding: str
    data: bytes


@dataclass
class ChannelRecord:
    topic: str
    schema_id: int
    encoding: str


def read_schema(buf: Any, pos: int, end: int) -> tuple[int, SchemaRecord]:
    """The id and content of the Schema record whose body is buf[pos:end]."""
    if pos + 2 > end:
        raise ValueError("a Schema record too short for its id")
    (sid,) = struct.unpack_from("<H", buf, pos)
    name, pos = read_string(buf, pos + 2, end)
    encoding, pos = read_string(buf, pos, end)
    if pos + 4 > end:
        raise ValueError("the schema data length runs past the record")
    (n,) = struct.unpack_from("<I", buf, pos)
    if pos + 4 + n > end:
        raise ValueError(f"schema data of {n} bytes runs past the record")
    return sid, SchemaRecord(name, encoding, bytes(buf[pos + 4 : pos + 4 + n]))


def read_channel(buf: Any, pos: int, end: int) -> tuple[int, ChannelRecord]:
    """The id and content (topic, schema id, message encoding) of the Channel record buf[pos:end]."""
    if pos + 4 > end:
        raise ValueError("a Channel record too short for its ids")
    cid, sid = struct.unpack_from("<HH", buf, pos)
    topic, pos = read_string(buf, pos + 4, end)
    encoding, pos = read_string(buf, pos, end)
    return cid, ChannelRecord(topic, sid, encoding)


def redefined(offset: int, kind: str, ident: int, before: object, now: object) -> LogDamage:
    """A Schema or Channel record giving a known id other content (the messages after it would be
    read as another topic or type): MCAP ids are unique in a file, a repeat repeats the content."""
    return LogDamage(
        offset,
        f"{kind} {ident} defined again with other content ({now}; before: {before})",
        f"one {kind} per id (a repeated {kind.capitalize()} record the same as the first)",
        False,
    )


def read_ints(raw: np.ndarray, at: np.ndarray, dtype: str) -> np.ndarray:
    """Little-endian integers of type ``dtype`` at byte offsets at [n] of raw (uint8 [N]) → [n]."""
    size = np.dtype(dtype).itemsize
    every = np.ndarray((raw.size - size + 1,), dtype=dtype, buffer=raw, strides=(1,))
    return every[at]


#: Largest chunk (uncompressed) read: a chunk's declared size is checked against it before any
#: allocation (MCAP writers make chunks of a few MB).
MAX_CHUNK_BYTES = 1 << 30


def chunk_payload(buf: Any, body: int, end: int) -> bytes:
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
    compression, pos = read_string(buf, body + 28, end)
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


def check_attachment(buf: Any, body: int, end: int) -> None:
    """ValueError unless buf[body:end] is an Attachment record's body: log and create time, name,
    media type, data, and a CRC (0: not computed) of everything before it."""
    if body + 16 > end:
        raise ValueError("too short for its times")
    _name, pos = read_string(buf, body + 16, end)
    _media_type, pos = read_string(buf, pos, end)
    if pos + 8 > end:
        raise ValueError("the data length runs past the record")
    (n,) = struct.unpack_from("<Q", buf, pos)
    if pos + 8 + n + 4 != end:
        raise ValueError(f"{n:,} bytes of data and a CRC do not fill the record's {end - pos - 8:,} bytes")
    (crc,) = struct.unpack_from("<I", buf, pos + 8 + n)
    if crc and crc32_of(buf, body, pos + 8 + n) != crc:
        raise ValueError(
            f"CRC mismatch (stored {crc:#010x}, computed {crc32_of(buf, body, pos + 8 + n):#010x})"
        )


def index_offsets(buf: Any, pos: int, size: int) -> np.ndarray | None:
    """Message offsets [n] (int64) listed by the MessageIndex records starting at pos, or None."""
    parts = []
    while pos + 15 <= size:
        op, length = REC_HEAD.unpack_from(buf, pos)
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


def verified_offsets(raw: np.ndarray, end: int, hint: np.ndarray) -> np.ndarray | None:
    """The sorted offsets ``hint`` if they are exactly the chain of records of raw[:end] (each record
    ends where the next starts, the first at 0, the last at end), else None."""
    if not hint.size:
        return None
    at = np.sort(hint)
    if at[0] != 0 or at[-1] > end - 9:  # not at[-1] + 9: an offset near 2**63 would wrap
        return None
    lengths = read_ints(raw, at + 1, "<u8")
    if (lengths > np.uint64(end)).any():
        return None
    if not (at + 9 + lengths.astype(np.int64) == np.append(at[1:], end)).all():
        return None
    return at


def _index_count(buf: Any, pos: int, size: int) -> tuple[int, int]:
    """Messages listed by the MessageIndex records starting at pos; returns (count, end)."""
    count = 0
    while pos + 9 <= size:
        op, length = REC_HEAD.unpack_from(buf, pos)
        if op != OP_MESSAGE_INDEX or pos + 9 + length > size:
            break
        (n,) = struct.unpack_from("<I", buf, pos + 11)
        count += n // 16
        pos += 9 + length
    return count, pos


def _message_index_problem(
    buf: Any, chunk_at: int, pos: int, size: int, data: bytes, count: int, layout: _Layout
) -> str | None:
    """How the MessageIndex records at pos (after the chunk at chunk_at, whose records are data and
    hold count messages) disagree with the chunk: each entry must point at a Message record of its
    channel and log time, every message listed once; None if they agree (or there are none)."""
    raw = np.frombuffer(data, dtype=np.uint8)
    listed = 0
    while pos + 15 <= size:
        op, length = REC_HEAD.unpack_from(buf, pos)
        if op != OP_MESSAGE_INDEX or pos + 9 + length > size:
            break
        layout.message_indexes.add(pos)
        cid, n = struct.unpack_from("<HI", buf, pos + 9)
        if n % 16 or 6 + n > length:
            return f"offset {pos}: a MessageIndex record whose entries ({n} bytes) do not fit it"
        pairs = np.frombuffer(buf, dtype="<u8", count=n // 8, offset=pos + 15).copy()
        times, at = pairs[0::2], pairs[1::2]
        listed += at.size
        if (at + 9 + MSG_HEAD.size > raw.size).any():
            return f"offset {pos}: a MessageIndex entry points past the end of the chunk at {chunk_at}"
        at = at.astype(np.int64)
        if (
            (raw[at] != OP_MESSAGE).any()
            or (read_ints(raw, at + 9, "<u2") != cid).any()
            or (read_ints(raw, at + 9 + 6, "<u8") != times).any()
        ):
            return (
                f"offset {pos}: a MessageIndex entry of channel {cid} points at no message of that channel "
                f"and log time in the chunk at {chunk_at}"
            )
        pos += 9 + length
    if listed and listed != count:
        return f"offset {pos}: the MessageIndex records list {listed} messages, the chunk at {chunk_at} holds {count}"
    return None


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
                chunk_payload(buf, pos + 9, end)
                return pos
            except Exception:
                pass
        pos += 1


@dataclass
class _Layout:
    """Where the data section's records are, and what the summary says of them (checked at the end)."""

    chunks: dict[int, tuple[int, int, int]] = field(default_factory=dict)  # offset: length, t0, t1
    summary_start: int = 0  # the offset after DataEnd
    summary_records: dict[int, int] = field(default_factory=dict)  # offset: opcode, after DataEnd
    chunk_indexes: list[tuple[int, int, int, int, int]] = field(default_factory=list)
    statistics_chunks: int | None = None
    index_offsets: list[tuple[int, int]] = field(default_factory=list)  # ChunkIndex at, MessageIndex offset
    message_indexes: set[int] = field(default_factory=set)  # the data section's MessageIndex records
    groups: list[tuple[int, int, int, int]] = field(
        default_factory=list
    )  # SummaryOffsets: at, op, start, length
    notes: list[str] = field(default_factory=list)

    def chunk_index(self, buf: Any, pos: int, body: int, end: int) -> None:
        """A summary ChunkIndex record: (its offset, chunk start, chunk length, start and end time)."""
        if end - body < 32:
            self.notes.append(f"offset {pos}: a ChunkIndex record of {end - body} bytes, too short")
            return
        t0, t1, start, length = struct.unpack_from("<QQQQ", buf, body)
        self.chunk_indexes.append((pos, start, length, t0, t1))
        (n,) = struct.unpack_from("<I", buf, body + 32)
        if body + 36 + n > end or n % 10:
            self.notes.append(
                f"offset {pos}: a ChunkIndex whose message index offsets ({n} bytes) do not fit it"
            )
            return
        pairs = np.frombuffer(buf, dtype=np.uint8, count=n, offset=body + 36).copy()
        offsets = np.ndarray((n // 10,), dtype="<u8", buffer=pairs, offset=2, strides=(10,))
        self.index_offsets += [(pos, int(o)) for o in offsets.tolist()]

    def problems(self, footer_at: int, summary_start: int, offset_start: int) -> list[str]:
        """Each way the summary (chunk indexes, statistics, summary offsets, footer) disagrees with the
        records the walk found, most telling first."""
        out = list(self.notes)
        for at, start, length, t0, t1 in self.chunk_indexes:
            chunk = self.chunks.get(start)
            if chunk is None:
                out.append(f"offset {at}: a ChunkIndex points at offset {start}, where no chunk starts")
            elif chunk[0] + 9 != length:
                out.append(
                    f"offset {at}: a ChunkIndex gives the chunk at {start} {length} bytes, it has {chunk[0] + 9}"
                )
            elif (t0, t1) != chunk[1:]:
                out.append(f"offset {at}: a ChunkIndex gives the chunk at {start} other message times")
        for at, offset in self.index_offsets:
            if offset not in self.message_indexes:
                out.append(
                    f"offset {at}: a ChunkIndex points at offset {offset}, where no MessageIndex record is"
                )
                break
        indexed = {start for _, start, *_ in self.chunk_indexes}
        if self.chunk_indexes and len(indexed) != len(self.chunks):
            out.append(
                f"the summary indexes {len(indexed)} chunks, the data section holds {len(self.chunks)}"
            )
        if self.statistics_chunks is not None and self.statistics_chunks != len(self.chunks):
            out.append(
                f"the Statistics record counts {self.statistics_chunks} chunks, the data section holds "
                f"{len(self.chunks)}"
            )
        if summary_start and summary_start != self.summary_start:
            out.append(
                f"offset {footer_at}: the footer puts the summary at offset {summary_start}, "
                f"it starts at {self.summary_start}"
            )
        ends = {*self.summary_records, footer_at}
        for at, op, start, length in self.groups:
            if length and (self.summary_records.get(start) != op or start + length not in ends):
                out.append(
                    f"offset {at}: a SummaryOffset puts the records of opcode {op:#04x} at offset {start} "
                    f"({length} bytes), where no such group is"
                )
        groups = [o for o, op in self.summary_records.items() if op == OP_SUMMARY_OFFSET]
        if offset_start and offset_start != (groups[0] if groups else footer_at):
            out.append(
                f"offset {footer_at}: the footer puts the summary offsets at {offset_start}, they start at "
                f"{groups[0] if groups else 'no offset'}"
            )
        return out

    def summary_offset(self, buf: Any, pos: int, body: int, end: int) -> None:
        """A SummaryOffset record: its group (opcode, start, length) must be a run of such records."""
        if end - body < 17:
            self.notes.append(f"offset {pos}: a SummaryOffset record of {end - body} bytes, too short")
            return
        self.groups.append((pos, *struct.unpack_from("<BQQ", buf, body)))


def _summary_definition(buf: Any, pos: int, body: int, end: int, op: int, dec: Any) -> str | None:
    """What is wrong with a Schema or Channel record of the summary, which must repeat the data
    section's record of its id; None if it does."""
    try:
        ident, record = (read_schema if op == OP_SCHEMA else read_channel)(buf, body, end)
    except (ValueError, struct.error) as exc:
        return f"offset {pos}: a summary {_OP_NAMES[op]} record that cannot be read ({exc})"
    known = getattr(dec, "schemas" if op == OP_SCHEMA else "channels", None)
    if known is None:
        return None
    kind = _OP_NAMES[op].lower()
    if ident in known and known[ident] != record:  # one unknown: a channel without messages
        return f"offset {pos}: the summary's {kind} {ident} ({record}) is not the data section's ({known[ident]})"
    return None


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
    layout = _Layout()
    while pos < size:
        dec.offset = pos
        skip_to: int | None = None
        try:
            if pos + 9 > size:
                raise LogDamage(pos, "the file is truncated inside a record header", complete, True)
            op, length = REC_HEAD.unpack_from(buf, pos)
            body, nxt = pos + 9, pos + 9 + length
            if op == 0 or (_MAX_OP <= op < 0x80):
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
                    problem = _message_index_problem(buf, pos, nxt, size, data, in_chunk, layout)
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
            elif op in _FIXED_SIZE and length < _FIXED_SIZE[op]:
                raise LogDamage(
                    pos,
                    f"corrupt record: opcode {op:#04x} declares {length} bytes, fewer than its fields",
                    f"at least {_FIXED_SIZE[op]} bytes",
                    False,
                )
            elif data_end_seen and op in (OP_SCHEMA, OP_CHANNEL):  # the data section's, repeated
                problem = _summary_definition(buf, pos, body, nxt, op, dec)
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
                        pos, f"corrupt {_OP_NAMES[op]} record: {exc}", f"a valid {_OP_NAMES[op]} record", True
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
                lost, _ = _index_count(buf, pos + 9 + length, size)
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


def crc32_of(buf: Any, start: int, end: int, block: int = 1 << 24) -> int:
    """CRC-32 of ``buf[start:end]`` in blocks of views: slicing an mmap would copy the whole range."""
    crc = 0
    view = memoryview(buf)
    try:
        for lo in range(start, end, block):
            crc = zlib.crc32(view[lo : min(lo + block, end)], crc)
    finally:
        view.release()
    return crc
