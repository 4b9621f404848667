"""ROS bag adapter: ROS 1 and ROS 2 (sqlite3, MCAP) round trips, independent reads, frames, topics."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pyarrow as pa
import pytest
from conftest import assert_same_table

from lanecast.io_adapters.contracts import track_table
from lanecast.io_adapters.errors import FrameError, LogError
from lanecast.io_adapters.formats import registry
from lanecast.io_adapters.logs import object_columns as to
from lanecast.io_adapters.logs.messages import ros_types
from lanecast.io_adapters.logs.rosbag import reader as rosbag_reader
from lanecast.io_adapters.logs.rosbag import writer as rosbag_writer

RATE = 10.0


def make_table(n_tracks: int = 3, n_frames: int = 25) -> pa.Table:
    """Two recordings of a few vehicles at 10 Hz; track 1 has no lane; classes include 'van'."""
    cols: dict[str, list[np.ndarray]] = {}
    metas = {}
    for ri, rec in enumerate(("north", "south")):
        for k in range(n_tracks):
            f = np.arange(n_frames) + 4 * k
            t = f / RATE
            heading = 0.4 * k - 0.3
            speed = 15.0 + 2 * k + 0.5 * t
            lane = np.where(np.arange(n_frames) < n_frames // 2, k + 1, k + 2).astype(float)
            values = {
                "recording": np.array([rec] * n_frames),
                "track_id": np.full(n_frames, 100 * ri + k + 1),
                "frame": f,
                "time_ns": np.rint(f * 1e9 / RATE).astype(np.int64) + ri * 7_000_000,
                "x": 5.0 * k + speed * t * math.cos(heading),
                "y": -3.0 * k + speed * t * math.sin(heading),
                "heading": np.full(n_frames, heading),
                "vx": speed * math.cos(heading),
                "vy": speed * math.sin(heading),
                "ax": np.full(n_frames, 0.5 * math.cos(heading)),
                "ay": np.full(n_frames, 0.5 * math.sin(heading)),
                "length": np.full(n_frames, 4.0 + 4 * k),
                "width": np.full(n_frames, 1.7 + 0.3 * k),
                "lane_id": np.full(n_frames, np.nan) if k == 0 else lane,
                "object_class": np.array([["car", "bus", "van"][k]] * n_frames),
            }
            for name, v in values.items():
                cols.setdefault(name, []).append(np.asarray(v))
        metas[rec] = track_table.RecordingMeta(RATE, "map", ["drive.bag"])
    columns = {k: np.concatenate(v) for k, v in cols.items()}
    table = track_table.build_table(columns, track_table.TableMeta("ros2", metas, ["drive.bag"]))
    track_table.validate(table)
    return table


CASES = [("ros2", "sqlite3", "bag2"), ("ros2", "mcap", "bag2m"), ("ros1", "sqlite3", "drive.bag")]


@pytest.mark.parametrize(("fmt", "storage", "name"), CASES)
def test_bag_round_trip(tmp_path: Path, fmt: str, storage: str, name: str) -> None:
    table = make_table()
    out = rosbag_writer.write(table, tmp_path / name, fmt, storage=storage)
    assert registry.detect(out) == "rosbag"
    back = rosbag_reader.read(out)
    assert_same_table(table, back)
    assert track_table.read_meta(back).source_format == "ros2"
    assert not list(tmp_path.glob(".*tmp*"))  # the temporary name is gone


def test_written_bags_read_by_anyreader_alone(tmp_path: Path) -> None:
    """rosbags' AnyReader decodes lanecast's bags from their own embedded definitions."""
    from rosbags.highlevel import AnyReader

    table = make_table()
    for fmt, storage, name in CASES:
        out = rosbag_writer.write(table, tmp_path / name, fmt, storage=storage)
        with AnyReader([out]) as reader:
            topics = {c.topic: c.msgtype for c in reader.connections}
            assert topics == {
                "/lanecast/metadata": "std_msgs/msg/String",
                "/tracked_objects/north": ros_types.TRACKED_OBJECTS,
                "/tracked_objects/north/markers": ros_types.MARKER_ARRAY,
                "/tracked_objects/south": ros_types.TRACKED_OBJECTS,
                "/tracked_objects/south/markers": ros_types.MARKER_ARRAY,
            }
            conns = [c for c in reader.connections if c.topic.startswith("/tracked_objects/north")]
            decoded = [
                (c.topic, t, reader.deserialize(raw, c.msgtype))
                for c, t, raw in reader.messages(connections=conns)
            ]
        objects = [(t, m) for topic, t, m in decoded if topic == "/tracked_objects/north"]
        # north: tracks start at frames 0, 4, 8 with 25 frames → frames 0..32 at 10 Hz.
        assert [t for t, _ in objects] == [f * 100_000_000 for f in range(33)]
        first = objects[0][1]
        assert first.header.frame_id == "map" and len(first.objects) == 1
        obj = first.objects[0]
        assert bytes(obj.object_id.uuid) == (1).to_bytes(8, "little") + bytes(8)
        assert obj.classification[0].label == 1  # CAR
        assert obj.kinematics.twist_with_covariance.twist.linear.x == pytest.approx(
            15.0, rel=1e-6
        )  # body frame: speed
        assert obj.kinematics.twist_with_covariance.twist.linear.y == pytest.approx(
            0.0, abs=1e-6
        )  # float32 columns
        assert obj.shape.dimensions.x == pytest.approx(4.0)
        markers = [m for topic, _, m in decoded if topic.endswith("/markers")]
        last = markers[-1].markers
        assert [(m.id, m.ns, m.text, m.type) for m in last] == [(3, "van", "lane_id=4", 1)]


def test_ros2_metadata_in_custom_data(tmp_path: Path) -> None:
    from ruamel.yaml import YAML  # rosbags' own YAML library

    out = rosbag_writer.write(make_table(), tmp_path / "bag", "ros2")
    info = YAML(typ="safe").load((out / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    doc = __import__("json").loads(info["custom_data"]["lanecast"])
    assert (
        doc["frame_rate"] == RATE
        and doc["units"]["vx"] == "m/s"
        and sorted(doc["recordings"]) == ["north", "south"]
    )
    assert (out / "bag.mcap").is_file()  # MCAP storage by default


def _ros1_bag(path: Path, with_tf: bool) -> Path:
    """A foreign ROS 1 bag: MarkerArray of one car in base_link; ego at (0, 0) turning, /tf optional."""
    from rosbags.rosbag1 import Writer

    store = ros_types.typestore(1)
    m = lambda name, **kw: ros_types.make(store, name, **kw)  # noqa: E731
    with Writer(path) as w:
        markers = w.add_connection("/viz/objects", ros_types.MARKER_ARRAY, typestore=store)
        tf = w.add_connection("/tf", ros_types.TF_MESSAGE, typestore=store) if with_tf else None
        for i in range(5):  # 5 Hz
            t = 2_000_000_000 + i * 200_000_000
            sec, nsec = divmod(t, 10**9)
            stamp = m("builtin_interfaces/msg/Time", sec=sec, nanosec=nsec)
            if tf is not None:
                yaw = 0.1 * i
                tr = m(
                    "geometry_msgs/msg/TransformStamped",
                    header=m("std_msgs/msg/Header", stamp=stamp, frame_id="odom"),
                    child_frame_id="base_link",
                    transform=m(
                        "geometry_msgs/msg/Transform",
                        translation=m("geometry_msgs/msg/Vector3", x=2.0 * i, y=0.0, z=0.0),
                        rotation=m(
                            "geometry_msgs/msg/Quaternion",
                            x=0.0,
                            y=0.0,
                            z=math.sin(yaw / 2),
                            w=math.cos(yaw / 2),
                        ),
                    ),
                )
                w.write(
                    tf,
                    t,
                    bytes(
                        store.serialize_ros1(m(ros_types.TF_MESSAGE, transforms=[tr]), ros_types.TF_MESSAGE)
                    ),
                )
            marker = m(
                "visualization_msgs/msg/Marker",
                header=m("std_msgs/msg/Header", stamp=stamp, frame_id="base_link"),
                ns="tracker",
                id=9,
                type=1,
                pose=m(
                    "geometry_msgs/msg/Pose",
                    position=m("geometry_msgs/msg/Point", x=20.0, y=0.0, z=0.0),
                    orientation=m("geometry_msgs/msg/Quaternion", x=0.0, y=0.0, z=0.0, w=1.0),
                ),
                scale=m("geometry_msgs/msg/Vector3", x=4.2, y=1.9, z=1.5),
            )
            arrow = m("visualization_msgs/msg/Marker", header=marker.header, id=10, type=0)
            msg = m(ros_types.MARKER_ARRAY, markers=[marker, arrow])
            w.write(markers, t, bytes(store.serialize_ros1(msg, ros_types.MARKER_ARRAY)))
    return path


def test_foreign_ros1_markers_in_ego_frame_transformed(tmp_path: Path) -> None:
    table = rosbag_reader.read(_ros1_bag(tmp_path / "viz.bag", with_tf=True))
    rec = track_table.read_meta(table).recordings["viz"]
    assert (rec.frame_rate, rec.coordinate_frame) == (5.0, "odom")
    i = np.arange(5)
    yaw = 0.1 * i
    np.testing.assert_array_equal(table.column("track_id").to_numpy(), 9)  # the arrow marker is ignored
    np.testing.assert_array_equal(table.column("frame").to_numpy(), i)
    np.testing.assert_allclose(table.column("x").to_numpy(), 2.0 * i + 20.0 * np.cos(yaw), atol=1e-9)
    np.testing.assert_allclose(table.column("y").to_numpy(), 20.0 * np.sin(yaw), atol=1e-9)
    np.testing.assert_allclose(table.column("heading").to_numpy(), yaw, atol=1e-6)
    np.testing.assert_allclose(table.column("length").to_numpy(), 4.2, rtol=1e-6)
    # No velocity in markers: differences of positions (central inside, one-sided at the ends).
    x = 2.0 * i + 20.0 * np.cos(yaw)
    expected = np.gradient(x, 0.2)
    np.testing.assert_allclose(table.column("vx").to_numpy(), expected, rtol=1e-5)
    assert set(table.column("object_class").cast(pa.string()).to_pylist()) == {"unknown"}


def test_foreign_ros1_without_tf_is_a_clear_error(tmp_path: Path) -> None:
    with pytest.raises(FrameError, match=r"'base_link'.*no transform"):
        rosbag_reader.read(_ros1_bag(tmp_path / "viz.bag", with_tf=False))


def test_bag_topic_selection_and_errors(tmp_path: Path) -> None:
    out = rosbag_writer.write(make_table(), tmp_path / "bag", "ros2")
    south = rosbag_reader.read(out, topic="/tracked_objects/south")
    assert list(track_table.read_meta(south).recordings) == ["south"]
    assert set(south.column("track_id").to_numpy().tolist()) == {101, 102, 103}
    with pytest.raises(LogError, match="'/lanecast/metadata' has type std_msgs/msg/String"):
        rosbag_reader.read(out, topic="/lanecast/metadata")
    with pytest.raises(LogError, match="'/missing' holds no tracked objects"):
        rosbag_reader.read(out, topic="/missing")


def test_uuid_track_ids() -> None:
    assert to.uuid_to_track_id(to.track_id_to_uuid(123456789)) == 123456789
    foreign = np.arange(16, dtype=np.uint8)
    assert to.uuid_to_track_id(foreign) == to.uuid_to_track_id(foreign.copy()) > 0


@pytest.mark.parametrize(
    ("edit", "line", "key", "match"),
    [
        (
            ("version: 9", "version: 99"),
            0,
            "version",
            "rosbag2 metadata version 99 .expected a version from 1 to 9",
        ),
        (
            ("storage_identifier: sqlite3", "storage_identifier: hdf5"),
            0,
            "storage_identifier",
            "plugin 'hdf5'",
        ),
        (("  - b.db3", "  - b.db3\n  - b.db3"), 0, "relative_file_paths", "lists 'b.db3' twice"),
        (("  - b.db3", "  - ../b.db3x"), 0, "relative_file_paths", "lists '../b.db3x', which is not in"),
        (("serialization_format: cdr", "serialization_format: ros1"), 0, "serialization_format", "as 'ros1'"),
        (("rosbag2_bagfile_information:", "rosbag2_bagfile_information: ["), None, None, "not YAML"),
        (("rosbag2_bagfile_information:", "other:"), 1, None, "no rosbag2_bagfile_information mapping"),
    ],
)
def test_bad_ros2_metadata_yaml_is_named_with_its_line_and_key(
    tmp_path: Path, edit: tuple[str, str], line: int | None, key: str | None, match: str
) -> None:
    """metadata.yaml that rosbags misreads was 'bag: cannot read the bag: AnyReaderError: Rosbag2
    version 99 not supported' (or 'Invalid bag metadata: …', or a file listed twice read twice);
    now metadata.yaml, its line and the key."""
    bag = rosbag_writer.write(make_table(), tmp_path / "b", "ros2", storage="sqlite3")
    meta = bag / "metadata.yaml"
    text = meta.read_text()
    assert edit[0] in text
    meta.write_text(text.replace(edit[0], edit[1], 1))
    with pytest.raises(LogError, match=match) as err:
        rosbag_reader.read(bag)
    assert err.value.path == str(meta) and err.value.column == key
    if line == 0:  # the line of the key
        at = next(
            i for i, t in enumerate(meta.read_text().splitlines(), 1) if t.strip().startswith(key + ":")
        )
        assert err.value.line == at
    elif line is not None:
        assert err.value.line == line
    else:
        assert err.value.line is not None


@pytest.mark.parametrize(
    ("sql", "match"),
    [
        (
            "UPDATE topics SET serialization_format = 'json'",
            r"table topics, row \d+: topic '.*' is stored with serialization format 'json'",
        ),
        ("ALTER TABLE messages RENAME TO msgs", "no table 'messages'"),
        ("ALTER TABLE topics DROP COLUMN serialization_format", "table topics: no such column"),
        (
            "UPDATE message_definitions SET encoded_message_definition = CAST(x'4142434445fe4647484950' AS TEXT) "
            "WHERE rowid = 1",
            "table message_definitions, row 1: the text is not UTF-8",
        ),
    ],
)
def test_sqlite3_tables_rosbags_cannot_read_are_named(tmp_path: Path, sql: str, match: str) -> None:
    """Topics stored as JSON were 'the supported topics hold no objects' (rosbags read none of
    their messages); a table missing was 'cannot read the bag: … or database missing tables'; a
    message definition that is not UTF-8 was 'cannot read the bag: UnicodeDecodeError'."""
    import sqlite3

    bag = rosbag_writer.write(make_table(), tmp_path / "b", "ros2", storage="sqlite3")
    with sqlite3.connect(bag / "b.db3") as con:
        con.execute(sql)
    with pytest.raises(LogError, match=match) as err:
        rosbag_reader.read(bag)
    assert err.value.path == str(bag / "b.db3")
    if "serialization format" in match:
        assert err.value.column == "serialization_format"
    if "UTF-8" in match:  # where the bytes are in the file, and the column
        bad = bytes.fromhex("4142434445fe4647484950")
        assert err.value.offset == (bag / "b.db3").read_bytes().index(bad)
        assert err.value.column == "encoded_message_definition"


def test_ros2_compression_mode_over_an_uncompressed_file_is_named(tmp_path: Path) -> None:
    """compression_mode FILE over a plain .db3 was 'cannot read the bag: ZstdError: Unknown frame
    descriptor' naming the bag; now metadata.yaml, the key and the file that is not compressed."""
    bag = rosbag_writer.write(make_table(), tmp_path / "b", "ros2", storage="sqlite3")
    meta = bag / "metadata.yaml"
    text = meta.read_text()
    text = text.replace("compression_format: ''", "compression_format: zstd")
    meta.write_text(text.replace("compression_mode: ''", "compression_mode: FILE"))
    with pytest.raises(LogError, match=r"compression_mode 'FILE', but b\.db3 is not zstd-compressed") as err:
        rosbag_reader.read(bag)
    assert (
        err.value.path == str(meta) and err.value.column == "compression_mode" and err.value.line is not None
    )


