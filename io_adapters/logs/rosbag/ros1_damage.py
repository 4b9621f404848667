"""Where a ROS 1 bag (``#ROSBAG V2.0``) that rosbags cannot read is damaged, which rosbags does not say.

rosbags says "Bag index looks damaged" for any ROS 1 bag cut short. After such a failure (never on
the happy path) :func:`ros1_damage` walks the file's records (``header_len, header, data_len,
data``), headers only, and names the first thing that is wrong: a record running past the end of
the file, a header field running past its header, a bag that was never indexed (index_pos 0, its
recorder killed) or whose index lies beyond the end or not at a record, a chunk whose bz2/lz4 data
does not decompress to the size it states, index data listing a message past its chunk, a chunk
info pointing where no chunk starts (or at a chunk another one lists) or stating more connections
than its data holds, an indexed connection without a message definition.
"""

from __future__ import annotations

import bz2
import mmap
import struct
from pathlib import Path

from lanecast.io_adapters.logs.rosbag.damage import short_error

ROS1_MAGIC = b"#ROSBAG V2.0\n"
_U32 = struct.Struct("<I")
_OP_MESSAGE_DATA = 0x02
_OP_BAG_HEADER = 0x03
_OP_INDEX_DATA = 0x04
_OP_CHUNK = 0x05
_OP_CHUNK_INFO = 0x06
_OP_CONNECTION = 0x07
_INDEX_DATA_HEADER = 47  # op (1 byte), ver, conn, count (4 bytes each), each with its length and name


def ros1_damage(path: Path) -> tuple[int, str] | None:
    """(offset, what is wrong) of the first fault of the ROS 1 bag at ``path``, or None."""
    with open(path, "rb") as f:
        size = f.seek(0, 2)
        if size <= len(ROS1_MAGIC):
            return size, f"the file is truncated: {size} bytes, no record after the magic"
        with mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) as mm:
            return _ros1_walk(mm, size)


