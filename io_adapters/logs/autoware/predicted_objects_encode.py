"""lanecast's forecasts as Autoware ``autoware_perception_msgs/msg/PredictedObjects`` (ROS 2 CDR).

A planner or Autoware's tools replaying an annotated log take predictions in this type, not as
Foxglove scenes: one message per forecast time on :data:`AUTOWARE_TOPIC`, per target its UUID
(the track id as the track reader reads it back), its pose at t0 and its K alternatives as paths,
most probable first, with lanecast's maneuver-sequence probabilities as confidences. A path starts
at the target's position at t0 (Autoware's convention: the first pose is at the header stamp) and
holds the 5 forecast positions 1 s apart; each pose faces along the path. The messages are written
straight as little-endian CDR (a rosbags message object per pose would cost more than the copy of
the log); the schema is Autoware's published definition, as shipped in ``data/ros_msgs``.
"""

from __future__ import annotations

import functools
import struct
from collections.abc import Iterator
from typing import Any

import numpy as np
from rosbags.typesys import Stores, get_typestore

from lanecast.io_adapters.logs.autoware.predicted_objects import PREDICTED_OBJECTS
from lanecast.io_adapters.logs.forecast_batch import ForecastBatch
from lanecast.io_adapters.logs.forecast_messages import BULK_ROWS, ChannelSpec
from lanecast.io_adapters.logs.foxglove.scene_update_cdr import ros2_typestore
from lanecast.io_adapters.logs.messages import ros_types
from lanecast.io_adapters.logs.object_columns import track_id_to_uuid

AUTOWARE_TOPIC = "/lanecast/predicted_objects"
STEP_S = 1  # the forecast positions are 1 s apart
_ZEROS_36 = bytes(8 * 36)
_HEADER = b"\x00\x01\x00\x00"  # CDR, little endian


def schema_text() -> str:
    """The ``ros2msg`` schema of :data:`PREDICTED_OBJECTS` (the shipped Autoware definitions)."""
    return ros_types.schema_text(PREDICTED_OBJECTS)


@functools.cache
def writer_typestore() -> Any:
    """A ROS 2 typestore with the Foxglove and the Autoware types (what a bag writer registers from)."""
    store = get_typestore(Stores.ROS2_HUMBLE)
    for other in (ros2_typestore(), ros_types.typestore(2)):
        store.register({n: d for n, d in other.fielddefs.items() if n not in store.fielddefs})
    return store


def _quat_z(yaw: np.ndarray) -> np.ndarray:
    """[..., 4] quaternions (x, y, z, w) of rotations by ``yaw`` about z."""
    q = np.zeros((*yaw.shape, 4))
    q[..., 2], q[..., 3] = np.sin(yaw / 2), np.cos(yaw / 2)
    return q


