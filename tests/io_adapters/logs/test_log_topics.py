"""A log's topics, message types and counts, from the summary or, without one, from the records."""

from __future__ import annotations

from pathlib import Path

import pytest
from mcap.writer import Writer

from lanecast.io_adapters.logs.topics import TopicCount, log_topics
from lanecast.workflows.cli import main

HIGHD = Path(__file__).resolve().parents[2] / "data" / "highd"


def _mcap(path: Path, statistics: bool) -> Path:
    with path.open("wb") as fh:
        w = Writer(fh, use_statistics=statistics, chunk_size=256)
        w.start(profile="", library="test")
        pose = w.register_schema("test.Pose", "jsonschema", b"{}")
        a = w.register_channel("/pose", "json", pose)
        b = w.register_channel("/raw", "cbor", 0)
        for i in range(25):
            w.add_message(a, i, b'{"x": 1}', i)
            if i % 5 == 0:
                w.add_message(b, i, b"\xa0", i)
        w.finish()
    return path


@pytest.mark.parametrize("statistics", [True, False])
def test_mcap_topics_are_counted_with_or_without_statistics(tmp_path: Path, statistics: bool) -> None:
    log = _mcap(tmp_path / "a.mcap", statistics)
    assert log_topics(log) == [
        TopicCount("/pose", "test.Pose", "json", 25),
        TopicCount("/raw", "", "cbor", 5),
    ]


def test_info_on_a_log_lists_its_topics(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bag = tmp_path / "sim-bag"
    assert main(["convert", str(HIGHD), "--to", "ros2", "--out", str(bag)]) == 0
    capsys.readouterr()
    assert main(["info", str(bag)]) == 0
    out = capsys.readouterr().out
    assert f"topics of {bag} (5; messages, type, encoding):" in out
    line = next(x for x in out.splitlines() if x.strip().startswith("/tracked_objects/highd_01_lower "))
    assert line.split()[1] == "5" and "autoware_perception_msgs/msg/TrackedObjects" in line


def test_topics_name_their_recording_as_ros_names() -> None:
    from lanecast.io_adapters.logs.conventions import recording_topics

    assert recording_topics(["highd-01-upper"]) == {"highd-01-upper": "/tracked_objects"}
    assert recording_topics(["highd-01-upper", "highd-01-lower", "sim@run2", "9 lanes", "a.b", "a-b"]) == {
        "highd-01-upper": "/tracked_objects/highd_01_upper",
        "highd-01-lower": "/tracked_objects/highd_01_lower",
        "sim@run2": "/tracked_objects/sim_run2",
        "9 lanes": "/tracked_objects/r_9_lanes",
        "a.b": "/tracked_objects/a_b",
        "a-b": "/tracked_objects/a_b_2",
    }
