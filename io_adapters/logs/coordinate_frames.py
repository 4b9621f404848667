"""Transforms between coordinate frames in a drive log, and moving points along a chain of them.

Collected from ``tf2_msgs/msg/TFMessage`` (``/tf``, ``/tf_static``), ``foxglove.FrameTransform(s)``
(protobuf or JSON) and ``nav_msgs/msg/Odometry`` as planar poses (x, y, yaw) of each child frame in
its parent over time; :meth:`Transforms.to_fixed` moves objects seen in a moving frame (an ego
vehicle's) into the fixed frame the chain reaches, interpolating each pose at the objects' times.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from types import SimpleNamespace
from typing import Any

import numpy as np

from lanecast.io_adapters.logs.object_columns import rotate, stamp_ns


@dataclass
class Transforms:
    """Planar poses of child frames in parent frames over time (from /tf, /tf_static, odometry)."""

    edges: dict[str, tuple[str, list[int], list[float]]] = field(
        default_factory=dict
    )  # child -> parent, t, xyyaw
    sources: set[str] = field(default_factory=set)

    def add(self, parent: str, child: str, t: int, x: float, y: float, q: Any, source: str) -> None:
        parent, child = parent.lstrip("/"), child.lstrip("/")
        entry = self.edges.get(child)
        if entry is None or entry[0] != parent:
            entry = (parent, [], [])
            self.edges[child] = entry
        entry[1].append(t)
        yaw = math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))
        entry[2].extend((x, y, yaw))
        self.sources.add(source)

    def add_tf(self, msg: Any, source: str) -> None:
        """A ``tf2_msgs/msg/TFMessage``."""
        for tr in msg.transforms:
            v = tr.transform.translation
            self.add(
                tr.header.frame_id,
                tr.child_frame_id,
                stamp_ns(tr.header),
                v.x,
                v.y,
                tr.transform.rotation,
                source,
            )

    def add_odometry(self, msg: Any, source: str) -> None:
        """A ``nav_msgs/msg/Odometry``: the pose of ``child_frame_id`` in ``header.frame_id``."""
        pose = msg.pose.pose
        self.add(
            msg.header.frame_id,
            msg.child_frame_id,
            stamp_ns(msg.header),
            pose.position.x,
            pose.position.y,
            pose.orientation,
            source,
        )

    def add_frame_transform(self, tr: Any, source: str) -> None:
        """A ``foxglove.FrameTransform`` (protobuf object, or its JSON document)."""
        if isinstance(tr, Mapping):
            ts, v, q = tr.get("timestamp") or {}, tr.get("translation") or {}, tr.get("rotation") or {}
            rotation = SimpleNamespace(**{k: float(q.get(k, 1.0 if k == "w" else 0.0)) for k in "xyzw"})
            t = int(ts.get("sec", 0)) * 1_000_000_000 + int(ts.get("nsec", 0))
            parent, child = str(tr.get("parent_frame_id", "")), str(tr.get("child_frame_id", ""))
            self.add(parent, child, t, float(v.get("x", 0.0)), float(v.get("y", 0.0)), rotation, source)
            return
        t = tr.timestamp.seconds * 1_000_000_000 + tr.timestamp.nanos
        self.add(
            tr.parent_frame_id, tr.child_frame_id, t, tr.translation.x, tr.translation.y, tr.rotation, source
        )

    def chain(self, frame: str, fixed: Iterable[str]) -> list[str] | None:
        """Frames from ``frame`` up to the first fixed frame, or None when the tree has no such path."""
        fixed = set(fixed)
        path = [frame]
        while path[-1] not in fixed:
            entry = self.edges.get(path[-1])
            if entry is None or entry[0] in path:
                return None
            path.append(entry[0])
        return path

    def to_fixed(
        self, path: list[str], t: np.ndarray, x: np.ndarray, y: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Points [n] at times t [n] in ``path[0]`` → (x, y, added yaw) in ``path[-1]`` (interpolated)."""
        yaw_total = np.zeros_like(x)
        for child in path[:-1]:
            _, times, xyyaw = self.edges[child]
            et = np.asarray(times, dtype=np.int64)
            poses = np.asarray(xyyaw, dtype=np.float64).reshape(-1, 3)
            order = np.argsort(et, kind="stable")
            et, poses = et[order], poses[order]
            tq = (t - et[0]).astype(np.float64)
            tr = (et - et[0]).astype(np.float64)
            ex = np.interp(tq, tr, poses[:, 0])
            ey = np.interp(tq, tr, poses[:, 1])
            eyaw = np.interp(tq, tr, np.unwrap(poses[:, 2]))
            x, y = rotate(x, y, eyaw)
            x, y = x + ex, y + ey
            yaw_total = yaw_total + eyaw
        return x, y, yaw_total
