"""Copy ROS bags record for record while merging extra messages in log-time order.

- ROS 2 bag directory → ROS 2 bag (rosbags): every connection (type, definition, hash, QoS) and
  message (bytes and time), the ``custom_data`` of metadata.yaml, plus the extra topics; the MCAP
  storage files rosbags writes (uncompressed, CRC 0) are then rewritten zstd-chunked with CRCs
  (:func:`compress_bag_storage`).
- ROS 1 bag → MCAP: every connection becomes a ``ros1msg`` schema and ``ros1`` channel, every
  message keeps its bytes and time.

The merge, counts and progress are those of :mod:`lanecast.io_adapters.logs.mcap.copy`
(:class:`~lanecast.io_adapters.logs.mcap.copy.Merge`).
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any, BinaryIO

from mcap.records import Channel, Schema

from lanecast.io_adapters.errors import LogError
from lanecast.io_adapters.logs.mcap.copy import (
    CHUNK_SIZE,
    LIBRARY,
    CopyStats,
    Merge,
    MergedCopy,
    check_new_topics,
    copy_mcap,
    finish_copy,
    zstd_writer,
)
from lanecast.io_adapters.logs.messages import ros_types
from lanecast.io_adapters.logs.rosbag.reader import check_storage, located
from lanecast.io_adapters.logs.rosbag.ros2_metadata import check_metadata


def copy_ros1_to_mcap(
    src: Path, out: BinaryIO, merge: Merge | None = None, *, chunk_size: int = CHUNK_SIZE
) -> CopyStats:
    """Every connection and message of ROS 1 bag ``src`` into an MCAP (no profile: the extra
    channels may use other encodings), merging ``merge``'s messages in log-time order."""
    from rosbags.rosbag1 import Reader

    src = Path(src)
    merge = merge or Merge()
    stats = CopyStats(profile="")
    writer = zstd_writer(out, chunk_size)
    writer.start(profile="", library=LIBRARY)
    try:
        with Reader(src) as reader:
            stats.bytes_in = src.stat().st_size
            check_new_topics(src, [c.topic for c in reader.connections], merge.channels)
            schema_of: dict[tuple[str, str], int] = {}
            channel_of: dict[int, int] = {}
            for conn in reader.connections:
                msgtype = conn.msgtype.replace("/msg/", "/")
                key = (msgtype, conn.msgdef.data)
                if key not in schema_of:
                    schema_of[key] = len(schema_of) + 1
                    writer.put_schema(
                        Schema(
                            id=schema_of[key],
                            name=msgtype,
                            encoding="ros1msg",
                            data=conn.msgdef.data.encode(),
                        )
                    )
                    stats.schemas += 1
                meta = {"md5sum": conn.digest}
                ext = conn.ext
                if getattr(ext, "callerid", None):
                    meta["callerid"] = str(ext.callerid)  # type: ignore[union-attr]
                if getattr(ext, "latching", None):
                    meta["latching"] = str(ext.latching)  # type: ignore[union-attr]
                cid = len(channel_of) + 1
                channel_of[conn.id] = cid
                writer.put_channel(
                    Channel(
                        id=cid,
                        topic=conn.topic,
                        message_encoding="ros1",
                        schema_id=schema_of[key],
                        metadata=meta,
                    )
                )
                stats.channels += 1
            base_schema, base_channel = len(schema_of), len(channel_of)
            extra_ids = [base_channel + 1 + i for i in range(len(merge.channels))]
            stats.extra_channel_ids = extra_ids
            writer.put_extra(
                merge.channels, [base_schema + 1 + i for i in range(len(merge.channels))], extra_ids
            )
            copying = MergedCopy(
                merge,
                stats,
                lambda item: writer.add_message(extra_ids[item[1]], item[0], item[2], item[0], 0),
            )
            for conn, timestamp, data in reader.messages():
                copying.before(timestamp)
                writer.add_message(channel_of[conn.id], timestamp, bytes(data), timestamp, 0)
                copying.copied()
            copying.before(None)
    except LogError:
        raise
    except Exception as exc:  # rosbags' reading: ReaderError, a corrupt bz2/lz4 chunk, …
        raise unreadable(src, exc, "ROS 1") from exc
    finish_copy(writer, copying, out)
    return stats


def unreadable(src: Path, exc: Exception, kind: str) -> Exception:
    """The error for a bag rosbags failed to copy (read without lanecast's reader first, as with
    precomputed forecasts): where its structure shows the damage, the file and offset; an error of
    the system (a full disk: an OSError with an errno) as it is."""
    if isinstance(exc, OSError) and exc.errno is not None:
        return exc
    ros1 = kind == "ROS 1"
    damage = located([src] if ros1 else check_metadata(src), ros1)
    if damage is not None:
        return damage
    return LogError(
        src, f"cannot read the {kind} bag: {type(exc).__name__}: {exc}", expected="an intact ROS bag"
    )


