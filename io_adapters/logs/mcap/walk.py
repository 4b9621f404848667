"""The record walk of an MCAP file: every record checked, chunks decompressed, damage located.

:func:`walk` goes through the top-level records of a whole file (an mmap) with every CRC checked
(chunks, data section, summary) and hands Schema, Channel, Message and Metadata records, and the
decompressed records of each chunk, to a :class:`RecordSink` (the decoder of
:mod:`lanecast.io_adapters.logs.mcap.reader`). A truncated file, a corrupt chunk or a bad record
raises an McapError (a LogError) of its kind with the byte offset; with ``salvage`` damaged chunks are skipped
(resynchronising on the next intact chunk) and the loss is counted in :class:`ReadStats`. Chunk
sizes are bounded before any allocation, so a chunk that lies about its size costs no more memory
than it declares.

The data section is the truth: the summary and the indexes (chunk indexes, message indexes,
summary offsets, the footer's offsets, the summary's copies of schemas and channels) are checked
against the records the walk found, and where they disagree :attr:`ReadStats.index` says how
(the read is the linear scan, right whatever the index says; tools that seek by it are not). A
Statistics message count that differs is refused: it says messages are missing. The records
are walked by :func:`~lanecast.io_adapters.logs.mcap.records.records` (layouts there), the summary
and index checks are in :mod:`~lanecast.io_adapters.logs.mcap.index`; damage raises an
:class:`~lanecast.io_adapters.logs.mcap.errors.McapError` of its kind.
"""

from __future__ import annotations

import mmap
import os
import re
import struct
import zlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

import numpy as np
from mcap.opcode import Opcode

from lanecast.io_adapters.logs.mcap.errors import (
    CorruptRecord,
    CrcMismatch,
    IndexMismatch,
    LogDamage,
    NotMcap,
    TruncatedFile,
)
from lanecast.io_adapters.logs.mcap.index import (
    Layout,
    index_count,
    index_offsets,
    message_index_problem,
    summary_definition,
    verified_offsets,
)
from lanecast.io_adapters.logs.mcap.records import (
    FIXED_SIZE,
    MAGIC,
    MAX_OP,
    CrcError,
    RecordOverrun,
    check_attachment,
    chunk_payload,
    crc32_of,
    op_name,
    records,
)

_COMPLETE = "a complete MCAP file ending with a footer and the magic"


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
        if self.messages_lost is None:  # cut short or unresynchronisable: what followed is not known
            least = f", at least {self.chunks_lost:,} of them" if self.chunks_lost else ""
            lost = f"an unknown number of chunks and messages{least}"
        else:
            lost = f"{self.chunks_lost:,} chunks with {self.messages_lost:,} messages"
        return (
            f"salvaged {self.messages:,} messages from {self.chunks - self.chunks_lost:,} intact chunks; "
            f"lost {lost}" + (f" ({'; '.join(self.damage)})" if self.damage else "")
        )


def _resync(buf: Any, start: int, size: int) -> int | None:
    """The offset of the next intact Chunk record at or after start, else None."""
    pos = start
    while True:
        pos = buf.find(bytes([Opcode.CHUNK]), pos, size)
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
        if in_chunk and hint is not None:  # the chunk's MessageIndex offsets, if they are its records
            raw = np.frombuffer(buf, dtype=np.uint8)
            at = verified_offsets(raw, end, hint)
            if at is not None:
                return int((raw[at] == Opcode.MESSAGE).sum())
        return sum(op == Opcode.MESSAGE for op, *_ in records(buf, start, end))

    def metadata(self, buf: Any, pos: int, end: int) -> None:
        pass


def _check_start(buf: Any, path: Path) -> None:
    """NotMcap or TruncatedFile unless buf starts with the MCAP magic."""
    size = len(buf)
    if size == 0:
        raise NotMcap(path, "the file is empty", offset=0, expected="an MCAP file")
    if size < 8 and MAGIC.startswith(bytes(buf[:size])):
        raise TruncatedFile(
            path,
            f"the file is truncated: {size} bytes, inside the magic",
            offset=size,
            expected="an MCAP file",
        )
    if size < 8 or bytes(buf[:8]) != MAGIC:
        raise NotMcap(
            path, f"not an MCAP file (starts with {bytes(buf[:8])!r})", offset=0, expected="the MCAP magic"
        )


