"""Empty and foreign files given as drive logs are refused naming the file and offset 0."""

from __future__ import annotations

from pathlib import Path

import pytest

from lanecast.io_adapters.errors import LogError
from lanecast.io_adapters.logs.mcap import reader as mcap_reader
from lanecast.io_adapters.logs.rosbag import reader as rosbag_reader


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