def ros2_custom_data(bag: Path) -> dict[str, str]:
    """The ``custom_data`` of a ROS 2 bag's metadata.yaml (string keys and values; empty if none)."""
    from ruamel.yaml import YAML  # rosbags' own YAML library

    check_metadata(Path(bag))  # an alias bomb in custom_data is refused before it is expanded
    try:
        doc = YAML(typ="safe").load((Path(bag) / "metadata.yaml").read_text(encoding="utf-8"))
        custom = doc["rosbag2_bagfile_information"].get("custom_data") or {}
    except Exception as exc:  # any YAML or shape problem: rosbags' reader reports it first anyway
        raise LogError(bag, f"cannot read metadata.yaml's custom_data: {exc}") from exc
    if not isinstance(custom, dict):
        raise LogError(bag, "metadata.yaml's custom_data is not a mapping", expected="key: value strings")
    return {str(k): str(v) for k, v in custom.items()}


def copy_ros2_bag(
    src: Path,
    dst: Path,
    merge: Merge | None = None,
    *,
    typestore: Any = None,
    custom_data: Mapping[str, str] | None = None,
) -> CopyStats:
    """Every connection and message of ROS 2 bag directory ``src`` into a new bag ``dst`` (which must
    not exist; same storage plugin, the same ``custom_data`` in metadata.yaml plus ``custom_data``),
    merging ``merge``'s messages on CDR topics registered from ``typestore``."""
    from rosbags.rosbag2 import Reader, Writer
    from rosbags.rosbag2.writer import StoragePlugin

    src = Path(src)
    merge = merge or Merge()
    stats = CopyStats(profile="ros2")
    check_storage(src)  # CRCs and indexes rosbags does not check (the tracks may not have been read)
    try:
        with Reader(src) as reader:
            stats.bytes_in = sum(p.stat().st_size for p in src.rglob("*") if p.is_file())
            check_new_topics(src, [c.topic for c in reader.connections], merge.channels)
            plugin = StoragePlugin.MCAP if any(src.glob("*.mcap")) else StoragePlugin.SQLITE3
            writer = Writer(dst, version=9, storage_plugin=plugin)
            for key, value in {**ros2_custom_data(src), **(custom_data or {})}.items():
                writer.set_custom_data(key, value)
            writer.open()
            try:
                out_conn = {}
                known = ros_types.typestore(2)
                for conn in reader.connections:
                    ext = conn.ext
                    definition: dict[str, Any] = {"msgdef": conn.msgdef.data, "rihs01": conn.digest}
                    if not conn.msgdef.data:
                        # a bag of rosbag2's sqlite3 schema before version 4 stores no definitions:
                        # the copy (version 9) gets the type's own where lanecast knows it, and no
                        # hash where it does not (a hash without a definition is a damaged bag)
                        definition = (
                            {"typestore": known}
                            if conn.msgtype in known.fielddefs
                            else {"msgdef": "", "rihs01": ""}
                        )
                    out_conn[conn.id] = writer.add_connection(
                        conn.topic,
                        conn.msgtype,
                        serialization_format=ext.serialization_format,  # type: ignore[union-attr]
                        offered_qos_profiles=ext.offered_qos_profiles,  # type: ignore[union-attr]
                        **definition,
                    )
                    stats.channels += 1
                extra_conns = [
                    writer.add_connection(
                        spec.topic, spec.ros_msgtype or spec.schema_name, typestore=typestore
                    )
                    for spec in merge.channels
                ]
                stats.extra_channel_ids = [c.id for c in extra_conns]
                copying = MergedCopy(
                    merge, stats, lambda item: writer.write(extra_conns[item[1]], item[0], item[2])
                )
                for conn, timestamp, data in reader.messages():
                    copying.before(timestamp)
                    writer.write(out_conn[conn.id], timestamp, data)
                    copying.copied()
                copying.before(None)
            finally:
                writer.close()
    except LogError:
        raise
    except Exception as exc:  # rosbags' reading: ReaderError, a damaged sqlite3 page, …
        raise unreadable(src, exc, "ROS 2") from exc
    compress_bag_storage(dst)
    copying.done()
    stats.bytes_out = sum(p.stat().st_size for p in dst.rglob("*") if p.is_file())
    return stats


def compress_bag_storage(bag: Path) -> None:
    """Rewrite the MCAP files of ROS 2 bag directory ``bag`` chunked, zstd-compressed and with CRCs.

    rosbags' MCAP storage plugin writes uncompressed chunks with every CRC 0: 5 minutes of traffic
    as TrackedObjects + MarkerArray made a 345 MB bag. The copy keeps every record (schemas,
    channels, messages, metadata: ``metadata.yaml`` stays valid) and makes it about 50× smaller (6.5 MB) and
    checkable. Each file is replaced only once its copy is complete.
    """
    for item in sorted(Path(bag).glob("*.mcap")):
        tmp = item.with_name(f".{item.name}.zstd-tmp")
        try:
            with open(tmp, "wb") as out:
                copy_mcap(item, out)
            os.replace(tmp, item)
        finally:
            tmp.unlink(missing_ok=True)
