"""Fill in the CRCs an MCAP writer left at 0 (:func:`fill_crcs`), and check them (:func:`verify_crcs`).

rosbags' MCAP storage plugin writes every CRC as 0 ("not computed"): a flipped byte in a ROS 2 bag
lanecast writes with ``--to ros2 --storage mcap`` would then pass unnoticed. After writing (before
the atomic rename) :func:`fill_crcs` computes them in place: each chunk's CRC of its uncompressed
records, the data section's CRC (DataEnd) and the summary's CRC (Footer). Lengths do not change,
so every offset in the summary and the indexes stays valid.
"""

from __future__ import annotations

import mmap
import struct
import zlib
from pathlib import Path

from lanecast.io_adapters.errors import LogError
from lanecast.io_adapters.logs.mcap_reader import (
    _REC_HEAD,
    MAGIC,
    OP_CHUNK,
    OP_DATA_END,
    OP_FOOTER,
    _chunk_payload,
    _crc32,
)

_FOOTER_SIZE = 9 + 20  # opcode, length, summary_start u64, summary_offset_start u64, summary_crc u32


def fill_crcs(path: str | Path) -> None:
    """Compute and store every CRC of the MCAP at ``path`` that is 0 (chunks, data end, summary)."""
    _walk_crcs(Path(path), fill=True)


def verify_crcs(path: str | Path) -> None:
    """Check every non-zero CRC of the MCAP at ``path``; LogError naming the offset of a mismatch.

    For MCAP files read through another library (rosbags' ROS 2 MCAP storage), which does not.
    """
    _walk_crcs(Path(path), fill=False)


def _walk_crcs(path: Path, fill: bool) -> None:
    try:
        with open(path, "r+b" if fill else "rb") as f:
            access = mmap.ACCESS_WRITE if fill else mmap.ACCESS_READ
            with mmap.mmap(f.fileno(), 0, access=access) as mm:
                _crcs(path, mm, fill)
    except (ValueError, struct.error) as exc:
        raise LogError(path, f"damaged MCAP: {exc}", expected="an intact MCAP file") from exc


def _crcs(path: Path, mm: mmap.mmap, fill: bool) -> None:
    size = len(mm)
    if size < 8 + _FOOTER_SIZE + 8 or mm[:8] != MAGIC or mm[size - 8 :] != MAGIC:
        raise LogError(path, "not a complete MCAP file", expected="magic, records, footer, magic")
    pos = 8
    while pos + 9 <= size:
        op, length = _REC_HEAD.unpack_from(mm, pos)
        body, nxt = pos + 9, pos + 9 + length
        if nxt > size:
            raise LogError(path, "a record runs past the end", offset=pos, expected="a complete MCAP file")
        if op == OP_CHUNK:
            (crc,) = struct.unpack_from("<I", mm, body + 24)
            if crc == 0 and fill:
                struct.pack_into("<I", mm, body + 24, zlib.crc32(_chunk_payload(mm, body, nxt)))
            elif not fill:
                try:
                    _chunk_payload(mm, body, nxt)  # checks a non-zero CRC
                except ValueError as exc:
                    raise LogError(
                        path, f"corrupt chunk: {exc}", offset=pos, expected="an intact chunk"
                    ) from exc
        elif op == OP_DATA_END:
            (crc,) = struct.unpack_from("<I", mm, body)
            _check_or_fill(path, mm, body, crc, _crc32(mm, 0, pos), fill, pos, "data section")
            break
        pos = nxt
    footer = size - 8 - _FOOTER_SIZE
    if mm[footer] != OP_FOOTER:
        raise LogError(path, "no footer before the closing magic", offset=footer, expected="a Footer record")
    summary_start, _, crc = struct.unpack_from("<QQI", mm, footer + 9)
    if summary_start and summary_start < footer:
        actual = _crc32(mm, summary_start, footer + 9 + 16)
        _check_or_fill(path, mm, footer + 9 + 16, crc, actual, fill, footer, "summary")
    if fill:
        mm.flush()


def _check_or_fill(
    path: Path, mm: mmap.mmap, at: int, stored: int, actual: int, fill: bool, offset: int, what: str
) -> None:
    """Store ``actual`` at ``at`` where ``stored`` is 0 (fill), or refuse a non-zero mismatch (check)."""
    if fill and stored == 0:
        struct.pack_into("<I", mm, at, actual)
    elif not fill and stored and stored != actual:
        raise LogError(
            path,
            f"{what} CRC mismatch (stored {stored:#010x}, computed {actual:#010x})",
            offset=offset,
            expected="an undamaged MCAP file",
        )
