"""Write a track table as a ROS bag: ROS 2 (sqlite3 or MCAP storage, a directory) or ROS 1 (.bag).

Per recording, one ``autoware_perception_msgs/msg/TrackedObjects`` message per frame on its topic
and a ``visualization_msgs/msg/MarkerArray`` companion on ``<topic>/markers`` (cube per object,
``ns`` = class, ``text`` = ``lane_id=<n>``), as fixed in :mod:`lanecast.io_adapters.logs.object_columns`. The
recording metadata (source, frame rate, units, recordings) is a ``std_msgs/msg/String`` (JSON) on
``/lanecast/metadata`` at the first message time, and in ROS 2 also rosbag2 ``custom_data``.
Written through rosbags' writers into a temporary path, renamed when complete.
"""

from __future__ import annotations

import json
import shutil
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa

from lanecast.io_adapters.contracts import track_table
from lanecast.io_adapters.errors import InputError, OutputError
from lanecast.io_adapters.files import atomic_path
from lanecast.io_adapters.formats import registry
from lanecast.io_adapters.logs import conventions as conv
from lanecast.io_adapters.logs import object_columns as to
from lanecast.io_adapters.logs.messages import ros_types
from lanecast.io_adapters.logs.rosbag.copy import compress_bag_storage
from lanecast.io_adapters.progress import bar

STORAGES = registry.ROS2_STORAGES
MAX_ROS_TIME_NS = (2**31 - 1) * 1_000_000_000 + 999_999_999  # a header stamp's sec is an int32


