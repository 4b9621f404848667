"""Forecast drawings as ``foxglove.SceneUpdate`` in protobuf and in Foxglove's JSON encoding.

Both render a :class:`~lanecast.io_adapters.logs.foxglove.forecast_drawing.Drawing` column-wise
(:mod:`lanecast.io_adapters.logs.messages.byte_rows`), one message per frame: protobuf byte for byte
what ``SceneUpdate.SerializeToString()`` writes (fields in number order, proto3 defaults omitted;
schema = the serialized FileDescriptorSet, for plain MCAP), JSON as Foxglove reads it (schema
encoding ``jsonschema``).
"""

from __future__ import annotations

import functools
import json

import numpy as np

from lanecast.io_adapters.logs.forecast_batch import N_STEPS, ForecastBatch
from lanecast.io_adapters.logs.foxglove.forecast_drawing import LINE_THICKNESS_M, Drawing, sec_nsec
from lanecast.io_adapters.logs.messages import byte_rows as br
from lanecast.io_adapters.logs.messages.byte_rows import ByteRows


def _json_string_rows(values: list[str]) -> ByteRows:
    """JSON string literals (quotes included) of a few values, e.g. one per frame."""
    return ByteRows.from_strings(np.array([json.dumps(v).encode() for v in values] or [b'""'], dtype="S"))


def scene_update_json(batch: ForecastBatch, drawing: Drawing) -> list[bytes]:
    """Foxglove's JSON form of each frame's ``foxglove.SceneUpdate`` (compact, one row per frame)."""
    n, lines_per = drawing.xy.shape[0], drawing.xy.shape[1]
    f = batch.n_frames
    m = n * lines_per
    xy = drawing.xy.reshape(m * (N_STEPS + 1), 2)
    points = br.concat(
        len(xy), b'{"x":', br.json_numbers(xy[:, 0]), b',"y":', br.json_numbers(xy[:, 1]), b',"z":0.0}'
    )
    keep = drawing.keep.reshape(m, N_STEPS + 1)
    comma = keep & (np.cumsum(keep, axis=1) > 1)  # before every kept point but the line's first
    points = br.concat(
        len(xy), ByteRows.constant(b",", len(xy)).blank(comma.reshape(-1)), points.blank(keep.reshape(-1))
    ).group_every(N_STEPS + 1)
    rgba = drawing.rgba.reshape(m, 4)
    identity = b'{"position":{"x":0.0,"y":0.0,"z":0.0},"orientation":{"x":0.0,"y":0.0,"z":0.0,"w":1.0}}'
    lines = br.concat(
        m,
        b'{"type":0,"pose":' + identity + b',"thickness":' + repr(LINE_THICKNESS_M).encode(),
        b',"scale_invariant":false,"points":[',
        points,
        b'],"color":{"r":',
        br.json_numbers(rgba[:, 0]),
        b',"g":',
        br.json_numbers(rgba[:, 1]),
        b',"b":',
        br.json_numbers(rgba[:, 2]),
        b',"a":',
        br.json_numbers(rgba[:, 3]),
        b'},"colors":[],"indices":[]}',
    )
    metadata: list[br.Column] = []
    for i, (key, value) in enumerate(drawing.metadata):
        metadata += [(b"," if i else b"") + b'{"key":' + json.dumps(key).encode() + b',"value":"']
        metadata += [br.escape_quotes(value), b'"}']
    sec, nsec = sec_nsec(batch.t0_ns)
    lsec, lnsec = sec_nsec(batch.lifetime_ns)
    stamp = br.concat(f, b'{"timestamp":{"sec":', br.json_ints(sec), b',"nsec":', br.json_ints(nsec), b"}")
    entities = br.concat(
        n,
        stamp.take(drawing.row_frame),
        b',"frame_id":',
        _json_string_rows(batch.frame_id).take(drawing.row_frame),
        b',"id":"',
        drawing.ids,
        f'","lifetime":{{"sec":{int(lsec[0])},"nsec":{int(lnsec[0])}}},"frame_locked":false,"metadata":['.encode(),
        *metadata,
        b'],"arrows":[],"cubes":[],"spheres":[],"cylinders":[],"lines":',
        br.json_lists(lines, n, lines_per),
        b',"triangles":[],"texts":[],"models":[]}',
    )
    return [b'{"deletions":[],"entities":[' + body + b"]}" for body in entities.join(batch.bounds, b",")]