def _crc_damage(stored: int, buf: Any, start: int, end: int, at: int, what: str) -> LogDamage | None:
    """The damage of the ``what`` section (data, summary) whose stored CRC (0: not computed) is not
    that of buf[start:end]."""
    computed = crc32_of(buf, start, end) if stored else 0
    if computed == stored:
        return None
    return LogDamage(
        at,
        f"{'data section' if what == 'data' else what} CRC mismatch (stored {stored:#010x}, computed {computed:#010x})",
        f"an undamaged {what} section",
        False,
        CrcMismatch,
    )


def _invalid(op: int, pos: int) -> LogDamage:
    """An opcode no record has (0) or one the specification reserves (0x10-0x7F)."""
    return LogDamage(pos, f"invalid record opcode {op:#04x}", "an MCAP record", True)


class _Walk:
    """One walk over the top-level records of a file: what it has seen, and where to go on."""

    def __init__(self, buf: Any, dec: RecordSink, crcs: bool = True) -> None:
        self.buf, self.dec, self.stats, self.size = buf, dec, dec.stats, len(buf)
        self.crcs = crcs  # False: the data section's and the chunks' CRCs are a later pass's
        self.ends_with_magic = self.size >= 16 and bytes(buf[self.size - 8 :]) == MAGIC
        self.footer_seen = self.data_end_seen = False
        self.total_expected: int | None = None
        self.statistics_at = self.pos = 0
        self.skip_to: int | None = None  # where to go on after damage to a record whose length held
        self.layout = Layout()

    def run(self, start: int) -> None:
        """Walk the records from ``start`` to the footer (or the end of the file)."""
        try:
            for op, pos, body, nxt in records(self.buf, start, self.size):
                self.dec.offset = self.pos = pos
                self.skip_to = None
                if op == 0 or (MAX_OP <= op < 0x80):
                    raise _invalid(op, pos)
                if self.record(op, pos, body, nxt):
                    return
        except RecordOverrun as over:
            self.dec.offset = self.pos = over.pos
            self.skip_to = None
            raise self.overrun(over) from over

    def overrun(self, over: RecordOverrun) -> LogDamage:
        op, pos = over.op, over.pos
        if op is None:
            return LogDamage(
                pos, "the file is truncated inside a record header", _COMPLETE, True, TruncatedFile
            )
        if op == 0 or (MAX_OP <= op < 0x80):
            return _invalid(op, pos)
        if self.ends_with_magic:
            return LogDamage(
                pos,
                f"corrupt record: {op_name(op)} declares {over.length} bytes, past the end",
                "a valid record length",
                True,
            )
        return LogDamage(
            pos,
            f"the file is truncated: a record ({op_name(op)}) declares {over.length} bytes but the file "
            f"ends {over.left} bytes later",
            _COMPLETE,
            True,
            TruncatedFile,
        )

    def record(self, op: int, pos: int, body: int, nxt: int) -> bool:
        """Check (and hand to the sink) one top-level record; True at the footer."""
        buf, dec, layout = self.buf, self.dec, self.layout
        if self.data_end_seen and op != Opcode.FOOTER:
            layout.summary_records[pos] = op
        if op == Opcode.CHUNK:
            self.chunk(pos, body, nxt)
        elif op in FIXED_SIZE and nxt - body < FIXED_SIZE[op]:
            raise LogDamage(
                pos,
                f"corrupt record: {op_name(op)} declares {nxt - body} bytes, fewer than its fields",
                f"at least {FIXED_SIZE[op]} bytes",
                False,
            )
        elif self.data_end_seen and op in (Opcode.SCHEMA, Opcode.CHANNEL):  # the data section's, repeated
            problem = summary_definition(buf, pos, body, nxt, op, dec)
            if problem:
                layout.notes.append(problem)
        elif op == Opcode.CHUNK_INDEX and self.data_end_seen:
            layout.chunk_index(buf, pos, body, nxt)
        elif op == Opcode.SUMMARY_OFFSET and self.data_end_seen:
            layout.summary_offset(buf, pos, body, nxt)
        elif op in (Opcode.SCHEMA, Opcode.CHANNEL, Opcode.MESSAGE, Opcode.METADATA, Opcode.ATTACHMENT):
            try:
                if op == Opcode.METADATA:
                    dec.metadata(buf, body, nxt)
                elif op == Opcode.ATTACHMENT:  # copied by annotate: its fields must hold, its CRC match
                    check_attachment(buf, body, nxt)
                    copy_attachment = getattr(dec, "attachment", None)  # a sink that copies the log
                    if copy_attachment is not None:
                        copy_attachment(buf, body, nxt)
                else:
                    self.stats.messages += dec.records(buf, pos, nxt, False)
            except (ValueError, struct.error) as exc:
                name = op_name(op)
                kind = CrcMismatch if isinstance(exc, CrcError) else CorruptRecord
                raise LogDamage(
                    pos, f"corrupt {name} record: {exc}", f"a valid {name} record", True, kind
                ) from exc
        elif op == Opcode.DATA_END:
            self.data_end_seen = True
            layout.summary_start = nxt
            (crc,) = struct.unpack_from("<I", buf, body)
            damage = _crc_damage(crc, buf, 0, pos, pos, "data") if self.crcs else None
            if damage is not None:
                self.skip_to = nxt
                raise damage
        elif op == Opcode.STATISTICS:
            (self.total_expected,) = struct.unpack_from("<Q", buf, body)
            self.statistics_at = pos
            if nxt - body >= 26:
                (layout.statistics_chunks,) = struct.unpack_from("<I", buf, body + 22)
        elif op == Opcode.FOOTER:
            self.footer_seen = True
            summary_start, offset_start, summary_crc = struct.unpack_from("<QQI", buf, body)
            damage = (
                _crc_damage(summary_crc, buf, summary_start, body + 16, pos, "summary")
                if summary_start
                else None
            )
            if damage is not None:
                self.total_expected = None
                raise damage
            if self.data_end_seen:
                self.stats.index += layout.problems(pos, summary_start, offset_start)
            if bytes(buf[nxt : nxt + 8]) != MAGIC:
                raise LogDamage(
                    nxt,
                    "the file does not end with the MCAP magic",
                    "the closing magic",
                    False,
                    TruncatedFile,
                )
            return True
        return False

    def chunk(self, pos: int, body: int, nxt: int) -> None:
        """A Chunk record: its records decompressed, CRC-checked and handed to the sink, its
        MessageIndex records checked against them."""
        buf, stats = self.buf, self.stats
        stats.chunks += 1
        if body + 16 <= nxt:
            self.layout.chunks[pos] = (nxt - body, *struct.unpack_from("<QQ", buf, body))
        try:
            data = chunk_payload(buf, body, nxt, self.crcs)
            hint = index_offsets(buf, nxt, self.size)
            in_chunk = self.dec.records(memoryview(data), 0, len(data), True, hint)
            stats.messages += in_chunk
            problem = message_index_problem(buf, pos, nxt, self.size, data, in_chunk, self.layout)
            if problem:
                stats.index.append(problem)
        except LogDamage as dmg:  # an intact chunk whose records lack something: it is lost
            self.skip_to = nxt  # its CRC held, so its length did: the walk goes on after it
            raise LogDamage(pos, f"corrupt chunk: {dmg.message}", dmg.expected, True) from dmg
        except (ValueError, struct.error, zlib.error) as exc:
            kind = CrcMismatch if isinstance(exc, CrcError) else CorruptRecord
            raise LogDamage(
                pos, f"corrupt chunk: {exc}", "an intact zstd/lz4 chunk with a matching CRC", True, kind
            ) from exc
        except Exception as exc:
            if type(exc).__module__.startswith(("zstandard", "lz4")):
                raise LogDamage(pos, f"corrupt chunk: {exc}", "an intact zstd/lz4 chunk", True) from exc
            raise

    def recover(self, dmg: LogDamage) -> int | None:
        """Record the damage (salvage) and say where the walk goes on (None: it stops)."""
        buf, stats, pos, size = self.buf, self.stats, self.pos, self.size
        stats.damage.append(f"offset {dmg.offset}: {dmg.message}")
        if not dmg.resync:
            return self.skip_to
        if "corrupt chunk" in dmg.message:
            stats.chunks_lost += 1
            (length,) = struct.unpack_from("<Q", buf, pos + 1)
            lost = index_count(buf, pos + 9 + length, size)
            if stats.messages_lost is not None:
                stats.messages_lost = stats.messages_lost + lost if lost else None
            if self.skip_to is not None:
                return self.skip_to
        elif not self.data_end_seen:
            if pos + 9 <= size and buf[pos] == Opcode.CHUNK:
                stats.chunks += 1
                stats.chunks_lost += 1
            stats.messages_lost = None
        return _resync(buf, pos + 1, size)

    def finish(self, path: Path, salvage: bool) -> None:
        """The checks of the whole file: a footer, and as many messages as its Statistics count."""
        stats, size, total = self.stats, self.size, self.total_expected
        if not self.footer_seen:
            if not salvage:
                raise TruncatedFile(
                    path,
                    f"the file is truncated: it ends at {size} bytes without a footer",
                    offset=size,
                    expected=_COMPLETE,
                )
            if not self.data_end_seen:
                stats.messages_lost = None
            if not any("truncated" in d for d in stats.damage):
                stats.damage.append(f"offset {size}: the file ends without a footer (truncated)")
        if total is not None and self.footer_seen and total != stats.messages:  # stale summary
            what = (
                f"the summary's Statistics record counts {total:,} messages, but the data section "
                f"holds {stats.messages:,} (a chunk missing, repeated or added since the summary was written)"
            )
            if not salvage:
                raise IndexMismatch(
                    path,
                    what,
                    offset=self.statistics_at,
                    expected="a summary that matches the data section (--salvage reads the chunks there are)",
                )
            if not stats.damage:
                stats.damage.append(f"offset {self.statistics_at}: {what}")
        if salvage and total is not None and self.footer_seen:
            stats.messages_lost = max(total - stats.messages, 0)


