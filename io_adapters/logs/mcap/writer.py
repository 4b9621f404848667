"""Write a track table as an MCAP drive log of ``foxglove.SceneUpdate`` messages.

One message per frame of each recording at the recording's own rate (log time = publish time =
the frame's earliest ``time_ns``), protobuf (default; the schema is SceneUpdate's file descriptor
set) or JSON (``encoding="json"``; schema encoding ``jsonschema``). Entities follow the conventions
of :mod:`lanecast.io_adapters.logs.object_columns` (cube, id = track id, metadata class, lane_id (absent for
null), vx, vy, ax, ay), so reading the log back gives the same table. Chunked with zstd, CRCs on, with summary
and indexes; written atomically. The log's metadata record ``lanecast`` holds the recording
metadata (source, frame rate, units, recordings).
"""

from __future__ import annotations

import functools
import json
from collections.abc import Callable
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa

from lanecast.io_adapters.contracts import track_table
from lanecast.io_adapters.errors import InputError
from lanecast.io_adapters.files import atomic_path
from lanecast.io_adapters.logs import conventions as conv
from lanecast.io_adapters.logs import object_columns as to
from lanecast.io_adapters.progress import bar

LIBRARY = "lanecast"
ENCODINGS = ("protobuf", "json")
#: The kinematics written as entity metadata (float32 text): the accelerations too, so that a reader
#: gets the table's own values, as from a ROS bag, instead of differentiating the velocities.
KINEMATICS = ("vx", "vy", "ax", "ay")


@functools.cache
def scene_update_jsonschema() -> bytes:
    """Foxglove's published JSON schema of ``foxglove.SceneUpdate`` (shipped in io_adapters/data)."""
    return (
        resources.files("lanecast.io_adapters") / "data" / "foxglove" / "jsonschema" / "SceneUpdate.json"
    ).read_bytes()