def path_poses(batch: ForecastBatch) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(poses [N, K, 6, 7] as x y z qx qy qz qw from t0 on, confidences [N, K], path order [N, K]).

    Paths are the alternatives (the forecast alone, confidence 1, where there are none), most probable
    first; a target whose position at t0 is unknown starts one step before its first point."""
    n = batch.track_id.size
    if batch.alt_points.shape[1]:
        pts, conf = batch.alt_points, np.nan_to_num(batch.alt_prob, nan=0.0)
    else:
        pts, conf = batch.points[:, None], np.ones((n, 1))
    origin = np.where(np.isfinite(batch.origin), batch.origin, 2 * batch.points[:, 0] - batch.points[:, 1])
    xy = np.concatenate([np.broadcast_to(origin[:, None, None], (n, pts.shape[1], 1, 2)), pts], axis=2)
    d = np.diff(xy, axis=2)
    yaw = np.arctan2(d[..., 1], d[..., 0])
    yaw = np.concatenate([yaw, yaw[..., -1:]], axis=2)
    poses = np.concatenate([xy, np.zeros((*xy.shape[:3], 1)), _quat_z(yaw)], axis=-1)
    order = np.argsort(-conf, axis=1, kind="stable")
    rows = np.arange(n)[:, None]
    return poses[rows, order], conf[rows, order], order


class _Cdr:
    """A CDR message being written; offsets align from the end of the 4-byte encapsulation header."""

    def __init__(self) -> None:
        self.buf = bytearray(_HEADER)

    def align(self, n: int) -> None:
        self.buf += bytes(-(len(self.buf) - 4) % n)

    def pack(self, align: int, fmt: str, *values: Any) -> None:
        self.align(align)
        self.buf += struct.pack(fmt, *values)

    def string(self, text: str) -> None:
        raw = text.encode()
        self.pack(4, "<I", len(raw) + 1)
        self.buf += raw + b"\x00"

    def float64s(self, values: np.ndarray) -> None:
        self.align(8)
        self.buf += np.ascontiguousarray(values, dtype="<f8").tobytes()


def predicted_objects_cdr(batch: ForecastBatch) -> list[bytes]:
    """One ``PredictedObjects`` CDR message per frame of ``batch``."""
    poses, conf, _ = path_poses(batch)
    speed = np.hypot(*(poses[:, 0, 1, :2] - poses[:, 0, 0, :2]).T) / STEP_S if len(poses) else np.zeros(0)
    uuids = [track_id_to_uuid(int(t)).tobytes() for t in batch.track_id]
    out = []
    for f in range(batch.n_frames):
        lo, hi = int(batch.bounds[f]), int(batch.bounds[f + 1])
        t0 = int(batch.t0_ns[f])
        w = _Cdr()
        w.pack(4, "<iI", t0 // 1_000_000_000, t0 % 1_000_000_000)
        w.string(batch.frame_id[f])
        w.pack(4, "<I", hi - lo)
        for i in range(lo, hi):
            w.buf += uuids[i]  # unique_identifier_msgs/UUID: uint8[16]
            w.pack(4, "<f", 1.0)  # existence_probability
            w.pack(4, "<IBxxxf", 1, 0, 1.0)  # classification: one, UNKNOWN (the tracks' class is not kept)
            w.float64s(poses[i, 0, 0])  # initial pose: the path's first pose, at t0
            w.buf += _ZEROS_36
            w.float64s(np.array([speed[i], 0, 0, 0, 0, 0]))  # twist in the body frame
            w.buf += _ZEROS_36
            w.float64s(np.zeros(6))  # acceleration
            w.buf += _ZEROS_36
            w.pack(4, "<I", poses.shape[1])
            for k in range(poses.shape[1]):
                w.pack(4, "<I", poses.shape[2])
                w.float64s(poses[i, k])
                w.pack(4, "<iIf", STEP_S, 0, float(conf[i, k]))
            w.pack(4, "<BxxxI", 0, 0)  # shape: BOUNDING_BOX, no footprint points
            w.float64s(np.zeros(3))  # dimensions unknown
        out.append(bytes(w.buf))
    return out


def channel_spec() -> ChannelSpec:
    """The channel a log with Autoware predictions gets (schema: Autoware's published definition)."""
    return ChannelSpec(
        AUTOWARE_TOPIC, PREDICTED_OBJECTS, "ros2msg", schema_text().encode(), "cdr", PREDICTED_OBJECTS
    )


def encode_batch(batch: ForecastBatch) -> Iterator[tuple[int, bytes]]:
    """(t0 in ns, PredictedObjects CDR) of each frame in order, up to ``BULK_ROWS`` targets at a time."""
    first = 0
    while first < batch.n_frames:
        last = int(np.searchsorted(batch.bounds, batch.bounds[first] + BULK_ROWS, side="right")) - 1
        last = min(max(last, first + 1), batch.n_frames)
        part = batch.slice(first, last)
        yield from zip(part.t0_ns.tolist(), predicted_objects_cdr(part), strict=True)
        first = last
