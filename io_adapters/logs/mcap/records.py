"""The MCAP wire format: record opcodes and layouts, and the checked decoding of the records
lanecast reads itself (strings, Schema and Channel records, chunk payloads, attachments).

Every reader of :mod:`mcap_walk` and the copies of :mod:`lanecast.io_adapters.annotations` share
these definitions: a length or CRC that does not hold raises ``ValueError`` with what is wrong,
and the walk turns it into a located error. Chunk sizes are bounded before any allocation.
"""

from __future__ import annotations

import struct
import zlib
from dataclasses import dataclass
from typing import Any

import numpy as np

MAGIC = b"\x89MCAP0\r\n"


OP_HEADER, OP_FOOTER, OP_SCHEMA, OP_CHANNEL, OP_MESSAGE, OP_CHUNK = 0x01, 0x02, 0x03, 0x04, 0x05, 0x06


OP_MESSAGE_INDEX, OP_ATTACHMENT, OP_STATISTICS, OP_METADATA, OP_DATA_END = 0x07, 0x09, 0x0B, 0x0C, 0x0F


OP_CHUNK_INDEX, OP_SUMMARY_OFFSET = 0x08, 0x0E


MAX_OP = 0x10


OP_NAMES = {OP_SCHEMA: "Schema", OP_CHANNEL: "Channel", OP_MESSAGE: "Message", OP_METADATA: "Metadata"}


# Records read with fixed-size fields: the least length their fields take.
FIXED_SIZE = {OP_DATA_END: 4, OP_STATISTICS: 8, OP_FOOTER: 20, OP_CHUNK: 28}


MSG_HEAD = struct.Struct("<HIQQ")


REC_HEAD = struct.Struct("<BQ")


LEN = struct.Struct("<Q")


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
