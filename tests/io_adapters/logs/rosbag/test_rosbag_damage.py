"""ROS 1 and ROS 2 bags on damaged input: truncated bags, index records that disagree with the
chunks, sqlite3 rows and type definitions, QoS metadata, CRCs and payload digests, orientations
that are no unit quaternion; each refused naming the file, record or row."""

from __future__ import annotations

import struct
from pathlib import Path

import pyarrow as pa
import pytest
from conftest import (
    US101,
    _ros1_damage,
    _ros1_records,
    _small_chunks_ros1_bag,
)

from lanecast.io_adapters.errors import LogError
from lanecast.io_adapters.formats import registry
from lanecast.io_adapters.logs.rosbag import reader as rosbag_reader
from lanecast.io_adapters.logs.rosbag import writer as rosbag_writer


def test_ros2_mcap_bags_are_written_with_crcs_and_checked(tmp_path: Path) -> None:
    from mcap.reader import make_reader

    from lanecast.io_adapters.logs.rosbag import reader as rosbag_reader

    table = registry.read_any([US101])
    bag = rosbag_writer.write(table, tmp_path / "bag", "ros2", storage="mcap")
    (storage,) = bag.glob("*.mcap")
    data = storage.read_bytes()
    with storage.open("rb") as f:  # the mcap library checks every CRC
        assert sum(1 for _ in make_reader(f, validate_crcs=True).iter_messages()) > 0
    chunk = data.index(b"\x06", 8)  # the first chunk record
    (crc,) = struct.unpack_from("<I", data, chunk + 9 + 24)
    assert crc != 0
    back = rosbag_reader.read(bag)
    assert back.num_rows == table.num_rows
    bad = bytearray(data)
    bad[chunk + 9 + 60] ^= 0x01  # inside the chunk's records
    storage.write_bytes(bytes(bad))
    with pytest.raises(LogError, match=r"CRC mismatch|corrupt chunk") as err:
        rosbag_reader.read(bag)
    assert err.value.path == str(storage)


@pytest.mark.parametrize(("fmt", "storage", "name"), [("ros1", "sqlite3", "b.bag"), ("ros2", "sqlite3", "b")])
def test_own_bags_without_checksums_carry_a_payload_digest(
    tmp_path: Path, fmt: str, storage: str, name: str
) -> None:
    """ROS 1 and sqlite3 bags have no checksum: lanecast's metadata holds one of every message."""
    from lanecast.io_adapters.logs.rosbag import reader as rosbag_reader

    table = registry.read_any([US101])
    bag = rosbag_writer.write(table, tmp_path / name, fmt, storage=storage)
    assert rosbag_reader.read(bag).num_rows == table.num_rows
    storage_file = bag if bag.is_file() else next(bag.glob("*.db3"))
    data = storage_file.read_bytes()
    # a float of a tracked object (x of the first row, little-endian double) with its last bit flipped
    x0 = struct.pack("<d", table.column("x")[0].as_py())
    at = data.index(x0)
    bad = bytearray(data)
    bad[at] ^= 0x01
    storage_file.write_bytes(bytes(bad))
    with pytest.raises(LogError, match="do not match the checksum") as err:
        rosbag_reader.read(bag)
    assert err.value.path == str(storage_file)  # the .db3 of a ROS 2 bag, not its directory


@pytest.mark.parametrize(
    ("fmt", "storage", "name"), [("ros1", "", "d.bag"), ("ros2", "sqlite3", "b"), ("ros2", "mcap", "b")]
)
@pytest.mark.parametrize("fraction", [0.05, 0.3, 0.6, 0.95, 0.9999])
def test_truncated_bag_names_file_and_offset(
    tmp_path: Path, table: pa.Table, fmt: str, storage: str, name: str, fraction: float
) -> None:
    """A bag cut short was 'cannot read the bag: Bag index looks damaged' (ROS 1), 'database disk
    image is malformed' (sqlite3) or 'not a complete MCAP file' (ROS 2 MCAP storage): no offset."""

    bag = rosbag_writer.write(table, tmp_path / name, fmt, **({"storage": storage} if storage else {}))
    data_file = bag if bag.is_file() else next(p for p in bag.iterdir() if p.suffix in (".db3", ".mcap"))
    data = data_file.read_bytes()
    cut = int(len(data) * fraction)
    data_file.write_bytes(data[:cut])
    with pytest.raises(LogError, match="truncated") as err:
        rosbag_reader.read(bag)
    assert err.value.path == str(data_file)
    assert err.value.offset is not None and 0 <= err.value.offset <= cut
    assert "\n" not in str(err.value)


