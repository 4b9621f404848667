"""What an MCAP's summary and indexes say, checked against the data section the walk reads.

The data section is the truth (:mod:`~lanecast.io_adapters.logs.mcap.walk`): chunk indexes, message indexes, summary offsets,
the footer's offsets and the summary's copies of schemas and channels are collected in a
:class:`Layout` while the walk goes, and :meth:`Layout.problems` says each way they disagree with
the records found. Message indexes also give the offsets of a chunk's messages
(:func:`index_offsets`), used where they are exactly the chunk's chain of records.
"""

from __future__ import annotations

import struct
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from mcap.opcode import Opcode

from lanecast.io_adapters.logs.mcap.records import (
    MSG_HEAD,
    RecordOverrun,
    op_name,
    read_channel,
    read_ints,
    read_schema,
    records,
)


def message_indexes(buf: Any, pos: int, size: int) -> Iterator[tuple[int, int, int, int]]:
    """(offset, channel id, bytes of entries, record end) of each MessageIndex record of the run
    that starts at pos (the records after a chunk); the run ends at any other record or damage."""
    try:
        for op, at, body, nxt in records(buf, pos, size):
            if op != Opcode.MESSAGE_INDEX or body + 6 > size:
                return
            yield at, *struct.unpack_from("<HI", buf, body), nxt
    except RecordOverrun:
        return


def index_offsets(buf: Any, pos: int, size: int) -> np.ndarray | None:
    """Message offsets [n] (int64) listed by the MessageIndex records starting at pos, or None."""
    parts = []
    for at, _cid, n, nxt in message_indexes(buf, pos, size):
        if n % 16 or at + 15 + n > nxt:
            return None
        pairs = np.frombuffer(buf, dtype="<u8", count=n // 8, offset=at + 15)
        parts.append(pairs[1::2].astype(np.int64))
        del pairs  # no view of the mmap may outlive the read
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


def index_count(buf: Any, pos: int, size: int) -> int:
    """Messages listed by the MessageIndex records starting at pos."""
    return sum(n // 16 for _at, _cid, n, _nxt in message_indexes(buf, pos, size))


def message_index_problem(
    buf: Any, chunk_at: int, pos: int, size: int, data: bytes, count: int, layout: Layout
) -> str | None:
    """How the MessageIndex records at pos (after the chunk at chunk_at, whose records are data and
    hold count messages) disagree with the chunk: each entry must point at a Message record of its
    channel and log time, every message listed once; None if they agree (or there are none)."""
    raw = np.frombuffer(data, dtype=np.uint8)
    listed, end = 0, pos
    for at, cid, n, end in message_indexes(buf, pos, size):
        layout.message_indexes.add(at)
        if n % 16 or at + 15 + n > end:
            return f"offset {at}: a MessageIndex record whose entries ({n} bytes) do not fit it"
        pairs = np.frombuffer(buf, dtype="<u8", count=n // 8, offset=at + 15).copy()
        times, offsets = pairs[0::2], pairs[1::2]
        listed += offsets.size
        if (offsets + 9 + MSG_HEAD.size > raw.size).any():
            return f"offset {at}: a MessageIndex entry points past the end of the chunk at {chunk_at}"
        offsets = offsets.astype(np.int64)
        if (
            (raw[offsets] != Opcode.MESSAGE).any()
            or (read_ints(raw, offsets + 9, "<u2") != cid).any()
            or (read_ints(raw, offsets + 9 + 6, "<u8") != times).any()
        ):
            return (
                f"offset {at}: a MessageIndex entry of channel {cid} points at no message of that channel "
                f"and log time in the chunk at {chunk_at}"
            )
    if listed and listed != count:
        return f"offset {end}: the MessageIndex records list {listed} messages, the chunk at {chunk_at} holds {count}"
    return None


@dataclass
class Layout:
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
                    f"offset {at}: a SummaryOffset puts the {op_name(op)} records at offset {start} "
                    f"({length} bytes), where no such group is"
                )
        groups = [o for o, op in self.summary_records.items() if op == Opcode.SUMMARY_OFFSET]
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


def summary_definition(buf: Any, pos: int, body: int, end: int, op: int, dec: Any) -> str | None:
    """What is wrong with a Schema or Channel record of the summary, which must repeat the data
    section's record of its id; None if it does."""
    try:
        ident, record = (read_schema if op == Opcode.SCHEMA else read_channel)(buf, body, end)
    except (ValueError, struct.error) as exc:
        return f"offset {pos}: a summary {op_name(op)} record that cannot be read ({exc})"
    known = getattr(dec, "schemas" if op == Opcode.SCHEMA else "channels", None)
    if known is None:
        return None
    kind = op_name(op).lower()
    if ident in known and known[ident] != record:  # one unknown: a channel without messages
        return f"offset {pos}: the summary's {kind} {ident} ({record}) is not the data section's ({known[ident]})"
    return None
