"""Recorded predictions as columns: Autoware ``PredictedObjects`` messages → one array per field.

A predictor recorded in a drive log (Autoware's ``autoware_perception_msgs/msg/PredictedObjects``,
or ``autoware_auto_perception_msgs``'s as Autoware.Universe recorded it before) gives, per object,
its UUID, classification and several predicted paths, each with a confidence and a time step. The
scorer needs them as arrays, not messages: :class:`RecordedPredictions` holds one row per predicted
object (stamp, track id, class) and one row per path (confidence, the time of its first pose, its
time step and its poses, NaN-padded to the longest path). Autoware's first pose is at the header
stamp; lanecast's own forecasts start one step later (``first_s``), so both kinds fit one layout.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

import numpy as np

from lanecast.io_adapters.logs.conventions import AUTOWARE_LABELS
from lanecast.io_adapters.logs.object_columns import stamp_ns, uuid_to_track_id

PREDICTED_OBJECTS = "autoware_perception_msgs/msg/PredictedObjects"
PREDICTED_OBJECTS_AUTO = "autoware_auto_perception_msgs/msg/PredictedObjects"
PREDICTED_OBJECT_TYPES = (PREDICTED_OBJECTS, PREDICTED_OBJECTS_AUTO)


@dataclass(frozen=True)
class RecordedPredictions:
    """P predicted objects with Q paths of at most L poses, from one topic of one log."""

    topic: str
    stamp_ns: np.ndarray  # int64 [P]: the message's header stamp (its log time where the stamp is 0)
    track_id: np.ndarray  # int64 [P]: from the UUID as the track reader makes it
    object_class: np.ndarray  # str [P]
    path_bounds: np.ndarray  # int64 [P + 1]: object i's paths are rows path_bounds[i]:path_bounds[i + 1]
    confidence: np.ndarray  # float64 [Q], NaN where unknown
    first_s: np.ndarray  # float64 [Q]: time of the first pose after the stamp (s)
    time_step_s: np.ndarray  # float64 [Q]
    n_poses: np.ndarray  # int64 [Q]
    points: np.ndarray  # float64 [Q, L, 2], NaN past n_poses

    def __len__(self) -> int:
        return int(self.stamp_ns.size)

    @property
    def path_object(self) -> np.ndarray:
        """int64 [Q]: the object row of each path."""
        return np.repeat(np.arange(len(self)), np.diff(self.path_bounds))


class PredictionColumns:
    """Collects predicted objects message by message; :meth:`finish` makes the arrays."""

    def __init__(self, topic: str) -> None:
        self.topic = topic
        self.stamps: list[int] = []
        self.tracks: list[int] = []
        self.classes: list[str] = []
        self.paths_per_object: list[int] = []
        self.path_rows: list[tuple[float, float, float]] = []  # confidence, first_s, time_step_s
        self.poses: list[np.ndarray] = []  # [n, 2] per path

    def add_message(self, msg: Any, log_time: int) -> None:
        """Append every object of a ``PredictedObjects`` message (either package)."""
        stamp = stamp_ns(msg.header) or log_time
        for obj in msg.objects:
            label = max(obj.classification, key=lambda c: c.probability).label if obj.classification else 0
            self.stamps.append(stamp)
            self.tracks.append(uuid_to_track_id(obj.object_id.uuid))
            self.classes.append(AUTOWARE_LABELS.get(int(label), "unknown"))
            paths = obj.kinematics.predicted_paths
            self.paths_per_object.append(len(paths))
            for path in paths:
                step = int(path.time_step.sec) + int(path.time_step.nanosec) * 1e-9
                self.path_rows.append((float(path.confidence), 0.0, step))
                xy = [(p.position.x, p.position.y) for p in path.path]
                self.poses.append(np.array(xy, dtype=np.float64).reshape(-1, 2))

    def add_paths(
        self,
        stamp: int,
        track_id: int,
        object_class: str,
        paths: Iterable[tuple[float, float, float, np.ndarray]],
    ) -> None:
        """Append one object given as (confidence, first_s, time_step_s, poses [n, 2]) per path."""
        rows = list(paths)
        self.stamps.append(stamp)
        self.tracks.append(track_id)
        self.classes.append(object_class)
        self.paths_per_object.append(len(rows))
        for confidence, first, step, xy in rows:
            self.path_rows.append((confidence, first, step))
            self.poses.append(np.asarray(xy, dtype=np.float64).reshape(-1, 2))

    def finish(self) -> RecordedPredictions:
        n_poses = np.array([len(p) for p in self.poses], dtype=np.int64)
        longest = int(n_poses.max()) if n_poses.size else 0
        points = np.full((len(self.poses), longest, 2), np.nan)
        if longest:
            rows = np.repeat(np.arange(len(self.poses)), n_poses)
            cols = np.arange(n_poses.sum()) - np.repeat(np.cumsum(n_poses) - n_poses, n_poses)
            points[rows, cols] = np.concatenate(self.poses)
        meta = np.array(self.path_rows, dtype=np.float64).reshape(-1, 3)
        return RecordedPredictions(
            topic=self.topic,
            stamp_ns=np.array(self.stamps, dtype=np.int64),
            track_id=np.array(self.tracks, dtype=np.int64),
            object_class=np.array(self.classes, dtype=object).astype(str),
            path_bounds=np.concatenate([[0], np.cumsum(self.paths_per_object, dtype=np.int64)]).astype(
                np.int64
            ),
            confidence=meta[:, 0],
            first_s=meta[:, 1],
            time_step_s=meta[:, 2],
            n_poses=n_poses,
            points=points,
        )


def resample(pred: RecordedPredictions, horizons_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Every path's position at ``horizons_s`` [H] after its stamp, linear between poses.

    Returns (points [Q, H, 2], reason [Q] str: "" where the path reaches every horizon, else why it
    is refused: a time step that is not a positive finite number, or a path that ends too early).
    """
    q = pred.n_poses.size
    out = np.full((q, horizons_s.size, 2), np.nan)
    reason = np.full(q, "", dtype=object)
    step, first, n = pred.time_step_s, pred.first_s, pred.n_poses
    bad_step = ~(np.isfinite(step) & (step > 0)) & (n > 1)
    last = first + np.where(n > 1, (n - 1) * np.where(bad_step, 0.0, step), 0.0)
    short = ~bad_step & ((n == 0) | (last + 1e-9 < horizons_s[-1]) | (first - 1e-9 > horizons_s[0]))
    bad_pose = ~np.isfinite(pred.points).all(axis=2) & (np.arange(pred.points.shape[1]) < n[:, None])
    for i in np.flatnonzero(bad_step):
        reason[i] = f"time step {step[i]:g} s is not a positive duration"
    for i in np.flatnonzero(short):
        reason[i] = (
            f"{n[i]} poses every {step[i]:g} s cover {first[i]:g}–{last[i]:g} s, "
            f"not {horizons_s[0]:g}–{horizons_s[-1]:g} s"
        )
    for i in np.flatnonzero(bad_pose.any(axis=1) & (reason == "")):
        reason[i] = "a pose is not finite"
    ok = np.flatnonzero(reason == "")
    if ok.size:
        pos = (horizons_s[None, :] - first[ok, None]) / np.where(n[ok, None] > 1, step[ok, None], 1.0)
        lo = np.clip(np.floor(pos + 1e-9).astype(np.int64), 0, np.maximum(n[ok, None] - 2, 0))
        frac = np.clip(pos - lo, 0.0, 1.0)[..., None]
        rows = ok[:, None]
        hi = np.minimum(lo + 1, n[ok, None] - 1)
        out[ok] = pred.points[rows, lo] * (1.0 - frac) + pred.points[rows, hi] * frac
    return out, reason.astype(str)