# Constant parts of a LINE_STRIP (type 0 is the default: not written): pose = identity orientation,
# thickness. Field numbers from foxglove's LinePrimitive, SceneEntity and SceneUpdate .proto files.
_PB_POSE = br.length_delimited(2, br.length_delimited(2, br.doubles(4, np.ones(1)))).join()[0]


_PB_THICKNESS = br.doubles(3, np.array([LINE_THICKNESS_M])).join()[0]


def _pb_time(sec: np.ndarray, nsec: np.ndarray) -> ByteRows:
    """google.protobuf.Timestamp/Duration payloads (seconds 1, nanos 2; zeros not written)."""
    return br.concat(len(sec), br.int_field(1, sec), br.int_field(2, nsec))


def _pb_string(field: int, rows: ByteRows) -> ByteRows:
    """A proto3 string field per row; empty strings are not written."""
    return br.length_delimited(field, rows).blank(rows.lengths > 0)


@functools.cache
def _pb_key(key: str) -> bytes:
    """A KeyValuePair's key field (1)."""
    return br.length_delimited(1, ByteRows.constant(key.encode(), 1)).join()[0]


def scene_update_protobuf(batch: ForecastBatch, drawing: Drawing) -> list[bytes]:
    """Each frame's ``foxglove.SceneUpdate`` serialized (protobuf wire format, one row per frame).

    Byte for byte what ``SceneUpdate.SerializeToString()`` writes for the same message: fields in
    number order, proto3 defaults (0, +0.0, false, "") omitted, sub-messages that were set kept.
    """
    n, lines_per = drawing.xy.shape[0], drawing.xy.shape[1]
    m = n * lines_per
    xy = drawing.xy.reshape(-1, 2)
    points = br.length_delimited(5, br.concat(len(xy), br.doubles(1, xy[:, 0]), br.doubles(2, xy[:, 1])))
    points = points.blank(drawing.keep.reshape(-1)).group_every(N_STEPS + 1)
    rgba = drawing.rgba.reshape(m, 4)
    color = br.length_delimited(6, br.concat(m, *(br.doubles(i + 1, rgba[:, i]) for i in range(4))))
    lines = br.length_delimited(11, br.concat(m, _PB_POSE, _PB_THICKNESS, points, color))
    sec, nsec = sec_nsec(batch.t0_ns)
    lsec, lnsec = sec_nsec(batch.lifetime_ns)
    frame_ids = ByteRows.from_strings(np.array([f.encode() for f in batch.frame_id] or [b""], dtype="S"))
    metadata = [
        br.length_delimited(
            6,
            br.concat(n, _pb_key(key), _pb_string(2, value)),
        )
        for key, value in drawing.metadata
    ]
    entities = br.length_delimited(
        2,
        br.concat(
            n,
            br.length_delimited(1, _pb_time(sec, nsec)).take(drawing.row_frame),
            _pb_string(2, frame_ids).take(drawing.row_frame),
            _pb_string(3, drawing.ids),
            br.length_delimited(4, _pb_time(lsec, lnsec)).join()[0],
            *metadata,
            lines.group_every(lines_per),
        ),
    )
    return entities.join(batch.bounds)


@functools.cache
def protobuf_schema() -> bytes:
    from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate
    from mcap_protobuf.schema import build_file_descriptor_set

    return bytes(build_file_descriptor_set(SceneUpdate).SerializeToString())
