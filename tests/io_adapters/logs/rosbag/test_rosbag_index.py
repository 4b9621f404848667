"""ROS 1 and ROS 2 bag index checks: an index that skips messages or disagrees with the chunks or
the data is refused at the index record."""

from __future__ import annotations

import struct
import zlib
from pathlib import Path

import pytest
from conftest import OP_CHUNK_INDEX, staggered_cars
from conftest import mcap_record_spans as records

from lanecast.io_adapters.errors import LogError
from lanecast.io_adapters.logs.rosbag import reader as rosbag_reader
from lanecast.io_adapters.logs.rosbag import writer as rosbag_writer


@pytest.fixture(scope="module")
def ros1_bag(tmp_path_factory: pytest.TempPathFactory) -> bytes:
    """The bytes of a ROS 1 bag lanecast wrote (3 cars, 30 frames)."""
    table = staggered_cars(3, 30, stagger=4, step_m=2.5, speed=25.0, rate=10.0)
    return rosbag_writer.write(table, tmp_path_factory.mktemp("ros1") / "b.bag", "ros1").read_bytes()


def _ros1_records(d: bytes) -> list[tuple[int, dict[bytes, tuple[int, bytes]]]]:
    """(offset, {field: (offset of its value, value)}) of the top-level records of a ROS 1 bag."""
    pos, out = d.index(b"\n") + 1, []
    while pos + 4 <= len(d):
        (hl,) = struct.unpack_from("<I", d, pos)
        fields, p = {}, pos + 4
        while p < pos + 4 + hl:
            (fl,) = struct.unpack_from("<I", d, p)
            key, _, value = d[p + 4 : p + 4 + fl].partition(b"=")
            fields[key] = (p + 4 + len(key) + 1, value)
            p += 4 + fl
        out.append((pos, fields))
        (dl,) = struct.unpack_from("<I", d, pos + 4 + hl)
        pos += 8 + hl + dl
    return out


def test_a_foreign_ros1_bag_whose_index_skips_messages_is_refused_at_the_index_record(
    tmp_path: Path,
) -> None:
    """A ROS 1 bag from another recorder (no lanecast checksum) whose index data record of one
    chunk names a connection the messages are not on: rosbags reads messages through the index
    only, so that chunk's objects vanished and convert exited 0 with the rows missing. The bag's
    structure is now checked before a foreign bag is read: the record's offset and what it lists."""
    from rosbags.rosbag1 import Reader, Writer

    table = staggered_cars(3, 30, stagger=4, step_m=2.5, speed=25.0, rate=10.0)
    own = rosbag_writer.write(table, tmp_path / "own.bag", "ros1")
    foreign = tmp_path / "foreign.bag"
    writer = Writer(foreign)
    writer.chunk_threshold = 2000
    with Reader(own) as r, writer as w:
        conns = {
            c.id: w.add_connection(c.topic, c.msgtype, msgdef=c.msgdef.data, md5sum=c.digest)
            for c in r.connections
            if c.topic != "/lanecast/metadata"
        }
        for c, t, raw in r.messages():
            if c.id in conns:
                w.write(conns[c.id], t, raw)
    clean = rosbag_reader.read(foreign)
    d = bytearray(foreign.read_bytes())
    index_data = [(o, f) for o, f in _ros1_records(bytes(d)) if f[b"op"][1] == b"\x04"]
    at, fields = index_data[len(index_data) // 2]
    d[fields[b"conn"][0] : fields[b"conn"][0] + 4] = struct.pack("<I", 99)
    foreign.write_bytes(bytes(d))
    with pytest.raises(
        LogError, match="an index data record of connection 99 lists the message at offset"
    ) as err:
        rosbag_reader.read(foreign)
    assert err.value.offset == at and err.value.path == str(foreign)
    assert clean.num_rows == table.num_rows


@pytest.mark.parametrize("damage", ["index_topic", "index_conn", "chunk_info_version"])
def test_a_ros1_index_record_that_disagrees_with_the_chunks_is_named(
    tmp_path: Path, damage: str, ros1_bag: bytes
) -> None:
    """The index's copy of a connection record renamed or renumbered (rosbags reads connections
    from the index: the chunk's messages went to another topic), or a chunk info record of version
    2: the error was a checksum mismatch naming no place, or rosbags' 'Bag index looks damaged'.
    Now the record's offset and what disagrees."""
    bag = tmp_path / "b.bag"
    d = bytearray(ros1_bag)
    recs = _ros1_records(bytes(d))
    index_pos = struct.unpack("<Q", recs[0][1][b"index_pos"][1])[0]
    if damage == "chunk_info_version":
        at, fields = next((o, f) for o, f in recs if f[b"op"][1] == b"\x06")
        d[fields[b"ver"][0]] = 2
        says = "a chunk info record of version 2"
    else:
        at, fields = next(
            (o, f)
            for o, f in recs
            if f[b"op"][1] == b"\x07" and o >= index_pos and b"/tracked" in f[b"topic"][1]
        )
        if damage == "index_topic":
            d[fields[b"topic"][0] + len(fields[b"topic"][1]) - 1] ^= 0x01
        else:
            (conn,) = struct.unpack("<I", fields[b"conn"][1])
            struct.pack_into("<I", d, fields[b"conn"][0], conn + 1 if conn + 1 < 3 else conn - 1)
        says = "connection record"
    bag.write_bytes(bytes(d))
    with pytest.raises(LogError) as err:
        rosbag_reader.read(bag)
    assert err.value.offset == at and err.value.path == str(bag) and says in str(err.value)


def test_a_ros2_bag_whose_mcap_index_disagrees_with_its_data_is_refused_at_the_index(tmp_path: Path) -> None:
    """A ROS 2 bag whose MCAP storage file has a chunk index pointing at another chunk (CRCs
    recomputed): rosbags reads the storage through its chunk indexes, so it read one chunk twice
    and another never (a lanecast bag failed its checksum naming no place; a foreign bag lost the
    rows without a word). The storage file's indexes are now checked before rosbags reads it."""
    table = staggered_cars(3, 30, stagger=4, step_m=2.5, speed=25.0, rate=10.0)
    bag = rosbag_writer.write(table, tmp_path / "bag", "ros2", storage="mcap")
    storage = next(bag.glob("*.mcap"))
    d = bytearray(storage.read_bytes())
    at = next(o for o, op, _ in records(bytes(d)) if op == OP_CHUNK_INDEX)
    (length,) = struct.unpack_from("<Q", d, at + 9 + 24)
    struct.pack_into("<Q", d, at + 9 + 24, length + 16)
    footer = records(bytes(d))[-1][0]
    (start,) = struct.unpack_from("<Q", d, footer + 9)
    struct.pack_into("<I", d, footer + 25, zlib.crc32(bytes(d[start : footer + 25])))
    storage.write_bytes(bytes(d))
    with pytest.raises(LogError, match="rosbags reads the bag through the index") as err:
        rosbag_reader.read(bag)
    assert err.value.path == str(storage) and err.value.offset == at
    assert f"{length + 16} bytes, it has {length}" in str(err.value)
    # annotate with precomputed forecasts copies the bag without reading its tracks: the same check
    from lanecast.io_adapters.logs.rosbag import copy as bag_copy

    with pytest.raises(LogError, match="rosbags reads the bag through the index") as err:
        bag_copy.copy_ros2_bag(bag, tmp_path / "copy")
    assert err.value.path == str(storage) and err.value.offset == at
