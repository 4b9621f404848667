"""Damaged and unsupported logs: the documented LogError (file, offset/topic, expected), and --salvage."""

from __future__ import annotations

import shutil
import struct
import zlib
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pytest
from conftest import channel_record, mcap_contents, mcap_record_spans, staggered_cars

from lanecast.io_adapters.contracts import track_table
from lanecast.io_adapters.errors import LogError
from lanecast.io_adapters.logs.mcap import reader as mcap_reader
from lanecast.io_adapters.logs.mcap import writer as mcap_writer
from lanecast.io_adapters.logs.rosbag import reader as rosbag_reader

RATE = 25.0


@pytest.fixture(scope="module")
def table() -> pa.Table:
    """4 cars × 60 frames at 25 Hz (frames 0..74)."""
    return staggered_cars(4, 60, stagger=5, step_m=1.2, speed=30.0, rate=RATE)


@pytest.fixture(scope="module")
def log(tmp_path_factory: pytest.TempPathFactory, table: pa.Table) -> Path:
    """The table as an MCAP with many small chunks."""
    return mcap_writer.write(table, tmp_path_factory.mktemp("log") / "log.mcap", "mcap", chunk_size=3000)


def chunk_layout(path: Path) -> list[tuple[int, int, set[int]]]:
    """(offset, length, log times of its messages) of every chunk, from the mcap library's summary."""
    from mcap.data_stream import ReadDataStream
    from mcap.reader import make_reader
    from mcap.records import Chunk, Message
    from mcap.stream_reader import breakup_chunk

    with path.open("rb") as f:
        summary = make_reader(f).get_summary()
        assert summary is not None
        out = []
        for ci in summary.chunk_indexes:
            f.seek(ci.chunk_start_offset + 9)
            chunk = Chunk.read(ReadDataStream(f))
            times = {r.log_time for r in breakup_chunk(chunk) if isinstance(r, Message)}
            out.append((ci.chunk_start_offset, ci.chunk_length, times))
    return out


def rows_at(table: pa.Table, times: set[int]) -> pa.Table:
    return table.filter(pc.is_in(table.column("time_ns"), pa.array(sorted(times), pa.int64())))


def test_empty_and_foreign_files(tmp_path: Path) -> None:
    empty = tmp_path / "empty.mcap"
    empty.write_bytes(b"")
    with pytest.raises(LogError, match="empty") as err:
        mcap_reader.read(empty)
    assert err.value.path == str(empty) and err.value.offset == 0
    text = tmp_path / "notes.mcap"
    text.write_bytes(b"hello, world, this is not a log")
    with pytest.raises(LogError, match="not an MCAP file") as err:
        mcap_reader.read(text)
    assert err.value.offset == 0 and err.value.expected == "the MCAP magic"
    bag = tmp_path / "empty.bag"
    bag.write_bytes(b"")
    with pytest.raises(LogError, match="empty"):
        rosbag_reader.read(bag)
    broken = tmp_path / "broken"
    broken.mkdir()
    (broken / "metadata.yaml").write_text("rosbag2_bagfile_information: [\n")
    with pytest.raises(LogError, match="not YAML") as err:  # named with its line, not the bag directory
        rosbag_reader.read(broken)
    assert err.value.path == str(broken / "metadata.yaml") and err.value.line == 2


@pytest.mark.parametrize("fraction", [0.001, 0.3, 0.55, 0.9, 0.999])
def test_truncated_log_names_offset(log: Path, tmp_path: Path, fraction: float) -> None:
    data = log.read_bytes()
    cut = max(int(len(data) * fraction), 5)
    path = tmp_path / "cut.mcap"
    path.write_bytes(data[:cut])
    with pytest.raises(LogError, match=r"truncated|does not end with the MCAP magic") as err:
        mcap_reader.read(path)
    assert err.value.path == str(path)
    assert err.value.offset is not None and 0 <= err.value.offset <= cut
    assert err.value.expected is not None