class _Builder:
    """Builds the TrackedObjects and MarkerArray messages of frame groups (ROS 1 or ROS 2 store)."""

    def __init__(self, table: pa.Table, ros_version: int) -> None:
        self.store = ros_types.typestore(ros_version)
        self.ros_version = ros_version
        c = conv.table_columns(table)
        self.c = c
        qz, qw = to.quat_of_yaw(c["heading"].astype(np.float64))
        heading = c["heading"].astype(np.float64)
        bvx, bvy = to.rotate(c["vx"].astype(np.float64), c["vy"].astype(np.float64), -heading)
        bax, bay = to.rotate(c["ax"].astype(np.float64), c["ay"].astype(np.float64), -heading)
        lane = c["lane_id"]
        self.rows = {
            "x": c["x"].tolist(),
            "y": c["y"].tolist(),
            "qz": qz.tolist(),
            "qw": qw.tolist(),
            "vx": bvx.tolist(),
            "vy": bvy.tolist(),
            "ax": bax.tolist(),
            "ay": bay.tolist(),
            "length": c["length"].astype(np.float64).tolist(),
            "width": c["width"].astype(np.float64).tolist(),
            "track": c["track_id"].tolist(),
            "cls": c["object_class"].astype(str).tolist(),
            "lane": np.where(
                np.isnan(lane), "", np.char.add("lane_id=", np.nan_to_num(lane).astype(np.int64).astype(str))
            ).tolist(),
        }
        self.seq = 0
        new = partial(ros_types.constructor, self.store)
        self.point = new("geometry_msgs/msg/Point", ("x", "y", "z"))
        self.quaternion = new("geometry_msgs/msg/Quaternion", ("x", "y", "z", "w"))
        self.pose_of = new("geometry_msgs/msg/Pose", ("position", "orientation"))
        self.vector = new("geometry_msgs/msg/Vector3", ("x", "y", "z"))
        self.pose_covariance = new("geometry_msgs/msg/PoseWithCovariance", ("pose", "covariance"))
        self.twist = new("geometry_msgs/msg/Twist", ("linear", "angular"))
        self.twist_covariance = new("geometry_msgs/msg/TwistWithCovariance", ("twist", "covariance"))
        self.accel = new("geometry_msgs/msg/Accel", ("linear", "angular"))
        self.accel_covariance = new("geometry_msgs/msg/AccelWithCovariance", ("accel", "covariance"))
        self.kinematics = new(
            "autoware_perception_msgs/msg/TrackedObjectKinematics",
            (
                "pose_with_covariance",
                "twist_with_covariance",
                "acceleration_with_covariance",
                "orientation_availability",
                "is_stationary",
            ),
        )
        self.uuid = new("unique_identifier_msgs/msg/UUID", ("uuid",))
        self.shape = new("autoware_perception_msgs/msg/Shape", ("type", "dimensions"))
        self.tracked_object = new(
            "autoware_perception_msgs/msg/TrackedObject",
            ("object_id", "existence_probability", "classification", "kinematics", "shape"),
        )
        marker_fields = ("header", "ns", "id", "type", "action", "pose", "scale", "color", "text")
        self.marker = new("visualization_msgs/msg/Marker", marker_fields)
        # sub-messages every object shares (rosbags' messages are serialized, never changed)
        self.zero = self.vector(x=0.0, y=0.0, z=0.0)
        self.covariance = np.zeros(36)
        self.classes = {
            cls: self._m(
                "autoware_perception_msgs/msg/ObjectClassification",
                label=conv.LABEL_OF_CLASS.get(cls, 0),
                probability=1.0,
            )
            for cls in set(self.rows["cls"])
        }
        self.color = self._m("std_msgs/msg/ColorRGBA", r=0.2, g=0.5, b=0.9, a=0.6)

    def _m(self, typename: str, **values: Any) -> Any:
        return ros_types.make(self.store, typename, **values)

    def header(self, stamp: int, frame_id: str) -> Any:
        sec, nsec = divmod(int(stamp), 1_000_000_000)
        t = self._m("builtin_interfaces/msg/Time", sec=sec, nanosec=nsec)
        self.seq += 1
        if self.ros_version == 1:
            return self._m("std_msgs/msg/Header", seq=self.seq, stamp=t, frame_id=frame_id)
        return self._m("std_msgs/msg/Header", stamp=t, frame_id=frame_id)

    def frame_messages(self, rows_idx: list[int], stamp: int, frame_id: str) -> tuple[bytes, bytes]:
        """The TrackedObjects and the MarkerArray message of one frame's rows (sharing each row's
        pose and size)."""
        rows, point, quaternion, pose, vector = (
            self.rows,
            self.point,
            self.quaternion,
            self.pose_of,
            self.vector,
        )
        x, y, qz, qw, length, width = (rows[k] for k in ("x", "y", "qz", "qw", "length", "width"))
        poses = [
            pose(
                position=point(x=x[r], y=y[r], z=0.0), orientation=quaternion(x=0.0, y=0.0, z=qz[r], w=qw[r])
            )
            for r in rows_idx
        ]
        sizes = [vector(x=length[r], y=width[r], z=conv.BOX_HEIGHT) for r in rows_idx]
        return (
            self.tracked_objects(rows_idx, poses, sizes, stamp, frame_id),
            self.markers(rows_idx, poses, sizes, stamp, frame_id),
        )

    def tracked_objects(
        self, rows_idx: list[int], poses: list[Any], sizes: list[Any], stamp: int, frame_id: str
    ) -> bytes:
        rows, cov, zero, vector = self.rows, self.covariance, self.zero, self.vector
        objects = []
        for r, pose, size in zip(rows_idx, poses, sizes, strict=True):
            kinematics = self.kinematics(
                pose_with_covariance=self.pose_covariance(pose=pose, covariance=cov),
                twist_with_covariance=self.twist_covariance(
                    twist=self.twist(linear=vector(x=rows["vx"][r], y=rows["vy"][r], z=0.0), angular=zero),
                    covariance=cov,
                ),
                acceleration_with_covariance=self.accel_covariance(
                    accel=self.accel(linear=vector(x=rows["ax"][r], y=rows["ay"][r], z=0.0), angular=zero),
                    covariance=cov,
                ),
                orientation_availability=2,
                is_stationary=False,
            )
            objects.append(
                self.tracked_object(
                    object_id=self.uuid(uuid=to.track_id_to_uuid(rows["track"][r])),
                    existence_probability=1.0,
                    classification=[self.classes[rows["cls"][r]]],
                    kinematics=kinematics,
                    shape=self.shape(type=0, dimensions=size),
                )
            )
        msg = self._m(ros_types.TRACKED_OBJECTS, header=self.header(stamp, frame_id), objects=objects)
        return self.serialize(msg, ros_types.TRACKED_OBJECTS)

    def markers(
        self, rows_idx: list[int], poses: list[Any], sizes: list[Any], stamp: int, frame_id: str
    ) -> bytes:
        rows, marker = self.rows, self.marker
        header = self.header(stamp, frame_id)
        markers = [
            marker(
                header=header,
                ns=rows["cls"][r],
                id=rows["track"][r],
                type=1,
                action=0,
                pose=pose,
                scale=size,
                color=self.color,
                text=rows["lane"][r],
            )
            for r, pose, size in zip(rows_idx, poses, sizes, strict=True)
        ]
        return self.serialize(self._m(ros_types.MARKER_ARRAY, markers=markers), ros_types.MARKER_ARRAY)

    def string(self, text: str) -> bytes:
        return self.serialize(self._m(ros_types.STRING, data=text), ros_types.STRING)

    def serialize(self, msg: Any, typename: str) -> bytes:
        if self.ros_version == 1:
            return bytes(self.store.serialize_ros1(msg, typename))
        return bytes(self.store.serialize_cdr(msg, typename))


