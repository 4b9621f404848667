"""Check the CRCs of an MCAP file read through another library (:func:`verify_crcs`).

rosbags reads ROS 2 bags in MCAP storage without checking any CRC; lanecast's own such bags are
rewritten with every CRC (``annotations.bag_copy.compress_bag_storage``), and this walk checks
each chunk's CRC of its uncompressed records, the data section's (DataEnd) and the summary's
(Footer) before rosbags reads them. A CRC of 0 means "not computed" and is not checked.
"""

from __future__ import annotations

import mmap
import re
import struct
from pathlib import Path

from lanecast.io_adapters.errors import LogError
from lanecast.io_adapters.logs.mcap.records import (
    MAGIC,
    OP_CHUNK,
    OP_DATA_END,
    OP_FOOTER,
    REC_HEAD,
    chunk_payload,
    crc32_of,
)
from lanecast.io_adapters.logs.mcap.walk import (
    CountingSink,
    walk,
)

_FOOTER_SIZE = 9 + 20  # opcode, length, summary_start u64, summary_offset_start u64, summary_crc u32


def verify_crcs(path: str | Path) -> None:
    """Check every non-zero CRC of the MCAP at ``path``; LogError naming the offset of a mismatch.

    For MCAP files read through another library (rosbags' ROS 2 MCAP storage), which does not.
    """
    path = Path(path)
    try:
        with open(path, "rb") as f, mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) as mm:
            _crcs(path, mm)
    except (ValueError, struct.error) as exc:
        raise LogError(path, f"damaged MCAP: {exc}", expected="an intact MCAP file") from exc


def _crcs(path: Path, mm: mmap.mmap) -> None:
    size = len(mm)
    if size < 8 or mm[:8] != MAGIC:
        raise LogError(path, "no MCAP magic at the start", offset=0, expected="magic, records, footer, magic")
    # A file cut short (a copy or a recorder killed) is walked up to where it ends: the error names
    # the record it cuts, or the end of the file where the summary and footer should be.
    complete = size >= 8 + _FOOTER_SIZE + 8 and mm[size - 8 :] == MAGIC
    pos = 8
    while pos + 9 <= size:
        op, length = REC_HEAD.unpack_from(mm, pos)
        body, nxt = pos + 9, pos + 9 + length
        if nxt > size:
            raise LogError(
                path,
                f"the file is truncated: a record (opcode {op:#04x}) declares {length} bytes but the file "
                f"ends {size - body} bytes later",
                offset=pos,
                expected="a complete MCAP file",
            )
        if op == OP_CHUNK:
            try:
                chunk_payload(mm, body, nxt)  # checks a non-zero CRC
            except ValueError as exc:
                raise LogError(path, f"corrupt chunk: {exc}", offset=pos, expected="an intact chunk") from exc
        elif op == OP_DATA_END:
            (crc,) = struct.unpack_from("<I", mm, body)
            _check(path, crc, crc32_of(mm, 0, pos), pos, "data section")
            break
        pos = nxt
    if not complete:
        raise LogError(
            path,
            f"the file is truncated: it ends at {size} bytes without a footer and the closing magic",
            offset=size,
            expected="a complete MCAP file",
        )
    footer = size - 8 - _FOOTER_SIZE
    if mm[footer] != OP_FOOTER:
        raise LogError(path, "no footer before the closing magic", offset=footer, expected="a Footer record")
    summary_start, _, crc = struct.unpack_from("<QQI", mm, footer + 9)
    if summary_start and summary_start < footer:
        actual = crc32_of(mm, summary_start, footer + 9 + 16)
        _check(path, crc, actual, footer, "summary")


def _check(path: Path, stored: int, actual: int, offset: int, what: str) -> None:
    """Refuse a non-zero stored CRC that differs from the computed one."""
    if stored and stored != actual:
        raise LogError(
            path,
            f"{what} CRC mismatch (stored {stored:#010x}, computed {actual:#010x})",
            offset=offset,
            expected="an undamaged MCAP file",
        )


def verify_index(path: str | Path) -> None:
    """LogError naming the first index record of the MCAP at ``path`` that disagrees with its data
    section (chunk indexes, message indexes, summary offsets): rosbags reads a ROS 2 bag's MCAP
    through its chunk indexes, so it would skip or repeat chunks where they lie, without a word."""
    path = Path(path)
    sink = CountingSink()
    with open(path, "rb") as f, mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) as mm:
        walk(mm, path, sink, False)
    if sink.stats.index:
        note = sink.stats.index[0]
        at = re.match(r"offset (\d+): (.*)", note)
        raise LogError(
            path,
            f"the file's index disagrees with its data section: {at.group(2) if at else note}; rosbags reads "
            "the bag through the index and would read other messages than the file holds",
            offset=int(at.group(1)) if at else None,
            expected="indexes that match the data section (mcap recover writes them anew)",
        )
