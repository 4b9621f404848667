"""MCAP reader checks on the messages of a log: protobuf and JSON faults, times beyond int64,
non-finite positions, undecodable messages, metadata and duplicate frames; each refused naming the
topic, record or offset, or read as the valid input it is."""

from __future__ import annotations

import json
import struct
from pathlib import Path
from typing import Any

import pyarrow as pa
import pytest
from conftest import RATE, REPO, _entity, convert_refused, json_log, refused, rewrite_mcap, straight_messages

from lanecast.io_adapters.errors import LogError
from lanecast.io_adapters.logs.mcap import reader as mcap_reader
from lanecast.io_adapters.logs.mcap import writer as mcap_writer


@pytest.mark.parametrize(
    ("edit", "says"),
    [
        (lambda e: {**e, "cubes": {"a": 1}}, "field 'entities[0].cubes': {'a': 1} (expected a list)"),
        (lambda e: {**e, "metadata": "car"}, "field 'entities[0].metadata': 'car' (expected a list)"),
    ],
)
def test_a_json_field_of_the_wrong_type_is_said_to_be_one(tmp_path: Path, edit: Any, says: str) -> None:
    """A JSON SceneUpdate whose entity has cubes as an object or metadata as a string: the error
    said only 'cannot be decoded: 0' (a KeyError's text) or an AttributeError's; it now names the
    field, what it holds and what was expected."""
    from conftest import _entity, json_log

    messages = [("/objects", t * 10**8, [_entity(1, 2.0 * t, 0, t * 10**8)]) for t in range(1, 20)]
    messages[5] = ("/objects", 6 * 10**8, [edit(_entity(1, 12.0, 0, 6 * 10**8))])
    log = json_log(tmp_path / "wrong-type.mcap", messages)
    with pytest.raises(LogError) as err:
        mcap_reader.read(log)
    assert f"message at log time {6 * 10**8} cannot be decoded: {says}" in str(err.value)
    assert err.value.path == str(log) and err.value.offset is not None


@pytest.mark.parametrize("chunked", [True, False])
def test_log_times_beyond_int64_are_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], chunked: bool
) -> None:
    """MCAP log times are uint64: 2^63 ns (valid MCAP) ended in 'OverflowError: Python int too large
    to convert to C long' (exit 1) when the track table's int64 times were built."""
    from conftest import _entity
    from mcap.writer import Writer

    schema = (REPO / "io_adapters/data/foxglove/jsonschema/SceneUpdate.json").read_bytes()
    path = tmp_path / "late.mcap"
    with path.open("wb") as f:
        writer = Writer(f, use_chunking=chunked)
        writer.start()
        channel = writer.register_channel(
            "/objects", "json", writer.register_schema("foxglove.SceneUpdate", "jsonschema", schema)
        )
        for i in range(5):
            data = json.dumps({"entities": [_entity(1, 2.0 * i)]}).encode()
            writer.add_message(channel, log_time=2**63 + i, data=data, publish_time=0)
        writer.finish()
    convert_refused(path, tmp_path, capsys, f"{path}, offset ", "log time 9223372036854775808 ns")


