"""Recorded PredictedObjects read from MCAP and ROS 2 bags into columns, and paths resampled to 1–5 s."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
from mcap.writer import Writer as McapWriter
from rosbags.rosbag2 import StoragePlugin
from rosbags.rosbag2 import Writer as Bag2Writer

from lanecast.io_adapters.errors import LogError
from lanecast.io_adapters.logs.autoware.predicted_objects import (
    PREDICTED_OBJECTS,
    PREDICTED_OBJECTS_AUTO,
    PredictionColumns,
    resample,
)
from lanecast.io_adapters.logs.autoware.predicted_objects_cdr import CdrLayoutError, add_predicted_objects_cdr
from lanecast.io_adapters.logs.messages import ros_types
from lanecast.workflows.annotation.recorded_predictions import read_predictions

TOPIC = "/perception/object_recognition/objects"
STAMP = 2_500_000_000


def message(store: Any, msgtype: str) -> Any:
    """Two objects: a truck (uuid byte 7) with paths of 3 and 2 poses, a pedestrian with none."""
    m = ros_types.make
    pkg = msgtype.split("/")[0]

    def pose(x: float, y: float) -> Any:
        return m(store, "geometry_msgs/msg/Pose", position=m(store, "geometry_msgs/msg/Point", x=x, y=y))

    def path(xs: list[float], step_ns: int, conf: float) -> Any:
        return m(
            store,
            f"{pkg}/msg/PredictedPath",
            path=[pose(x, -x) for x in xs],
            time_step=m(
                store, "builtin_interfaces/msg/Duration", sec=step_ns // 10**9, nanosec=step_ns % 10**9
            ),
            confidence=conf,
        )

    def obj(uid: int, label: int, paths: list[Any]) -> Any:
        return m(
            store,
            f"{pkg}/msg/PredictedObject",
            object_id=m(store, "unique_identifier_msgs/msg/UUID", uuid=np.array([uid] + [0] * 15, np.uint8)),
            classification=[m(store, f"{pkg}/msg/ObjectClassification", label=label, probability=0.9)],
            kinematics=m(store, f"{pkg}/msg/PredictedObjectKinematics", predicted_paths=paths),
        )

    stamp = m(store, "builtin_interfaces/msg/Time", sec=STAMP // 10**9, nanosec=STAMP % 10**9)
    return m(
        store,
        msgtype,
        header=m(store, "std_msgs/msg/Header", stamp=stamp, frame_id="map"),
        objects=[
            obj(7, 2, [path([1.0, 2.0, 3.0], 2_500_000_000, 0.75), path([4.0, 5.0], 500_000_000, 0.25)]),
            obj(8, 7, []),
        ],
    )


def check(pred: Any) -> None:
    assert pred.topic == TOPIC
    assert pred.stamp_ns.tolist() == [STAMP, STAMP]
    assert pred.track_id.tolist() == [7, 8]
    assert pred.object_class.tolist() == ["truck", "pedestrian"]
    assert pred.path_bounds.tolist() == [0, 2, 2]
    np.testing.assert_allclose(pred.confidence, [0.75, 0.25])
    np.testing.assert_allclose(pred.time_step_s, [2.5, 0.5])
    assert pred.n_poses.tolist() == [3, 2]
    np.testing.assert_array_equal(pred.points[0], [[1, -1], [2, -2], [3, -3]])
    np.testing.assert_array_equal(pred.points[1, :2], [[4, -4], [5, -5]])
    assert np.isnan(pred.points[1, 2]).all()


@pytest.mark.parametrize("msgtype", [PREDICTED_OBJECTS, PREDICTED_OBJECTS_AUTO])
def test_an_mcap_of_predicted_objects_is_read_by_schema(tmp_path: Path, msgtype: str) -> None:
    store = ros_types.typestore(2)
    log = tmp_path / "log.mcap"
    with log.open("wb") as fh:
        writer = McapWriter(fh)
        writer.start()
        schema = writer.register_schema(msgtype, "ros2msg", ros_types.schema_text(msgtype).encode())
        channel = writer.register_channel(TOPIC, "cdr", schema)
        other = writer.register_channel("/other", "json", 0)
        writer.add_message(other, log_time=1, data=b"{}", publish_time=1)
        data = bytes(store.serialize_cdr(message(store, msgtype), msgtype))
        writer.add_message(channel, log_time=STAMP + 5, data=data, publish_time=STAMP + 5)
        writer.finish()
    (pred,) = read_predictions(log)
    check(pred)
    with pytest.raises(LogError, match="'/other' holds"):
        read_predictions(log, ["/other"])
    with pytest.raises(LogError, match="no topic '/nowhere'"):
        read_predictions(log, ["/nowhere"])


def test_a_ros2_bag_of_predicted_objects_is_read_by_topic(tmp_path: Path) -> None:
    store = ros_types.typestore(2)
    bag = tmp_path / "bag"
    with Bag2Writer(bag, version=Bag2Writer.VERSION_LATEST, storage_plugin=StoragePlugin.SQLITE3) as writer:
        conn = writer.add_connection(TOPIC, PREDICTED_OBJECTS, typestore=store)
        writer.write(
            conn, STAMP, bytes(store.serialize_cdr(message(store, PREDICTED_OBJECTS), PREDICTED_OBJECTS))
        )
    (pred,) = read_predictions(bag, [TOPIC])
    check(pred)


def test_paths_are_resampled_to_the_horizons_or_refused_with_the_reason() -> None:
    cols = PredictionColumns("/p")
    line = np.stack([np.arange(11.0), np.zeros(11)], axis=1)  # x = pose index
    cols.add_paths(
        0,
        1,
        "car",
        [
            (0.5, 0.0, 0.5, line),  # 0…5 s every 0.5 s: x = 2 h
            (0.3, 0.0, 0.4, line),  # 0…4 s: too short
            (0.2, 0.0, 0.0, line),  # no time step
            (0.1, 1.0, 1.0, line[:5]),  # lanecast's layout: 1…5 s
        ],
    )
    points, reason = resample(cols.finish(), np.array([1.0, 2.5, 5.0]))
    np.testing.assert_allclose(points[0, :, 0], [2.0, 5.0, 10.0])
    np.testing.assert_allclose(points[3, :, 0], [0.0, 1.5, 4.0])
    assert reason[0] == "" and reason[3] == ""
    assert reason[1] == "11 poses every 0.4 s cover 0–4 s, not 1–5 s"
    assert reason[2] == "time step 0 s is not a positive duration"
    assert np.isnan(points[1:3]).all()


def varied_message(store: Any, msgtype: str, rng: np.random.Generator) -> Any:
    """Objects with 0–3 classifications, 0–3 paths of 0–7 poses and footprints of 0–4 points."""
    m = ros_types.make
    pkg = msgtype.split("/")[0]
    objects = []
    for _ in range(5):
        paths = [
            m(
                store,
                f"{pkg}/msg/PredictedPath",
                path=[
                    m(store, "geometry_msgs/msg/Pose", position=m(store, "geometry_msgs/msg/Point", x=x, y=y))
                    for x, y in rng.normal(size=(int(rng.integers(0, 8)), 2))
                ],
                time_step=m(
                    store, "builtin_interfaces/msg/Duration", sec=0, nanosec=int(rng.integers(1, 10**9))
                ),
                confidence=float(rng.random()),
            )
            for _ in range(int(rng.integers(0, 4)))
        ]
        footprint = m(
            store,
            "geometry_msgs/msg/Polygon",
            points=[
                m(store, "geometry_msgs/msg/Point32", x=1.0, y=2.0) for _ in range(int(rng.integers(0, 5)))
            ],
        )
        objects.append(
            m(
                store,
                f"{pkg}/msg/PredictedObject",
                object_id=m(
                    store, "unique_identifier_msgs/msg/UUID", uuid=rng.integers(0, 256, 16).astype(np.uint8)
                ),
                classification=[
                    m(store, f"{pkg}/msg/ObjectClassification", label=int(rng.integers(0, 8)), probability=p)
                    for p in rng.random(int(rng.integers(0, 4)))
                ],
                kinematics=m(store, f"{pkg}/msg/PredictedObjectKinematics", predicted_paths=paths),
                shape=m(store, f"{pkg}/msg/Shape", footprint=footprint),
            )
        )
    stamp = m(store, "builtin_interfaces/msg/Time", sec=3, nanosec=7)
    header = m(store, "std_msgs/msg/Header", stamp=stamp, frame_id="odom" * int(rng.integers(0, 3)))
    return m(store, msgtype, header=header, objects=objects)


@pytest.mark.parametrize("msgtype", [PREDICTED_OBJECTS, PREDICTED_OBJECTS_AUTO])
def test_the_direct_cdr_reader_agrees_with_rosbags(msgtype: str) -> None:
    store = ros_types.typestore(2)
    rng = np.random.default_rng(4)
    direct, reference = PredictionColumns("/p"), PredictionColumns("/p")
    for _ in range(20):
        msg = varied_message(store, msgtype, rng)
        data = bytes(store.serialize_cdr(msg, msgtype))
        add_predicted_objects_cdr(direct, data, 1)
        reference.add_message(store.deserialize_cdr(data, msgtype), 1)
        with pytest.raises(CdrLayoutError):
            add_predicted_objects_cdr(PredictionColumns("/p"), data[: len(data) // 2], 1)
    a, b = direct.finish(), reference.finish()
    for name in ("stamp_ns", "track_id", "object_class", "path_bounds", "n_poses"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    for name in ("confidence", "first_s", "time_step_s", "points"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