def walk(buf: Any, path: Path, dec: RecordSink, salvage: bool, crcs: bool = True) -> None:
    """Walk the top-level records of buf (the whole file), decoding into dec.

    Damage raises an McapError, or with ``salvage`` is recorded in ``dec.stats`` and skipped: a
    damaged chunk by resynchronising on the next intact chunk, a damaged index/summary by going on.
    ``crcs`` False leaves the CRCs of the data section and the chunks to a later pass over the same
    bytes that checks them (annotate's copy), a third of a large log's first pass.
    """
    _check_start(buf, path)
    state = _Walk(buf, dec, crcs)
    start: int | None = 8
    while start is not None:
        try:
            state.run(start)
            start = None
        except LogDamage as dmg:
            if not salvage:
                raise dmg.error(path) from dmg
            start = state.recover(dmg)
    state.finish(path, salvage)


def check_file(path: str | Path) -> list[tuple[int | None, str]]:
    """Walk the MCAP file at ``path`` with every check, decoding nothing (for a log read or copied
    by another library): an McapError for the first damage; returns where its index disagrees with
    its data section, as (offset, or None for the summary as a whole, what)."""
    path = Path(path)
    sink = CountingSink()
    with open(path, "rb") as f:
        if os.fstat(f.fileno()).st_size == 0:
            raise NotMcap(path, "the file is empty", offset=0, expected="an MCAP file")
        with mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) as mm:
            walk(mm, path, sink, False)
    found = [(re.match(r"offset (\d+): (.*)", note), note) for note in sink.stats.index]
    return [(int(m.group(1)), m.group(2)) if m else (None, note) for m, note in found]