@pytest.mark.parametrize(("column", "value"), [("data", "x''"), ("data", "'text'"), ("timestamp", "'abc'")])
def test_bad_sqlite3_message_names_where_reading_stopped(
    tmp_path: Path, table: pa.Table, column: str, value: str
) -> None:
    """An empty or text payload or a text timestamp in a sqlite3 bag: 'cannot read the bag:
    AnyReaderError: Invalid or unsupported CDR encapsulation', no message, topic or time."""
    import sqlite3

    bag = rosbag_writer.write(table, tmp_path / "b", "ros2", storage="sqlite3")
    with sqlite3.connect(bag / "b.db3") as con:
        con.execute(f"UPDATE messages SET {column}={value} WHERE id=(SELECT MIN(id) FROM messages)")
    with pytest.raises(LogError, match=r"cannot read the bag at message \d+ \(topic '/") as err:
        rosbag_reader.read(bag)
    assert err.value.path == str(bag)


def _damage_first_message(bag: Path, topic: str, at: int, new: bytes) -> int:
    """Overwrite bytes ``at`` of the first message on ``topic`` in place in the bag's sqlite3 file
    (a damaged page that sqlite's own check cannot see); its file offset."""
    import sqlite3

    db = bag / f"{bag.name}.db3"
    with sqlite3.connect(db) as con:
        (raw,) = con.execute(
            "SELECT data FROM messages JOIN topics ON topics.id = topic_id WHERE name = ? ORDER BY timestamp",
            (topic,),
        ).fetchone()
    data = bytearray(db.read_bytes())
    offset = data.find(raw[:256])
    assert offset > 0 and data.find(raw[:256], offset + 1) < 0
    data[offset + at : offset + at + len(new)] = new
    db.write_bytes(bytes(data))
    return offset


def test_undecodable_message_in_a_sqlite3_page_names_its_offset_and_page(
    tmp_path: Path, table: pa.Table
) -> None:
    """A message whose bytes on its page were damaged (sqlite's quick_check sees only the b-trees)
    was 'cannot read the bag at message 2 … or the next: … Invalid string length' naming the bag
    directory and no offset; now the .db3, the message's byte offset and its page."""

    bag = rosbag_writer.write(table, tmp_path / "b", "ros2", storage="sqlite3")
    offset = _damage_first_message(bag, "/tracked_objects", 12, b"\xf0\xff\xff\x7f")  # frame_id's length
    with pytest.raises(
        LogError, match=r"cannot read the bag at message \d+ \(topic '/tracked_objects'"
    ) as err:
        rosbag_reader.read(bag)
    assert err.value.path == str(bag / "b.db3")
    assert err.value.offset == offset
    assert f"on page {offset // 4096 + 1}:" in str(err.value) and "or the next" not in str(err.value)
    assert err.value.expected == "a valid autoware_perception_msgs/msg/TrackedObjects message"


def test_changed_message_bytes_that_still_decode_name_the_sqlite3_file(
    tmp_path: Path, table: pa.Table
) -> None:
    """A changed byte of a message that still decodes was caught by lanecast's payload checksum only,
    naming the bag directory; now the .db3 whose bytes changed, and that sqlite3 finds it intact."""

    bag = rosbag_writer.write(table, tmp_path / "b", "ros2", storage="sqlite3")
    _damage_first_message(bag, "/tracked_objects", 4, b"\x01")  # the header's stamp (seconds)
    with pytest.raises(LogError, match="do not match the checksum lanecast wrote") as err:
        rosbag_reader.read(bag)
    assert err.value.path == str(bag / "b.db3")
    assert "sqlite3's own check finds the database intact" in str(err.value)


