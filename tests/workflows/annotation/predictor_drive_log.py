"""A drive log written with rosbags and mcap directly (not lanecast's writers): Autoware tracked
objects at 10 Hz and a recorded predictor whose errors are known by construction.

Cars (track id = first UUID byte): 1 drives at 20 m/s, 2 at 15 m/s drifting left at 0.5 m/s, 3
accelerates from 10 m/s at 1 m/s², 4 drives at 18 m/s and leaves the log at ``LEAVES_S``. The
predictor (every second from ``FIRST_PREDICTION_S``) gives each object three paths of constant
velocity from its true state, shifted by ``OFFSETS`` (confidences ``CONFIDENCES``), 0.1 s apart over
5 s from the stamp, and predicts an object the tracker never had (``GHOST``).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
from mcap.writer import Writer as McapWriter
from rosbags.rosbag2 import StoragePlugin
from rosbags.rosbag2 import Writer as Bag2Writer

from lanecast.io_adapters.logs.messages import ros_types

PKG = "autoware_perception_msgs"
TRACKED = f"{PKG}/msg/TrackedObjects"
PREDICTED = f"{PKG}/msg/PredictedObjects"
TRACKS_TOPIC = "/perception/object_recognition/tracking/objects"
PREDICTIONS_TOPIC = "/perception/object_recognition/objects"
START_S, END_S = 0.5, 12.9  # tracked objects, 10 Hz
FIRST_PREDICTION_S, LAST_PREDICTION_S = 4.0, 12.0
LEAVES_S = 7.0
GHOST = 99
OFFSETS = ((1.0, 0.5), (0.0, 3.5), (0.0, -3.5))  # (dx, dy) m of the three paths
CONFIDENCES = (0.6, 0.3, 0.1)
CARS = {  # id: (x0, y0, vx, vy, ax) at t = 0
    1: (0.0, 0.0, 20.0, 0.0, 0.0),
    2: (5.0, 3.5, 15.0, 0.5, 0.0),
    3: (-20.0, -3.5, 10.0, 0.0, 1.0),
    4: (30.0, 7.0, 18.0, 0.0, 0.0),
}


def state(car: int, t: float) -> tuple[float, float, float, float]:
    """(x, y, vx, vy) of ``car`` at ``t`` s."""
    x0, y0, vx, vy, ax = CARS[car]
    return x0 + vx * t + 0.5 * ax * t * t, y0 + vy * t, vx + ax * t, vy


def present(car: int, t: float) -> bool:
    return START_S - 1e-9 <= t <= (LEAVES_S if car == 4 else END_S) + 1e-9


def _header(store: Any, t_ns: int) -> Any:
    m = ros_types.make
    stamp = m(store, "builtin_interfaces/msg/Time", sec=t_ns // 10**9, nanosec=t_ns % 10**9)
    return m(store, "std_msgs/msg/Header", stamp=stamp, frame_id="map")


def _pose(store: Any, x: float, y: float, yaw: float) -> Any:
    m = ros_types.make
    return m(
        store,
        "geometry_msgs/msg/Pose",
        position=m(store, "geometry_msgs/msg/Point", x=x, y=y),
        orientation=m(store, "geometry_msgs/msg/Quaternion", z=math.sin(yaw / 2), w=math.cos(yaw / 2)),
    )


def _uuid(store: Any, car: int) -> Any:
    return ros_types.make(
        store, "unique_identifier_msgs/msg/UUID", uuid=np.array([car] + [0] * 15, dtype=np.uint8)
    )


def tracked(store: Any, t_ns: int) -> Any:
    m = ros_types.make
    t = t_ns * 1e-9
    objects = []
    for car in CARS:
        if not present(car, t):
            continue
        x, y, vx, vy = state(car, t)
        yaw = math.atan2(vy, vx)
        speed = math.hypot(vx, vy)
        twist = m(store, "geometry_msgs/msg/Twist", linear=m(store, "geometry_msgs/msg/Vector3", x=speed))
        kin = m(
            store,
            f"{PKG}/msg/TrackedObjectKinematics",
            pose_with_covariance=m(
                store, "geometry_msgs/msg/PoseWithCovariance", pose=_pose(store, x, y, yaw)
            ),
            orientation_availability=2,
            twist_with_covariance=m(store, "geometry_msgs/msg/TwistWithCovariance", twist=twist),
        )
        objects.append(
            m(
                store,
                f"{PKG}/msg/TrackedObject",
                object_id=_uuid(store, car),
                existence_probability=1.0,
                classification=[m(store, f"{PKG}/msg/ObjectClassification", label=1, probability=1.0)],
                kinematics=kin,
                shape=m(
                    store, f"{PKG}/msg/Shape", dimensions=m(store, "geometry_msgs/msg/Vector3", x=4.5, y=1.8)
                ),
            )
        )
    return m(store, TRACKED, header=_header(store, t_ns), objects=objects)


def cv_path(car: int, t: float, dx: float, dy: float, steps: int = 51, step_s: float = 0.1) -> np.ndarray:
    """[steps, 2]: constant velocity from the true state at ``t`` (first pose at ``t``), shifted."""
    x, y, vx, vy = state(car, t)
    tau = np.arange(steps) * step_s
    return np.stack([x + vx * tau + dx, y + vy * tau + dy], axis=1)


def predicted(store: Any, t_ns: int, stamp_shift_ns: int = 0) -> Any:
    m = ros_types.make
    t = t_ns * 1e-9
    objects = []
    for car in [*(c for c in CARS if present(c, t)), GHOST]:
        source = car if car != GHOST else 1
        paths = []
        for (dx, dy), conf in zip(OFFSETS, CONFIDENCES, strict=True):
            xy = cv_path(source, t, dx + (40.0 if car == GHOST else 0.0), dy)
            paths.append(
                m(
                    store,
                    f"{PKG}/msg/PredictedPath",
                    path=[_pose(store, float(px), float(py), 0.0) for px, py in xy],
                    time_step=m(store, "builtin_interfaces/msg/Duration", sec=0, nanosec=100_000_000),
                    confidence=conf,
                )
            )
        kin = m(store, f"{PKG}/msg/PredictedObjectKinematics", predicted_paths=paths)
        objects.append(
            m(
                store,
                f"{PKG}/msg/PredictedObject",
                object_id=_uuid(store, car),
                existence_probability=1.0,
                classification=[m(store, f"{PKG}/msg/ObjectClassification", label=1, probability=1.0)],
                kinematics=kin,
            )
        )
    return m(store, PREDICTED, header=_header(store, t_ns + stamp_shift_ns), objects=objects)


def track_stamps() -> list[int]:
    return [round((START_S + i / 10) * 1e9) for i in range(round((END_S - START_S) * 10) + 1)]


def prediction_stamps() -> list[int]:
    n = round(LAST_PREDICTION_S - FIRST_PREDICTION_S) + 1
    return [round((FIRST_PREDICTION_S + i) * 1e9) for i in range(n)]


def messages(stamp_shift_ns: int = 0) -> list[tuple[str, str, int, bytes]]:
    """(topic, type, log time, CDR) of the whole log, in log-time order."""
    store = ros_types.typestore(2)
    out = [
        (TRACKS_TOPIC, TRACKED, t, bytes(store.serialize_cdr(tracked(store, t), TRACKED)))
        for t in track_stamps()
    ]
    out += [
        (
            PREDICTIONS_TOPIC,
            PREDICTED,
            t,
            bytes(store.serialize_cdr(predicted(store, t, stamp_shift_ns), PREDICTED)),
        )
        for t in prediction_stamps()
    ]
    return sorted(out, key=lambda r: r[2])


def write_mcap(path: Path, stamp_shift_ns: int = 0) -> Path:
    """The log as an MCAP with ros2msg schemas (the definitions the test module ships)."""
    with path.open("wb") as fh:
        writer = McapWriter(fh)
        writer.start()
        channels = {}
        for topic, msgtype in ((TRACKS_TOPIC, TRACKED), (PREDICTIONS_TOPIC, PREDICTED)):
            schema = writer.register_schema(msgtype, "ros2msg", ros_types.schema_text(msgtype).encode())
            channels[topic] = writer.register_channel(topic, "cdr", schema)
        for topic, _, t, data in messages(stamp_shift_ns):
            writer.add_message(channels[topic], log_time=t, data=data, publish_time=t)
        writer.finish()
    return path


def write_bag(path: Path) -> Path:
    """The log as a ROS 2 bag (MCAP storage)."""
    store = ros_types.typestore(2)
    with Bag2Writer(path, version=Bag2Writer.VERSION_LATEST, storage_plugin=StoragePlugin.MCAP) as writer:
        conns = {
            topic: writer.add_connection(topic, msgtype, typestore=store)
            for topic, msgtype in ((TRACKS_TOPIC, TRACKED), (PREDICTIONS_TOPIC, PREDICTED))
        }
        for topic, _, t, data in messages():
            writer.write(conns[topic], t, data)
    return path