def _ros1_walk(mm: mmap.mmap, size: int) -> tuple[int, str] | None:
    pos = len(ROS1_MAGIC)
    index_pos: int | None = None
    header_at = 0
    starts: set[int] = set()  # where records start
    chunks: dict[int, int | None] = {}  # chunk offset → uncompressed size it states
    chunk_size: int | None = None  # of the chunk the IndexData records that follow it index
    listed: set[int] = set()  # chunks a ChunkInfo record points at
    conns: dict[int, tuple[bytes, bytes]] = {}  # connections defined so far: (topic, type and md5sum)
    message_starts: dict[int, int] = {}  # where message records start in the last chunk's records: conn
    unindexed: set[int] = set()  # the last chunk's messages no index data record has listed yet
    chunk_at = 0  # the offset of the last chunk
    stated: tuple[int | None, int | None] = (None, None)  # the bag header's conn_count, chunk_count
    indexed_conns = 0  # connection records in the index (at or after index_pos)
    while pos < size:
        if pos + 4 > size:
            return pos, f"the file is truncated inside a record header ({size - pos} bytes left)"
        (header_len,) = _U32.unpack_from(mm, pos)
        header_end = pos + 4 + header_len
        if header_end + 4 > size:
            return (
                pos,
                f"the file is truncated: a record header declares {header_len} bytes, the file ends first",
            )
        fields = _fields(mm, pos + 4, header_end)
        if fields is None:
            return pos, "a record header whose fields run past the header"
        (data_len,) = _U32.unpack_from(mm, header_end)
        data, end = header_end + 4, header_end + 4 + data_len
        op = fields.get("op", b"\xff")[:1]
        opcode = op[0] if op else 0xFF
        if end > size:
            return pos, (
                f"the file is truncated: a record (op {opcode:#04x}) declares {data_len} bytes of data "
                f"but the file ends {size - data} bytes later"
            )
        starts.add(pos)
        in_index = index_pos is not None and pos >= index_pos and index_pos in starts  # (else: named below)
        if in_index and opcode not in (_OP_CONNECTION, _OP_CHUNK_INFO):
            return pos, (
                f"a record of op {opcode:#04x} in the index (from offset {index_pos}), which holds only "
                "connection (0x07) and chunk info (0x06) records"
            )
        if opcode == _OP_BAG_HEADER and len(fields.get("index_pos", b"")) == 8:
            (index_pos,) = struct.unpack("<Q", fields["index_pos"])
            header_at = pos
            stated = (_u32(fields.get("conn_count")), _u32(fields.get("chunk_count")))
            if index_pos == 0:
                return pos, "the bag was never indexed (index_pos 0: its recorder did not close it)"
            if index_pos > size:
                return (
                    pos,
                    f"the file is truncated: the bag header puts the index at offset {index_pos}, the file "
                    f"ends at {size}",
                )
        elif opcode == _OP_CHUNK:
            if unindexed:
                return chunk_at, _unindexed(unindexed)
            message_starts = {}
            problem = _chunk_problem(fields, mm[data:end], conns, message_starts)
            if problem is not None:
                return pos, problem
            unindexed, chunk_at = set(message_starts), pos
            chunk_size = _u32(fields.get("size"))
            chunks[pos] = chunk_size
        elif opcode == _OP_INDEX_DATA:
            problem = _index_data_problem(fields, header_len, mm[data:end], chunk_size, message_starts)
            if problem is not None:
                return pos, problem
            count = _u32(fields.get("count")) or 0
            unindexed -= {_U32.unpack_from(mm, data + 12 * k + 8)[0] for k in range(count)}
        elif opcode == _OP_CHUNK_INFO:
            at = (
                struct.unpack("<Q", fields["chunk_pos"])[0]
                if len(fields.get("chunk_pos", b"")) == 8
                else None
            )
            if at not in chunks:
                return pos, f"a chunk info record points at offset {at}, where no chunk starts"
            if _u32(fields.get("ver")) != 1:
                return pos, f"a chunk info record of version {_u32(fields.get('ver'))} (1 is the only one)"
            listed_conns = _u32(fields.get("count"))
            if listed_conns is None or data_len < 8 * listed_conns:
                return pos, (
                    f"a chunk info record states {listed_conns} connections in {data_len} bytes of data "
                    "(8 bytes each)"
                )
            if at in listed:
                return pos, f"a chunk info record points at the chunk at offset {at}, which another one lists"
            listed.add(at)
        elif opcode == _OP_CONNECTION:
            conn = _u32(fields.get("conn")) or 0
            this = (fields.get("topic", b""), _conn_type(bytes(mm[data:end])))
            if pos >= (index_pos or size):  # the index's copy, which rosbags reads
                indexed_conns += 1
                problem = _connection_problem(fields, mm[data:end])
                if problem is not None:
                    return pos, problem
                if conn in conns and conns[conn] != this:
                    return pos, (
                        f"the index's connection record {conn} (topic {_text(this[0])}) is not the one its "
                        f"chunks hold (topic {_text(conns[conn][0])}): their messages would be read as another's"
                    )
            conns.setdefault(conn, this)
        pos = end
    if unindexed:
        return chunk_at, _unindexed(unindexed)
    if index_pos is not None and index_pos not in starts:
        return header_at, f"the bag header puts the index at offset {index_pos}, where no record starts"
    return _index_count_problem(header_at, stated, indexed_conns, chunks, listed)


def _index_count_problem(
    header_at: int,
    stated: tuple[int | None, int | None],
    indexed_conns: int,
    chunks: dict[int, int | None],
    listed: set[int],
) -> tuple[int, str] | None:
    """The bag header's conn_count and chunk_count against the index (rosbags reads that many
    records and, a record deleted or added, says only 'Header could not be read from file')."""
    conn_count, chunk_count = stated
    if conn_count is not None and conn_count != indexed_conns:
        return header_at, f"the bag header states {conn_count} connections, the index holds {indexed_conns}"
    if chunk_count is not None and chunk_count != len(listed):
        return header_at, f"the bag header states {chunk_count} chunks, the index lists {len(listed)}"
    unlisted = sorted(set(chunks) - listed)
    if unlisted:
        return unlisted[0], f"a chunk no chunk info record lists ({len(unlisted)} such chunk(s))"
    return None