def write(table: pa.Table, out: Path, fmt: str = "ros2", *, storage: str = "mcap", **options: Any) -> Path:
    """Write ``table`` as a ROS 2 bag directory (``fmt="ros2"``, ``storage`` mcap|sqlite3) or a ROS 1 .bag.

    MCAP storage by default: chunked, zstd-compressed and with CRCs, about 1/50 of sqlite3's size for
    the same traffic; sqlite3 for tools that read nothing else."""
    if fmt not in ("ros1", "ros2"):
        raise InputError(out, f"unknown bag format {fmt!r}", expected="ros1 or ros2")
    if storage not in STORAGES:
        raise InputError(out, f"unknown rosbag2 storage {storage!r}", expected=" or ".join(STORAGES))
    track_table.validate(table)
    out = Path(out)
    track_ids = table.column("track_id").to_numpy()
    if track_ids.size and (track_ids.min() < -(2**31) or track_ids.max() >= 2**31):
        raise InputError(
            out, "track ids do not fit the int32 marker id", column="track_id", expected="ids < 2**31"
        )
    offset = conv.log_time_offset(table)
    table = conv.shifted(table, offset)  # the log's clock: the recordings' dates, not 1970
    times = table.column("time_ns").to_numpy()
    if times.size and times.max() > MAX_ROS_TIME_NS:
        row = int(np.flatnonzero(times > MAX_ROS_TIME_NS)[0])
        raise OutputError(
            out,
            f"cannot be a ROS bag: row {row} of the table has time_ns {times[row]}, after what a ROS time "
            "holds (int32 seconds: 2038-01-19)",
            column="time_ns",
            expected=f"times up to {MAX_ROS_TIME_NS} ns, or an MCAP log (--to mcap)",
        )
    meta = track_table.read_meta(table)
    names = sorted(meta.recordings)
    topics = conv.recording_topics(names)
    builder = _Builder(table, 1 if fmt == "ros1" else 2)
    c = builder.c
    groups, plan = conv.message_plan(c["recording"], c["frame"], c["track_id"], c["time_ns"], names)
    meta_doc = conv.log_metadata(table, topics, groups, offset)
    doc = json.dumps(meta_doc, sort_keys=True)
    frames = [meta.recordings[n].coordinate_frame for n in names]
    first = int(plan[0, 0]) if plan.shape[0] else 0

    def emit(writer: Any, conns: dict[str, Any]) -> None:
        group_list = [groups[n] for n in names]
        digest = conv.PayloadDigest()
        with bar(desc=f"writing {out.name}", total=int(plan.shape[0]), unit="msg") as progress:
            for stamp, rec, gi in plan.tolist():
                g = group_list[rec]
                rows = g.order[g.starts[gi] : g.starts[gi + 1]].tolist()
                topic = topics[names[rec]]
                tracked, markers = builder.frame_messages(rows, stamp, frames[rec])
                for name, payload in ((topic, tracked), (topic + conv.MARKER_SUFFIX, markers)):
                    writer.write(conns[name], stamp, payload)
                    digest.add(name, stamp, payload)
                progress.update(1)
        # Written last (at the first stamp, so that readers meet it first): the metadata carries
        # the checksum of every message, which ROS 1 and sqlite3 bags otherwise lack.
        checked = {**meta_doc, "payload_digest": digest.hexdigest(), "payload_messages": digest.count}
        writer.write(conns[conv.META_TOPIC], first, builder.string(json.dumps(checked, sort_keys=True)))

    connections = [(conv.META_TOPIC, ros_types.STRING)]
    for n in names:
        connections += [
            (topics[n], ros_types.TRACKED_OBJECTS),
            (topics[n] + conv.MARKER_SUFFIX, ros_types.MARKER_ARRAY),
        ]
    if fmt == "ros1":
        from rosbags.rosbag1 import Writer as Writer1

        with atomic_path(out) as tmp:
            tmp.unlink()
            w1 = Writer1(tmp)
            w1.set_compression(Writer1.CompressionFormat.LZ4)
            with w1:
                conns = {t: w1.add_connection(t, ty, typestore=builder.store) for t, ty in connections}
                emit(w1, conns)
        return out
    from rosbags.rosbag2 import StoragePlugin
    from rosbags.rosbag2 import Writer as Writer2

    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
    with atomic_path(out, directory=True, replaces=conv.BAG_FILES) as tmp:
        inner = tmp / out.name
        w2 = Writer2(inner, version=Writer2.VERSION_LATEST, storage_plugin=plugin)
        w2.set_custom_data(conv.META_NAME, doc)
        with w2:
            conns = {t: w2.add_connection(t, ty, typestore=builder.store) for t, ty in connections}
            emit(w2, conns)
        compress_bag_storage(inner)  # rosbags writes uncompressed chunks and CRC 0 everywhere
        for item in inner.iterdir():
            shutil.move(str(item), tmp / item.name)
        inner.rmdir()
    return out
