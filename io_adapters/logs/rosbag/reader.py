"""Read tracked objects from ROS bags (ROS 1 ``.bag``, ROS 2 directories with sqlite3 or MCAP storage).

Through rosbags' ``AnyReader``: the bag's own message definitions where it stores them, else
lanecast's typestore (ROS 2 Humble / ROS 1 Noetic plus the Autoware types from their ``.msg``
files, :mod:`lanecast.io_adapters.logs.messages.ros_types`). Same message types and frame handling as the MCAP adapter:
``autoware_perception_msgs/msg/TrackedObjects``, ``visualization_msgs/msg/MarkerArray``, ``/tf``
and odometry (see :mod:`lanecast.io_adapters.logs.object_columns`).
"""

from __future__ import annotations

import re
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import pyarrow as pa

from lanecast.io_adapters.contracts import track_table
from lanecast.io_adapters.errors import LogError
from lanecast.io_adapters.logs import assembly as log_assembly
from lanecast.io_adapters.logs import conventions as conv
from lanecast.io_adapters.logs import coordinate_frames as frame_transforms
from lanecast.io_adapters.logs import object_columns as to
from lanecast.io_adapters.logs.mcap.errors import IndexMismatch
from lanecast.io_adapters.logs.mcap.walk import check_file
from lanecast.io_adapters.logs.messages import ros_types
from lanecast.io_adapters.logs.rosbag import damage as bag_damage
from lanecast.io_adapters.logs.rosbag import ros2_metadata as bag_metadata
from lanecast.io_adapters.logs.rosbag import ros2_open_damage
from lanecast.io_adapters.logs.rosbag.ros1_damage import ROS1_MAGIC, ros1_damage

FORMAT = "rosbag"
ROS1_PREFIX = b"#ROSBAG V"  # any version: recognised as a ROS 1 bag, refused unless 2.0
OBJECT_TYPES = (*ros_types.TRACKED_OBJECT_TYPES, ros_types.MARKER_ARRAY)
SUPPORTED = ros_types.OBJECT_MESSAGES


def bag_path(path: str | Path) -> Path | None:
    """The path AnyReader opens for ``path`` (a .bag, a ROS 2 bag directory or a file in one), else None."""
    path = Path(path)
    if path.is_dir():
        return path if (path / "metadata.yaml").is_file() else None
    if path.is_file():
        if path.suffix in (".db3", ".mcap") and (path.parent / "metadata.yaml").is_file():
            return path.parent
        with path.open("rb") as f:
            if f.read(len(ROS1_PREFIX)) == ROS1_PREFIX:
                return path
    return None


def sniff(path: str | Path) -> bool:
    """True for a ROS 1 bag (by its magic) or a ROS 2 bag directory (with metadata.yaml)."""
    return bag_path(path) is not None


def _storage_topic_unread(bag: Path, reader: Any) -> LogError | None:
    """LogError naming metadata.yaml (the topic's line and key) for a topic of a storage file that
    metadata.yaml describes otherwise: rosbags reads only messages whose storage topic equals one of
    metadata.yaml (name, type, serialization format, QoS profiles, type hash) and skips every other
    without a word (a QoS profile edited in metadata.yaml lost the whole topic)."""
    for bag_reader in reader.readers:
        directory = getattr(bag_reader, "storage", bag_reader)  # rosbags' metadata.yaml reader
        listed = directory.connections
        for storage in getattr(directory, "storages", None) or []:  # its storage files' readers
            for x in storage.connections:
                if any(
                    y.topic == x.topic
                    and y.msgtype == x.msgtype
                    and y.ext == x.ext
                    and (not x.digest or not y.digest or y.digest == x.digest)
                    for y in listed
                ):
                    continue
                same = [y for y in listed if y.topic == x.topic]
                if not same:
                    key, what = "name", "is not listed in metadata.yaml"
                elif all(y.msgtype != x.msgtype for y in same):
                    key, what = "type", f"has type {x.msgtype!r} there, {same[0].msgtype!r} in metadata.yaml"
                elif all(y.ext.serialization_format != x.ext.serialization_format for y in same):
                    key, what = "serialization_format", "has another serialization format there"
                elif all(y.ext.offered_qos_profiles != x.ext.offered_qos_profiles for y in same):
                    key, what = "offered_qos_profiles", "has other offered QoS profiles there"
                else:
                    key, what = "type_description_hash", "has another type description hash there"
                return LogError(
                    bag / "metadata.yaml",
                    f"topic {x.topic!r} of the storage file {what}: rosbags would skip all its messages",
                    line=bag_metadata.topic_key_line(bag, x.topic, key),
                    column=key,
                    expected="metadata.yaml's topics as the storage file records them (ros2 bag reindex writes them)",
                )
    return None