def _unindexed(offsets: set[int]) -> str:
    """A chunk with messages no index data record lists (rosbags reads a chunk's messages from its
    index data records: these it skips without a word)."""
    return (
        f"{len(offsets)} message(s) of the chunk, the first at byte {min(offsets)} of its records, "
        "listed by no index data record after it"
    )


def _conn_type(data: bytes) -> bytes:
    """The message type and md5sum a connection record's data (its connection header) states: what
    two copies of one connection must agree on (other fields, such as callerid, may differ)."""
    fields = _fields(data) or {}
    return fields.get("type", b"") + b" " + fields.get("md5sum", b"")


def _text(raw: bytes) -> str:
    return repr(raw.decode("utf-8", "replace"))


def _u32(raw: bytes | None) -> int | None:
    return struct.unpack("<I", raw)[0] if raw is not None and len(raw) == 4 else None


def _index_data_problem(
    fields: dict[str, bytes],
    header_len: int,
    data: bytes,
    chunk_size: int | None,
    message_starts: dict[int, int],
) -> str | None:
    """An IndexData record (version 1: op, ver, conn, count in a 47-byte header; count × (time,
    offset)) whose header or count does not fit that layout (rosbags asserts both), listing a
    message past its chunk, where none of the chunk's message records starts or where one of another
    connection does (``message_starts``: offset → connection; empty if unknown)."""
    conn, count = _u32(fields.get("conn")), _u32(fields.get("count"))
    if count is None or len(data) != 12 * count:
        return (
            f"an index data record of connection {conn} lists {count} messages in {len(data)} bytes "
            "(12 bytes each)"
        )
    if header_len != _INDEX_DATA_HEADER:
        return (
            f"an index data record header of {header_len} bytes ({_INDEX_DATA_HEADER} expected: op, ver, "
            "conn and count)"
        )
    if chunk_size is None:
        return None
    for k in range(count):
        (offset,) = _U32.unpack_from(data, 12 * k + 8)
        if offset >= chunk_size:
            return (
                f"an index data record of connection {conn} lists a message at offset {offset} of a chunk "
                f"of {chunk_size} bytes"
            )
        if message_starts and offset not in message_starts:
            return (
                f"an index data record of connection {conn} lists a message at offset {offset} of its "
                "chunk, where no message record starts"
            )
        if message_starts and message_starts[offset] != conn:
            return (
                f"an index data record of connection {conn} lists the message at offset {offset} of its "
                f"chunk, which is on connection {message_starts[offset]}"
            )
    return None


def _connection_problem(fields: dict[str, bytes], data: bytes) -> str | None:
    """A connection record without a message definition (rosbags then refuses its type's hash)."""
    conn, topic = _u32(fields.get("conn")), fields.get("topic", b"").decode("latin-1")
    found = _fields(data)
    if found is None:
        return f"connection {conn} (topic {topic!r}): its fields run past the record"
    definition = found.get("message_definition")
    if definition is None:
        return f"connection {conn} (topic {topic!r}) has no message_definition field"
    text = definition.decode("latin-1")
    if not any(line.split("#", 1)[0].strip() for line in text.splitlines()):
        return f"connection {conn} (topic {topic!r}) has an empty message definition"
    return _definition_problem(
        f"connection {conn} (topic {topic!r})",
        text,
        found.get("type", b"").decode("latin-1"),
        found.get("md5sum", b"").decode("latin-1"),
    )