@pytest.mark.parametrize(
    "kind",
    [
        "chunk info listing a listed chunk",
        "index data past its chunk",
        "connection without message definition",
        "index_pos not at a record",
        "chunk compressed with an unknown method",
        "message on an undefined connection",
        "connection definition that does not parse",
        "connection md5sum not its definition's",
        "a chunk info record deleted",
        "a record of another kind in the index",
        "index data listing no message record",
        "chunk info stating more connections than it holds",
        "index data stating fewer messages than it lists",
        "bag header stating no chunks",
    ],
)
def test_ros1_index_damage_names_its_record(tmp_path: Path, table: pa.Table, kind: str) -> None:
    """A ROS 1 bag whose index lies (a chunk info pointing at a chunk another one lists, index data
    past its chunk, a connection without its definition, index_pos inside a chunk) was 'cannot read
    the bag: … Bag index looks damaged' or 'hash mismatch' or, for the chunk listed twice, a
    checksum mismatch (lanecast's bags) or one chunk read twice and another never (others); a chunk
    compressed with 'zzzz' or a message on a connection never defined was 'Compression 'zzzz' is
    not supported' or 'KeyError: 77': no offset; a connection whose definition does not parse or
    whose md5sum is another's was 'Could not parse: <the whole definition>' or 'hash mismatch' (fuzz
    seeds 1014, 1050); a chunk info stating 4294967295 connections was 'Bag index looks damaged:
    Could not read uint32' (fuzz2 seed 5021); index data whose count is 0 was 'AssertionError:'
    and nothing else (fuzz2 seed 5145); a bag header whose chunk_count is 0 was 'no supported topic
    with tracked objects (topics: none)' (rosbags read no chunk; fuzz2 seed 5236). Now the record's
    offset and what it says."""
    bag = _small_chunks_ros1_bag(table, tmp_path / "b.bag")
    data = bytearray(bag.read_bytes())
    assert sum(1 for r in _ros1_records(bytes(data)) if r[1]["op"] == b"\x05") >= 3
    offset, text = _ros1_damage(kind, data)
    bag.write_bytes(bytes(data))
    with pytest.raises(LogError) as err:
        rosbag_reader.read(bag)
    assert err.value.path == str(bag) and err.value.offset == offset
    assert text in str(err.value)


@pytest.mark.parametrize(
    ("sql", "text"),
    [
        (
            "UPDATE message_definitions SET encoded_message_definition = encoded_message_definition || "
            "char(10) || 'float64 extra' WHERE topic_type LIKE '%TrackedObjects'",
            "type_description_hash",
        ),
        ("UPDATE message_definitions SET encoded_message_definition = ''", "the definition is empty"),
        ("UPDATE message_definitions SET encoding = 'flatbuffer'", "encoding 'flatbuffer'"),
    ],
)
def test_a_sqlite3_type_definition_rosbags_refuses_names_its_table_and_row(
    tmp_path: Path, table: pa.Table, sql: str, text: str
) -> None:
    """A message_definitions row that is not the type its topic's hash states (or is empty, or of an
    unknown encoding) was 'cannot read the bag: AnyReaderError: Message type X hash mismatch A != B'
    or 'KeyError: ...' naming the bag directory only (fuzz seeds 1031, 1085). Now the storage file,
    table and row."""
    import sqlite3

    bag = rosbag_writer.write(table, tmp_path / "b", "ros2", storage="sqlite3")
    with sqlite3.connect(bag / "b.db3") as con:
        con.execute(sql)
    with pytest.raises(LogError) as err:
        rosbag_reader.read(bag)
    assert err.value.path == str(bag / "b.db3"), str(err.value)
    assert "row " in str(err.value) and text in str(err.value)


def test_ros2_mcap_channel_with_garbage_qos_metadata_names_its_record(
    tmp_path: Path, table: pa.Table
) -> None:
    """A channel whose offered_qos_profiles metadata is not a list of QoS profiles was 'cannot read
    the bag: TypeError: string indices must be integers, not 'str'' (fuzz seed 1044): rosbags' own
    crash, no file, record or topic. Now the channel record's offset and topic."""
    from mcap.reader import make_reader
    from mcap.writer import Writer

    bag = rosbag_writer.write(table, tmp_path / "b", "ros2", storage="mcap")
    storage = next(bag.glob("*.mcap"))
    with storage.open("rb") as f:
        reader = make_reader(f)
        header, summary = reader.get_header(), reader.get_summary()
        assert summary is not None
        messages = [(ch.id, m.log_time, m.publish_time, m.data) for _s, ch, m in reader.iter_messages()]
    victim = max(summary.channels)
    with storage.open("wb") as f:
        w = Writer(f)
        w.start(profile=header.profile, library=header.library)
        sids = {i: w.register_schema(s.name, s.encoding, s.data) for i, s in summary.schemas.items()}
        cids = {}
        for i, c in summary.channels.items():
            meta = {**c.metadata, "offered_qos_profiles": "just a string"} if i == victim else c.metadata
            cids[i] = w.register_channel(c.topic, c.message_encoding, sids[c.schema_id], meta)
        for cid, log_time, publish_time, data in messages:
            w.add_message(cids[cid], log_time, data, publish_time)
        w.finish()
    with pytest.raises(LogError, match="offered_qos_profiles metadata is not QoS profiles") as err:
        rosbag_reader.read(bag)
    assert err.value.path == str(storage) and err.value.offset is not None
    assert repr(summary.channels[victim].topic) in str(err.value)


