"""Decoded objects of one drive log → one validated track table.

:func:`assemble` takes what the MCAP and ROS bag decoders collected per topic
(:class:`TopicData`), moves objects in moving frames into the fixed frame their transform chain
reaches (map, odom, world, road, or a frame named in lanecast's metadata), orders rows by (track,
frame) dropping rows that repeat another exactly (a message recorded twice; a repeat that says
something else is refused, never dropped), and fills heading from the quaternion yaw (from the
velocity where there is no orientation), velocities and accelerations from the message where it
has them, else from differences (positions, then velocities). Frame indices lie on the topic's
timeline at its nominal rate (median message interval, snapped to a whole rate within 1 %), from
each message's stamp (header stamp; for a SceneUpdate its earliest entity stamp), not the log time
the recorder gave it (:mod:`stamp_frames`).
Recordings: one per object topic, named after the file stem (``<stem>-<topic>`` when a log has
several), or the names stored in lanecast's metadata.
"""

from __future__ import annotations

import re
import sys
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa

from lanecast.io_adapters.contracts import track_table
from lanecast.io_adapters.contracts.track_runs import (
    along_track_derivative,
    row_extent,
    run_starts,
)
from lanecast.io_adapters.errors import FrameError, LanecastError, LogError, TrackTableError
from lanecast.io_adapters.logs.conventions import FIXED_FRAMES, KNOWN_CLASSES, MARKER_SUFFIX, OFFSET_KEY
from lanecast.io_adapters.logs.coordinate_frames import Transforms
from lanecast.io_adapters.logs.frames_from_stamps import frames_of
from lanecast.io_adapters.logs.object_columns import Categorical, ObjectColumns, rotate


@dataclass
class TopicData:
    """What was decoded from one topic."""

    topic: str
    msgtype: str
    columns: ObjectColumns = field(default_factory=ObjectColumns)


def _merge_markers(main: dict[str, np.ndarray], classes: Categorical, markers: ObjectColumns) -> Categorical:
    """Take lane ids and class strings from a lanecast marker companion, matched on (stamp, id)."""
    if len(markers) == 0:
        return classes
    m, m_cls, _ = markers.arrays()
    n_main = main["msg_time"].size
    # Dense ranks of (stamp, id) over both sides make one sortable int64 key per row.
    _, rt = np.unique(np.concatenate([main["msg_time"], m["msg_time"]]), return_inverse=True)
    ids, ri = np.unique(np.concatenate([main["track_id"], m["track_id"]]), return_inverse=True)
    key = rt.astype(np.int64) * ids.size + ri
    q, mk = key[:n_main], key[n_main:]
    order = np.argsort(mk, kind="stable")
    mk_sorted = mk[order]
    idx = np.minimum(np.searchsorted(mk_sorted, q), max(order.size - 1, 0))
    hit = mk_sorted[idx] == q
    src = order[idx]
    main["lane"] = np.where(hit, m["lane"][src], main["lane"])
    return classes.where(hit, m_cls.take(src))