def read_log(
    path: str | Path, *, topic: str | None = None, fixed_frames: Sequence[str] | None = None
) -> pa.Table:
    """One bag → a validated track table (``topic`` picks one object topic, default all)."""
    from rosbags.highlevel import AnyReader

    path = Path(path)
    target = bag_path(path)
    if target is None:
        if path.is_file() and path.stat().st_size == 0:
            raise LogError(
                path, "the file is empty", offset=0, expected="a ROS 1 bag or a ROS 2 bag directory"
            )
        raise LogError(
            path,
            "not a ROS bag",
            offset=0,
            expected="a ROS 1 .bag (#ROSBAG V2.0) or a ROS 2 bag directory with metadata.yaml",
        )
    ros1 = target.is_file()
    if ros1:
        other = _other_version(path, target)
        if other is not None:
            raise other
    if target.is_dir():
        check_storage(target)
    topics: dict[str, log_assembly.TopicData] = {}
    transforms = frame_transforms.Transforms()
    log_meta: dict[str, Any] | None = None
    at: tuple[int, str, int] = (0, "", 0)  # the messages read, the last one's topic and log time
    try:
        with AnyReader([target], default_typestore=ros_types.typestore(1 if ros1 else 2)) as reader:
            if ros1 and _chunk_listed_twice(reader):  # rosbags would read one chunk twice, another never
                raise _located_damage(target, ros1) or LogError(
                    path, "two chunk info records list the same chunk", expected="an intact ROS bag"
                )
            unread = None if ros1 else _storage_topic_unread(target, reader)
            if unread is not None:
                raise unread
            listing = ", ".join(sorted(f"{c.topic} [{c.msgtype}]" for c in reader.connections)) or "none"
            handlers: dict[int, Callable[[Any, int], None]] = {}
            for conn in reader.connections:
                h = _handler(path, conn.topic, conn.msgtype, topic, topics, transforms)
                if h is not None:
                    handlers[conn.id] = h
            # A damaged index can make rosbags list no topic or no message (a bag header whose
            # chunk_count is 0): where the bag's structure shows damage, that is the error.
            if topic is not None and topic not in topics:
                raise _located_damage(target, ros1) or LogError(
                    path, f"topic {topic!r} holds no tracked objects (topics: {listing})", expected=SUPPORTED
                )
            if not topics:
                raise _located_damage(target, ros1) or LogError(
                    path, f"no supported topic with tracked objects (topics: {listing})", expected=SUPPORTED
                )
            # A bag lanecast wrote (it has the metadata topic) is read whole, so that every message
            # counts towards the payload checksum its metadata states.
            own = any(c.topic == conv.META_TOPIC for c in reader.connections)
            if ros1 and not own:  # no checksum to catch what rosbags skips (an index missing messages)
                damage = _located_damage(target, ros1)
                if damage is not None:
                    raise damage
            wanted = [c for c in reader.connections if own or c.id in handlers]
            digest = conv.PayloadDigest()
            for conn, timestamp, raw in reader.messages(connections=wanted):
                at = (at[0] + 1, conn.topic, timestamp)
                if conn.topic == conv.META_TOPIC and conn.msgtype == ros_types.STRING:
                    meta_msg: Any = _decode(reader, path, target, ros1, at, conn.msgtype, raw)
                    log_meta = conv.parse_log_metadata(path, meta_msg.data)
                    continue
                if own and not conn.topic.startswith(conv.OWN_TOPIC_PREFIX):  # not forecasts added later
                    digest.add(conn.topic, timestamp, raw)
                handler = handlers.get(conn.id)
                if handler is not None:
                    handler(_decode(reader, path, target, ros1, at, conn.msgtype, raw), timestamp)
            if own:
                try:
                    conv.check_payload_digest(path, log_meta, digest)
                except LogError as exc:
                    raise _digest_mismatch(target, ros1, exc) from exc
    except LogError:
        raise
    except Exception as exc:  # rosbags reader/serde errors: damaged or unreadable bag
        damage = _located_damage(target, ros1)
        if damage is not None:
            raise damage from exc
        where = f" at message {at[0]} (topic {at[1]!r}, log time {at[2]} ns) or the next" if at[0] else ""
        raise LogError(
            path,
            f"cannot read the bag{where}: {type(exc).__name__}: {exc}",
            expected="an intact ROS bag",
        ) from exc
    found = {t: d for t, d in topics.items() if len(d.columns)}
    if not found:
        raise _located_damage(target, ros1) or LogError(
            path, "the supported topics hold no objects", expected=f"messages of type {SUPPORTED}"
        )
    return log_assembly.assemble(
        path,
        found,
        transforms,
        log_meta,
        source_format="ros1" if ros1 else "ros2",
        topic=topic,
        fixed_frames=fixed_frames or conv.FIXED_FRAMES,
    )