@pytest.mark.parametrize("first_line", [b"#ROSBAG V1.2\n", b"#ROSBAG V2.0 ", b"#ROSBAG Vx.y\n"])
def test_ros1_bag_of_another_version_says_which(tmp_path: Path, first_line: bytes) -> None:
    """A ROS 1 bag whose version line is not '#ROSBAG V2.0\\n' was 'format not recognised'; now a
    ROS 1 bag of another version, the line it has and the one lanecast reads."""
    bag = rosbag_writer.write(make_table(), tmp_path / "b.bag", "ros1")
    bag.write_bytes(first_line + bag.read_bytes()[len(first_line) :])
    with pytest.raises(LogError, match="a ROS 1 bag of another format version") as err:
        registry.read_any([bag])
    assert err.value.path == str(bag) and err.value.offset == 0
    assert first_line.rstrip(b"\n").decode() in str(err.value) and "'#ROSBAG V2.0'" in str(err.value)


def test_files_beside_a_ros2_bag_that_metadata_yaml_does_not_list_are_not_read(tmp_path: Path) -> None:
    """A cut-short .mcap left beside a sqlite3 bag's .db3 (not in metadata.yaml, so not the bag's)
    made the bag unreadable ('old.mcap, offset 8: the file is truncated'); now only the listed
    storage files are checked, and a listed file that is damaged is still named."""
    bag = rosbag_writer.write(make_table(), tmp_path / "b", "ros2", storage="sqlite3")
    (bag / "old.mcap").write_bytes(b"\x89MCAP0\r\n" + b"\x01" * 20)
    (bag / "old.db3").write_bytes(b"SQLite format 3\x00" + b"\x10\x00" + bytes(82))
    assert rosbag_reader.read(bag).num_rows == make_table().num_rows
    data = (bag / "b.db3").read_bytes()
    (bag / "b.db3").write_bytes(data[: len(data) // 2])
    with pytest.raises(LogError, match="truncated") as err:
        rosbag_reader.read(bag)
    assert err.value.path == str(bag / "b.db3")


def test_a_yaml_alias_bomb_in_metadata_yaml_is_refused_before_it_expands(tmp_path: Path) -> None:
    """Nine nested aliases in custom_data (9**9 values): annotate spent 85 s and 2 GB before a
    MemoryError ('cannot read the ROS 2 bag: MemoryError:'); now metadata.yaml is refused at once."""

    from lanecast.io_adapters.logs.rosbag.copy import ros2_custom_data

    bag = rosbag_writer.write(make_table(), tmp_path / "b", "ros2", storage="sqlite3")
    meta = bag / "metadata.yaml"
    levels = ['a0: &a0 ["lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol"]']
    levels += [f"a{i}: &a{i} [{', '.join([f'*a{i - 1}'] * 9)}]" for i in range(1, 9)]
    text = meta.read_text()
    meta.write_text(
        "\n".join(levels) + "\n" + text.replace("  custom_data:\n", "  custom_data:\n    bomb: *a8\n", 1)
    )
    for read in (rosbag_reader.read, ros2_custom_data):  # refused by the count, not by a MemoryError
        with pytest.raises(LogError, match=r"expands to more than 200,000 values") as err:
            read(bag)
        assert err.value.path == str(meta)


def test_undecodable_messages_are_described_in_words_not_in_rosbags_texts(tmp_path: Path) -> None:
    """rosbags' own errors for damaged message bytes read "unpack_from requires a buffer of at least
    … bytes" or "'utf-8' codec can't decode": lanecast says what is wrong with the message."""
    import struct

    from rosbags.highlevel import AnyReader

    from lanecast.io_adapters.logs.rosbag.reader import why_undecodable

    bag = rosbag_writer.write(make_table(), tmp_path / "log.bag", "ros1")
    with AnyReader([bag]) as reader:
        conn = next(c for c in reader.connections if c.topic == "/tracked_objects/north")
        _, _, raw = next(iter(reader.messages(connections=[conn])))
        frame_id_length = struct.unpack_from("<I", raw, 12)[0]
        count_at = 16 + frame_id_length  # seq, stamp, frame_id, then the objects' count
        assert struct.unpack_from("<I", raw, count_at)[0] == 1  # one vehicle in the first frame
        texts = []
        for damaged in (
            raw[:count_at] + struct.pack("<I", 10_000) + raw[count_at + 4 :],  # a count too large
            raw[:16] + b"\xff" + raw[17:],  # the frame id's first byte: not UTF-8
        ):
            with pytest.raises(Exception) as err:
                reader.deserialize(bytes(damaged), conn.msgtype)
            texts.append(why_undecodable(err.value, len(damaged)))
    assert texts[0] == (
        f"the message's {len(raw):,} bytes end before the data its fields announce: a length or count "
        "inside it is damaged"
    )
    assert texts[1] == "a text field holds bytes that are not UTF-8 (byte 0xff at position 0 of the text)"
    unpack = struct.error(
        "unpack_from requires a buffer of at least 3255 bytes for unpacking 4 bytes at offset 3251"
    )
    assert why_undecodable(RuntimeError("Could not deserialize"), 3251).startswith("its 3,251 bytes")
    wrapped = RuntimeError("Could not deserialize 'x'")
    wrapped.__cause__ = unpack
    assert why_undecodable(wrapped, 3251) == (
        "the message's 3,251 bytes end before its field at byte 3,251 (3,255 bytes needed): a length or "
        "count inside it is damaged"
    )
