"""Autoware ``PredictedObjects`` decoded straight from little-endian CDR bytes into columns.

rosbags builds a Python object per pose and per covariance array: about a millisecond per predicted
object, which made decoding a log's predictions cost more than annotating it. This reader walks the
message with ``struct`` and takes each path's poses as one numpy view. It reads exactly the layout
of the definitions shipped in ``data/ros_msgs`` (both packages lay the message out alike); a log
that defines the message otherwise, or a message it cannot walk, is left to rosbags (the caller's
fallback), which decodes it by the log's own definition or names what is wrong.
"""

from __future__ import annotations

import struct

import numpy as np

from lanecast.io_adapters.logs.autoware.predicted_objects import PredictionColumns
from lanecast.io_adapters.logs.conventions import AUTOWARE_LABELS
from lanecast.io_adapters.logs.object_columns import uuid_to_track_id

#: PoseWithCovariance, TwistWithCovariance and AccelWithCovariance: (7 + 36) + 2 × (6 + 36) float64
_KINEMATICS_BYTES = 8 * (7 + 36 + 2 * (6 + 36))
_U32 = struct.Struct("<I")
_TIME = struct.Struct("<iI")
_STEP_CONF = struct.Struct("<iIf")


class CdrLayoutError(ValueError):
    """The bytes do not follow the shipped layout (cut short, big endian, counts past the end)."""


def add_predicted_objects_cdr(cols: PredictionColumns, data: bytes | memoryview, log_time: int) -> None:
    """Append every object of one ``PredictedObjects`` CDR message to ``cols`` (as ``add_message``)."""
    buf = memoryview(data)
    if len(buf) < 4 or buf[1] != 1:
        raise CdrLayoutError("not little-endian CDR")
    end = len(buf)
    pos = 4

    def align(n: int) -> None:
        nonlocal pos
        pos += -(pos - 4) % n

    def u32() -> int:
        nonlocal pos
        align(4)
        if pos + 4 > end:
            raise CdrLayoutError(f"cut short at byte {pos}")
        (value,) = _U32.unpack_from(buf, pos)
        pos += 4
        return int(value)

    found: list[tuple[int, int, str, list[tuple[float, float, float, np.ndarray]]]] = []
    try:
        sec, nanosec = _TIME.unpack_from(buf, pos)
        pos += 8
        frame_id_bytes = u32()  # (u32 moves pos: never ``pos += u32()``)
        pos += frame_id_bytes
        stamp = (sec * 1_000_000_000 + nanosec) or log_time
        for _ in range(u32()):
            if pos + 16 > end:
                raise CdrLayoutError(f"cut short at byte {pos}")
            uuid = np.frombuffer(buf, np.uint8, 16, pos)
            pos += 16
            align(4)
            pos += 4  # existence_probability
            n_cls = u32()
            label = 0
            if n_cls:
                labels = np.frombuffer(buf, np.uint8, 8 * n_cls, pos)[::8]
                probs = np.frombuffer(buf, "<f4", 2 * n_cls, pos)[1::2]
                label = int(labels[int(np.argmax(probs))])
                pos += 8 * n_cls
            align(8)
            pos += _KINEMATICS_BYTES
            paths = []
            for _ in range(u32()):
                n = u32()
                if n:
                    align(8)
                poses = np.frombuffer(buf, "<f8", 7 * n, pos).reshape(n, 7)[:, :2]
                pos += 56 * n
                align(4)
                step_s, step_ns, confidence = _STEP_CONF.unpack_from(buf, pos)
                pos += 12
                paths.append((float(confidence), 0.0, step_s + step_ns * 1e-9, poses))
            pos += 1  # shape.type
            footprint = u32()
            pos += 12 * footprint  # points of float32 x, y, z
            align(8)
            pos += 24  # dimensions
            if pos > end:
                raise CdrLayoutError(f"cut short at byte {end}")
            name = AUTOWARE_LABELS.get(label, "unknown")
            found.append((stamp, uuid_to_track_id(uuid), name, paths))
    except (struct.error, ValueError) as exc:
        raise CdrLayoutError(str(exc)) from exc
    for stamp, track, name, paths in found:  # all or nothing: a fallback decodes the message again
        cols.add_paths(stamp, track, name, paths)
