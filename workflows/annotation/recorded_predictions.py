"""The predictors recorded in a drive log: which topics hold predictions, and their columns.

A log (MCAP or ROS 2 bag) may hold the predictions of the stack that recorded it, Autoware's
``PredictedObjects`` (found by schema), and lanecast's own ``/lanecast/prediction`` (found by
topic). Each topic becomes one :class:`~lanecast.io_adapters.logs.autoware.predicted_objects.RecordedPredictions`:
the scorer treats every recorded predictor alike. Topics can be named (``--predictions TOPIC``);
a named topic the log does not hold, or holds in another type, is an error naming it.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from mcap.reader import NonSeekingReader, make_reader
from rosbags.highlevel import AnyReader

from lanecast.io_adapters.errors import LanecastError, LogError
from lanecast.io_adapters.logs.autoware.predicted_objects import (
    PREDICTED_OBJECT_TYPES,
    PredictionColumns,
    RecordedPredictions,
)
from lanecast.io_adapters.logs.autoware.predicted_objects_cdr import CdrLayoutError, add_predicted_objects_cdr
from lanecast.io_adapters.logs.forecast_messages import PREDICTION_TOPIC
from lanecast.io_adapters.logs.messages import ros_types
from lanecast.workflows.annotation.log_scores import (
    checked_forecast_times,
    log_forecasts,
    prediction_documents,
)

SUPPORTED = f"{' or '.join(PREDICTED_OBJECT_TYPES)} (cdr), or {PREDICTION_TOPIC}"


def read_predictions(
    log: Path, topics: Sequence[str] = (), *, checked: bool = False
) -> list[RecordedPredictions]:
    """The recorded predictors of ``log``: the named ``topics``, else every topic of a supported type.

    ``checked``: the log's CRCs were checked already (lanecast's track reader checks every one and
    names the offset of a damage), so an MCAP's are not computed again (most of the time the read
    took, on a log of camera frames).

    LogError naming the log when a named topic is missing or of another type, when no topic holds
    predictions, or when a message cannot be decoded (with its topic and log time).
    """
    try:
        found = _bag_topics(log) if log.is_dir() else _mcap_topics(log)
    except LanecastError:
        raise
    except Exception as exc:  # the mcap and rosbags libraries' own error types
        raise LogError(log, f"cannot list its topics: {type(exc).__name__}: {exc}") from exc
    wanted = list(dict.fromkeys(topics)) or sorted(t for t, kind in found.items() if _supported(t, kind))
    for topic in wanted:
        if topic not in found:
            raise LogError(log, f"no topic {topic!r}", column=topic, expected=f"one of {sorted(found)}")
        if not _supported(topic, found[topic]):
            raise LogError(
                log,
                f"topic {topic!r} holds {found[topic]}",
                column=topic,
                expected=f"predictions: {SUPPORTED}",
            )
    if not wanted:
        raise LogError(log, "no topic holds recorded predictions", expected=SUPPORTED)
    autoware = [t for t in wanted if t != PREDICTION_TOPIC]
    out = _autoware_predictions(log, autoware, checked) if autoware else {}
    if PREDICTION_TOPIC in wanted:
        out[PREDICTION_TOPIC] = lanecast_predictions(log)
    return [out[t] for t in wanted]


def _supported(topic: str, kind: str) -> bool:
    return kind in PREDICTED_OBJECT_TYPES or topic == PREDICTION_TOPIC


def _mcap_topics(log: Path) -> dict[str, str]:
    """Topic → schema name, from the summary (a scan of the messages where the log has none)."""
    topics: dict[str, str] = {}
    with log.open("rb") as fh:
        summary = make_reader(fh).get_summary()
        if summary is not None:
            for ch in summary.channels.values():
                schema = summary.schemas.get(ch.schema_id)
                topics[ch.topic] = schema.name if schema is not None else ch.message_encoding
            return topics
    with log.open("rb") as fh:
        for record in NonSeekingReader(fh).iter_messages():
            schema, channel, _ = record
            topics.setdefault(channel.topic, schema.name if schema is not None else channel.message_encoding)
    return topics


def _bag_topics(log: Path) -> dict[str, str]:
    with AnyReader([log], default_typestore=ros_types.typestore(2)) as reader:
        return {c.topic: c.msgtype for c in reader.connections}


def _autoware_predictions(log: Path, topics: list[str], checked: bool) -> dict[str, RecordedPredictions]:
    cols = {t: PredictionColumns(t) for t in topics}
    count = dict.fromkeys(topics, 0)

    def add(topic: str, log_time: int, decode: Any, raw: bytes | None = None) -> None:
        """Append one message: straight from its bytes where ``raw`` (the shipped layout), else
        (or where those bytes do not follow it) through rosbags' ``decode``."""
        count[topic] += 1
        if raw is not None:
            try:
                add_predicted_objects_cdr(cols[topic], raw, log_time)
                return
            except CdrLayoutError:
                pass  # rosbags decodes it, or names what is wrong
        try:
            msg = decode()
            cols[topic].add_message(msg, log_time)
        except Exception as exc:  # rosbags' own error types, a message cut short
            raise LogError(
                log,
                f"topic {topic!r} message {count[topic]} (log time {log_time} ns) cannot be decoded: "
                f"{type(exc).__name__}: {exc}",
                column=topic,
                expected="a PredictedObjects message as its schema defines it",
            ) from exc

    if log.is_dir():
        with AnyReader([log], default_typestore=ros_types.typestore(2)) as reader:
            conns = [c for c in reader.connections if c.topic in cols]
            fast = {c.topic: _shipped_layout(reader.typestore, c.msgtype) for c in conns}
            for conn, log_time, raw in reader.messages(connections=conns):
                decode = lambda: reader.deserialize(raw, conn.msgtype)  # noqa: B023, E731
                add(conn.topic, log_time, decode, raw if fast[conn.topic] else None)
    else:
        with log.open("rb") as fh:
            for schema, channel, message in NonSeekingReader(fh, validate_crcs=not checked).iter_messages(
                topics=topics, log_time_order=False
            ):
                name = schema.name if schema is not None else ""
                text = schema.data.decode("utf-8", "replace") if schema is not None else ""
                store = ros_types.store_for(name, text, 2)
                data = message.data
                decode = lambda: store.deserialize_cdr(data, name)  # noqa: B023, E731
                add(
                    channel.topic, message.log_time, decode, data if store is ros_types.typestore(2) else None
                )
    return {t: c.finish() for t, c in cols.items()}