def assemble(
    path: Path,
    topics: Mapping[str, TopicData],
    transforms: Transforms,
    log_meta: Mapping[str, Any] | None,
    *,
    source_format: str,
    topic: str | None = None,
    fixed_frames: Iterable[str] = FIXED_FRAMES,
    extra: Mapping[str, Any] | None = None,
) -> pa.Table:
    """One track table from the decoded topics of one log (validated).

    With lanecast's metadata the recordings and their topics come from it (marker companions fill
    lanes and classes); otherwise every supported topic with objects is one recording, named after
    the file's stem (``<stem>-<topic>`` when there are several).
    """
    fixed = set(fixed_frames)
    recordings_meta = (log_meta or {}).get("recordings") or {}
    if recordings_meta:
        fixed |= {str(r.get("coordinate_frame")) for r in recordings_meta.values()}
    plan: list[tuple[str, str | None]]
    if topic is not None:
        plan = [(topic, None)]
        for name, spec in recordings_meta.items():
            if spec.get("topic") == topic:
                plan = [(topic, name)]
    elif recordings_meta:
        plan = [
            (spec["topic"], name) for name, spec in recordings_meta.items() if spec.get("topic") in topics
        ]
        # The metadata is the log's word, not the truth: a topic with objects that it does not name
        # (a renamed topic, an edited document) is read as a recording of its own, never dropped.
        claimed = {t for t, _ in plan}
        claimed |= {t + MARKER_SUFFIX for t in claimed}
        for t in sorted(set(topics) - claimed):
            if len(topics[t].columns):
                name = _fallback_name(path, t, set(recordings_meta))
                print(
                    f"lanecast: {path}: topic {t!r} has objects but no entry in the log's lanecast "
                    f"metadata; read as recording {name!r}",
                    file=sys.stderr,
                )
                plan.append((t, name))
    else:
        marker_topics = {t + MARKER_SUFFIX for t in topics}
        plan = [(t, None) for t in sorted(topics) if t not in marker_topics or len(topics) == 1]
    stem = path.stem if path.suffix else path.name
    multi = len(plan) > 1
    pieces: list[dict[str, np.ndarray]] = []
    piece_classes: list[Categorical] = []
    rec_names: list[str] = []
    recordings: dict[str, track_table.RecordingMeta] = {}
    for tp, name in plan:
        data = topics[tp]
        spec = recordings_meta.get(name) if name else None
        rec_name = name or (f"{stem}-{tp.strip('/').replace('/', '-')}" if multi else stem)
        cols, classes, frame_ids = data.columns.arrays()
        times = cols["msg_time"]
        if data.columns.messages > 1 and times.size and times.min() == times.max():
            raise LogError(
                path,
                f"topic {tp!r}: all {data.columns.messages:,} messages are stamped {int(times[0])} ns "
                "(their recorder set no times): one frame, every other row a duplicate",
                expected="message times (header stamps, else log times) that advance",
            )
        marker = topics.get(tp + MARKER_SUFFIX)
        if spec is not None and marker is not None and marker is not data:
            classes = _merge_markers(cols, classes, marker.columns)
        elif data.msgtype.endswith("MarkerArray"):
            known = np.asarray([n in KNOWN_CLASSES for n in classes.names] + [True], dtype=bool)
            unknown = ~known[classes.codes]
            classes = classes.where(unknown, Categorical(np.zeros(unknown.size, np.int32), ["unknown"]))
        frame_name = _to_fixed_frame(
            path, tp, cols, frame_ids, transforms, fixed, data.columns.velocity_in_body
        )
        frames, rate = frames_of(cols["msg_time"], spec, cols["track_id"])
        order, keep = _row_order(cols["track_id"], frames, cols["time_ns"])
        dropped = int(keep.size - np.count_nonzero(keep))
        if dropped:
            _refuse_conflicting_repeats(path, tp, cols, classes.codes, frames, order, keep, rate)
            order = order[keep]
        _check_lanes(path, tp, cols)
        piece = _derive(cols, frames, order, data.columns.velocity_in_body)
        pieces.append(piece)
        piece_classes.append(classes.take(order))
        rec_names.append(rec_name)
        rec_extra: dict[str, Any] = dict(spec.get("extra", {})) if spec else {}
        rec_extra.update({"topic": tp, "message_type": data.msgtype, "messages": data.columns.messages})
        if dropped:
            rec_extra["duplicates_dropped"] = dropped
            print(
                f"lanecast: {path}: topic {tp!r}: {dropped:,} rows repeat an object of the same track, "
                "frame and stamp exactly (a message recorded twice); kept one of each",
                file=sys.stderr,
            )
        if extra:
            rec_extra.update(extra)
        recordings[rec_name] = track_table.RecordingMeta(
            frame_rate=float(spec["frame_rate"]) if spec else rate,
            coordinate_frame=frame_name,
            source_files=list(spec.get("source_files", [])) if spec else [str(path)],
            extra=rec_extra,
        )
    columns: dict[str, Any] = (
        dict(pieces[0])
        if len(pieces) == 1
        else {k: np.concatenate([p[k] for p in pieces]) for k in pieces[0]}
    )
    columns["object_class"] = Categorical.concat(piece_classes).to_arrow()
    offset = int((log_meta or {}).get("time_offset_ns") or 0)
    if offset:  # the table's clock: times from the recordings' start (conventions: the log's clock)
        columns["time_ns"] = columns["time_ns"] - np.int64(offset)
        for rec in recordings.values():
            rec.extra[OFFSET_KEY] = offset
    sizes = [p["track_id"].size for p in pieces]
    columns["recording"] = Categorical(np.repeat(np.arange(len(sizes)), sizes), rec_names).to_arrow()
    meta = track_table.TableMeta(
        source_format=str((log_meta or {}).get("source_format") or source_format),
        recordings=recordings,
        source_files=[str(path)],
    )
    table = track_table.build_table(columns, meta)
    try:
        track_table.validate(table, source=path)
    except TrackTableError as exc:
        raise _in_the_log(path, table, exc) from exc
    return table


