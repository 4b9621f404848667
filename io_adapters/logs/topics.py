"""The topics of a drive log with their message types and counts: what a robotics user asks first.

MCAP: from the summary's channels, schemas and statistics where the file has them (no pass over the
data), else by counting the message records of one pass. ROS 1 and ROS 2 bags: from rosbags'
connections (their indexes and metadata.yaml). Used by ``lanecast info``; lanecast's own topics
(``/lanecast/forecast``, ``/lanecast/prediction``, ``/lanecast/metadata``) are listed like any other.

Which model made a log's forecasts (:func:`forecast_model`): an annotated MCAP names it in the
metadata of its ``/lanecast/forecast`` channel (``model``, ``model_sha256``, ``model_trained_on``), an
annotated ROS 2 bag in its metadata.yaml ``custom_data`` under the same keys prefixed with
:data:`MODEL_KEY_PREFIX`, where ``ros2 bag info`` and rosbags show it.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

from mcap.exceptions import McapError
from mcap.reader import make_reader
from mcap.records import Channel, Message, Schema
from mcap.stream_reader import StreamReader

from lanecast.io_adapters.errors import LanecastError, LogError
from lanecast.io_adapters.logs.forecast_batch import FORECAST_TOPIC

#: custom_data keys of an annotated ROS 2 bag naming the model: ``lanecast.forecast.model`` …
MODEL_KEY_PREFIX = "lanecast.forecast."


@dataclass(frozen=True)
class TopicCount:
    """One topic of a log: its name, message type, encoding and number of messages."""

    topic: str
    message_type: str
    encoding: str
    messages: int


def mcap_topics(path: Path) -> list[TopicCount]:
    """The topics of an MCAP file, sorted by name."""
    try:
        with path.open("rb") as fh:
            summary = make_reader(fh).get_summary()
    except (McapError, OSError, ValueError, EOFError):
        summary = None
    if summary is not None and summary.statistics is not None and summary.channels:
        counts = summary.statistics.channel_message_counts
        return _sorted(
            TopicCount(
                c.topic,
                summary.schemas[c.schema_id].name if c.schema_id in summary.schemas else "",
                c.message_encoding,
                int(counts.get(c.id, 0)),
            )
            for c in summary.channels.values()
        )
    channels: dict[int, Channel] = {}
    schemas: dict[int, Schema] = {}
    counts_by_channel: Counter[int] = Counter()
    try:
        with path.open("rb") as fh:
            for record in StreamReader(fh, skip_magic=False).records:
                if isinstance(record, Message):
                    counts_by_channel[record.channel_id] += 1
                elif isinstance(record, Channel):
                    channels[record.id] = record
                elif isinstance(record, Schema):
                    schemas[record.id] = record
    except (McapError, OSError, ValueError, EOFError) as exc:
        raise LogError(path, f"cannot list its topics: {exc}", expected="an intact MCAP file") from exc
    return _sorted(
        TopicCount(
            c.topic,
            schemas[c.schema_id].name if c.schema_id in schemas else "",
            c.message_encoding,
            counts_by_channel[c.id],
        )
        for c in channels.values()
    )


def bag_topics(path: Path) -> list[TopicCount]:
    """The topics of a ROS 1 bag or ROS 2 bag directory, sorted by name."""
    from rosbags.highlevel import AnyReader  # heavy: only for bags

    counts: Counter[tuple[str, str]] = Counter()
    with AnyReader([path]) as reader:
        for c in reader.connections:
            counts[(c.topic, c.msgtype)] += c.msgcount
    encoding = "ros1" if path.is_file() else "cdr"
    return _sorted(TopicCount(topic, msgtype, encoding, n) for (topic, msgtype), n in counts.items())


def log_topics(path: Path) -> list[TopicCount]:
    """The topics of any drive log lanecast reads (an MCAP file, a ROS 1 bag, a ROS 2 bag directory)."""
    if path.is_file() and path.suffix.lower() == ".mcap":
        return mcap_topics(path)
    return bag_topics(path)


def _sorted(topics: Iterable[TopicCount]) -> list[TopicCount]:
    return sorted(topics, key=lambda t: t.topic)


def forecast_model(path: Path) -> dict[str, str]:
    """The model an annotated log names for its forecasts: ``model``, ``model_sha256``,
    ``model_trained_on`` (empty for other logs, ROS 1 bags and damaged files: the reading itself
    names the damage)."""
    if path.is_file() and path.suffix.lower() == ".mcap":
        try:
            with path.open("rb") as fh:
                summary = make_reader(fh).get_summary()
        except (McapError, OSError, ValueError, EOFError):
            return {}
        channels = summary.channels.values() if summary is not None else ()
        for channel in channels:
            if channel.topic == FORECAST_TOPIC and channel.metadata.get("model"):
                return {k: v for k, v in channel.metadata.items() if k.startswith("model")}
        return {}
    if path.is_dir() and (path / "metadata.yaml").is_file():
        from lanecast.io_adapters.logs.rosbag.copy import ros2_custom_data

        try:
            custom = ros2_custom_data(path)
        except LanecastError:
            return {}
        return {k[len(MODEL_KEY_PREFIX) :]: v for k, v in custom.items() if k.startswith(MODEL_KEY_PREFIX)}
    return {}


def time_offset(path: Path) -> int:
    """The ``time_offset_ns`` of a log lanecast wrote (what its clock adds to the track table's
    times; 0 for other logs): from an MCAP's metadata or a bag's ``/lanecast/metadata`` message."""
    from lanecast.io_adapters.logs import conventions as conv

    text: str | bytes | None = None
    try:
        if path.is_file() and path.suffix.lower() == ".mcap":
            with path.open("rb") as fh:
                for record in make_reader(fh).iter_metadata():
                    if record.name == conv.META_NAME:
                        text = record.metadata.get(conv.META_NAME)
        else:
            from rosbags.highlevel import AnyReader

            with AnyReader([path]) as reader:
                conns = [c for c in reader.connections if c.topic == conv.META_TOPIC]
                for conn, _, raw in reader.messages(connections=conns):
                    text = getattr(reader.deserialize(raw, conn.msgtype), "data", None)
                    break
    except (McapError, OSError, ValueError, EOFError, LanecastError):
        return 0
    except Exception:  # rosbags' errors: the reading itself names a damaged bag
        return 0
    if not text:
        return 0
    try:
        return int(conv.parse_log_metadata(path, text).get("time_offset_ns") or 0)
    except LogError:  # not lanecast's document: the log's clock is the tracks'
        return 0
