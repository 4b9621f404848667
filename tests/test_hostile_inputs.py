"""Malformed and hostile inputs, one minimal input per cause: a clean refusal naming the file and
where, or a correct reading; never a traceback, a hang or a silent change (issue 13)."""

from __future__ import annotations

import json
import os
import struct
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from conftest import synthetic_windows

from lanecast.io_adapters.contracts import track_table
from lanecast.io_adapters.errors import InputError, LanecastError, LogError, TrackTableError
from lanecast.io_adapters.formats import registry
from lanecast.io_adapters.logs.mcap import reader as mcap_reader
from lanecast.io_adapters.windows_store.dataset import load_windows, save_windows
from lanecast.workflows.cli import main

REPO = Path(__file__).resolve().parents[1]


def _s(text: str | bytes) -> bytes:
    raw = text.encode() if isinstance(text, str) else text
    return struct.pack("<I", len(raw)) + raw


def _record(op: int, body: bytes) -> bytes:
    return bytes([op]) + struct.pack("<Q", len(body)) + body


def _entity(track: int, x: float, sec: int = 0, nsec: int = 0) -> dict[str, object]:
    return {
        "timestamp": {"sec": sec, "nsec": nsec},
        "frame_id": "map",
        "id": str(track),
        "metadata": [{"key": "class", "value": "car"}],
        "cubes": [
            {
                "pose": {"position": {"x": x, "y": 0.0, "z": 0.0}, "orientation": {"w": 1.0}},
                "size": {"x": 4.5, "y": 1.8, "z": 1.5},
            }
        ],
    }


def json_log(
    path: Path,
    messages: list[tuple[str, int, list[dict[str, object]]]],
    metadata: dict[str, str] | None = None,
) -> Path:
    """An MCAP of JSON SceneUpdates: (topic, log time ns, entities) per message."""
    from mcap.writer import Writer

    schema = (REPO / "io_adapters/data/foxglove/jsonschema/SceneUpdate.json").read_bytes()
    with path.open("wb") as f:
        w = Writer(f)
        w.start()
        sid = w.register_schema("foxglove.SceneUpdate", "jsonschema", schema)
        channels: dict[str, int] = {}
        for topic, t, entities in messages:
            if topic not in channels:
                channels[topic] = w.register_channel(topic, "json", sid)
            data = json.dumps({"entities": entities}).encode()
            w.add_message(channels[topic], log_time=t, data=data, publish_time=t)
        if metadata is not None:
            w.add_metadata("lanecast", metadata)
        w.finish()
    return path


def straight_messages(topic: str = "/objects", n: int = 20) -> list[tuple[str, int, list[dict[str, object]]]]:
    return [(topic, (i + 1) * 100_000_000, [_entity(1, 2.0 * i), _entity(2, 50 + 2.0 * i)]) for i in range(n)]


def cli(args: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str]:
    status = main(args)
    err = capsys.readouterr().err.strip()
    return status, err


def assert_one_line_error(status: int, err: str, command: str, name: str) -> None:
    assert status == 2
    lines = err.splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"lanecast {command}: error: "), err
    assert name in lines[0]


# ------------------------------------------------------------------------------- paths in and out