def test_salvage_truncated_log_keeps_complete_chunks(
    log: Path, table: pa.Table, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    chunks = chunk_layout(log)
    data = log.read_bytes()
    offset, length, _ = chunks[5]
    path = tmp_path / "cut.mcap"
    path.write_bytes(data[: offset + length // 2])  # cut in the middle of the sixth chunk
    back, stats = mcap_reader.read_log(path, salvage=True)
    kept = set().union(*(times for _, _, times in chunks[:5]))
    expected = rows_at(table, kept)
    assert back.num_rows == expected.num_rows
    np.testing.assert_array_equal(back.column("time_ns").to_numpy(), expected.column("time_ns").to_numpy())
    np.testing.assert_allclose(back.column("x").to_numpy(), expected.column("x").to_numpy())
    assert (stats.chunks, stats.chunks_lost, stats.messages, stats.messages_lost) == (6, 1, len(kept), None)
    err = capsys.readouterr().err
    assert "salvaged" in err and "truncated" in err and str(path) in err


def test_flipped_byte_in_chunk(
    log: Path, table: pa.Table, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    chunks = chunk_layout(log)
    offset, length, lost_times = chunks[3]
    data = bytearray(log.read_bytes())
    data[offset + length // 2] ^= 0x5A  # inside the compressed records
    path = tmp_path / "flip.mcap"
    path.write_bytes(bytes(data))
    with pytest.raises(LogError, match="corrupt chunk") as err:
        mcap_reader.read(path)
    assert err.value.offset == offset and err.value.path == str(path)
    back, stats = mcap_reader.read_log(path, salvage=True)
    kept = set(table.column("time_ns").to_numpy().tolist()) - lost_times
    expected = rows_at(table, kept)
    np.testing.assert_array_equal(back.column("time_ns").to_numpy(), expected.column("time_ns").to_numpy())
    np.testing.assert_array_equal(back.column("track_id").to_numpy(), expected.column("track_id").to_numpy())
    assert stats.chunks == len(chunks) and stats.chunks_lost == 1
    assert stats.messages_lost == len(lost_times)
    assert track_table.read_meta(back).recordings["r"].extra["salvage"]["chunks_lost"] == 1
    assert "lost 1 chunks" in capsys.readouterr().err


def test_flipped_byte_in_chunk_length_resyncs(log: Path, table: pa.Table, tmp_path: Path) -> None:
    chunks = chunk_layout(log)
    offset, _, lost_times = chunks[2]
    data = bytearray(log.read_bytes())
    data[offset + 6] ^= 0x40  # the record length: the walk loses its place
    path = tmp_path / "flip.mcap"
    path.write_bytes(bytes(data))
    with pytest.raises(LogError, match="corrupt record") as err:
        mcap_reader.read(path)
    assert err.value.offset == offset
    back, stats = mcap_reader.read_log(path, salvage=True)
    kept = set(table.column("time_ns").to_numpy().tolist()) - lost_times
    assert back.num_rows == rows_at(table, kept).num_rows
    assert stats.chunks_lost == 1 and stats.messages_lost == len(lost_times)


def _foreign_log(path: Path, schema_name: str) -> Path:
    """An MCAP with one channel whose schema is unknown to lanecast."""
    from mcap.writer import Writer

    with path.open("wb") as f:
        w = Writer(f)
        w.start()
        sid = w.register_schema(schema_name, "protobuf", b"\x00")
        cid = w.register_channel("/sensors/thing", "protobuf", sid)
        w.add_message(cid, log_time=1, data=b"\x08\x01", publish_time=1)
        w.finish()
    return path


def test_unknown_schema_and_no_supported_topic(tmp_path: Path) -> None:
    path = _foreign_log(tmp_path / "thing.mcap", "acme.Thing")
    with pytest.raises(LogError, match=r"no supported topic.*/sensors/thing \[acme.Thing\]") as err:
        mcap_reader.read(path)
    assert "foxglove.SceneUpdate" in (err.value.expected or "")
    with pytest.raises(
        LogError, match=r"'/sensors/thing' has schema 'acme.Thing'.*holds no tracked objects"
    ) as err:
        mcap_reader.read(path, topic="/sensors/thing")
    assert err.value.offset is not None


def test_channel_with_undefined_schema(tmp_path: Path) -> None:
    """Hand-written records: a channel refers to schema 9, which the file never defines."""
    from mcap.writer import Writer

    path = tmp_path / "orphan.mcap"
    with path.open("wb") as f:
        w = Writer(f, use_chunking=False, repeat_schemas=False)
        w.start()
        body = struct.pack("<HH", 1, 9) + _s("/objects") + _s("protobuf") + struct.pack("<I", 0)
        f.write(bytes([0x04]) + struct.pack("<Q", len(body)) + body)
        w.add_message(1, log_time=5, data=b"", publish_time=5)
        w.finish()
    with pytest.raises(LogError, match=r"'/objects' refers to schema 9") as err:
        mcap_reader.read(path)
    assert err.value.offset is not None and err.value.offset > 8


def _s(text: str) -> bytes:
    raw = text.encode()
    return struct.pack("<I", len(raw)) + raw


def test_undecodable_message_names_topic(tmp_path: Path) -> None:
    from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate
    from mcap.writer import Writer
    from mcap_protobuf.schema import build_file_descriptor_set

    path = tmp_path / "garbled.mcap"
    with path.open("wb") as f:
        w = Writer(f)
        w.start()
        sid = w.register_schema(
            "foxglove.SceneUpdate", "protobuf", build_file_descriptor_set(SceneUpdate).SerializeToString()
        )
        cid = w.register_channel("/scene", "protobuf", sid)
        w.add_message(
            cid, log_time=1, data=b"\x12\x50\x1a\x01", publish_time=1
        )  # entity runs past the message
        w.finish()
    with pytest.raises(LogError, match="SceneUpdate messages cannot be decoded") as err:
        mcap_reader.read(path)
    assert err.value.path == str(path) and err.value.offset is not None


def test_convert_cli_reports_damage_and_salvages(
    log: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from lanecast.workflows.cli import main

    chunks = chunk_layout(log)
    data = bytearray(log.read_bytes())
    data[chunks[1][0] + chunks[1][1] // 2] ^= 0xFF
    path = tmp_path / "damaged.mcap"
    path.write_bytes(bytes(data))
    assert main(["convert", str(path), "--out", str(tmp_path / "t.parquet")]) == 2
    err = capsys.readouterr().err
    assert "corrupt chunk" in err and f"offset {chunks[1][0]}" in err and str(path) in err
    assert main(["convert", str(path), "--salvage", "--out", str(tmp_path / "t.parquet")]) == 0
    captured = capsys.readouterr()
    assert "lost 1 chunks" in captured.err and "wrote" in captured.out


@pytest.mark.parametrize(
    ("fmt", "storage", "name"), [("ros1", "", "d.bag"), ("ros2", "sqlite3", "b"), ("ros2", "mcap", "b")]
)
@pytest.mark.parametrize("fraction", [0.05, 0.3, 0.6, 0.95, 0.9999])
def test_truncated_bag_names_file_and_offset(
    tmp_path: Path, table: pa.Table, fmt: str, storage: str, name: str, fraction: float
) -> None:
    """A bag cut short was 'cannot read the bag: Bag index looks damaged' (ROS 1), 'database disk
    image is malformed' (sqlite3) or 'not a complete MCAP file' (ROS 2 MCAP storage): no offset."""
    from lanecast.io_adapters.logs.rosbag import writer as rosbag_writer

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

    from lanecast.io_adapters.logs.rosbag import writer as rosbag_writer

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
    from lanecast.io_adapters.logs.rosbag import writer as rosbag_writer

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
    from lanecast.io_adapters.logs.rosbag import writer as rosbag_writer

    bag = rosbag_writer.write(table, tmp_path / "b", "ros2", storage="sqlite3")
    _damage_first_message(bag, "/tracked_objects", 4, b"\x01")  # the header's stamp (seconds)
    with pytest.raises(LogError, match="do not match the checksum lanecast wrote") as err:
        rosbag_reader.read(bag)
    assert err.value.path == str(bag / "b.db3")
    assert "sqlite3's own check finds the database intact" in str(err.value)


def _ros1_records(
    data: bytes, pos: int = 13, stop: int | None = None
) -> list[tuple[int, dict[str, bytes], int, int]]:
    """(offset, header fields, data offset, data length) of every record of a ROS 1 bag (or of an
    uncompressed chunk's records data[pos:stop])."""
    out = []
    while pos < (len(data) if stop is None else stop):
        (header_len,) = struct.unpack_from("<I", data, pos)
        fields, q = {}, pos + 4
        while q < pos + 4 + header_len:
            (n,) = struct.unpack_from("<I", data, q)
            name, _, value = data[q + 4 : q + 4 + n].partition(b"=")
            fields[name.decode()] = value
            q += 4 + n
        (data_len,) = struct.unpack_from("<I", data, q)
        out.append((pos, fields, q + 4, data_len))
        pos = q + 4 + data_len
    return out


def _small_chunks_ros1_bag(table: pa.Table, path: Path) -> Path:
    """lanecast's ROS 1 bag of ``table`` rewritten by rosbags into uncompressed chunks of ~4 kB."""
    from rosbags.rosbag1 import Reader, Writer

    from lanecast.io_adapters.logs.rosbag import writer as rosbag_writer

    src = rosbag_writer.write(table, path.with_name("src.bag"), "ros1")
    with Reader(src) as r:
        w = Writer(path)
        w.chunk_threshold = 4096
        with w:
            conns = {
                c.id: w.add_connection(c.topic, c.msgtype, msgdef=c.msgdef.data, md5sum=c.digest)
                for c in r.connections
            }
            for c, t, raw in r.messages():
                w.write(conns[c.id], t, raw)
    return path


def _ros1_damage(kind: str, data: bytearray) -> tuple[int, str]:
    """Damage ``data`` (a ROS 1 bag) in place: (the offset of the record the error must name, its text)."""
    recs = _ros1_records(bytes(data))
    ops = [(off, f, d, n) for off, f, d, n in recs]
    chunks = [r for r in ops if r[1]["op"] == b"\x05"]
    if kind == "chunk info listing a listed chunk":
        info = [r for r in ops if r[1]["op"] == b"\x06"][1]
        at = data.index(b"chunk_pos=", info[0]) + len(b"chunk_pos=")
        data[at : at + 8] = struct.pack("<Q", chunks[0][0])
        return info[0], f"points at the chunk at offset {chunks[0][0]}, which another one lists"
    if kind == "index data past its chunk":
        index = next(r for r in ops if r[1]["op"] == b"\x04" and r[0] > chunks[1][0])
        struct.pack_into("<I", data, index[2] + 8, 10**8)
        return index[0], "lists a message at offset 100000000 of a chunk of"
    if kind == "connection without message definition":
        conn = next(r for r in ops if r[1]["op"] == b"\x07" and r[0] > chunks[-1][0])
        at = data.index(b"message_definition=", conn[2])
        data[at : at + 1] = b"x"
        return conn[0], "has no message_definition field"
    if kind in ("connection definition that does not parse", "connection md5sum not its definition's"):
        conn = next(
            r
            for r in ops
            if r[1]["op"] == b"\x07" and r[0] > chunks[-1][0] and b"[]" in data[r[2] : r[2] + r[3]]
        )
        if kind.endswith("parse"):
            at = data.index(b"[]", data.index(b"message_definition=", conn[2]))
            data[at : at + 2] = b"[["
            return conn[0], "cannot be parsed"
        at = data.index(b"md5sum=", conn[2]) + len(b"md5sum=")
        data[at : at + 1] = b"0" if data[at : at + 1] != b"0" else b"1"
        return conn[0], "is not that of its message definition"
    if kind == "a record of another kind in the index":
        conn = next(r for r in ops if r[1]["op"] == b"\x07" and r[0] > chunks[-1][0])
        at = data.index(b"op=\x07", conn[0]) + 3
        data[at : at + 1] = b"\x02"
        return conn[0], "a record of op 0x02 in the index"
    if kind == "index data listing no message record":
        index = next(r for r in ops if r[1]["op"] == b"\x04" and r[0] > chunks[1][0])
        struct.pack_into("<I", data, index[2] + 8, 3)  # the first message's offset: inside a record
        return index[0], "lists a message at offset 3 of its chunk, where no message record starts"
    if kind == "a chunk info record deleted":
        info = [r for r in ops if r[1]["op"] == b"\x06"][1]
        del data[info[0] : info[2] + info[3]]
        return ops[0][0], "the bag header states"
    if kind == "chunk info stating more connections than it holds":
        info = [r for r in ops if r[1]["op"] == b"\x06"][1]
        at = data.index(b"count=", info[0]) + len(b"count=")
        data[at : at + 4] = struct.pack("<I", 0xFFFFFFFF)
        return info[0], "a chunk info record states 4294967295 connections in"
    if kind == "index data stating fewer messages than it lists":
        index = next(r for r in ops if r[1]["op"] == b"\x04" and r[0] > chunks[1][0])
        at = data.index(b"count=", index[0]) + len(b"count=")
        data[at : at + 4] = struct.pack("<I", 0)
        return index[0], f"lists 0 messages in {index[3]} bytes (12 bytes each)"
    if kind == "bag header stating no chunks":
        at = data.index(b"chunk_count=", ops[0][0]) + len(b"chunk_count=")
        data[at : at + 4] = struct.pack("<I", 0)
        return ops[0][0], "the bag header states 0 chunks, the index lists"
    if kind == "chunk compressed with an unknown method":
        at = data.index(b"compression=none", chunks[1][0]) + len(b"compression=")
        data[at : at + 4] = b"zzzz"
        return chunks[1][0], "a chunk compressed with 'zzzz', which ROS 1 bags do not use"
    if kind == "message on an undefined connection":
        inner = _ros1_records(bytes(data), chunks[2][2], chunks[2][2] + chunks[2][3])
        msg = next(r for r in inner if r[1]["op"] == b"\x02")
        at = data.index(b"conn=", msg[0]) + len(b"conn=")
        data[at : at + 4] = struct.pack("<I", 77)
        return chunks[2][
            0
        ], f"a message at byte {msg[0] - chunks[2][2]} of the chunk's records is on connection 77"
    header = ops[0]
    at = data.index(b"index_pos=", header[0]) + len(b"index_pos=")
    data[at : at + 8] = struct.pack("<Q", chunks[1][0] + 7)
    return header[0], f"puts the index at offset {chunks[1][0] + 7}, where no record starts"


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


@pytest.mark.parametrize("damage", ["name length", "data length", "crc"])
def test_damaged_attachment_is_named_by_convert_and_annotate(tmp_path: Path, damage: str) -> None:
    """An Attachment record whose fields do not fit it (or whose CRC is wrong) was read without a
    word by convert and refused by annotate's copy as 'cannot copy the MCAP: ' (no reason, the
    offset of the read buffer); now both name the record's offset and what is wrong."""
    import zlib

    import pyarrow.parquet as pq
    from conftest import forecasts_for, make_mcap

    from lanecast.workflows.annotation.annotate_log import AnnotateOptions, annotate_log

    log = make_mcap(tmp_path / "log.mcap", n=40)
    pq.write_table(forecasts_for("log", [1, 2], [1]), tmp_path / "fc.parquet")  # no track reading: the copy
    data = bytearray(log.read_bytes())
    at = next(o for o, op, _ in mcap_record_spans(bytes(data)) if op == 0x09)
    if damage == "name length":
        struct.pack_into("<I", data, at + 9 + 16, 10**6)
    elif damage == "data length":
        pos = at + 9 + 16
        pos += 4 + struct.unpack_from("<I", data, pos)[0]
        pos += 4 + struct.unpack_from("<I", data, pos)[0]
        struct.pack_into("<Q", data, pos, 10**9)
    else:
        n = struct.unpack_from("<Q", data, at + 1)[0]
        struct.pack_into("<I", data, at + 9 + n - 4, 0xDEADBEEF)
    end = next(
        o for o, op, _ in mcap_record_spans(bytes(data)) if op == 0x0F
    )  # the writer meant it: data CRC ok
    struct.pack_into("<I", data, end + 9, zlib.crc32(bytes(data[:end])))
    log.write_bytes(bytes(data))
    with pytest.raises(LogError, match="corrupt Attachment record") as err:
        mcap_reader.read_log(log)
    assert err.value.path == str(log) and err.value.offset == at
    if damage == "crc":  # the mcap library's copy checks no attachment CRC (the data section's is right)
        return
    with pytest.raises(LogError, match="corrupt Attachment record") as err:
        annotate_log(log, tmp_path / "out.mcap", AnnotateOptions(forecasts=tmp_path / "fc.parquet"))
    assert err.value.offset == at and not (tmp_path / "out.mcap").exists()


def test_annotating_a_file_of_only_the_mcap_magic_says_it_is_truncated(tmp_path: Path) -> None:
    """'cannot read the MCAP header: ' (the mcap library's empty message) at offset 0; now the
    reader's own error: truncated at 8 bytes, without a footer."""
    from lanecast.workflows.annotation.annotate_log import AnnotateOptions, annotate_log

    log = tmp_path / "log.mcap"
    log.write_bytes(b"\x89MCAP0\r\n")
    with pytest.raises(LogError, match="the file is truncated: it ends at 8 bytes without a footer") as err:
        annotate_log(log, tmp_path / "out.mcap", AnnotateOptions())
    assert err.value.offset == 8
    log.write_bytes(b"")
    with pytest.raises(LogError, match="the file is empty"):
        annotate_log(log, tmp_path / "out.mcap", AnnotateOptions())


def _prediction_doc() -> dict[str, object]:
    target = {
        "track_id": 4,
        "origin": [0.0, 0.0],
        "x": [1.0, 2.0, 3.0, 4.0, 5.0],
        "y": [0.0] * 5,
        "maneuver": [0] * 5,
        "maneuver_probs": [[0.9, 0.05, 0.05]] * 5,
        "alternatives": [{"prob": 0.1, "x": [1.0] * 5, "y": [0.5] * 5, "maneuver": [1] * 5}],
    }
    return {
        "recording": "r",
        "frame_id": "map",
        "t0_ns": 3_000_000_000,
        "horizon_s": [1, 2, 3, 4, 5],
        "targets": [target],
    }


@pytest.mark.parametrize(
    ("edit", "column", "expected"),
    [
        (lambda d: d["targets"][0].update(x=[1.0, 2.0, 3.0, 4.0]), "targets[0].x", "5 finite numbers"),
        (lambda d: d["targets"][0]["y"].__setitem__(2, None), "targets[0].y", "5 finite numbers"),
        (lambda d: d.pop("targets"), "targets", "a list"),
        (lambda d: d["targets"][0].update(track_id="car-7"), "targets[0].track_id", "an integer"),
        (lambda d: d.update(t0_ns="soon"), "t0_ns", "an integer (ns)"),
        (lambda d: d["targets"][0].update(maneuver_probs=[[1, 0]]), "targets[0].maneuver_probs", "null or 5"),
        (
            lambda d: d["targets"][0]["alternatives"][0].pop("x"),
            "targets[0].alternatives[0]",
            "an object with",
        ),
        # fuzz seeds 1131 and 1134: 1e308 was taken in, and the report was a traceback
        (lambda d: d["targets"][0]["y"].__setitem__(1, 1e308), "targets[0].y", "5 finite numbers within"),
        (
            lambda d: d["targets"][0]["maneuver_probs"][2].__setitem__(0, 1e308),
            "targets[0].maneuver_probs",
            "null or 5 lists of 3 numbers from 0 to 1",
        ),
        (
            lambda d: d["targets"][0]["maneuver_probs"][0].__setitem__(1, -0.5),
            "targets[0].maneuver_probs",
            "null or 5",
        ),
        (
            lambda d: d["targets"][0]["alternatives"][0].update(prob=7),
            "targets[0].alternatives[0].prob",
            "a number",
        ),
        (lambda d: d["targets"][0].update(origin=[1e300, 0.0]), "targets[0].origin", "null or 2 finite"),
    ],
)
def test_a_bad_prediction_document_names_its_message_and_field(
    tmp_path: Path, edit: object, column: str, expected: str
) -> None:
    """`lanecast report` on a log whose /lanecast/prediction JSON has a field of the wrong shape or
    type (4 points, a null coordinate, no targets, a string track id): a ValueError/KeyError/
    TypeError traceback, or (a null point) NaN taken into the metrics; now the message, its log
    time and the field."""
    import json

    from mcap.writer import Writer

    from lanecast.workflows.annotation.log_scores import prediction_documents

    bad = _prediction_doc()
    edit(bad)  # type: ignore[operator]
    log = tmp_path / "annotated.mcap"
    with log.open("wb") as f:
        w = Writer(f)
        w.start()
        cid = w.register_channel("/lanecast/prediction", "json", 0)
        for i, doc in enumerate([_prediction_doc(), bad]):
            w.add_message(cid, log_time=(i + 1) * 10**9, data=json.dumps(doc).encode(), publish_time=0)
        w.finish()
    with pytest.raises(LogError, match=r"/lanecast/prediction message 2 \(log time 2000000000 ns\)") as err:
        prediction_documents(log)
    assert err.value.path == str(log) and err.value.column == column
    assert (err.value.expected or "").startswith(expected)


def rewrite_mcap(
    clean: Path,
    bad: Path,
    edit: Callable[[int, int, int, bytes], bytes | None] | None = None,
    log_time_of: Callable[[int, int], int] | None = None,
    **writer_options: Any,
) -> None:
    """``clean`` rewritten to ``bad`` by the mcap library (valid CRCs; ``writer_options`` for its
    Writer), every message's data passed through ``edit(index, number of messages, log_time,
    data)`` (None: unchanged) and its log time through ``log_time_of(index, log_time)``."""
    from mcap.reader import make_reader
    from mcap.writer import Writer

    with clean.open("rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None
        messages = [(ch.id, m.log_time, m.publish_time, m.data) for _s, ch, m in reader.iter_messages()]
    with bad.open("wb") as f:
        w = Writer(f, **writer_options)
        w.start()
        sids = {i: w.register_schema(s.name, s.encoding, s.data) for i, s in summary.schemas.items()}
        cids = {
            i: w.register_channel(c.topic, c.message_encoding, sids[c.schema_id], c.metadata)
            for i, c in summary.channels.items()
        }
        for k, (cid, log_time, publish_time, data) in enumerate(messages):
            edited = None if edit is None else edit(k, len(messages), log_time, data)
            new_time = log_time if log_time_of is None else log_time_of(k, log_time)
            w.add_message(cids[cid], new_time, data if edited is None else edited, publish_time)
        w.finish()


@pytest.mark.parametrize(
    ("old", "new", "what"),
    [(b"car", b"c\xffr", "class name"), (b"class", b"cl\xedss", "metadata key")],
)
def test_a_class_name_that_is_not_utf8_is_refused_with_its_offset(
    tmp_path: Path, table: pa.Table, old: bytes, new: bytes, what: str
) -> None:
    """A damaged byte in a protobuf string used to become U+FFFD: the class 'car' of one message a
    new class 'c\ufffdr' in the table (fuzz seed 1071), the metadata key 'class' no key, so the
    vehicle's class silently 'unknown' (seed 1221). Protobuf strings are UTF-8, so either is a
    LogError naming the record."""
    clean = mcap_writer.write(table, tmp_path / "clean.mcap", "mcap")
    bad = tmp_path / "bad.mcap"
    damaged: list[int] = []

    def edit(k: int, n: int, _log_time: int, data: bytes) -> bytes | None:
        if k == n // 2 and old in data:
            damaged.append(k)
            return data.replace(old, new, 1)
        return None

    rewrite_mcap(clean, bad, edit)
    assert damaged
    with pytest.raises(LogError, match=f"{what} .* is not UTF-8") as err:
        mcap_reader.read(bad)
    assert err.value.path == str(bad) and err.value.offset is not None


@pytest.mark.parametrize(
    "kind",
    [
        "index_pos not at a record",
        "connection without message definition",
        "chunk info listing a listed chunk",
    ],
)
def test_annotate_names_the_damaged_record_of_a_ros1_bag_as_convert_does(
    tmp_path: Path, table: pa.Table, kind: str
) -> None:
    """annotate opens a bag to list its topics before reading it; a bag rosbags could not open
    there was 'cannot open the bag: Header could not be read from file.' (fuzz seed 1101), no
    offset, where convert names the record. Now annotate gives convert's error."""
    from lanecast.workflows.annotation.annotate_log import AnnotateOptions, annotate_log

    bag = _small_chunks_ros1_bag(table, tmp_path / "b.bag")
    data = bytearray(bag.read_bytes())
    offset, text = _ros1_damage(kind, data)
    bag.write_bytes(bytes(data))
    with pytest.raises(LogError) as err:
        annotate_log(bag, tmp_path / "out.mcap", AnnotateOptions())
    assert err.value.path == str(bag) and err.value.offset == offset, str(err.value)
    assert text in str(err.value)
    assert not (tmp_path / "out.mcap").exists()


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

    from lanecast.io_adapters.logs.rosbag import writer as rosbag_writer

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

    from lanecast.io_adapters.logs.rosbag import writer as rosbag_writer

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


@pytest.mark.parametrize("opcode", [0x0F, 0x00, 0x06])
def test_a_record_of_another_kind_inside_a_chunk_is_refused(
    tmp_path: Path, table: pa.Table, opcode: int
) -> None:
    """A Message record inside an uncompressed chunk whose opcode became DataEnd (0x0f), 0x00 or
    Chunk, CRCs recomputed (a writer bug, or damage before the CRCs were written): the record was
    skipped and its vehicles' rows silently lost (fuzz seed 1151). A chunk holds only Schema,
    Channel and Message records; now the chunk's offset and the record's place in it."""
    import zlib

    from mcap.writer import CompressionType

    clean = mcap_writer.write(table, tmp_path / "clean.mcap", "mcap")
    log = tmp_path / "log.mcap"
    rewrite_mcap(clean, log, compression=CompressionType.NONE, chunk_size=4000)
    data = bytearray(log.read_bytes())
    chunk = [o for o, op, _n in mcap_record_spans(bytes(data)) if op == 0x06][1]
    body = chunk + 9
    (clen,) = struct.unpack_from("<I", data, body + 28)
    records_at = body + 32 + clen + 8
    (records_len,) = struct.unpack_from("<Q", data, records_at - 8)
    pos = records_at
    while data[pos] != 0x05:  # the chunk's first Message record
        pos += 9 + struct.unpack_from("<Q", data, pos + 1)[0]
    data[pos] = opcode
    struct.pack_into("<I", data, body + 24, zlib.crc32(bytes(data[records_at : records_at + records_len])))
    end = next(o for o, op, _ in mcap_record_spans(bytes(data)) if op == 0x0F)
    struct.pack_into("<I", data, end + 9, zlib.crc32(bytes(data[:end])))
    log.write_bytes(bytes(data))
    with pytest.raises(
        LogError, match=f"a record of opcode {opcode:#04x} at byte {pos - records_at} "
    ) as err:
        mcap_reader.read_log(log)
    assert err.value.path == str(log) and err.value.offset == chunk


def test_a_sqlite3_message_on_no_topic_is_refused_not_dropped(tmp_path: Path, table: pa.Table) -> None:
    """A messages row whose topic_id is no topic (a damaged or hand-edited bag, without lanecast's
    checksum) was skipped by rosbags, its vehicles' rows silently lost (fuzz seed 1207). Now the
    table, row and column."""
    import sqlite3

    from lanecast.io_adapters.logs.rosbag import writer as rosbag_writer

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
    from lanecast.io_adapters.logs.rosbag import writer as rosbag_writer

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


def test_a_non_finite_position_is_named_by_topic_track_and_stamp(tmp_path: Path, table: pa.Table) -> None:
    """A position of inf in one message (CRCs valid: the writer meant it) was 'log.mcap: row 12658:
    column 'x' is -inf', a row of a table the user never sees (fuzz seed 1112). Now the topic, the
    track and the stamp of the object, which find the message in the log."""
    clean = mcap_writer.write(table, tmp_path / "clean.mcap", "mcap")
    bad = tmp_path / "bad.mcap"
    xs = {struct.pack("<d", v) for v in table.column("x").to_pylist()}
    damaged: list[int] = []

    def edit(k: int, n: int, log_time: int, data: bytes) -> bytes | None:
        at = next((i for i in range(len(data) - 7) if data[i : i + 8] in xs), None)
        if damaged or k < n // 2 or at is None:
            return None
        damaged.append(log_time)
        return data[:at] + struct.pack("<d", float("inf")) + data[at + 8 :]

    rewrite_mcap(clean, bad, edit)
    assert damaged
    with pytest.raises(LogError, match=r"topic '[^']+', the object of track \d+ stamped \d+ ns") as err:
        mcap_reader.read(bad)
    assert "column 'x' is inf" in str(err.value) and err.value.path == str(bad)


@pytest.mark.parametrize("storage", ["sqlite3", "mcap"])
def test_annotate_names_a_damaged_ros2_bag_as_convert_does(
    tmp_path: Path, table: pa.Table, storage: str
) -> None:
    """annotate lists a ROS 2 bag's topics with rosbags before reading it; a bad metadata.yaml
    version or an MCAP storage file with a record deleted was 'cannot open the bag: Invalid bag
    metadata: '>' not supported between instances of 'str' and 'int'' or 'cannot open the bag:'
    with nothing after it (fuzz seeds 1382, 1386). Now convert's error: the file and line/offset."""
    from lanecast.io_adapters.logs.rosbag import writer as rosbag_writer
    from lanecast.workflows.annotation.annotate_log import AnnotateOptions, annotate_log

    bag = rosbag_writer.write(table, tmp_path / "b", "ros2", storage=storage)
    meta = bag / "metadata.yaml"
    meta.write_text(meta.read_text().replace("version: 9", "version: x"))
    with pytest.raises(LogError, match="version") as err:
        annotate_log(bag, tmp_path / "out", AnnotateOptions())
    assert err.value.path == str(meta) and err.value.line is not None
    if storage == "mcap":
        meta.write_text(meta.read_text().replace("version: x", "version: 9"))
        storage_file = next(bag.glob("*.mcap"))
        data = storage_file.read_bytes()
        end = next(o for o, op, _ in mcap_record_spans(data) if op == 0x0F)
        storage_file.write_bytes(data[:end] + data[end + 13 :])  # the DataEnd record deleted
        with pytest.raises(LogError) as err:
            annotate_log(bag, tmp_path / "out", AnnotateOptions())
        assert err.value.path == str(storage_file) and err.value.offset is not None, str(err.value)
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("encoding", ["protobuf", "json"])
def test_a_message_logged_at_the_previous_frames_time_keeps_its_objects_own_stamps(
    tmp_path: Path, table: pa.Table, encoding: str, capsys: pytest.CaptureFixture[str]
) -> None:
    """A SceneUpdate whose log time repeats the previous message's, its entities stamped with their
    own (later) time: frames came from the log time, so its objects fell on the previous frame and
    were dropped as repeated (track, frame) rows, exit 0 with a stderr note (fuzz seed 1390: 16
    rows lost). An entity's timestamp is the object's time, the log time the recorder's: the frame
    now follows the objects' stamps and nothing is lost."""
    clean = mcap_writer.write(table, tmp_path / "clean.mcap", "mcap", encoding=encoding)
    bad = tmp_path / "bad.mcap"
    period = int(1e9 / RATE)
    moved = int(30 * 1e9 / RATE)
    rewrite_mcap(clean, bad, log_time_of=lambda k, t: t - period if t == moved else t)
    got, want = mcap_reader.read(bad), mcap_reader.read(clean)
    assert got.num_rows == want.num_rows == table.num_rows
    for name in ("track_id", "frame", "time_ns", "x", "y", "vx"):
        assert got.column(name).equals(want.column(name)), name
    assert "repeat a (track, frame)" not in capsys.readouterr().err


def test_a_chunk_deleted_under_an_intact_summary_is_refused_not_read_short(
    log: Path, table: pa.Table, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A chunk (with its message indexes) deleted and the summary's pointers moved to match: every
    CRC holds, so the file was read without that chunk's frames, exit 0 (fuzz2 family
    m_stale_summary). The summary's Statistics record counts the messages written: a data section
    holding another number is refused at that record; --salvage reads the chunks there are."""
    from lanecast.workflows.cli import main

    data = log.read_bytes()
    recs = mcap_record_spans(data)
    k = next(i for i, (_o, op, _n) in enumerate(recs) if op == 0x06 and i > 3)
    start, end = recs[k][0], recs[k][0] + 9 + recs[k][2]
    while recs[k + 1][1] == 0x07:
        k += 1
        end = recs[k][0] + 9 + recs[k][2]
    cut = bytearray(data[:start] + data[end:])
    footer = len(cut) - 8 - 29
    summary_start, offsets_start = struct.unpack_from("<QQ", cut, footer + 9)
    struct.pack_into("<QQ", cut, footer + 9, summary_start - (end - start), offsets_start - (end - start))
    pos = summary_start - (end - start)
    while pos < footer:  # summary offset records point into the summary
        op, n = struct.unpack_from("<BQ", cut, pos)
        if op == 0x0E:
            (group,) = struct.unpack_from("<Q", cut, pos + 10)
            struct.pack_into("<Q", cut, pos + 10, group - (end - start))
        pos += 9 + n
    data_end = next(o for o, op, _ in mcap_record_spans(bytes(cut)) if op == 0x0F)
    struct.pack_into("<I", cut, data_end + 9, zlib.crc32(bytes(cut[:data_end])))
    struct.pack_into(
        "<I", cut, footer + 25, zlib.crc32(bytes(cut[summary_start - (end - start) : footer + 25]))
    )
    bad = tmp_path / "stale.mcap"
    bad.write_bytes(bytes(cut))
    with pytest.raises(LogError, match="Statistics record counts") as err:
        mcap_reader.read(bad)
    assert err.value.offset is not None and err.value.offset > start
    out = tmp_path / "t.parquet"
    assert main(["convert", str(bad), "--out", str(out)]) == 2 and not out.exists()
    assert main(["convert", str(bad), "--salvage", "--out", str(out)]) == 0
    assert "Statistics record counts" in capsys.readouterr().err
    assert 0 < track_table.read_parquet(out).num_rows < table.num_rows


def test_ros2_metadata_naming_qos_profiles_rosbags_cannot_parse_names_its_line(
    tmp_path: Path, table: pa.Table
) -> None:
    """offered_qos_profiles: 'junk' was 'cannot read the bag: AnyReaderError: Invalid bag metadata:
    string indices must be integers, not 'str'': neither metadata.yaml nor a line (found by
    tests/test_fuzz_logs.py). Now metadata.yaml, the line and the key."""
    from lanecast.io_adapters.logs.rosbag import writer as rosbag_writer

    bag = rosbag_writer.write(table, tmp_path / "b", "ros2", storage="mcap")
    meta = bag / "metadata.yaml"
    meta.write_text(meta.read_text().replace("offered_qos_profiles: []", "offered_qos_profiles: 'junk'", 1))
    with pytest.raises(LogError, match="offered QoS profiles that do not parse") as err:
        rosbag_reader.read(bag)
    assert err.value.path == str(meta) and err.value.line is not None
    assert err.value.column == "offered_qos_profiles"


def test_ros2_metadata_listing_a_copy_of_its_storage_file_names_both(tmp_path: Path, table: pa.Table) -> None:
    """A bag listing its storage file and a byte copy of it was 'the messages do not match the
    checksum lanecast wrote (6,000 messages read, 3000 written)', no line (fuzz2 seed 5017); a
    foreign bag would read every message twice. Now metadata.yaml's relative_file_paths line."""
    from lanecast.io_adapters.logs.rosbag import writer as rosbag_writer

    bag = rosbag_writer.write(table, tmp_path / "b", "ros2", storage="mcap")
    storage = next(bag.glob("*.mcap"))
    shutil.copy(storage, bag / "copy.mcap")
    meta = bag / "metadata.yaml"
    meta.write_text(
        meta.read_text().replace(
            f"relative_file_paths:\n  - {storage.name}",
            f"relative_file_paths:\n  - {storage.name}\n  - copy.mcap",
        )
    )
    with pytest.raises(LogError, match="which hold the same bytes") as err:
        rosbag_reader.read(bag)
    assert err.value.path == str(meta) and err.value.column == "relative_file_paths"
    assert err.value.line is not None


@pytest.mark.parametrize("change", ["topic", "schema"])
def test_a_channel_defined_again_with_other_content_is_refused_at_its_record(
    tmp_path: Path, log: Path, change: str
) -> None:
    """A Channel record half-way through a log giving channel 1 another topic (or no schema): the
    messages after it were read as that topic's, not an object topic, and dropped: exit 0 with
    6,869 of 21,971 rows lost (fuzz2 seed 5043). MCAP channel ids are unique in a file: a record
    that repeats an id with other content is refused at its offset."""
    from mcap.writer import Writer

    summary, messages, metadata = mcap_contents(log)
    bad = tmp_path / "redefined.mcap"
    with bad.open("wb") as f:
        w = Writer(f, use_chunking=False)
        w.start()
        sids = {i: w.register_schema(s.name, s.encoding, s.data) for i, s in summary.schemas.items()}
        cids = {
            i: w.register_channel(c.topic, c.message_encoding, sids[c.schema_id], c.metadata)
            for i, c in summary.channels.items()
        }
        for m in metadata:
            w.add_metadata(m.name, m.metadata)
        for k, (cid, log_time, data) in enumerate(messages):
            if k == len(messages) // 2:
                first = summary.channels[cid]
                topic = "/other" if change == "topic" else first.topic
                schema = sids[first.schema_id] if change == "topic" else 0
                at = f.tell()
                f.write(channel_record(cids[cid], schema, topic, first.message_encoding))
            w.add_message(cids[cid], log_time, data, log_time)
        w.finish()
    with pytest.raises(LogError, match=rf"channel {cids[cid]} defined again with other content") as err:
        mcap_reader.read(bad)
    assert err.value.offset == at and err.value.path == str(bad)
