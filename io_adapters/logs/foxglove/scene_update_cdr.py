"""Forecast drawings as ROS 2 ``foxglove_msgs/msg/SceneUpdate`` in CDR, for ROS 2 logs.

Byte for byte what rosbags' ``serialize_cdr`` writes, built column-wise: CDR aligns every field to
its size counted from the start of the payload, so each entity's padding depends on where it starts
(mod 8), found for all entities at once with a parallel prefix scan. The ``foxglove_msgs`` types
come from the .msg files shipped in ``io_adapters/data/foxglove/ros2`` (:func:`ros2_typestore`);
/lanecast/prediction travels as ``std_msgs/msg/String`` (:func:`strings_cdr`).
"""

from __future__ import annotations

import functools
from importlib import resources
from typing import Any

import numpy as np

from lanecast.io_adapters.logs.forecast_batch import N_STEPS, ForecastBatch
from lanecast.io_adapters.logs.foxglove.forecast_drawing import LINE_THICKNESS_M, Drawing, sec_nsec
from lanecast.io_adapters.logs.messages import byte_rows as br
from lanecast.io_adapters.logs.messages.byte_rows import ByteRows


@functools.cache
def ros2_typestore() -> Any:
    """A rosbags ROS 2 typestore with every ``foxglove_msgs/msg/*`` type registered from the .msg files."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE)
    types: dict[str, Any] = {}
    folder = resources.files("lanecast.io_adapters") / "data" / "foxglove" / "ros2"
    for entry in sorted(folder.iterdir(), key=lambda p: p.name):
        if entry.name.endswith(".msg"):
            types.update(
                get_types_from_msg(entry.read_text(encoding="utf-8"), f"foxglove_msgs/msg/{entry.name[:-4]}")
            )
    store.register(types)
    return store


SCENE_UPDATE_ROS2 = "foxglove_msgs/msg/SceneUpdate"


STRING_ROS2 = "std_msgs/msg/String"


CDR_HEADER = b"\x00\x01\x00\x00"  # XCDR1, little endian: what rosbags' serialize_cdr writes


_CDR_POSE = np.array([0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0], "<f8").tobytes()  # position 0, identity orientation


_CDR_LINE_HEAD = b"\x00"  # type LINE_STRIP (uint8)


class _CdrLayout:
    """Columns of N CDR serializations written side by side, with each row's position (mod 8) tracked.

    Alignment (padding with zeros to a multiple of the field's size, counted from the start of the
    payload after the 4-byte header) depends on what came before, so every row has its own cursor.
    ``build`` False only tracks positions (to learn a row's size for a given start).
    """

    def __init__(self, start: np.ndarray, build: bool = True) -> None:
        self.pos = np.asarray(start, np.int64).copy()
        self.n = len(self.pos)
        self.build = build
        self.columns: list[br.Column] = []

    def pad(self, align: int) -> None:
        padding = (-self.pos) % align
        if self.build and padding.any():
            self.columns.append(ByteRows.from_matrix(np.zeros((self.n, 8), np.uint8), padding))
        self.pos += padding

    def put(self, column: br.Column | None, size: np.ndarray | int) -> None:
        if self.build and column is not None:
            self.columns.append(column)
        self.pos += size

    def u32(self, value: int) -> None:
        self.pad(4)
        self.put(np.uint32(value).tobytes(), 4)

    def string(self, rows: ByteRows | None, lengths: np.ndarray) -> None:
        """A string: uint32 length with the NUL, the bytes, NUL."""
        self.pad(4)
        if self.build and rows is not None:
            self.put(br.concat(self.n, _u32_rows(lengths + 1), rows, b"\x00"), 5 + lengths)
        else:
            self.pos += 5 + lengths

    def rows(self) -> ByteRows:
        return br.concat(self.n, *self.columns)


def _u32_rows(values: np.ndarray) -> ByteRows:
    """Little-endian uint32 per row."""
    return br.fixed(np.asarray(values)[:, None], "<u4")


def _cdr_entities(batch: ForecastBatch, drawing: Drawing, start: np.ndarray, build: bool) -> _CdrLayout:
    """The SceneEntity of every target, each starting at payload position ``start`` (mod 8)."""
    n, lines_per = drawing.xy.shape[0], drawing.xy.shape[1]
    sec, nsec = sec_nsec(batch.t0_ns)
    lsec, lnsec = sec_nsec(batch.lifetime_ns)
    frame_ids = ByteRows.from_strings(np.array([f.encode() for f in batch.frame_id] or [b""], dtype="S"))
    frame_ids = frame_ids.take(drawing.row_frame)
    out = _CdrLayout(start, build)
    out.pad(4)
    stamp = np.stack([sec.astype("<i4").view("<u4"), nsec.astype("<u4")], axis=1)[drawing.row_frame]
    out.put(ByteRows.from_matrix(stamp.view(np.uint8).reshape(n, 8), np.full(n, 8)) if build else None, 8)
    out.string(frame_ids, frame_ids.lengths)
    out.string(drawing.ids, drawing.ids.lengths)
    out.pad(4)
    out.put(
        np.array([lsec[0], lnsec[0]], "<i8").astype("<i4").tobytes() + b"\x00", 9
    )  # lifetime, frame_locked
    out.u32(len(drawing.metadata))
    for key, value in drawing.metadata:
        out.string(ByteRows.constant(key.encode(), n), np.full(n, len(key.encode())))
        out.string(value, value.lengths)
    for _ in range(4):  # arrows, cubes, spheres, cylinders
        out.u32(0)
    out.u32(lines_per)
    keep = drawing.keep
    for j in range(lines_per):
        out.put(_CDR_LINE_HEAD, 1)
        out.pad(8)
        out.put(
            _CDR_POSE + np.float64(LINE_THICKNESS_M).tobytes() + b"\x00", 65
        )  # pose, thickness, scale_invariant
        count = keep[:, j].sum(axis=1)
        out.pad(4)
        out.put(_u32_rows(count) if build else None, 4)
        out.pad(8)
        if build:
            xyz = np.zeros((n, N_STEPS + 1, 3), "<f8")
            xyz[..., :2] = drawing.xy[:, j]
            points = ByteRows.from_matrix(
                xyz.view(np.uint8).reshape(n * (N_STEPS + 1), 24), np.full(n * (N_STEPS + 1), 24)
            )
            out.put(points.blank(keep[:, j].reshape(-1)).group_every(N_STEPS + 1), 24 * count)
            rgba = np.ascontiguousarray(drawing.rgba[:, j], "<f8")
            out.put(ByteRows.from_matrix(rgba.view(np.uint8).reshape(n, 32), np.full(n, 32)), 32)
        else:
            out.put(None, 24 * count + 32)
        out.u32(0)  # colors
        out.u32(0)  # indices
    for _ in range(3):  # triangles, texts, models
        out.u32(0)
    return out


def scene_update_cdr(batch: ForecastBatch, drawing: Drawing) -> list[bytes]:
    """Each frame's ROS 2 ``foxglove_msgs/msg/SceneUpdate`` as CDR (one row per frame).

    Byte for byte what rosbags' ``serialize_cdr`` writes. An entity's padding depends on where it
    starts (mod 8), which depends on every entity before it in its message: the start of each
    entity is found with a parallel prefix scan over the two possible residues (0 or 4).
    """
    n, f = drawing.xy.shape[0], batch.n_frames
    size0 = _cdr_entities(batch, drawing, np.zeros(n, np.int64), build=False).pos
    size4 = _cdr_entities(batch, drawing, np.full(n, 4, np.int64), build=False).pos - 4
    # state = start residue / 4 (0 or 1); after entity i: (state*4 + size_state) mod 8 / 4
    after = np.stack([(size0 % 8) // 4, ((4 + size4) % 8) // 4], axis=1)  # [N, 2]
    entering = np.empty((n, 2), np.int64)  # map from "state entering the previous entity" to mine
    entering[1:] = after[:-1]
    first = np.asarray(batch.bounds[:-1], np.int64)[np.diff(batch.bounds) > 0]
    entering[first] = 0  # the first entity of a message starts at payload offset 8
    scan = entering.copy()
    step = 1
    while step < n:  # inclusive prefix composition: scan[i] = entering[i] ∘ … ∘ entering[0]
        scan[step:] = np.take_along_axis(scan[step:], scan[:-step], axis=1)
        step *= 2
    start = scan[:, 0] * 4
    entities = _cdr_entities(batch, drawing, start, build=True).rows()
    counts = np.diff(batch.bounds)
    head = np.zeros((f, 12), np.uint8)
    head[:, :4] = np.frombuffer(CDR_HEADER, np.uint8)
    head[:, 8:] = counts.astype("<u4").view(np.uint8).reshape(f, 4)
    return [h.tobytes() + body for h, body in zip(head, entities.join(batch.bounds), strict=True)]


def strings_cdr(texts: list[bytes]) -> list[bytes]:
    """Each text as a ROS 2 ``std_msgs/msg/String`` in CDR (one header and length per message)."""
    return [CDR_HEADER + np.uint32(len(t) + 1).tobytes() + t + b"\x00" for t in texts]