def test_a_position_is_blamed_before_the_speed_derived_from_it(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """x = 1e300 in one SceneUpdate was reported as 'column 'vx' is inf' (the speed derived from it)."""
    from conftest import _entity, json_log, straight_messages

    messages = straight_messages(n=30)
    messages[10][2][0] = _entity(1, 1e300)
    path = json_log(tmp_path / "far.mcap", messages)
    refused(
        ["convert", str(path), "--out", str(tmp_path / "o.parquet")],
        capsys,
        f"{path}: topic '/objects', the object of track 1 stamped ",  # where it is in the log
        "column 'x' is 1e+300",
    )


def _protobuf_log(path: Path, message: bytes) -> Path:
    from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate
    from mcap.writer import CompressionType, Writer
    from mcap_protobuf.schema import build_file_descriptor_set

    with path.open("wb") as f:
        w = Writer(f, compression=CompressionType.ZSTD, chunk_size=1 << 24)
        w.start()
        sid = w.register_schema(
            "foxglove.SceneUpdate", "protobuf", build_file_descriptor_set(SceneUpdate).SerializeToString()
        )
        cid = w.register_channel("/scene", "protobuf", sid)
        w.add_message(cid, log_time=1, data=message, publish_time=1)
        w.finish()
    return path


@pytest.mark.parametrize(
    ("message", "match"),
    [
        (bytes(4 << 20), "field number 0"),  # the hang: 4 MiB of zeros, a few KB on disk
        (b"\x12\x04\x00\x00\x00\x00", "field number 0"),  # inside an entity
        (b"\x12\x02\x0b\x00", "bad wire type"),  # a group start
        (b"\x12\x03\x0f\x00\x00", "bad wire type"),  # wire type 7
        (b"\x12\x0c\x0a\x0a\x08\xff\xff\xff\xff\xff\xff\xff\xff\x7f", "timestamp out of range"),  # sec 2^63-1
    ],
)
def test_protobuf_scene_update_wire_faults(tmp_path: Path, message: bytes, match: str) -> None:
    path = _protobuf_log(tmp_path / "pb.mcap", message)
    assert path.stat().st_size < 16_000
    with pytest.raises(LogError, match=match) as err:
        mcap_reader.read(path)
    assert err.value.path == str(path) and err.value.offset is not None


@pytest.mark.slow
def test_long_run_of_tiny_fields_is_read_in_bounded_work(tmp_path: Path) -> None:
    """1M two-byte unknown fields (valid protobuf): decoded by the scalar walk, no objects in it."""
    path = _protobuf_log(tmp_path / "tiny.mcap", b"\x18\x00" * 1_000_000)
    with pytest.raises(LogError, match="no supported topic with tracked objects"):
        mcap_reader.read(path)


def test_json_timestamp_beyond_int64(tmp_path: Path) -> None:
    messages = straight_messages()
    messages[3][2][0]["timestamp"] = {"sec": 2**63, "nsec": 0}
    path = json_log(tmp_path / "t.mcap", messages)
    with pytest.raises(LogError, match=r"sec=9223372036854775808.*out of range") as err:
        mcap_reader.read(path)
    assert err.value.offset is not None


@pytest.mark.parametrize(
    ("doc", "column"),
    [
        ('{"recordings": {"r": {"topic": "/objects", "frame_rate": "abc"}}}', "recordings.r.frame_rate"),
        ('{"source_files": 1, "recordings": {}}', "source_files"),
        ('{"recordings": {"r": {"frame_rate": 10}}}', "recordings.r.topic"),
        (
            '{"recordings": {"r": {"topic": "/objects", "frame_rate": 10, "frames": [1.5]}}}',
            "recordings.r.frames",
        ),
        ("[" * 100_000 + "]" * 100_000, "lanecast"),
        ("not json", "lanecast"),
        ('{"recordings": []}', "recordings"),
    ],
)
def test_lanecast_metadata_in_a_log_is_checked(tmp_path: Path, doc: str, column: str) -> None:
    path = json_log(tmp_path / "m.mcap", straight_messages(), {"lanecast": doc})
    with pytest.raises(LogError, match="lanecast metadata") as err:
        mcap_reader.read(path)
    assert err.value.column == column and err.value.path == str(path)


def test_wrong_topic_in_metadata_does_not_drop_objects(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    doc = {"recordings": {"r": {"topic": "/renamed", "frame_rate": 10.0, "coordinate_frame": "map"}}}
    path = json_log(tmp_path / "w.mcap", straight_messages(), {"lanecast": json.dumps(doc)})
    table = mcap_reader.read(path)
    assert table.num_rows == 40
    assert "'/objects' has objects but no entry" in capsys.readouterr().err


def test_duplicate_track_frames_in_a_log_are_reported(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """An exact repeat (a message recorded twice) is dropped with a note: nothing is lost. A
    repeat that says something else is refused: dropping either object would lose data."""
    messages = straight_messages()
    messages.insert(6, messages[5])  # the message at 0.6 s recorded twice
    table = mcap_reader.read(json_log(tmp_path / "d.mcap", messages))
    assert table.num_rows == 40
    assert "2 rows repeat an object of the same track, frame and stamp exactly" in capsys.readouterr().err
    messages[5][2].append(_entity(1, 99.0))  # track 1 twice in one message, at another place
    with pytest.raises(LogError, match=r"topic '/objects': track 1 has two different objects on frame 5"):
        mcap_reader.read(json_log(tmp_path / "d2.mcap", messages))


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
