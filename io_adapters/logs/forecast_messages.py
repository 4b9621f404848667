"""Forecasts as log messages: ``foxglove.SceneUpdate`` on /lanecast/forecast and JSON on /lanecast/prediction.

The public face of the forecast encoders: which channels a log gets (:func:`channel_specs`) and the
payloads of each forecast frame (:func:`encode_batch`, :func:`encode_frame`), in the encoding the
log needs:

- ``protobuf``: ``foxglove.SceneUpdate`` (schema = serialized FileDescriptorSet), for plain MCAP;
- ``json``: Foxglove's JSON encoding of ``foxglove.SceneUpdate`` (schema encoding ``jsonschema``);
- ``cdr``: ROS 2 ``foxglove_msgs/msg/SceneUpdate`` (schema encoding ``ros2msg``), for ROS 2 logs.

/lanecast/prediction is JSON with lanecast's own JSON schema (``PREDICTION_SCHEMA``); in ROS 2 logs
it is a ``std_msgs/msg/String`` whose ``data`` is that same JSON text. The pieces, one concern each:
``forecast_batch`` (forecasts table → frames and batches), ``forecast_drawing`` (lines, colours,
metadata), ``prediction_json``, ``scene_update_encoders`` (protobuf, JSON), ``scene_update_cdr``;
what callers use of them is re-exported here (``__all__``).
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Literal

import numpy as np

from lanecast.io_adapters.errors import InputError
from lanecast.io_adapters.logs.forecast_batch import (
    EXPLAIN_TOPIC,
    FORECAST_TOPIC,
    N_STEPS,
    PREDICTION_TOPIC,
    WHAT_IF_SLOTS,
    ForecastBatch,
    ForecastFrame,
    batch_from_table,
    frames_from_table,
)
from lanecast.io_adapters.logs.foxglove.forecast_drawing import (
    ALT_ALPHA,
    COLOURS,
    LABELS,
    LINE_THICKNESS_M,
    MAIN_ALPHA,
    dominant_maneuver,
    drawing_of,
)
from lanecast.io_adapters.logs.foxglove.scene_update_cdr import (
    SCENE_UPDATE_ROS2,
    STRING_ROS2,
    ros2_typestore,
    scene_update_cdr,
    strings_cdr,
)
from lanecast.io_adapters.logs.foxglove.scene_update_encode import (
    protobuf_schema,
    scene_update_json,
    scene_update_protobuf,
)
from lanecast.io_adapters.logs.mcap.writer import scene_update_jsonschema
from lanecast.io_adapters.logs.messages.prediction_json import (
    PREDICTION_SCHEMA,
    prediction_dict,
    prediction_texts,
)

__all__ = [
    "ALT_ALPHA",
    "BULK_ROWS",
    "COLOURS",
    "ENCODINGS",
    "EXPLAIN_TOPIC",
    "FORECAST_TOPIC",
    "LABELS",
    "LINE_THICKNESS_M",
    "MAIN_ALPHA",
    "N_STEPS",
    "PREDICTION_SCHEMA",
    "PREDICTION_TOPIC",
    "SCENE_UPDATE_ROS2",
    "STRING_ROS2",
    "WHAT_IF_SLOTS",
    "ChannelSpec",
    "Encoding",
    "ForecastBatch",
    "ForecastFrame",
    "batch_from_table",
    "channel_specs",
    "dominant_maneuver",
    "encode_batch",
    "encode_frame",
    "explain_channel_spec",
    "frames_from_table",
    "prediction_dict",
    "prediction_texts",
    "ros2_typestore",
    "scene_update_cdr",
    "scene_update_json",
    "scene_update_jsonschema",
    "scene_update_protobuf",
]

Encoding = Literal["protobuf", "json", "cdr"]
ENCODINGS: tuple[str, ...] = ("protobuf", "json", "cdr")


@dataclass(frozen=True)
class ChannelSpec:
    """What a writer registers for one forecast topic."""

    topic: str
    schema_name: str
    schema_encoding: str
    schema_data: bytes
    message_encoding: str
    ros_msgtype: str | None = None  # for rosbags writers (cdr only)
    #: MCAP channel metadata: which model made the forecasts (``model``, ``model_sha256``,
    #: ``model_trained_on``), so that the log itself says it
    metadata: tuple[tuple[str, str], ...] = ()


def channel_specs(encoding: str) -> list[ChannelSpec]:
    """The two forecast channels (forecast, prediction) a log with ``encoding`` gets."""
    if encoding == "protobuf":
        scene = ChannelSpec(FORECAST_TOPIC, "foxglove.SceneUpdate", "protobuf", protobuf_schema(), "protobuf")
    elif encoding == "json":
        scene = ChannelSpec(
            FORECAST_TOPIC, "foxglove.SceneUpdate", "jsonschema", scene_update_jsonschema(), "json"
        )
    elif encoding == "cdr":
        store = ros2_typestore()
        scene_def, _ = store.generate_msgdef(SCENE_UPDATE_ROS2, ros_version=2)
        string_def, _ = store.generate_msgdef(STRING_ROS2, ros_version=2)
        scene = ChannelSpec(
            FORECAST_TOPIC, SCENE_UPDATE_ROS2, "ros2msg", scene_def.encode(), "cdr", SCENE_UPDATE_ROS2
        )
        pred = ChannelSpec(PREDICTION_TOPIC, STRING_ROS2, "ros2msg", string_def.encode(), "cdr", STRING_ROS2)
        return [scene, pred]
    else:
        raise InputError(None, f"unknown forecast encoding {encoding!r}", expected=f"one of {ENCODINGS}")
    pred = ChannelSpec(
        PREDICTION_TOPIC, "lanecast.Prediction", "jsonschema", json.dumps(PREDICTION_SCHEMA).encode(), "json"
    )
    return [scene, pred]


#: Targets encoded per bulk pass: bounds the memory of the encoded messages, not their speed.
BULK_ROWS = 20_000


def explain_channel_spec(encoding: str) -> ChannelSpec:
    """The /lanecast/explain channel: SceneUpdate as on /lanecast/forecast, one entity per what-if."""
    return dataclasses.replace(channel_specs(encoding)[0], topic=EXPLAIN_TOPIC)


def encode_batch(batch: ForecastBatch, encoding: str) -> Iterator[tuple[int, bytes, bytes]]:
    """(t0 in ns, /lanecast/forecast payload, /lanecast/prediction payload) of each frame, in order.

    Frames are encoded in bulk, up to :data:`BULK_ROWS` targets at a time.
    """
    if encoding not in ENCODINGS:
        raise InputError(None, f"unknown forecast encoding {encoding!r}", expected=f"one of {ENCODINGS}")
    first = 0
    while first < batch.n_frames:
        last = int(np.searchsorted(batch.bounds, batch.bounds[first] + BULK_ROWS, side="right")) - 1
        last = min(max(last, first + 1), batch.n_frames)
        part = batch.slice(first, last)
        drawing = drawing_of(part)
        predictions = prediction_texts(part)
        if encoding == "protobuf":
            scenes = scene_update_protobuf(part, drawing)
        elif encoding == "json":
            scenes = scene_update_json(part, drawing)
        else:
            scenes = scene_update_cdr(part, drawing)
            predictions = strings_cdr(predictions)
        yield from zip(part.t0_ns.tolist(), scenes, predictions, strict=True)
        first = last


def encode_frame(frame: ForecastFrame, encoding: str) -> tuple[bytes, bytes]:
    """(/lanecast/forecast payload, /lanecast/prediction payload) of one frame in ``encoding``."""
    ((_, scene, prediction),) = encode_batch(ForecastBatch.of(frame), encoding)
    return scene, prediction
