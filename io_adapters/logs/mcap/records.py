"""The MCAP wire format: opcodes, the one walk over records, and the checked decoding of the
records lanecast reads itself (strings, Schema and Channel records, chunk payloads, attachments).

:func:`records` is the only loop over MCAP record headers in lanecast: the file walk of
:mod:`~lanecast.io_adapters.logs.mcap.walk`, the chunk decoders, the index checks, the salvage copy
and the ROS 2 storage checks all go through it. Opcodes are ``mcap``'s own :class:`Opcode`.
``mcap``'s record parsers read a stream without bounds (a short read is not an error), so the
records lanecast decodes are parsed here against their record's end: a length or CRC that does not
hold raises ``ValueError`` saying what is wrong, and the walk turns it into a located error. Chunk
sizes are bounded before any allocation.
"""

from __future__ import annotations

import contextlib
import struct
import zlib
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

import numpy as np
from mcap.opcode import Opcode

MAGIC = b"\x89MCAP0\r\n"
MAX_OP = 0x10  # opcodes 0x10-0x7F are reserved; 0x80 and above are private records, skipped
# Records read with fixed-size fields: the least length their fields take.
FIXED_SIZE: dict[int, int] = {Opcode.DATA_END: 4, Opcode.STATISTICS: 8, Opcode.FOOTER: 20, Opcode.CHUNK: 28}
MSG_HEAD = struct.Struct("<HIQQ")
REC_HEAD = struct.Struct("<BQ")
LEN = struct.Struct("<Q")


def op_name(op: int) -> str:
    """The record's name as the MCAP specification writes it ("ChunkIndex"), or its opcode."""
    try:
        return Opcode(op).name.title().replace("_", "")
    except ValueError:
        return f"opcode {op:#04x}"


class RecordOverrun(ValueError):
    """A record header (``op`` None) or a record that runs past the end of its region."""

    def __init__(self, pos: int, start: int, end: int, op: int | None = None, length: int = 0) -> None:
        self.pos, self.op, self.length, self.left = pos, op, length, end - pos - 9
        at = pos - start
        super().__init__(
            f"record header at {at} runs past the end"
            if op is None
            else f"record at {at} declares {length} bytes, only {self.left} left"
        )


class CrcError(ValueError):
    """A chunk or attachment whose stored CRC is not that of its bytes."""


def records(buf: Any, start: int, end: int) -> Iterator[tuple[int, int, int, int]]:
    """(opcode, offset, body, end) of each record of buf[start:end], in order: the one MCAP record
    walk. :class:`RecordOverrun` for a record that runs past ``end``."""
    unpack = REC_HEAD.unpack_from
    pos = start
    while pos < end:
        body = pos + 9
        if body > end:
            raise RecordOverrun(pos, start, end)
        op, length = unpack(buf, pos)
        nxt = body + length
        if nxt > end:
            raise RecordOverrun(pos, start, end, op, length)
        yield op, pos, body, nxt
        pos = nxt


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


def read_ints(raw: np.ndarray, at: np.ndarray, dtype: str) -> np.ndarray:
    """Little-endian integers of type ``dtype`` at byte offsets at [n] of raw (uint8 [N]) → [n]."""
    size = np.dtype(dtype).itemsize
    every = np.ndarray((raw.size - size + 1,), dtype=dtype, buffer=raw, strides=(1,))
    return every[at]


#: Largest chunk (uncompressed) read: a chunk's declared size is checked against it before any
#: allocation (MCAP writers make chunks of a few MB).
MAX_CHUNK_BYTES = 1 << 30


def chunk_payload(buf: Any, body: int, end: int, crc_checked: bool = True) -> bytes:
    """The decompressed, CRC-checked records of a Chunk record whose body is buf[body:end]
    (``crc_checked`` False: the CRC is left to a later pass that checks it).

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
    with memoryview(buf) as view, view[pos + 8 : pos + 8 + n] as raw:  # no copy of the compressed bytes
        data = _decompressed(raw, compression, size)
    if len(data) != size:
        said = "more than" if len(data) > size else f"{len(data)} bytes,"
        raise ValueError(f"decompressed to {said} the {size} bytes the chunk says")
    if crc_checked and crc and zlib.crc32(data) != crc:
        raise CrcError(f"CRC mismatch (stored {crc:#010x}, computed {zlib.crc32(data):#010x})")
    return data


def _decompressed(raw: memoryview, compression: str, size: int) -> bytes:
    """A chunk's records, decompressed into one allocation of at most ``size`` + 1 bytes."""
    if compression == "zstd":
        import zstandard

        if zstandard.frame_content_size(raw) == size:  # one frame that says its size: one pass
            with contextlib.suppress(zstandard.ZstdError):  # the stream below names the damage
                return zstandard.ZstdDecompressor().decompress(
                    raw, max_output_size=size, allow_extra_data=False
                )
        pieces = []
        try:
            with zstandard.ZstdDecompressor().stream_reader(raw, read_across_frames=True) as reader:
                wanted = size + 1
                while wanted > 0 and (piece := reader.read(wanted)):
                    pieces.append(piece)
                    wanted -= len(piece)
        except zstandard.ZstdError as exc:  # a damaged frame (flipped or missing bytes)
            raise ValueError(f"damaged zstd frame: {exc}") from exc
        return b"".join(pieces)
    if compression == "lz4":
        import lz4.frame

        try:
            return bytes(lz4.frame.LZ4FrameDecompressor().decompress(raw, max_length=size + 1))
        except RuntimeError as exc:  # lz4 reports a damaged frame as RuntimeError
            raise ValueError(f"damaged LZ4 frame: {exc}") from exc
    if compression == "":
        return bytes(raw)
    raise ValueError(f"unknown compression {compression!r}")


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
        raise CrcError(
            f"CRC mismatch (stored {crc:#010x}, computed {crc32_of(buf, body, pos + 8 + n):#010x})"
        )


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
