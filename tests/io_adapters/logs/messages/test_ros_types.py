"""Tracked objects under Autoware's two package names, and logs that carry another version of a
message: real drive logs recorded with Autoware.Universe before 2024 use
``autoware_auto_perception_msgs`` (its kinematics hold ``orientation_availability`` right after the
pose), and an MCAP's own schema says how its messages are laid out."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from mcap.writer import Writer as McapWriter
from rosbags.rosbag2 import StoragePlugin
from rosbags.rosbag2 import Writer as Bag2Writer

from lanecast.io_adapters.formats import registry
from lanecast.io_adapters.logs.messages import ros_types

AUTO = "autoware_auto_perception_msgs"


SPEED = 12.5  # m/s, along each object's heading (Autoware's twist is in the body frame)


YAW = 0.3  # rad


def tracked_objects(store: Any, package: str, stamp_ns: int, n_objects: int = 2) -> Any:
    """One TrackedObjects message of ``package`` at ``stamp_ns``: cars 1 … n at x = 10·id + speed·t."""
    m = ros_types.make
    t = stamp_ns * 1e-9
    objects = []
    for track in range(1, n_objects + 1):
        pose = m(
            store,
            "geometry_msgs/msg/Pose",
            position=m(
                store, "geometry_msgs/msg/Point", x=10.0 * track + SPEED * math.cos(YAW) * t, y=2.0 * track
            ),
            orientation=m(store, "geometry_msgs/msg/Quaternion", z=math.sin(YAW / 2), w=math.cos(YAW / 2)),
        )
        twist = m(store, "geometry_msgs/msg/Twist", linear=m(store, "geometry_msgs/msg/Vector3", x=SPEED))
        kinematics = m(
            store,
            f"{package}/msg/TrackedObjectKinematics",
            pose_with_covariance=m(store, "geometry_msgs/msg/PoseWithCovariance", pose=pose),
            orientation_availability=2,
            twist_with_covariance=m(store, "geometry_msgs/msg/TwistWithCovariance", twist=twist),
        )
        objects.append(
            m(
                store,
                f"{package}/msg/TrackedObject",
                object_id=m(
                    store,
                    "unique_identifier_msgs/msg/UUID",
                    uuid=np.array([track] + [0] * 15, dtype=np.uint8),
                ),
                existence_probability=1.0,
                classification=[m(store, f"{package}/msg/ObjectClassification", label=1, probability=1.0)],
                kinematics=kinematics,
                shape=m(
                    store,
                    f"{package}/msg/Shape",
                    dimensions=m(store, "geometry_msgs/msg/Vector3", x=4.5, y=1.8, z=1.5),
                ),
            )
        )
    header = m(
        store,
        "std_msgs/msg/Header",
        stamp=m(store, "builtin_interfaces/msg/Time", sec=stamp_ns // 10**9, nanosec=stamp_ns % 10**9),
        frame_id="map",
    )
    return m(store, f"{package}/msg/TrackedObjects", header=header, objects=objects)


STAMPS = [10**9 + i * 100_000_000 for i in range(30)]  # 3 s at 10 Hz


def check_tracks(path: Path) -> None:
    """The table read from ``path`` holds both cars, where they were, at the speed they drove."""
    table = registry.read_any([path])
    assert table.num_rows == 2 * len(STAMPS)
    track = table.column("track_id").to_numpy()
    assert sorted(set(track.tolist())) == [1, 2]
    t = table.column("time_ns").to_numpy() * 1e-9
    x = table.column("x").to_numpy()
    y = table.column("y").to_numpy()
    np.testing.assert_allclose(x, 10.0 * track + SPEED * math.cos(YAW) * t, atol=1e-6)
    np.testing.assert_allclose(y, 2.0 * track, atol=1e-6)
    np.testing.assert_allclose(table.column("heading").to_numpy(), YAW, atol=1e-6)
    speed = np.hypot(table.column("vx").to_numpy(), table.column("vy").to_numpy())
    np.testing.assert_allclose(speed, SPEED, rtol=1e-5)
    assert set(table.column("object_class").to_pylist()) == {"car"}


@pytest.mark.parametrize("storage", ["sqlite3", "mcap"])
def test_a_ros2_bag_of_autoware_auto_tracked_objects_is_read(tmp_path: Path, storage: str) -> None:
    store = ros_types.typestore(2)
    msgtype = ros_types.TRACKED_OBJECTS_AUTO
    bag = tmp_path / "bag"
    with Bag2Writer(
        bag,
        version=Bag2Writer.VERSION_LATEST,
        storage_plugin=getattr(StoragePlugin, storage.upper()),
    ) as writer:
        conn = writer.add_connection(
            "/perception/object_recognition/tracking/objects", msgtype, typestore=store
        )
        for stamp in STAMPS:
            writer.write(
                conn, stamp, bytes(store.serialize_cdr(tracked_objects(store, AUTO, stamp), msgtype))
            )
    check_tracks(bag)


def write_mcap(path: Path, schema_name: str, schema_text: str, payloads: list[tuple[int, bytes]]) -> None:
    with path.open("wb") as fh:
        writer = McapWriter(fh)
        writer.start()
        schema = writer.register_schema(schema_name, "ros2msg", schema_text.encode())
        channel = writer.register_channel("/objects", "cdr", schema)
        for stamp, data in payloads:
            writer.add_message(channel, log_time=stamp, data=data, publish_time=stamp)
        writer.finish()


def test_an_mcap_of_autoware_auto_tracked_objects_is_read(tmp_path: Path) -> None:
    store = ros_types.typestore(2)
    msgtype = ros_types.TRACKED_OBJECTS_AUTO
    payloads = [(s, bytes(store.serialize_cdr(tracked_objects(store, AUTO, s), msgtype))) for s in STAMPS]
    write_mcap(tmp_path / "log.mcap", msgtype, ros_types.schema_text(msgtype), payloads)
    check_tracks(tmp_path / "log.mcap")


def test_an_mcap_is_decoded_with_its_own_definition_of_a_message(tmp_path: Path) -> None:
    """An MCAP whose schema lays out ``autoware_perception_msgs/msg/TrackedObjects`` with the fields
    of another version (here: orientation_availability right after the pose) is decoded with that
    layout. Decoded with lanecast's own, the twist would start one byte early: wrong speeds or a
    message that does not decode."""
    name = ros_types.TRACKED_OBJECTS
    other = ros_types.schema_text(ros_types.TRACKED_OBJECTS_AUTO).replace(AUTO, "autoware_perception_msgs")
    theirs = ros_types.store_for(name, other)
    assert theirs is not ros_types.typestore(2)
    payloads = [
        (s, bytes(theirs.serialize_cdr(tracked_objects(theirs, "autoware_perception_msgs", s), name)))
        for s in STAMPS
    ]
    write_mcap(tmp_path / "log.mcap", name, other, payloads)
    check_tracks(tmp_path / "log.mcap")


def test_a_definition_that_agrees_or_does_not_parse_keeps_lanecasts_own() -> None:
    ours = ros_types.typestore(2)
    name = ros_types.TRACKED_OBJECTS
    assert ros_types.store_for(name, ros_types.schema_text(name)) is ours
    assert ros_types.store_for(name, "") is ours
    assert ros_types.store_for(name, "int32 x\n====\nMSG: foo") is ours  # does not parse
    # parses, but names a type nobody defines (a damaged schema): lanecast's own decodes
    assert ros_types.store_for(name, "std_msgs/Header header\nNoSuchType[] objects\n") is ours


@pytest.mark.parametrize("ros_version", [1, 2])
def test_a_constructor_is_the_class_where_the_fields_are_all_given_else_make(ros_version: int) -> None:
    store = ros_types.typestore(ros_version)
    point = ros_types.constructor(store, "geometry_msgs/msg/Point", ("x", "y", "z"))
    assert point is store.types["geometry_msgs/msg/Point"]
    assert point(x=1.0, y=2.0, z=3.0) == ros_types.make(store, "geometry_msgs/msg/Point", x=1.0, y=2.0, z=3.0)
    # a Marker has fields lanecast never sets (ROS 2's texture, …): the others take their defaults
    typename = ros_types.MARKER_ARRAY.replace("Array", "")
    marker = ros_types.constructor(store, typename, ("ns", "id", "text"))
    built = marker(ns="car", id=7, text="lane_id=2")
    assert (built.ns, built.id, built.text, built.frame_locked) == ("car", 7, "lane_id=2", False)
    assert (
        store.serialize_cdr(built, typename).tobytes()
        == store.serialize_cdr(
            ros_types.make(store, typename, ns="car", id=7, text="lane_id=2"), typename
        ).tobytes()
    )
    # a field of the other ROS version's definition is left out, as make leaves it
    header = ros_types.make(store, "std_msgs/msg/Header", seq=3, frame_id="map")
    assert header.frame_id == "map"
    assert header.seq == 3 if ros_version == 1 else not hasattr(header, "seq")