def _chunk_listed_twice(reader: Any) -> bool:
    positions = [info.pos for r in reader.readers for info in getattr(r, "chunk_infos", [])]
    return len(set(positions)) != len(positions)


def check_storage(target: Path) -> None:
    """A ROS 2 bag directory's metadata.yaml and storage files, before rosbags reads them: MCAP
    files walked with every check (rosbags checks no CRC, and reads through the chunk indexes, so
    it would skip or repeat chunks where they lie, without a word), a sqlite3 file cut short (it
    may still open) and its tables."""
    listed = bag_metadata.check_metadata(target)  # other files in the directory are not the bag's
    for storage_file in (f for f in listed if f.suffix == ".mcap"):
        for offset, problem in check_file(storage_file)[:1]:
            raise IndexMismatch(
                storage_file,
                f"the file's index disagrees with its data section: {problem}; rosbags reads the bag "
                "through the index and would read other messages than the file holds",
                offset=offset,
                expected="indexes that match the data section (mcap recover writes them anew)",
            )
    for storage_file in (f for f in listed if f.suffix == ".db3"):
        cut = bag_damage.sqlite_truncation(storage_file)
        if cut is not None:
            raise LogError(storage_file, cut[1], offset=cut[0], expected="an intact ROS bag")
        bag_metadata.check_sqlite_tables(storage_file)


def _other_version(path: Path, target: Path) -> LogError | None:
    """The error for a ROS 1 bag file whose version line is not 2.0, else None."""
    with target.open("rb") as f:
        first = f.read(len(ROS1_MAGIC))
    if first == ROS1_MAGIC:
        return None
    version = first.partition(b"\n")[0].decode("latin-1")
    return LogError(
        path,
        f"a ROS 1 bag of another format version ({version!r})",
        offset=0,
        expected="'#ROSBAG V2.0' (the only ROS 1 bag version lanecast reads)",
    )


def damage_of(target: Path) -> LogError | None:
    """The error naming the file and byte offset of the damage in a bag (a ROS 1 file or a ROS 2
    directory) that rosbags cannot open, where its structure shows it, else None: the checks
    :func:`read_log` makes before and after rosbags fails."""
    try:
        if target.is_dir():
            check_storage(target)
        elif target.is_file() and (other := _other_version(target, target)) is not None:
            return other
        return _located_damage(target, target.is_file())
    except LogError as exc:  # found by the checks of the metadata and the storage files
        return exc


def located(files: Sequence[Path], ros1: bool) -> LogError | None:
    """The error naming the file, byte offset and what is wrong of the first of a bag's storage
    ``files`` whose structure shows damage (a ROS 1 bag's records, a sqlite3 file's header and
    pages; MCAP storage is left to its checked walk), else None: rosbags' own errors give no offset."""
    for file in files:
        if not ros1 and file.suffix != ".db3":
            continue
        try:
            found = ros1_damage(file) if ros1 else bag_damage.sqlite_damage(file)
        except OSError:
            continue
        if found is not None:
            return LogError(file, found[1], offset=found[0], expected="an intact ROS bag")
    return None


def _located_damage(target: Path, ros1: bool) -> LogError | None:
    files = _storage_files(target, ros1)
    return located(files, ros1) or (None if ros1 else ros2_open_damage.located(files))


def _storage_files(target: Path, ros1: bool) -> list[Path]:
    return [target] if ros1 else bag_metadata.check_metadata(target)


def _decode(
    reader: Any, path: Path, target: Path, ros1: bool, at: tuple[int, str, int], msgtype: str, raw: Any
) -> Any:
    """The message ``raw`` deserialized, or the LogError naming where its bytes are damaged."""
    try:
        return reader.deserialize(raw, msgtype)
    except Exception as exc:  # this message's bytes, not the reading of the bag
        raise _undecodable(path, target, ros1, at, msgtype, raw, exc) from exc