class RowStrings:
    """Per-row values of a table prepared once, vectorised, for message building."""

    def __init__(self, table: pa.Table) -> None:
        c = conv.table_columns(table)
        self.recording = c["recording"]
        self.track_id = c["track_id"]
        self.frame = c["frame"]
        self.time_ns = c["time_ns"]
        self.id = c["track_id"].astype(str).tolist()
        self.sec = (c["time_ns"] // 1_000_000_000).tolist()
        self.nsec = (c["time_ns"] % 1_000_000_000).tolist()
        self.x = c["x"].tolist()
        self.y = c["y"].tolist()
        qz, qw = to.quat_of_yaw(c["heading"].astype(np.float64))
        self.qz, self.qw = qz.tolist(), qw.tolist()
        self.length = c["length"].astype(np.float64).tolist()
        self.width = c["width"].astype(np.float64).tolist()
        self.cls = c["object_class"].astype(str).tolist()
        lane = c["lane_id"]
        self.lane = np.where(np.isnan(lane), "", np.nan_to_num(lane).astype(np.int64).astype(str)).tolist()
        self.kinematics = {k: c[k].astype(np.float32).astype(str).tolist() for k in KINEMATICS}


def _colour(cls: str) -> tuple[float, float, float, float]:
    return {
        "truck": (0.9, 0.5, 0.1, 0.6),
        "bus": (0.9, 0.5, 0.1, 0.6),
        "motorcycle": (0.2, 0.8, 0.2, 0.6),
    }.get(cls, (0.2, 0.5, 0.9, 0.6))


def _pb_encoder(frame_id: str, rs: RowStrings) -> Callable[[np.ndarray], bytes]:
    from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate

    kin = rs.kinematics

    def encode(rows: np.ndarray) -> bytes:
        msg = SceneUpdate()
        for r in rows.tolist():
            e = msg.entities.add()
            e.timestamp.seconds = rs.sec[r]
            e.timestamp.nanos = rs.nsec[r]
            e.frame_id = frame_id
            e.id = rs.id[r]
            c = e.cubes.add()
            c.pose.position.x = rs.x[r]
            c.pose.position.y = rs.y[r]
            c.pose.orientation.z = rs.qz[r]
            c.pose.orientation.w = rs.qw[r]
            c.size.x = rs.length[r]
            c.size.y = rs.width[r]
            c.size.z = conv.BOX_HEIGHT
            c.color.r, c.color.g, c.color.b, c.color.a = _colour(rs.cls[r])
            md = e.metadata
            md.add(key="class", value=rs.cls[r])
            if rs.lane[r]:
                md.add(key="lane_id", value=rs.lane[r])
            for key in KINEMATICS:
                md.add(key=key, value=kin[key][r])
        return msg.SerializeToString()

    return encode


def _json_encoder(frame_id: str, rs: RowStrings) -> Callable[[np.ndarray], bytes]:
    kin = rs.kinematics

    def entity(r: int) -> dict[str, Any]:
        cr, cg, cb, ca = _colour(rs.cls[r])
        metadata = [{"key": "class", "value": rs.cls[r]}]
        if rs.lane[r]:
            metadata.append({"key": "lane_id", "value": rs.lane[r]})
        metadata += [{"key": key, "value": kin[key][r]} for key in KINEMATICS]
        return {
            "timestamp": {"sec": rs.sec[r], "nsec": rs.nsec[r]},
            "frame_id": frame_id,
            "id": rs.id[r],
            "lifetime": {"sec": 0, "nsec": 0},
            "frame_locked": False,
            "metadata": metadata,
            "arrows": [],
            "cubes": [
                {
                    "pose": {
                        "position": {"x": rs.x[r], "y": rs.y[r], "z": 0.0},
                        "orientation": {"x": 0.0, "y": 0.0, "z": rs.qz[r], "w": rs.qw[r]},
                    },
                    "size": {"x": rs.length[r], "y": rs.width[r], "z": conv.BOX_HEIGHT},
                    "color": {"r": cr, "g": cg, "b": cb, "a": ca},
                }
            ],
            "spheres": [],
            "cylinders": [],
            "lines": [],
            "triangles": [],
            "texts": [],
            "models": [],
        }

    def encode(rows: np.ndarray) -> bytes:
        doc = {"deletions": [], "entities": [entity(r) for r in rows.tolist()]}
        return json.dumps(doc, separators=(",", ":")).encode()

    return encode


def metadata_record(doc: dict[str, Any]) -> dict[str, str]:
    """The key/value map of the ``lanecast`` metadata record (all strings)."""
    return {
        conv.META_NAME: json.dumps(doc, sort_keys=True),
        "source": str(doc["source_format"]),
        "source_files": json.dumps(doc["source_files"]),
        "frame_rate": "" if doc["frame_rate"] is None else repr(doc["frame_rate"]),
        "units": json.dumps(doc["units"], sort_keys=True),
        "recordings": json.dumps(sorted(doc["recordings"])),
    }


def write(
    table: pa.Table,
    out: Path,
    fmt: str = "mcap",
    *,
    encoding: str = "protobuf",
    chunk_size: int = 1 << 20,
    **options: Any,
) -> Path:
    """Write ``table`` as an MCAP of SceneUpdate messages (``encoding`` protobuf or json; chunks of ``chunk_size`` bytes)."""
    from mcap.writer import CompressionType, Writer

    if encoding not in ENCODINGS:
        raise InputError(out, f"unknown SceneUpdate encoding {encoding!r}", expected=" or ".join(ENCODINGS))
    track_table.validate(table)
    out = Path(out)
    offset = conv.log_time_offset(table)
    table = conv.shifted(table, offset)  # the log's clock: the recordings' dates, not 1970
    meta = track_table.read_meta(table)
    names = sorted(meta.recordings)
    topics = conv.recording_topics(names)
    rs = RowStrings(table)
    groups, plan = conv.message_plan(rs.recording, rs.frame, rs.track_id, rs.time_ns, names)
    doc = conv.log_metadata(table, topics, groups, offset)
    with atomic_path(out) as tmp, tmp.open("wb") as f:
        w = Writer(f, chunk_size=chunk_size, compression=CompressionType.ZSTD, enable_data_crcs=True)
        w.start(profile="", library=LIBRARY)
        w.add_metadata(conv.META_NAME, metadata_record(doc))
        if encoding == "protobuf":
            from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate
            from mcap_protobuf.schema import build_file_descriptor_set

            schema_id = w.register_schema(
                "foxglove.SceneUpdate", "protobuf", build_file_descriptor_set(SceneUpdate).SerializeToString()
            )
        else:
            schema_id = w.register_schema("foxglove.SceneUpdate", "jsonschema", scene_update_jsonschema())
        channels, encoders = [], []
        for name in names:
            channels.append(w.register_channel(topics[name], encoding, schema_id))
            make = _pb_encoder if encoding == "protobuf" else _json_encoder
            encoders.append(make(meta.recordings[name].coordinate_frame, rs))
        group_list = [groups[n] for n in names]
        with bar(desc=f"writing {out.name}", total=int(plan.shape[0]), unit="msg") as progress:
            for stamp, rec, gi in plan.tolist():
                g = group_list[rec]
                rows = g.order[g.starts[gi] : g.starts[gi + 1]]
                w.add_message(
                    channels[rec], log_time=stamp, data=encoders[rec](rows), publish_time=stamp, sequence=gi
                )
                progress.update(1)
        w.finish()
    return out