_ROW = re.compile(r"row (\d+): (.*)$")


def _in_the_log(path: Path, table: pa.Table, exc: TrackTableError) -> LanecastError:
    """A track-table error about row N, said of the log: the topic, track and stamp of the object
    that row came from (the row of a table the user never sees locates nothing in the log)."""
    found = _ROW.search(str(exc))
    if found is None or int(found.group(1)) >= table.num_rows:
        return exc
    row, what = int(found.group(1)), found.group(2)
    recording = table.column("recording")[row].as_py()
    track = table.column("track_id")[row].as_py()
    stamp = table.column("time_ns")[row].as_py()
    spec = track_table.read_meta(table).recordings.get(recording)
    topic = spec.extra.get("topic") if spec is not None else None
    where = f"topic {topic!r}, " if topic else ""
    return LogError(
        path, f"{where}the object of track {track} stamped {stamp} ns (the message holding it): {what}"
    )


def _fallback_name(path: Path, topic: str, taken: set[str]) -> str:
    """A recording name for a topic the log's metadata does not name, distinct from ``taken``."""
    stem = path.stem if path.suffix else path.name
    name = f"{stem}-{topic.strip('/').replace('/', '-')}"
    while name in taken:
        name += "-unlisted"
    return name


def _to_fixed_frame(
    path: Path,
    topic: str,
    cols: dict[str, np.ndarray],
    frame_ids: Categorical,
    transforms: Transforms,
    fixed: set[str],
    body: bool,
) -> str:
    """Move rows in moving frames into a fixed frame (in place); return the fixed frame's name.

    Velocities and accelerations given in the message frame's axes are rotated with it; body-frame
    ones (``body``) stay as they are (they turn with the heading later).
    """
    present = np.bincount(frame_ids.codes, minlength=len(frame_ids.names)) > 0
    distinct = sorted({frame_ids.names[i].lstrip("/") for i in np.flatnonzero(present)})
    names = [n.lstrip("/") for n in frame_ids.names]
    target: str | None = next((f for f in distinct if f in fixed), None)

    def rows_in(frame: str) -> np.ndarray:
        return np.isin(frame_ids.codes, [i for i, n in enumerate(names) if n == frame])

    def first_of(frame: str) -> str:
        """Where the first object in ``frame`` is: one bad entity among thousands is found by it."""
        rows = rows_in(frame)
        i = int(np.argmin(np.where(rows, cols["msg_time"], np.iinfo(np.int64).max)))
        n = int(rows.sum())
        return f"{n:,} object(s), the first of track {int(cols['track_id'][i])} in the message stamped {int(cols['msg_time'][i])} ns"

    for frame in distinct:
        if frame in fixed:
            if target is not None and frame != target:
                raise FrameError(
                    f"{path}: topic {topic!r} mixes the fixed frames {target!r} and {frame!r} "
                    f"({first_of(frame)} in {frame!r}); expected one fixed frame per topic"
                )
            continue
        chain = transforms.chain(frame, [target] if target else fixed)
        if chain is None:
            have = ", ".join(sorted(transforms.sources)) or "none"
            raise FrameError(
                f"{path}: topic {topic!r} has objects in frame {frame!r} ({first_of(frame)}), which is "
                f"not a fixed frame ({', '.join(sorted(fixed))}), and the log has no transform from it "
                f"to one (transform topics found: {have}); expected /tf (tf2_msgs/msg/TFMessage or "
                f"foxglove.FrameTransform(s)) or an odometry topic (nav_msgs/msg/Odometry) linking "
                f"{frame!r} to a fixed frame"
            )
        target = chain[-1]
        rows = rows_in(frame)
        x, y, dyaw = transforms.to_fixed(chain, cols["msg_time"][rows], cols["x"][rows], cols["y"][rows])
        cols["x"][rows], cols["y"][rows] = x, y
        cols["yaw"][rows] += dyaw
        for a, b in () if body else (("vx", "vy"), ("ax", "ay")):
            va, vb = rotate(cols[a][rows], cols[b][rows], dyaw)
            cols[a][rows], cols[b][rows] = va, vb
    return target or "map"