def _undecodable(
    path: Path, target: Path, ros1: bool, at: tuple[int, str, int], msgtype: str, raw: Any, exc: Exception
) -> LogError:
    """The error for a message whose bytes cannot be decoded: at its offset in the bag's storage
    file where sqlite3's own check or the message's bytes show it (stored uncompressed), else in
    the bag."""
    damage = _located_damage(target, ros1)
    if damage is not None:
        return damage
    what = f"cannot read the bag at message {at[0]} (topic {at[1]!r}, log time {at[2]} ns)"
    reason = why_undecodable(exc, len(raw))
    expected = f"a valid {msgtype} message"
    for file in _storage_files(target, ros1):
        try:
            offset = bag_damage.message_offset(file, raw)
        except OSError:
            continue
        if offset is not None:
            page = bag_damage.sqlite_page(file, offset) if file.suffix == ".db3" else None
            where = f", on page {page}" if page is not None else ""
            return LogError(file, f"{what}{where}: {reason}", offset=offset, expected=expected)
    return LogError(path, f"{what}: {reason}", expected=expected)


_SHORT = re.compile(r"at least (\d+) bytes for unpacking \d+ bytes at offset (\d+)")
_NOT_UTF8 = re.compile(r"can't decode byte (0x[0-9a-f]{2}) in position (\d+)")
_ENDS_EARLY = ("buffer is smaller than requested size", "unpack_from requires a buffer", "out of range")


def why_undecodable(exc: BaseException, size: int) -> str:
    """What is wrong with a message's ``size`` bytes that rosbags could not deserialize, in words
    (rosbags passes on Python's texts: "unpack_from requires a buffer of at least …")."""
    cause: BaseException | None = exc
    while cause is not None:  # rosbags wraps the decoder's error, sometimes twice
        text = str(cause)
        if isinstance(cause, UnicodeDecodeError):
            return (
                f"a text field holds bytes that are not UTF-8 (byte 0x{cause.object[cause.start]:02x} "
                f"at position {cause.start} of the text)"
            )
        if (short := _SHORT.search(text)) is not None:
            need, field = (int(v) for v in short.groups())
            return (
                f"the message's {size:,} bytes end before its field at byte {field:,} ({need:,} bytes "
                "needed): a length or count inside it is damaged"
            )
        if (utf := _NOT_UTF8.search(text)) is not None:
            return (
                f"a text field holds bytes that are not UTF-8 (byte {utf.group(1)} at position "
                f"{utf.group(2)} of the text)"
            )
        if any(words in text for words in _ENDS_EARLY):
            return (
                f"the message's {size:,} bytes end before the data its fields announce: a length or "
                "count inside it is damaged"
            )
        cause = cause.__cause__ or cause.__context__
    return f"its {size:,} bytes do not decode as this type"


def _digest_mismatch(target: Path, ros1: bool, exc: LogError) -> LogError:
    """The payload checksum does not match: the damage sqlite3's own check (or the ROS 1 record
    walk) locates, else the checksum's error naming the one storage file whose bytes changed."""
    damage = _located_damage(target, ros1)
    if damage is not None:
        return damage
    files = _storage_files(target, ros1)
    if len(files) != 1 or files[0] == target:
        return exc
    check = "sqlite3's own check finds the database intact: " if files[0].suffix == ".db3" else ""
    return LogError(
        files[0],
        f"{exc.reason} ({check}a message's bytes, topic or log time changed; the checksum covers the "
        "whole bag and cannot say which)",
        expected=exc.expected,
    )


def _handler(
    path: Path,
    conn_topic: str,
    msgtype: str,
    topic: str | None,
    topics: dict[str, log_assembly.TopicData],
    transforms: frame_transforms.Transforms,
) -> Callable[[Any, int], None] | None:
    if msgtype in OBJECT_TYPES:
        if topic is not None and conn_topic not in (topic, topic + conv.MARKER_SUFFIX):
            return None
        data = topics.setdefault(conn_topic, log_assembly.TopicData(conn_topic, msgtype))
        add = to.add_tracked_objects if msgtype in ros_types.TRACKED_OBJECT_TYPES else to.add_marker_array
        cols = data.columns
        return lambda msg, t: add(cols, msg, t)
    if msgtype == ros_types.TF_MESSAGE:
        return lambda msg, _t: transforms.add_tf(msg, conn_topic)
    if msgtype == ros_types.ODOMETRY:
        return lambda msg, _t: transforms.add_odometry(msg, conn_topic)
    if topic is not None and conn_topic == topic:
        raise LogError(
            path, f"topic {topic!r} has type {msgtype}, which holds no tracked objects", expected=SUPPORTED
        )
    return None


def read(paths: Sequence[str | Path] | str | Path, **options: Any) -> pa.Table:
    """Bags → one validated track table (options: topic, fixed_frames; salvage applies to MCAP only)."""
    options.pop("salvage", None)
    if isinstance(paths, (str, Path)):
        paths = [paths]
    tables = [read_log(p, **options) for p in paths]
    return tables[0] if len(tables) == 1 else track_table.concat(tables, [str(p) for p in paths])
