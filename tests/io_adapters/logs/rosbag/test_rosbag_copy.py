"""An annotated ROS 2 bag of an older schema reads back."""

from __future__ import annotations

from pathlib import Path

from conftest import staggered_cars

from lanecast.io_adapters.logs.rosbag import reader as rosbag_reader
from lanecast.io_adapters.logs.rosbag import writer as rosbag_writer
from lanecast.workflows.cli import main


def test_an_annotated_sqlite3_bag_of_an_older_schema_reads_back(tmp_path: Path) -> None:
    """A sqlite3 ROS 2 bag of rosbag2's schema before version 4 (no schema table, or version 2:
    no message definitions): annotate copied each topic with an empty definition and its type hash
    into a version 9 bag, which lanecast's own reader then refused ('the definition is empty').
    The copy now takes the definition of each type lanecast knows; the output converts to the
    same table as the input."""
    import sqlite3

    table = staggered_cars(3, 30, stagger=4, step_m=2.5, speed=25.0, rate=10.0)
    bag = rosbag_writer.write(table, tmp_path / "old", "ros2", storage="sqlite3")
    with sqlite3.connect(next(bag.glob("*.db3"))) as con:
        con.execute("UPDATE schema SET schema_version = 2")  # as rosbags reads it: no table, the same
    clean = rosbag_reader.read(bag)
    assert main(["annotate", str(bag), "--out", str(tmp_path / "out")]) == 0
    out = tmp_path / "out" / "old"
    annotated = rosbag_reader.read(out)
    assert annotated.num_rows == clean.num_rows
    assert annotated.column("x").equals(clean.column("x"))
    with sqlite3.connect(next(out.glob("*.db3"))) as con:
        empty = con.execute(
            "SELECT topic_type FROM message_definitions WHERE encoded_message_definition = ''"
        )
        assert not [t for (t,) in empty if t.startswith("autoware_perception_msgs")]