def _row_order(track: np.ndarray, frame: np.ndarray, time_ns: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The order [n] sorting rows by (track, frame, time) and, in that order, bool [n] True on the
    first row of each (track, frame). One argsort of a combined integer key where (track, frame)
    pairs are distinct and the key fits, else a lexsort (a third of the speed)."""
    if track.size:
        t0, f0 = int(track.min()), int(frame.min())
        frames = int(frame.max()) - f0 + 1
        if (int(track.max()) - t0 + 1) * frames < 2**62:
            key = (track - t0) * frames + (frame - f0)
            order = np.argsort(key, kind="stable")  # rows come in message order: runs a merge sort uses
            ordered = key[order]
            if not (ordered[1:] == ordered[:-1]).any():
                return order, np.ones(order.size, dtype=bool)
    order = np.lexsort((time_ns, frame, track))
    return order, run_starts(track[order], frame[order])


# Columns in which a repeated (track, frame) row must equal the row kept (NaN equals NaN).
_SAME_IN_A_REPEAT = ("time_ns", "x", "y", "yaw", "length", "width", "vx", "vy", "ax", "ay", "lane")


def _refuse_conflicting_repeats(
    path: Path,
    topic: str,
    cols: Mapping[str, np.ndarray],
    class_codes: np.ndarray,
    frames: np.ndarray,
    order: np.ndarray,
    keep: np.ndarray,
    rate: float,
) -> None:
    """LogError where a row repeats the (track, frame) of an earlier one with other values: one
    of the two would be lost, and nothing tells which is right. Exact repeats pass (a message
    recorded twice: dropping one loses nothing)."""
    pos = np.arange(keep.size)
    kept = order[np.maximum.accumulate(np.where(keep, pos, 0))][~keep]
    rep = order[~keep]
    columns = {k: cols[k] for k in _SAME_IN_A_REPEAT if k in cols}
    columns["object_class"] = class_codes
    for name, values in columns.items():
        a, b = values[rep], values[kept]
        differs = a != b
        if values.dtype.kind == "f":
            differs &= ~(np.isnan(a) & np.isnan(b))
        if not differs.any():
            continue
        i = int(np.flatnonzero(differs)[0])
        r, k = int(rep[i]), int(kept[i])
        stamps = cols["time_ns"]
        if name == "time_ns":
            what = f"stamped {int(stamps[k])} ns and {int(stamps[r])} ns"
        elif name == "object_class":
            what = f"both stamped {int(stamps[r])} ns, of two classes"
        else:
            what = f"both stamped {int(stamps[r])} ns, {name} {float(b[i]):g} and {float(a[i]):g}"
        raise LogError(
            path,
            f"topic {topic!r}: track {int(cols['track_id'][r])} has two different objects on frame "
            f"{int(frames[r])} at {rate:g} Hz ({what}; messages stamped {int(cols['msg_time'][k])} "
            f"and {int(cols['msg_time'][r])} ns); keeping either would drop the other",
            column=name,
            expected="one object per track and frame (messages on the topic's frame timeline)",
        )


def _gather(column: np.ndarray, order: np.ndarray) -> np.ndarray:
    """column[order]; a float column that is all NaN (what the log does not have, e.g. the
    accelerations lanecast does not write) becomes NaN without a gather."""
    if column.dtype.kind == "f" and column.size and np.isnan(column[0]) and np.isnan(column).all():
        return np.full(order.size, np.nan)
    return column[order]


#: The largest lane id the track table holds (int32).
LANE_ID_MAX = 2**31 - 1


def _check_lanes(path: Path, topic: str, cols: dict[str, np.ndarray]) -> None:
    """LogError at the first lane id that is no int32 integer (1.5, 1e20): cast, it became 1 or
    -2147483648 without a word."""
    lane = cols["lane"]
    known = ~np.isnan(lane)
    with np.errstate(invalid="ignore"):
        bad = known & ((np.abs(lane) > LANE_ID_MAX) | (lane != np.trunc(np.where(known, lane, 0.0))))
    if bad.any():
        r = int(np.flatnonzero(bad)[0])
        raise LogError(
            path,
            f"topic {topic!r}: object of track {int(cols['track_id'][r])} stamped {int(cols['time_ns'][r])} ns "
            f"has lane_id {float(lane[r]):g}",
            column="lane_id",
            expected=f"an integer lane id within ±{LANE_ID_MAX}",
        )


def _derive(
    cols: dict[str, np.ndarray], frames: np.ndarray, order: np.ndarray, body: bool
) -> dict[str, np.ndarray]:
    """Rows taken in ``order`` [m] (sorted by (track, frame), one per pair); heading, velocity and
    acceleration derived where the message has none."""
    c = {k: _gather(v, order) for k, v in cols.items() if k != "msg_time"}
    track, frame = c["track_id"], frames[order]
    heading = c["yaw"]
    t = c["time_ns"]
    vx, vy = c["vx"], c["vy"]
    if body:
        vx, vy = rotate(vx, vy, np.nan_to_num(heading))
        ax, ay = rotate(c["ax"], c["ay"], np.nan_to_num(heading))
    else:
        ax, ay = c["ax"], c["ay"]
    first, last = row_extent(run_starts(track))

    def derivative(values: np.ndarray) -> np.ndarray:
        return along_track_derivative(values, t, first, last, t_unit=1e-9)

    missing_v = np.isnan(vx) | np.isnan(vy)
    if missing_v.any():
        vx = np.where(np.isnan(vx), derivative(c["x"]), vx)
        vy = np.where(np.isnan(vy), derivative(c["y"]), vy)
    if (np.isnan(ax) | np.isnan(ay)).any():
        ax = np.where(np.isnan(ax), derivative(vx), ax)
        ay = np.where(np.isnan(ay), derivative(vy), ay)
    no_yaw = np.isnan(heading)
    out = {
        "track_id": track,
        "frame": frame,
        "time_ns": t,
        "x": c["x"],
        "y": c["y"],
        "heading": np.where(no_yaw, np.arctan2(vy, vx), heading) if no_yaw.any() else heading,
        "vx": vx,
        "vy": vy,
        "ax": ax,
        "ay": ay,
        "length": c["length"],
        "width": c["width"],
        "lane_id": c["lane"],
    }
    return out