def _definition_problem(who: str, text: str, msgtype: str, md5: str) -> str | None:
    """A message definition rosbags cannot parse, or whose md5sum is not the one it states (rosbags
    says only 'Could not parse: <the whole text>' or 'hash mismatch', naming no record)."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore
    from rosbags.typesys.msg import normalize_msgtype

    try:
        msgtype = normalize_msgtype(msgtype)  # std_msgs/String → std_msgs/msg/String, as rosbags names it
        types = get_types_from_msg(text, msgtype)
    except Exception as exc:  # rosbags' parser raises its own and generic errors
        return f"{who}: its message definition of {msgtype!r} cannot be parsed ({short_error(exc)})"
    if not md5 or md5 == "*":
        return None
    try:
        store = get_typestore(Stores.EMPTY)
        store.register(types)
        have = store.generate_msgdef(msgtype)[1]
    except Exception as exc:  # a type it uses is not defined in the text
        return f"{who}: its message definition of {msgtype!r} is incomplete ({short_error(exc)})"
    if have != md5:
        return f"{who}: md5sum {md5} is not that of its message definition of {msgtype!r} ({have})"
    return None


def _fields(buf: bytes | mmap.mmap, pos: int = 0, end: int | None = None) -> dict[str, bytes] | None:
    """The ``name=value`` fields of a ROS 1 record header (or connection header) buf[pos:end], each
    with its length; None where one runs past ``end``."""
    end = len(buf) if end is None else end
    out: dict[str, bytes] = {}
    while pos < end:
        if pos + 4 > end:
            return None
        (n,) = _U32.unpack_from(buf, pos)
        if pos + 4 + n > end:
            return None
        name, _, value = bytes(buf[pos + 4 : pos + 4 + n]).partition(b"=")
        out[name.decode("latin-1")] = value
        pos += 4 + n
    return out


def _chunk_problem(
    fields: dict[str, bytes],
    data: bytes,
    conns: dict[int, tuple[bytes, bytes]],
    message_starts: dict[int, int],
) -> str | None:
    """What is wrong with a chunk: its compression, its size, or a record inside it (a message on a
    connection no connection record defined before it; ``conns`` grows with those the chunk defines)."""
    compression = fields.get("compression", b"none").decode("latin-1")
    stated = struct.unpack("<I", fields["size"])[0] if len(fields.get("size", b"")) == 4 else None
    try:
        if compression == "bz2":
            raw = bz2.decompress(data)
        elif compression == "lz4":
            import lz4.frame

            raw = lz4.frame.decompress(data)
        elif compression == "none":
            raw = data
        else:
            return f"a chunk compressed with {compression!r}, which ROS 1 bags do not use (none, bz2 or lz4)"
    except (OSError, ValueError, RuntimeError) as exc:
        return f"a corrupt {compression} chunk: {exc}"
    if stated is not None and len(raw) != stated:
        return f"a {compression} chunk of {len(raw)} bytes, its header states {stated}"
    return _chunk_records_problem(raw, conns, message_starts)


def _chunk_records_problem(
    raw: bytes, conns: dict[int, tuple[bytes, bytes]], message_starts: dict[int, int]
) -> str | None:
    """What is wrong with a chunk's records (``message_starts`` collects where its messages start,
    and their connections)."""
    pos = 0
    while pos < len(raw):
        if pos + 4 > len(raw):
            return f"a record header at byte {pos} of the chunk's records runs past them"
        (header_len,) = _U32.unpack_from(raw, pos)
        header = _fields(raw[pos + 4 : pos + 4 + header_len]) if pos + 8 + header_len <= len(raw) else None
        if header is None:
            return f"a record at byte {pos} of the chunk's records runs past them"
        (data_len,) = _U32.unpack_from(raw, pos + 4 + header_len)
        end = pos + 8 + header_len + data_len
        if end > len(raw):
            return f"a record at byte {pos} of the chunk's records declares {data_len} bytes, past them"
        op, conn = header.get("op", b"")[:1], _u32(header.get("conn"))
        if op == bytes([_OP_CONNECTION]) and conn is not None:
            conns.setdefault(conn, (header.get("topic", b""), _conn_type(raw[pos + 8 + header_len : end])))
        elif op == bytes([_OP_MESSAGE_DATA]):
            if conn not in conns:
                return (
                    f"a message at byte {pos} of the chunk's records is on connection {conn}, which no "
                    "connection record defines before it"
                )
            message_starts[pos] = conn
        pos = end
    return None
