"""ROS 2 bag metadata.yaml checks: missing, naming QoS profiles rosbags cannot parse, listing a copy
of its storage file, describing a topic otherwise; each named at its line."""

from __future__ import annotations

import shutil
from pathlib import Path

import pyarrow as pa
import pytest
from conftest import staggered_cars

from lanecast.io_adapters.errors import LanecastError, LogError
from lanecast.io_adapters.formats import registry
from lanecast.io_adapters.logs.rosbag import reader as rosbag_reader
from lanecast.io_adapters.logs.rosbag import writer as rosbag_writer

QOS = (
    '"- history: 3\\n  depth: 0\\n  reliability: 1\\n  durability: 2\\n  deadline:\\n    sec: 2147483647\\n'
    "    nsec: 4294967295\\n  lifespan:\\n    sec: 2147483647\\n    nsec: 4294967295\\n  liveliness: 1\\n"
    "  liveliness_lease_duration:\\n    sec: 2147483647\\n    nsec: 4294967295\\n"
    '  avoid_ros_namespace_conventions: false"'
)


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_a_ros2_topic_metadata_yaml_describes_otherwise_is_named_at_its_line(
    tmp_path: Path, storage: str
) -> None:
    """metadata.yaml giving one object topic QoS profiles its storage file does not record (an
    edited or regenerated metadata.yaml): rosbags matches storage topics to metadata.yaml's by name,
    type, format and QoS and skips every message of a topic that differs, without a word; lanecast
    saw a topic with no messages (in a bag it wrote, a checksum mismatch that named no place). Now
    the error names metadata.yaml, the topic's line and the key that differs."""
    table = staggered_cars(3, 30, stagger=4, step_m=2.5, speed=25.0, rate=10.0)
    bag = rosbag_writer.write(table, tmp_path / "bag", "ros2", storage=storage)
    meta = bag / "metadata.yaml"
    lines = meta.read_text().splitlines()
    name = next(i for i, line in enumerate(lines) if line.strip() == "name: /tracked_objects")
    qos = next(i for i in range(name, len(lines)) if "offered_qos_profiles" in lines[i])
    lines[qos] = lines[qos].split(":")[0] + ": " + QOS
    meta.write_text("\n".join(lines) + "\n")
    with pytest.raises(
        LogError, match="topic '/tracked_objects' of the storage file has other offered QoS"
    ) as err:
        rosbag_reader.read(bag)
    assert err.value.path == str(meta) and err.value.line == qos + 1
    assert err.value.column == "offered_qos_profiles"


def test_a_ros2_bag_without_metadata_yaml_says_so(tmp_path: Path) -> None:
    """A ROS 2 bag directory whose metadata.yaml was lost said only 'format not recognised'."""
    bag = tmp_path / "bag"
    bag.mkdir()
    (bag / "bag_0.db3").write_bytes(b"SQLite format 3\x00" + bytes(100))
    with pytest.raises(LanecastError, match=r"holds 'bag_0\.db3' but no metadata\.yaml") as err:
        registry.read_any([bag])
    assert str(bag) in str(err.value)


def test_ros2_metadata_naming_qos_profiles_rosbags_cannot_parse_names_its_line(
    tmp_path: Path, table: pa.Table
) -> None:
    """offered_qos_profiles: 'junk' was 'cannot read the bag: AnyReaderError: Invalid bag metadata:
    string indices must be integers, not 'str'': neither metadata.yaml nor a line (found by
    tests/io_adapters/logs/test_logs_fuzz.py). Now metadata.yaml, the line and the key."""
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