def test_fifo_input_is_refused_without_opening_it(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    fifo = tmp_path / "log.mcap"
    os.mkfifo(fifo)
    for fmt in (["--format", "mcap"], []):
        status, err = cli(["convert", str(fifo), *fmt, "--out", str(tmp_path / "x.parquet")], capsys)
        assert_one_line_error(status, err, "convert", str(fifo))
        assert "not a regular file" in err


def test_symlink_loops_and_directories(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    loop = tmp_path / "loop"
    loop.symlink_to(loop)
    good = json_log(tmp_path / "good.mcap", straight_messages())
    status, err = cli(["convert", str(loop), "--out", str(tmp_path / "x.parquet")], capsys)
    assert_one_line_error(status, err, "convert", str(loop))
    status, err = cli(["convert", str(good), "--out", str(loop)], capsys)
    assert_one_line_error(status, err, "convert", str(loop))
    status, err = cli(["convert", str(good), "--out", str(tmp_path)], capsys)
    assert_one_line_error(status, err, "convert", str(tmp_path))
    assert "is a directory" in err
    blocker = tmp_path / "file"
    blocker.write_text("x")
    status, err = cli(["convert", str(good), "--out", str(blocker / "x.parquet")], capsys)
    assert_one_line_error(status, err, "convert", str(blocker))
    assert not (tmp_path / "x.parquet").exists()


@pytest.mark.skipif(os.geteuid() == 0, reason="root reads and writes regardless of modes")
def test_unreadable_input_and_read_only_output(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    good = json_log(tmp_path / "good.mcap", straight_messages())
    good.chmod(0)
    status, err = cli(["convert", str(good), "--out", str(tmp_path / "x.parquet")], capsys)
    assert_one_line_error(status, err, "convert", str(good))
    good.chmod(0o644)
    ro = tmp_path / "ro"
    ro.mkdir(mode=0o555)
    status, err = cli(["convert", str(good), "--out", str(ro / "x.parquet")], capsys)
    assert_one_line_error(status, err, "convert", str(ro))


@pytest.mark.slow
def test_cli_subprocess_prints_no_traceback(tmp_path: Path) -> None:
    """End to end through the installed entry point: exit 2 and one line."""
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(mcap_reader.MAGIC + _record(0x03, struct.pack("<H", 1) + _s("x")[:3]))
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    done = subprocess.run(
        [sys.executable, "-m", "lanecast", "convert", str(bad), "--out", str(tmp_path / "x.parquet")],
        capture_output=True,
        text=True,
        env=env,
        timeout=120,
    )
    assert done.returncode == 2, done.stderr
    assert done.stderr.count("\n") == 1 and done.stderr.startswith("lanecast convert: error: ")
    assert str(bad) in done.stderr and "offset 8" in done.stderr


# ------------------------------------------------------------------------------------------- MCAP


def raw_log(path: Path, records: bytes) -> Path:
    """An unchunked MCAP: header, the given records, data end, footer, magic."""
    header = _record(0x01, _s("") + _s("test"))
    footer = _record(0x02, struct.pack("<QQI", 0, 0, 0))
    path.write_bytes(
        mcap_reader.MAGIC
        + header
        + records
        + _record(0x0F, struct.pack("<I", 0))
        + footer
        + mcap_reader.MAGIC
    )
    return path


@pytest.mark.parametrize(
    ("name", "records", "match"),
    [
        (
            "string past record",
            _record(0x03, struct.pack("<H", 1) + struct.pack("<I", 999) + b"abc"),
            "runs past",
        ),
        (
            "non-UTF-8 schema name",
            _record(0x03, struct.pack("<H", 1) + _s(b"\xff\xfe") + _s("jsonschema") + _s("{}")),
            "not UTF-8",
        ),
        (
            "non-UTF-8 topic",
            _record(0x04, struct.pack("<HH", 1, 0) + _s(b"/a\xc3") + _s("json") + struct.pack("<I", 0)),
            "not UTF-8",
        ),
        ("metadata map past record", _record(0x0C, _s("lanecast") + struct.pack("<I", 1 << 20)), "runs past"),
        ("message shorter than its header", _record(0x05, b"\x01\x00"), "shorter than its header"),
        ("statistics too short", _record(0x0B, b"\x01"), "fewer than its fields"),
    ],
)
def test_unchunked_records_with_bad_fields(tmp_path: Path, name: str, records: bytes, match: str) -> None:
    path = raw_log(tmp_path / "bad.mcap", records)
    with pytest.raises(LogError, match=match) as err:
        mcap_reader.read(path)
    assert (
        err.value.path == str(path) and err.value.offset == 8 + 9 + 4 + 8
    )  # the first record after the header


def _chunk(records: bytes, size: int, compression: str, compressed: bytes) -> bytes:
    body = (
        struct.pack("<QQQI", 0, 0, size, 0)
        + _s(compression)
        + struct.pack("<Q", len(compressed))
        + compressed
    )
    return _record(0x06, body)


def test_chunk_claiming_a_terabyte_is_refused_before_allocating(tmp_path: Path) -> None:
    import lz4.frame
    import zstandard

    records = _record(0x03, struct.pack("<H", 1) + _s("x") + _s("y") + _s(""))
    for compression, data in (
        ("zstd", zstandard.ZstdCompressor().compress(records)),
        ("lz4", lz4.frame.compress(records)),
        ("", records),
    ):
        path = raw_log(tmp_path / f"big-{compression}.mcap", _chunk(records, 1 << 40, compression, data))
        with pytest.raises(LogError, match="declares 1,099,511,627,776 uncompressed bytes") as err:
            mcap_reader.read(path)
        assert err.value.offset == 29


def test_lz4_frame_that_expands_past_the_declared_size(tmp_path: Path) -> None:
    """A frame whose own header claims 2^40 bytes, and a zero bomb: decompression stops at the chunk's size."""
    import lz4.frame

    bomb = lz4.frame.compress(bytes(64 << 20))
    path = raw_log(tmp_path / "bomb.mcap", _chunk(b"", 1000, "lz4", bomb))
    with pytest.raises(LogError, match="more than the 1000 bytes the chunk says"):
        mcap_reader.read(path)
    frame = bytearray(lz4.frame.compress(b"abc", store_size=True))
    frame[6:14] = struct.pack("<Q", 1 << 40)  # content size in the frame descriptor
    path = raw_log(tmp_path / "lie.mcap", _chunk(b"", 3, "lz4", bytes(frame)))
    with pytest.raises(LogError, match="corrupt chunk"):
        mcap_reader.read(path)


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


# ----------------------------------------------------------------------------------------- Parquet


def _parquet(tmp_path: Path) -> tuple[Path, pa.Table]:
    table = mcap_reader.read(json_log(tmp_path / "src.mcap", straight_messages()))
    return track_table.write_parquet(table, tmp_path / "t.parquet"), table


@pytest.mark.parametrize(
    ("edit", "match"),
    [
        (lambda d: d["recordings"]["src"].update(frame_rate="abc"), "recordings.src.frame_rate"),
        (lambda d: d["recordings"]["src"].update(frame_rate=1e-9), r"recordings.src.frame_rate.*0.1 to 1000"),
        (
            lambda d: d["recordings"]["src"].update(frame_rate=1e308),
            r"recordings.src.frame_rate.*0.1 to 1000",
        ),
        (lambda d: d.update(source_files=1), "source_files"),
        (lambda d: d.pop("source_format"), "source_format"),
        (lambda d: d["recordings"].update(src=[]), "recordings.src"),
    ],
)
def test_parquet_metadata_with_wrong_types(tmp_path: Path, edit: object, match: str) -> None:
    path, table = _parquet(tmp_path)
    doc = json.loads(table.schema.metadata[b"lanecast"])
    edit(doc)  # type: ignore[operator]
    bad = table.replace_schema_metadata({b"lanecast": json.dumps(doc).encode()})
    pq.write_table(bad, path)
    with pytest.raises(TrackTableError, match=match) as err:
        registry.read_any([path])
    assert str(path) in str(err.value)


def test_parquet_metadata_deeply_nested(tmp_path: Path) -> None:
    path, table = _parquet(tmp_path)
    pq.write_table(table.replace_schema_metadata({b"lanecast": b"[" * 50_000 + b"]" * 50_000}), path)
    with pytest.raises(TrackTableError, match="nested 50000 levels"):
        registry.read_any([path])


def test_parquet_flipped_data_byte_is_detected(tmp_path: Path) -> None:
    """Every byte of the first column chunk's pages flipped in turn: refused or (header bytes the
    checksum does not cover) read back equal; never a different table."""
    path, _ = _parquet(tmp_path)
    good = registry.read_any([path])
    data = path.read_bytes()
    meta = pq.ParquetFile(path).metadata.row_group(0).column(4)  # x
    start = meta.data_page_offset
    refused = 0
    for offset in range(start, start + meta.total_compressed_size, 7):
        bad = bytearray(data)
        bad[offset] ^= 0x5A
        out = tmp_path / "flipped.parquet"
        out.write_bytes(bytes(bad))
        try:
            back = registry.read_any([out])
        except LanecastError:
            refused += 1
            continue
        assert back.equals(good)
    assert refused > 0


def test_parquet_written_with_page_checksums(tmp_path: Path) -> None:
    path, _ = _parquet(tmp_path)
    data = bytearray(path.read_bytes())
    col = pq.ParquetFile(path).metadata.row_group(0).column(4)
    end = col.data_page_offset + col.total_compressed_size
    data[end - 3] ^= 0xFF  # inside the compressed page body
    path.write_bytes(bytes(data))
    with pytest.raises(InputError, match=r"(?i)checksum|crc|corrupt|not a readable"):
        registry.read_any([path])


def test_values_are_identical_after_reading(tmp_path: Path) -> None:
    path, table = _parquet(tmp_path)
    back = registry.read_any([path])
    assert np.array_equal(back.column("x").to_numpy(), table.column("x").to_numpy())


# ------------------------------------------------------------------------------------------- highD

HIGHD = REPO / "tests" / "data" / "highd"


def _highd_variant(tmp_path: Path, line: int, column: str, value: str) -> Path:
    """A copy of the highD fixture with one cell of 01_tracks.csv replaced (line 1 = header)."""
    for kind in ("tracks", "tracksMeta", "recordingMeta"):
        (tmp_path / f"01_{kind}.csv").write_bytes((HIGHD / f"01_{kind}.csv").read_bytes())
    path = tmp_path / "01_tracks.csv"
    lines = path.read_text().splitlines()
    header = lines[0].split(",")
    cells = lines[line - 1].split(",")
    cells[header.index(column)] = value
    lines[line - 1] = ",".join(cells)
    path.write_text("\n".join(lines) + "\n")
    return path


@pytest.mark.parametrize(
    ("column", "value", "expected"),
    [
        ("laneId", str(2**31), "within int32"),
        ("laneId", str(2**40), "within int32"),
        # lane changes are changes of laneId: -1, 0 or beyond the lower road edge (7) was a lane change
        # that never happened
        *(("laneId", lane, "a highD lane id, 1 to 7") for lane in ("-1", "0", "8")),
        ("width", "0.0", "a length > 0"),
        ("height", "-1.5", "a width > 0"),
        ("frame", "-3", "a frame from 0"),
        ("frame", str(2**62), "a frame from 0"),
        ("id", str(2**63), "within int64"),
    ],
)
def test_highd_values_out_of_range(tmp_path: Path, column: str, value: str, expected: str) -> None:
    path = _highd_variant(tmp_path, 3, column, value)
    with pytest.raises(InputError) as err:
        registry.read_any([path])
    assert err.value.path == str(path) and err.value.line == 3 and err.value.column == column
    assert expected in (err.value.expected or "")


@pytest.mark.parametrize("lane", ["1", "4", "2", "7"])
def test_highd_edge_median_and_other_carriageway_lanes_are_kept(tmp_path: Path, lane: str) -> None:
    """The road edges (1, 7), the median (4) or the other carriageway's lane (2) are areas of highD's
    numbering a real recording may place a vehicle in: read as given, not refused."""
    table = registry.read_any([_highd_variant(tmp_path, 3, "laneId", lane)])
    original = registry.read_any([HIGHD / "01_tracks.csv"])
    assert table.num_rows == original.num_rows
    changed = table.column("lane_id").to_numpy() != original.column("lane_id").to_numpy()
    assert changed.sum() == 1 and table.column("lane_id").to_numpy()[changed][0] == int(lane)


# ------------------------------------------------------------------------------------------- NGSIM

US101 = REPO / "tests" / "data" / "ngsim" / "us-101" / "trajectories-fixture.txt"
PEACHTREE = REPO / "tests" / "data" / "ngsim" / "peachtree_sample.csv"


def _txt_variant(tmp_path: Path, edits: dict[tuple[int, int], str]) -> Path:
    """The US-101 fixture with cells replaced: (1-based line, 0-based field) → text."""
    lines = [line.split() for line in US101.read_text().splitlines()]
    for (line, field), value in edits.items():
        lines[line - 1][field] = value
    path = tmp_path / "us-101" / "trajectories-edit.txt"
    path.parent.mkdir(exist_ok=True)
    path.write_text("\n".join("  ".join(cells) for cells in lines) + "\n")
    return path


def test_ngsim_ids_beyond_2_53_stay_distinct(tmp_path: Path) -> None:
    """Vehicles 2^53 and 2^53 + 1 are two vehicles (float64 would merge them and drop rows)."""
    lines = US101.read_text().splitlines()
    ids = {line.split()[0] for line in lines}
    edits = {}
    for i, line in enumerate(lines, start=1):
        vid = line.split()[0]
        if vid == "1":
            edits[(i, 0)] = str(2**53)
        elif vid == "2":
            edits[(i, 0)] = str(2**53 + 1)
    table = registry.read_any([_txt_variant(tmp_path, edits)])
    original = registry.read_any([US101])
    got = set(table.column("track_id").to_pylist())
    assert {2**53, 2**53 + 1} <= got and len(got) == len(ids)
    assert table.num_rows == original.num_rows


@pytest.mark.parametrize(
    ("field", "value", "column", "expected"),
    [
        (1, str(2**62), "Frame_ID", "0 to"),
        (1, "-5", "Frame_ID", "0 to"),
        (3, "1e30", "Global_Time", "below 2^53"),
        (3, str(2**60), "Global_Time", "0 to 2^53"),
        (8, "0.0", "v_Length", "a length > 0"),
        (9, "-6.0", "v_Width", "a width > 0"),
        (11, "-40.0", "v_Vel", "a speed >= 0"),
        (13, str(2**33), "Lane_ID", "within int32"),
        (0, "9.3e18", "Vehicle_ID", "below 2^53"),
        (0, "-2", "Vehicle_ID", "a vehicle id >= 0"),  # was a phantom one-row track -2
    ],
)
def test_ngsim_values_out_of_range(
    tmp_path: Path, field: int, value: str, column: str, expected: str
) -> None:
    path = _txt_variant(tmp_path, {(5, field): value})
    with pytest.raises(InputError) as err:
        registry.read_any([path])
    assert err.value.path == str(path) and err.value.line == 5 and err.value.column == column
    assert expected in (err.value.expected or "")


def test_ngsim_stray_global_time_makes_no_phantom_recording(tmp_path: Path) -> None:
    path = _txt_variant(tmp_path, {(5, 3): "1118846990000"})  # one row 9 s off its vehicle's epoch
    with pytest.raises(InputError, match=r"recording period of its own|another recording period") as err:
        registry.read_any([path])
    assert err.value.line == 5 and err.value.column == "Global_Time"


def test_ngsim_conflicting_duplicates_are_reported(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = _txt_variant(tmp_path, {(4, 5): "109.000"})  # line 4 repeats line 3's (vehicle, frame)
    original = registry.read_any([US101])
    before = capsys.readouterr().err
    table = registry.read_any([path])
    after = capsys.readouterr().err
    assert "rows repeat a (Vehicle_ID, Frame_ID)" in after and after != before
    assert table.column("x").equals(original.column("x"))  # the first in file order is kept


def _quoted(source: Path, target: Path, line: int, edit: Callable[[str], str]) -> Path:
    """A copy of ``source`` (its first 200 lines) with ``edit`` applied to ``line`` (1 = header)."""
    lines = source.read_text().splitlines()[:200]
    lines[line - 1] = edit(lines[line - 1])
    target.write_text("\n".join(lines) + "\n")
    return target


@pytest.mark.parametrize(
    ("victim", "edit"),
    [
        ("peachtree.csv", lambda text: text.replace(",peachtree", ',"peachtree')),  # the Location
        ("peachtree.csv", lambda text: '"' + text),  # the first value
        ("peachtree.csv", lambda text: text.replace(",", ',"', 3)),  # numbers
        ("01_tracksMeta.csv", lambda text: text.replace(",Truck", ',"Truck')),  # highD's class
        ("01_tracks.csv", lambda text: '"' + text),
    ],
)
def test_an_open_quote_that_swallows_the_lines_after_it_is_refused_at_its_line(
    tmp_path: Path, victim: str, edit: Callable[[str], str]
) -> None:
    """A quoted value that runs on over line ends: the CSV parser read the rest of the file as one
    value and kept a single row, silently (the fuzzer found it in NGSIM's Location column). No
    dataset lanecast reads quotes across lines."""
    for kind in ("tracks", "tracksMeta", "recordingMeta"):
        (tmp_path / f"01_{kind}.csv").write_bytes((HIGHD / f"01_{kind}.csv").read_bytes())
    source = PEACHTREE if victim == "peachtree.csv" else HIGHD / victim
    path = _quoted(source, tmp_path / victim, 3, edit)
    with pytest.raises(InputError, match="double quote opens a value") as err:
        registry.read_any([path])
    assert err.value.path == str(path) and err.value.line == 3


def test_an_open_quote_in_a_location_is_refused_by_the_streaming_reader_too(tmp_path: Path) -> None:
    from lanecast.io_adapters.datasets.ngsim import stream as ngsim_stream

    path = _quoted(
        PEACHTREE, tmp_path / "peachtree.csv", 3, lambda text: text.replace(",peachtree", ',"peachtree')
    )
    with pytest.raises(InputError, match="double quote opens a value") as err:
        ngsim_stream.split_csv(path, tmp_path / "spill")
    assert err.value.line == 3


def test_peachtree_vehicle_570_heading_does_not_flip() -> None:
    """Its front bumper first runs 4 m backwards (a tracking glitch), then it stops and drives
    north: the heading stays north through the stop, so the centre does not jump a vehicle length
    when it moves off (it did: 8.86 m between frames 3389 and 3390)."""
    import pandas as pd

    table = registry.read_any([PEACHTREE])
    rows = table.filter(pa.compute.equal(table.column("track_id"), 570)).to_pandas()
    rows = rows[rows.recording == rows.recording.iloc[0]].sort_values("frame")
    assert rows.frame.iloc[0] == 3345 and rows.frame.iloc[-1] == 3439
    heading = np.degrees(rows.heading.to_numpy())
    assert np.abs(heading).max() < 30  # north (+x) all along
    centre_step = np.hypot(np.diff(rows.x.to_numpy()), np.diff(rows.y.to_numpy()))
    source = pd.read_csv(PEACHTREE)
    src = source[source.Vehicle_ID == 570].sort_values("Frame_ID")
    bumper_step = 0.3048 * np.hypot(np.diff(src.Local_X.to_numpy()), np.diff(src.Local_Y.to_numpy()))
    frames = rows.frame.to_numpy()
    at_3389 = int(np.flatnonzero(frames == 3389)[0])
    assert centre_step[at_3389] < 0.5
    # Per frame the centre moves < 0.5 m beyond what the front bumper itself moves (the source's
    # own first steps are 2.3 m: the glitch) and < 0.5 m wherever the bumper moves < 0.45 m.
    assert (centre_step - bumper_step).max() < 0.5
    assert (centre_step[bumper_step < 0.45] < 0.5).all()


# ------------------------------------------------------------------------------------- model cards


def _model_copy(tmp_path: Path, edit: object = None) -> Path:
    from lanecast.models.card import SHIPPED_STEM, WEIGHTS_DIR

    out = tmp_path / "model"
    out.mkdir()
    for suffix in (".safetensors", ".json"):
        (out / f"stcnn{suffix}").write_bytes((WEIGHTS_DIR / f"{SHIPPED_STEM}{suffix}").read_bytes())
    if edit is not None:
        card = json.loads((out / "stcnn.json").read_text())
        edit(card)  # type: ignore[operator]
        (out / "stcnn.json").write_text(json.dumps(card))
    return out


def _set(path: str, value: object) -> object:
    def edit(card: dict[str, object]) -> None:
        *parents, last = path.split(".")
        node = card
        for key in parents:
            node = node[key]  # type: ignore[index, assignment]
        node[last] = value  # type: ignore[index]

    return edit


@pytest.mark.parametrize(
    ("field", "value"),
    [
        ("format_version", "1"),
        ("architecture.config.hidden", 2**40),
        ("architecture.config.conv_channels", [24, -40, 56, 24]),
        ("architecture.config.conv_kernels", [[5, 10], [3], [2, 3], [1, 1]]),
        ("architecture.config.channels", 0),
        ("normalisation.inputs.std", [1.0, 1.0, 0.0, 1.0]),
        ("normalisation.inputs.mean", [1.0, "x", 0.0, 1.0]),
        ("normalisation.future.std", -1.0),
        ("normalisation.future.mean", [1.0, 2.0]),
        ("normalisation", []),
        ("architecture.config.conv_dilations", [[1, 2], [1, 2], [1, 1]]),
        ("training", [1]),
        ("training.config", 3),
        ("training.data.distribution.speed_mps", {"p0.5": "slow", "p99.5": 40.0}),
        ("training.data.distribution.lon_acc_mps2", {"p0.5": 3.0, "p99.5": -3.0}),
        ("windows.neighbour_range_m", -5),
    ],
)
def test_model_card_with_wrong_types_is_refused_naming_the_card(
    tmp_path: Path, field: str, value: object
) -> None:
    from lanecast.models.checkpoint import load_checkpoint

    model = _model_copy(tmp_path, _set(field, value))
    with pytest.raises(InputError) as err:
        load_checkpoint(model)
    assert err.value.path == str(model / "stcnn.json")
    assert err.value.column is not None and err.value.column.startswith(field.split(".")[0])


@pytest.mark.parametrize(
    ("model", "column"),
    [
        (5, "model"),
        ({"hidden": -3}, "model.hidden"),
        ({"hidden": 10**8}, "model.hidden"),
        ({"conv_kernels": [[3, 3]]}, "model.conv_kernels"),
    ],
)
def test_training_config_with_a_bad_model_is_refused_before_torch(
    tmp_path: Path, model: object, column: str
) -> None:
    from lanecast.models.train import TrainConfig

    config = tmp_path / "config.json"
    config.write_text(json.dumps({"epochs": 1, "model": model}))
    with pytest.raises(InputError) as err:
        TrainConfig.from_file(config)
    assert err.value.path == str(config)
    assert err.value.column == column


def test_training_config_with_kernels_larger_than_the_window_is_refused(tmp_path: Path) -> None:
    from lanecast.models.train import TrainConfig

    config = tmp_path / "config.json"
    config.write_text(json.dumps({"model": {"conv_kernels": [[9, 30], [3, 3], [2, 3], [1, 1]]}}))
    with pytest.raises(InputError, match="conv1 leaves no output"):
        TrainConfig.from_file(config)


def test_model_card_nan_is_not_json_and_nan_weights_are_refused(tmp_path: Path) -> None:
    import torch
    from safetensors.torch import load_file, save_file

    from lanecast.models.checkpoint import load_checkpoint

    model = _model_copy(tmp_path)
    card = (model / "stcnn.json").read_text()
    (model / "stcnn.json").write_text(card.replace('"std": [', '"std": [NaN, ', 1))
    with pytest.raises(InputError, match="model card") as err:
        load_checkpoint(model)
    assert err.value.path == str(model / "stcnn.json")
    (model / "stcnn.json").write_text(card)
    state = load_file(str(model / "stcnn.safetensors"))
    name = sorted(state)[0]
    state[name] = state[name].clone()
    state[name].view(-1)[0] = torch.nan
    save_file(state, str(model / "stcnn.safetensors"))
    with pytest.raises(InputError, match=f"tensor '{name}' holds NaN") as err:
        load_checkpoint(model)
    assert err.value.path == str(model / "stcnn.safetensors")


def test_weights_of_another_run_under_a_card_are_refused(tmp_path: Path) -> None:
    """save_checkpoint writes the weights, then the card (two renames): a run stopped between them
    leaves new weights under the old card. The card names its weights' SHA-256, so that pair is
    refused instead of served; a card without the field (written before it) still loads."""
    import torch

    from lanecast.models.card import SHIPPED_STEM, WEIGHTS_DIR, file_sha256
    from lanecast.models.checkpoint import load_checkpoint, save_checkpoint

    net, card = load_checkpoint(None)
    assert card["weights_sha256"] == file_sha256(WEIGHTS_DIR / f"{SHIPPED_STEM}.safetensors")
    first, other = tmp_path / "first", tmp_path / "other"
    save_checkpoint(net, card, first)
    load_checkpoint(first)
    with torch.no_grad():
        next(net.parameters()).add_(0.01)  # another run's weights
    save_checkpoint(net, card, other)
    (first / "stcnn.safetensors").write_bytes((other / "stcnn.safetensors").read_bytes())
    with pytest.raises(InputError, match="not the weights file this card was written with") as err:
        load_checkpoint(first)
    assert err.value.path == str(first / "stcnn.json") and err.value.column == "weights_sha256"
    older = json.loads((first / "stcnn.json").read_text())
    del older["weights_sha256"]
    (first / "stcnn.json").write_text(json.dumps(older))
    reloaded, _ = load_checkpoint(first)
    assert torch.equal(next(reloaded.parameters()), next(net.parameters()))


def test_annotate_with_a_bad_card_is_one_clean_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    model = _model_copy(tmp_path, _set("architecture.config.hidden", 2**40))
    log = json_log(tmp_path / "in.mcap", straight_messages(n=60))
    status, err = cli(["annotate", str(log), "--model", str(model), "--out", str(tmp_path / "out")], capsys)
    assert status == 2 and "stcnn.json" in err and "hidden" in err
    assert "Traceback" not in err


@pytest.mark.parametrize(
    ("damage", "match"),
    [
        (lambda b: b[: len(b) // 2], "unreadable weights"),
        (lambda b: b"", "unreadable weights"),
        (lambda b: b[:8] + b[8:].replace(b'"F32"', b'"F16"', 1), "unreadable weights|do not fit"),
    ],
)
def test_annotate_with_bad_weights_leaves_no_trace(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], damage: object, match: str
) -> None:
    """Truncated, empty or mistyped weights failed per log, after OUT_DIR got a manifest.jsonl and a
    lock file: the model is now loaded (as the logs will be) before anything is created."""
    import re

    model = _model_copy(tmp_path)
    weights = model / "stcnn.safetensors"
    weights.write_bytes(damage(weights.read_bytes()))  # type: ignore[operator]
    log = json_log(tmp_path / "in.mcap", straight_messages(n=60))
    out = tmp_path / "out"
    status, err = cli(["annotate", str(log), "--model", str(model), "--out", str(out)], capsys)
    assert status == 2 and err.startswith(f"lanecast annotate: error: {weights}") and re.search(match, err), (
        err
    )
    assert not out.exists()


def test_an_onnx_export_onnx_runtime_cannot_load(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """An .onnx file the card vouches for (its sha256 updated) that is not ONNX escaped as
    onnxruntime's InvalidProtobuf traceback; now ``engine="onnx"`` refuses it naming the file and
    ``"auto"`` predicts with torch, saying why. (A file that differs from the card's checksum was
    already never used.)"""
    from lanecast.models.card import SHIPPED_STEM, WEIGHTS_DIR, file_sha256
    from lanecast.models.predict import STCNNForecaster
    from lanecast.models.runtime import load_forecaster

    model = tmp_path / "model"
    model.mkdir()
    for suffix in (".safetensors", ".json", ".onnx"):
        (model / f"{SHIPPED_STEM}{suffix}").write_bytes(
            (WEIGHTS_DIR / f"{SHIPPED_STEM}{suffix}").read_bytes()
        )
    onnx = model / f"{SHIPPED_STEM}.onnx"
    onnx.write_bytes(b"not onnx" * 100)
    card_path = model / f"{SHIPPED_STEM}.json"
    card = json.loads(card_path.read_text())
    card["onnx"]["sha256"] = file_sha256(onnx)
    card_path.write_text(json.dumps(card))
    with pytest.raises(InputError, match="ONNX Runtime cannot load it") as err:
        load_forecaster(model, engine="onnx")
    assert err.value.path == str(onnx)
    capsys.readouterr()
    assert isinstance(load_forecaster(model), STCNNForecaster)
    assert f"{SHIPPED_STEM}.onnx: ONNX Runtime cannot load it" in capsys.readouterr().err


# --------------------------------------------------------------------------------------- ROS bags


def test_ros2_mcap_bags_are_written_with_crcs_and_checked(tmp_path: Path) -> None:
    from mcap.reader import make_reader

    from lanecast.io_adapters.logs.rosbag import reader as rosbag_reader
    from lanecast.io_adapters.logs.rosbag import writer as rosbag_writer

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


def test_damaged_zstd_chunks_of_a_log_are_a_clean_error(tmp_path: Path) -> None:
    """Flipped bytes inside a zstd-compressed chunk (lanecast's own MCAP logs are zstd) are refused
    as a LogError naming the file, whether zstd or the chunk CRC notices first."""
    table = registry.read_any([US101])
    log = registry.write_any(table, tmp_path / "log.mcap", "mcap")
    data = log.read_bytes()
    pos = 8  # after the magic: walk the records (opcode u8, length u64) to the first chunk
    while data[pos] != 0x06:
        pos += 9 + struct.unpack_from("<Q", data, pos + 1)[0]
    (length,) = struct.unpack_from("<Q", data, pos + 1)
    assert data[pos + 9 + 28 : pos + 9 + 32] == b"\x04\x00\x00\x00"  # the compression string "zstd"
    assert data[pos + 9 + 32 : pos + 9 + 36] == b"zstd"
    records_start = pos + 9 + 36 + 8
    for at in np.linspace(records_start + 8, pos + 9 + length - 8, 6).astype(int):
        bad = bytearray(data)
        bad[at] ^= 0xFF
        damaged = tmp_path / f"damaged-{at}.mcap"
        damaged.write_bytes(bytes(bad))
        with pytest.raises(LogError) as err:
            registry.read_any([damaged])
        assert err.value.path == str(damaged)


# ------------------------------------------------------------------------- the output directory


def test_planted_lock_and_manifest_symlinks_touch_nothing_outside(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    log = json_log(tmp_path / "in.mcap", straight_messages(n=60))
    victim = tmp_path / "victim.txt"
    victim.write_text("precious\n")
    out = tmp_path / "out"
    out.mkdir()
    (out / ".lanecast-annotate.lock").symlink_to(victim)
    status, err = cli(["annotate", str(log), "--out", str(out)], capsys)
    assert_one_line_error(status, err, "annotate", ".lanecast-annotate.lock")
    assert "symlink" in err and victim.read_text() == "precious\n"
    (out / ".lanecast-annotate.lock").unlink()
    (out / "manifest.jsonl").symlink_to(victim)
    status, err = cli(["annotate", str(log), "--out", str(out)], capsys)
    assert_one_line_error(status, err, "annotate", "manifest.jsonl")
    assert victim.read_text() == "precious\n"


def test_forged_manifest_entry_does_not_skip_a_log(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    log = json_log(tmp_path / "in.mcap", straight_messages(n=60))
    out = tmp_path / "out"
    assert main(["annotate", str(log), "--out", str(out)]) == 0
    capsys.readouterr()
    manifest = out / "manifest.jsonl"

    def done() -> list[dict[str, object]]:
        return [e for e in map(json.loads, manifest.read_text().splitlines()) if e["status"] == "done"]

    (entry,) = done()
    assert isinstance(entry["output_sha256"], str)
    # a second run skips the log: its output is there with the recorded checksum
    lines = manifest.read_text()
    assert main(["annotate", str(log), "--out", str(out)]) == 0
    assert manifest.read_text() == lines
    # a forged line: the output is elsewhere (a system file), size and mtime as recorded
    outside = tmp_path / "system-file"
    outside.write_bytes((out / "in.mcap").read_bytes())
    planted = outside.stat().st_mtime_ns
    (out / "in.mcap").unlink()
    forged = {**entry, "output": str(outside)}
    manifest.write_text(json.dumps(forged) + "\n")
    assert main(["annotate", str(log), "--out", str(out)]) == 0
    assert (out / "in.mcap").is_file() and len(done()) == 2
    assert outside.stat().st_mtime_ns == planted  # a forged name is never written to
    # an output changed since it was recorded is redone
    data = bytearray((out / "in.mcap").read_bytes())
    data[100] ^= 1
    (out / "in.mcap").write_bytes(bytes(data))
    assert main(["annotate", str(log), "--out", str(out)]) == 0
    assert len(done()) == 3
    assert (out / "in.mcap").read_bytes() != bytes(data)


def test_values_beyond_float32_are_refused_at_their_line(tmp_path: Path) -> None:
    path = _highd_variant(tmp_path, 3, "xVelocity", "1e300")
    with pytest.raises(InputError) as err:
        registry.read_any([path])
    assert (err.value.line, err.value.column) == (3, "xVelocity")
    path = _txt_variant(tmp_path, {(5, 12): "-1e308"})  # v_Acc
    with pytest.raises(InputError) as err:
        registry.read_any([path])
    assert (err.value.line, err.value.column) == (5, "v_Acc")


def test_two_inputs_with_one_recording_name_are_named(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    a = track_table.write_parquet(registry.read_any([US101]), tmp_path / "a.parquet")
    b = tmp_path / "b.parquet"
    b.write_bytes(a.read_bytes())
    status, err = cli(["convert", str(a), str(b), "--out", str(tmp_path / "c.parquet")], capsys)
    assert_one_line_error(status, err.splitlines()[-1], "convert", str(b))
    assert str(a) in err


@pytest.mark.parametrize(("fmt", "storage", "name"), [("ros1", "sqlite3", "b.bag"), ("ros2", "sqlite3", "b")])
def test_own_bags_without_checksums_carry_a_payload_digest(
    tmp_path: Path, fmt: str, storage: str, name: str
) -> None:
    """ROS 1 and sqlite3 bags have no checksum: lanecast's metadata holds one of every message."""
    from lanecast.io_adapters.logs.rosbag import reader as rosbag_reader
    from lanecast.io_adapters.logs.rosbag import writer as rosbag_writer

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


def test_a_ros2_bag_without_metadata_yaml_says_so(tmp_path: Path) -> None:
    """A ROS 2 bag directory whose metadata.yaml was lost said only 'format not recognised'."""
    bag = tmp_path / "bag"
    bag.mkdir()
    (bag / "bag_0.db3").write_bytes(b"SQLite format 3\x00" + bytes(100))
    with pytest.raises(LanecastError, match=r"holds 'bag_0\.db3' but no metadata\.yaml") as err:
        registry.read_any([bag])
    assert str(bag) in str(err.value)


@pytest.mark.parametrize(
    ("name", "content", "expected"),
    [
        ("log.mcap", b"garbage, not a log", r"an MCAP file, which starts with b'\\x89MCAP0"),
        ("log.bag", b"#ROSX V2.0\n" + bytes(40), r"a ROS 1 bag, which starts with b'#ROSBAG V2\.0"),
        (
            "bag_0.db3",
            b"not sqlite at all" + bytes(40),
            r"SQLite storage, which starts with b'SQLite format 3",
        ),
    ],
)
def test_a_log_named_by_its_suffix_that_is_not_one_names_its_first_bytes(
    tmp_path: Path, name: str, content: bytes, expected: str
) -> None:
    """A file named .mcap, .bag or .db3 whose content is not was only 'format not recognised'."""
    path = tmp_path / name
    path.write_bytes(content)
    with pytest.raises(LanecastError, match=expected) as err:
        registry.read_any([path])
    assert f"{path}, offset 0: format not recognised: the file is named {path.suffix} but starts with" in str(
        err.value
    )


def test_a_model_given_where_data_goes_is_named_as_a_model(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A model directory (or its weights) given to info, windows, evaluate or train was 'format
    not recognised' or 'inputs.npy: missing file of a windows dataset'."""
    model = _model_copy(tmp_path)
    weights = next(model.glob("*.safetensors"))
    for argv, named, words in (
        (["info", str(model)], model, "a model (the output of `lanecast train`), not a dataset or log"),
        (["info", str(weights)], weights, "a model (the output of `lanecast train`), not a dataset or log"),
        (["windows", str(model), "--out", str(tmp_path / "w")], model, "not a dataset or log"),
        (["evaluate", str(model), "--out", str(tmp_path / "e")], model, "a model directory (the output of"),
        (["train", str(model), "--out", str(tmp_path / "t")], model, "not a windows dataset"),
    ):
        assert main(argv) == 2
        err = capsys.readouterr().err
        assert f"error: {named}: " in err and words in err and "--model or --init" in err, err
    assert not any((tmp_path / name).exists() for name in ("w", "e", "t"))


def test_a_recording_of_highds_sister_datasets_is_named_as_one(tmp_path: Path) -> None:
    """inD/rounD/exiD files (recordingId, trackId, xCenter; same file names as highD) were refused as
    a highD recordingMeta without column 'id', as if one column were missing."""
    (tmp_path / "00_tracks.csv").write_text(
        "recordingId,trackId,frame,trackLifetime,xCenter,yCenter,heading,width,length,xVelocity,yVelocity\n"
        "0,0,0,0,10.0,-5.0,90.0,1.8,4.5,0.0,2.0\n"
    )
    (tmp_path / "00_tracksMeta.csv").write_text(
        "recordingId,trackId,initialFrame,finalFrame,numFrames,width,length,class\n0,0,0,0,1,1.8,4.5,car\n"
    )
    (tmp_path / "00_recordingMeta.csv").write_text(
        "recordingId,locationId,frameRate,speedLimit,weekday,startTime,duration\n0,1,25,13.89,monday,8,1000\n"
    )
    with pytest.raises(InputError, match="highD's sister datasets \\(inD, rounD, exiD") as err:
        registry.read_any([tmp_path])
    assert err.value.path == str(tmp_path / "00_recordingMeta.csv") and err.value.line == 1


# ------------------------------------------------------------------------------- wave 8: tables


def _cell_edit(column: str, value: str) -> Callable[[str], str]:
    """An edit for :func:`_quoted` replacing the (unquoted) ``column`` of a highD tracks or NGSIM CSV line."""

    def edit(text: str) -> str:
        header = (HIGHD / "01_tracks.csv" if column == "x" else PEACHTREE).read_text().split("\n", 1)[0]
        cells = text.split(",")
        cells[header.split(",").index(column)] = value
        return ",".join(cells)

    return edit


@pytest.mark.parametrize(
    ("victim", "column", "value"),
    [
        ("01_tracks.csv", "x", '"952,93"'),  # a decimal comma, quoted by the spreadsheet that wrote it
        ("01_tracks.csv", "x", '"1,952.5"'),  # a thousands separator
        ("peachtree.csv", "Local_Y", '"4,566"'),
    ],
)
def test_a_quoted_comma_is_a_bad_cell_not_a_wrong_field_count(
    tmp_path: Path, victim: str, column: str, value: str
) -> None:
    """A comma inside a quoted value separates no fields: the CSV parser reads the line's fields
    right, so the error names the cell that is no number, not "wrong number of fields"."""
    for kind in ("tracks", "tracksMeta", "recordingMeta"):
        (tmp_path / f"01_{kind}.csv").write_bytes((HIGHD / f"01_{kind}.csv").read_bytes())
    source = PEACHTREE if victim == "peachtree.csv" else HIGHD / victim
    path = _quoted(source, tmp_path / victim, 3, _cell_edit(column, value))
    with pytest.raises(InputError) as err:
        registry.read_any([path])
    assert (err.value.path, err.value.line, err.value.column) == (str(path), 3, column)
    assert value.strip('"') in str(err.value) and "number of fields" not in str(err.value)


@pytest.mark.parametrize(
    ("victim", "edit", "match", "line"),
    [
        # a Latin-1 "é" (a file saved by a spreadsheet in the locale's encoding): pyarrow's message
        # named a column number and no line
        ("01_tracksMeta.csv", lambda text: text.replace(",Car,", ",C\xe9r,", 1), "not UTF-8", 2),
        ("01_tracks.csv", lambda text: text.replace(",", "\xe9,", 1), "not UTF-8", 3),
        ("peachtree.csv", lambda text: text.replace(",peachtree", ",peacht\xe9ree"), "not UTF-8", 3),
        # a line longer than the parser's block: "straddling object straddles two block boundaries"
        ("01_tracks.csv", lambda text: text.replace(",", "," + "0" * (1 << 21), 1), "a line of 2,097,", 3),
        (
            "peachtree.csv",
            lambda text: text.replace(",peachtree", ",peachtree" + "x" * (1 << 21)),
            "a line of",
            3,
        ),
    ],
)
def test_bytes_the_csv_parser_cannot_read_as_text_are_named_at_their_line(
    tmp_path: Path, victim: str, edit: Callable[[str], str], match: str, line: int
) -> None:
    for kind in ("tracks", "tracksMeta", "recordingMeta"):
        (tmp_path / f"01_{kind}.csv").write_bytes((HIGHD / f"01_{kind}.csv").read_bytes())
    source = PEACHTREE if victim == "peachtree.csv" else HIGHD / victim
    path = _quoted(source, tmp_path / victim, line, edit)
    path.write_bytes(path.read_text().encode("latin-1"))
    with pytest.raises(InputError, match=match) as err:
        registry.read_any([path])
    assert err.value.path == str(path) and err.value.line == line


def test_json_with_a_utf8_byte_order_mark_is_read(tmp_path: Path) -> None:
    """Windows editors save "UTF-8" JSON with a BOM: a training config or a windows manifest.json
    so saved was refused ("Unexpected UTF-8 BOM")."""
    from lanecast.models.train import TrainConfig

    config = tmp_path / "config.json"
    config.write_bytes(b'\xef\xbb\xbf{\r\n  "epochs": 3\r\n}\r\n')
    assert TrainConfig.from_file(config).epochs == 3
    directory = save_windows(synthetic_windows(n=20), tmp_path / "windows")
    manifest = directory / "manifest.json"
    manifest.write_bytes(b"\xef\xbb\xbf" + manifest.read_bytes())
    assert load_windows(directory).manifest == json.loads(manifest.read_bytes()[3:])


def test_a_training_config_that_is_a_fifo_is_refused_without_reading_it(tmp_path: Path) -> None:
    """`--config` naming a FIFO blocked forever, /dev/zero ran out of memory (MemoryError traceback)."""
    import threading

    from lanecast.models.train import TrainConfig

    fifo = tmp_path / "config.json"
    os.mkfifo(fifo)

    def unblock() -> None:  # should the read block again, give it a document: the test fails, not hangs
        with open(fifo, "w") as fh:
            fh.write("{}")

    writer = threading.Timer(5.0, unblock)
    writer.daemon = True
    writer.start()
    try:
        with pytest.raises(InputError, match="not a regular file") as err:
            TrainConfig.from_file(fifo)
    finally:
        writer.cancel()
    assert err.value.path == str(fifo)


@pytest.mark.parametrize(
    ("column", "value", "shown"),
    [("track_id", None, "null"), ("recording", None, "null"), ("origin_x", float("nan"), "nan")],
)
def test_a_windows_index_with_nulls_is_refused_at_its_row(
    tmp_path: Path, column: str, value: object, shown: str
) -> None:
    """A null track_id in windows.parquet was trained on and evaluated silently."""
    directory = save_windows(synthetic_windows(n=20), tmp_path / "windows")
    index = pq.read_table(directory / "windows.parquet")
    values = index.column(column).to_pylist()
    values[7] = value
    i = index.schema.get_field_index(column)
    index = index.set_column(i, index.schema.field(column), pa.array(values, index.schema.field(column).type))
    pq.write_table(index, directory / "windows.parquet")
    with pytest.raises(InputError, match=f"row 7: {column} is {shown}") as err:
        load_windows(directory)
    assert err.value.path == str(directory / "windows.parquet") and err.value.column == column


def test_a_windows_index_row_written_twice_is_named(tmp_path: Path) -> None:
    """A row of windows.parquet repeated (the fuzzer's seed 100071) gave only "windows index has
    21 rows, the arrays 20 windows", naming no row."""
    directory = save_windows(synthetic_windows(n=20), tmp_path / "windows")
    index = pq.read_table(directory / "windows.parquet")
    pq.write_table(
        pa.concat_tables([index.slice(0, 12), index.slice(5, 1), index.slice(12)]),
        directory / "windows.parquet",
    )
    with pytest.raises(InputError, match="21 rows, the arrays 20 windows; row 12 repeats row 5") as err:
        load_windows(directory)
    assert err.value.path == str(directory / "windows.parquet")


@pytest.mark.parametrize("command", ["convert", "info"])
def test_a_dataset_part_that_is_no_parquet_is_named(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], command: str
) -> None:
    """A CSV saved under a part's name in a dataset directory made the whole directory "format not
    recognised", naming neither the part nor what is wrong with it."""
    dataset = tmp_path / "dataset"
    dataset.mkdir()
    _parquet(dataset)[0].rename(dataset / "part-00000.parquet")
    (dataset / "src.mcap").unlink()
    (dataset / "part-00001.parquet").write_bytes((HIGHD / "01_tracks.csv").read_bytes())
    args = [command, str(dataset)] + (
        ["--out", str(tmp_path / "out.parquet")] if command == "convert" else []
    )
    status, err = cli(args, capsys)
    assert_one_line_error(status, err, command, str(dataset / "part-00001.parquet"))
    assert "Parquet" in err and not (tmp_path / "out.parquet").exists()


@pytest.mark.parametrize("form", ["highd", "ngsim-txt", "ngsim-csv"])
def test_a_huge_bad_cell_is_shown_cut_short(tmp_path: Path, form: str) -> None:
    """A damaged file's bad "cell" may be megabytes (a run of NULs after a crash): the one-line error
    quoted all of it."""
    junk = "7" + "z" * 100_000
    if form == "highd":
        path = _highd_variant(tmp_path, 3, "x", junk)
    elif form == "ngsim-txt":
        path = _txt_variant(tmp_path, {(3, 5): junk})
    else:
        path = _quoted(PEACHTREE, tmp_path / "peachtree.csv", 3, _cell_edit("Local_Y", junk))
    with pytest.raises(InputError) as err:
        registry.read_any([path])
    assert err.value.line == 3 and "'7zzz" in str(err.value) and "100,001 characters" in str(err.value)
    assert len(str(err.value)) < 400


@pytest.mark.parametrize("form", ["highd", "ngsim-txt", "ngsim-csv"])
def test_files_with_carriage_returns_alone_as_line_ends_are_read(tmp_path: Path, form: str) -> None:
    """Line ends of a lone CR (old Mac editors and exports): an NGSIM .txt was "format not
    recognised" and a highD recording had a header "line" of the whole file ("no column ...");
    the parsers read such line ends, and the header detection now does too."""
    if form == "highd":
        sources = [HIGHD / f"01_{kind}.csv" for kind in ("tracks", "tracksMeta", "recordingMeta")]
    else:
        sources = [US101 if form == "ngsim-txt" else PEACHTREE]
    for source in sources:
        lines = source.read_bytes().split(b"\n")[:300]
        (tmp_path / source.name).write_bytes(b"\r".join(line.rstrip(b"\r") for line in lines) + b"\r")
        (tmp_path / "lf").mkdir(exist_ok=True)
        (tmp_path / "lf" / source.name).write_bytes(b"\n".join(lines) + b"\n")
    got = registry.read_any([tmp_path / sources[0].name])
    want = registry.read_any([tmp_path / "lf" / sources[0].name])
    assert got.num_rows > 0 and got.select(got.column_names[1:]).equals(want.select(want.column_names[1:]))
    if form == "ngsim-txt":  # a bad cell in such a file is named at its line
        path = tmp_path / sources[0].name
        lines = path.read_bytes().split(b"\r")
        lines[4] = lines[4].replace(lines[4].split()[5], b"x", 1)
        path.write_bytes(b"\r".join(lines))
        with pytest.raises(InputError) as err:
            registry.read_any([path])
        assert err.value.line == 5 and err.value.column == "Local_Y"


def _folder_with(tmp_path: Path, form: str) -> tuple[Path, str]:
    """An input folder of ``form`` with one good file, and the name under which to plant an entry."""
    folder = tmp_path / "in"
    folder.mkdir()
    if form == "ngsim":
        (folder / US101.name).write_bytes(US101.read_bytes())
        return folder, "x.txt"
    if form == "highd":
        for kind in ("tracks", "tracksMeta", "recordingMeta"):
            (folder / f"01_{kind}.csv").write_bytes((HIGHD / f"01_{kind}.csv").read_bytes())
        return folder, "02_tracks.csv"
    _parquet(tmp_path)[0].rename(folder / "part-00000.parquet")
    return folder, "part-00001.parquet"


@pytest.mark.parametrize("form", ["ngsim", "highd", "parquet"])
@pytest.mark.parametrize("entry", ["fifo", "device", "dangling link"])
def test_an_entry_of_an_input_folder_that_is_no_file_is_named(tmp_path: Path, form: str, entry: str) -> None:
    """A FIFO, a link to /dev/zero or a link to nothing under a data file's name in an NGSIM folder,
    a highD folder or a Parquet dataset was left out without a word (its rows silently missing);
    it is refused naming it, and never opened (a FIFO would block the run)."""
    folder, name = _folder_with(tmp_path, form)
    planted = folder / name
    if entry == "fifo":
        os.mkfifo(planted)
    else:
        planted.symlink_to("/dev/zero" if entry == "device" else tmp_path / "gone.txt")
    with pytest.raises(InputError) as err:
        registry.read_any([folder])
    assert err.value.path == str(planted)
    words = "a symbolic link to a missing file" if entry == "dangling link" else "not a regular file"
    assert words in str(err.value)


@pytest.mark.parametrize("form", ["highd", "highd-streamed", "ngsim-txt", "ngsim-csv", "ngsim-csv-streamed"])
def test_a_header_repeated_mid_file_is_named_as_such(tmp_path: Path, form: str) -> None:
    """Two files joined into one (``cat a.csv b.csv``) put the header line amid the rows: it was
    refused as "cell 'frame' is not an integer" ('Vehicle_ID' is not a finite number), which sends
    a user looking for a bad value; now it says the header is there again, at its line."""
    from lanecast.io_adapters.datasets.highd import reader as highd
    from lanecast.io_adapters.datasets.highd import stream as highd_stream
    from lanecast.io_adapters.datasets.ngsim.reader import TXT_COLUMNS
    from lanecast.io_adapters.formats import streaming

    if form.startswith("highd"):
        source = HIGHD / "01_tracks.csv"
        for kind in ("tracksMeta", "recordingMeta"):
            (tmp_path / f"01_{kind}.csv").write_bytes((HIGHD / f"01_{kind}.csv").read_bytes())
    else:
        source = US101 if form == "ngsim-txt" else PEACHTREE
    lines = source.read_text().splitlines()[:50]
    header = "  ".join(TXT_COLUMNS) if form == "ngsim-txt" else lines[0]
    path = tmp_path / source.name
    path.write_text("\n".join([*lines[:4], header, *lines[4:]]) + "\n")
    with pytest.raises(InputError) as err:
        if form == "highd-streamed":
            highd_stream.split_tracks(highd.recordings([path])[0], tmp_path, block_bytes=1 << 10)
        elif form == "ngsim-csv-streamed":
            streaming.plan([path], spill_dir=tmp_path / "spill", stream_bytes=0)
        else:
            registry.read_any([path])
    assert err.value.path == str(path) and err.value.line == 5, str(err.value)
    assert ("column names" if form == "ngsim-txt" else "header line again") in str(err.value)


@pytest.mark.parametrize("name", ["inputs.npy", "manifest.json"])
@pytest.mark.parametrize("entry", ["fifo", "device"])
def test_a_windows_file_that_is_no_regular_file_says_so(tmp_path: Path, name: str, entry: str) -> None:
    """inputs.npy or manifest.json of a windows dataset as a FIFO or a link to /dev/zero was
    "missing file of a windows dataset" (the file is there); now 'not a regular file', unopened."""
    directory = save_windows(synthetic_windows(n=20), tmp_path / "windows")
    (directory / name).unlink()
    if entry == "fifo":
        os.mkfifo(directory / name)
    else:
        (directory / name).symlink_to("/dev/zero")
    with pytest.raises(InputError) as err:
        load_windows(directory)
    assert err.value.path == str(directory / name) and "not a regular file" in str(err.value)