def _shipped_layout(store: Any, msgtype: str) -> bool:
    """Whether ``store`` (a bag's own) defines ``msgtype`` as the shipped definitions do."""
    ours = ros_types.typestore(2)
    try:
        return bool(store.generate_msgdef(msgtype)[0] == ours.generate_msgdef(msgtype)[0])
    except Exception:  # rosbags' own error types: a type the store cannot expand
        return False


def lanecast_predictions(log: Path) -> RecordedPredictions:
    """lanecast's own forecasts on /lanecast/prediction as recorded predictions: per target, its K
    alternatives with their probabilities as the paths (the forecast alone where it has none), five
    poses at 1–5 s."""
    fc = log_forecasts(checked_forecast_times(log, prediction_documents(log)))
    cols = PredictionColumns(PREDICTION_TOPIC)
    k = fc.alt_points.shape[1]
    for i in range(fc.track_id.size):
        if k:
            valid = [j for j in range(k) if not np.isnan(fc.alt_probs[i, j]) or j == 0]
            paths = [(float(fc.alt_probs[i, j]), 1.0, 1.0, fc.alt_points[i, j]) for j in valid]
        else:
            paths = [(np.nan, 1.0, 1.0, fc.points[i])]
        cols.add_paths(int(fc.t0_ns[i]), int(fc.track_id[i]), "", paths)
    return cols.finish()