def test_a_sqlite3_message_on_no_topic_is_refused_not_dropped(tmp_path: Path, table: pa.Table) -> None:
    """A messages row whose topic_id is no topic (a damaged or hand-edited bag, without lanecast's
    checksum) was skipped by rosbags, its vehicles' rows silently lost (fuzz seed 1207). Now the
    table, row and column."""
    import sqlite3

    bag = rosbag_writer.write(table, tmp_path / "b", "ros2", storage="sqlite3")
    with sqlite3.connect(bag / "b.db3") as con:  # another tool's bag: no lanecast checksum
        con.execute(
            "DELETE FROM messages WHERE topic_id=(SELECT id FROM topics WHERE name='/lanecast/metadata')"
        )
        con.execute("DELETE FROM topics WHERE name='/lanecast/metadata'")
        (victim,) = con.execute(
            "SELECT MIN(id) FROM messages WHERE topic_id=(SELECT id FROM topics WHERE name LIKE '/tracked%' "
            "AND type LIKE '%TrackedObjects')"
        ).fetchone()
        con.execute(f"UPDATE messages SET topic_id=99 WHERE id={victim}")
    with pytest.raises(LogError, match=f"table messages, row {victim}: topic_id 99 is no topic") as err:
        rosbag_reader.read(bag)
    assert err.value.path == str(bag / "b.db3") and err.value.column == "topic_id"


@pytest.mark.parametrize("z", [1e300, float("nan"), 3.0])
def test_an_orientation_that_is_no_unit_quaternion_is_refused(
    tmp_path: Path, table: pa.Table, z: float
) -> None:
    """A TrackedObjects pose whose orientation is no unit quaternion ((0, 0, 1e300, 1): a damaged
    double) turned the vehicle by 90 degrees and rotated its velocity with it, silently (fuzz seed
    1317, a bag without lanecast's checksum). Now the message, its topic and log time."""
    import dataclasses
    import sqlite3

    from lanecast.io_adapters.logs.messages import ros_types

    bag = rosbag_writer.write(table, tmp_path / "b", "ros2", storage="sqlite3")
    store = ros_types.typestore(2)
    with sqlite3.connect(bag / "b.db3") as con:
        con.execute(
            "DELETE FROM messages WHERE topic_id=(SELECT id FROM topics WHERE name='/lanecast/metadata')"
        )
        con.execute("DELETE FROM topics WHERE name='/lanecast/metadata'")
        rid, msgtype, raw = con.execute(
            "SELECT m.id, t.type, m.data FROM messages m JOIN topics t ON t.id = m.topic_id "
            "WHERE t.type LIKE '%TrackedObjects' ORDER BY m.id LIMIT 1 OFFSET 10"
        ).fetchone()
        msg = store.deserialize_cdr(raw, msgtype)
        pose = msg.objects[0].kinematics.pose_with_covariance.pose
        pose = dataclasses.replace(pose, orientation=dataclasses.replace(pose.orientation, z=z))
        msg.objects[0].kinematics.pose_with_covariance.pose = pose
        con.execute("UPDATE messages SET data=? WHERE id=?", (bytes(store.serialize_cdr(msg, msgtype)), rid))
    with pytest.raises(
        LogError, match=r"cannot read the bag at message \d+ \(topic '/tracked_objects"
    ) as err:
        rosbag_reader.read(bag)
    assert "is not a unit quaternion" in str(err.value)
