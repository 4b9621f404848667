"""Where a ROS 2 bag that rosbags refuses to open is at fault, which rosbags does not say.

rosbags opens a ROS 2 bag by reading its storage's type information: an MCAP file's schema and
channel records (with each channel's QoS metadata), a sqlite3 file's ``topics`` and
``message_definitions`` tables; then it checks every topic's type hash against its definition. Its
errors name no record: "TypeError: string indices must be integers" (QoS metadata that is not a
list of profiles), "KeyError: 'flatbuffer'" (a schema encoding it does not know), "Could not
parse: <the whole definition>", "Message type X hash mismatch A != B". After such a failure (never
on the happy path) these checks name the record: in MCAP the byte offset of the schema or channel
record, in sqlite3 the table and row.
"""

from __future__ import annotations

import sqlite3
import struct
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from mcap.opcode import Opcode

from lanecast.io_adapters.errors import LogError
from lanecast.io_adapters.logs.mcap.records import MAGIC, RecordOverrun, read_schema, read_string, records
from lanecast.io_adapters.logs.rosbag.damage import short_error as _short

_FOOTER = 1 + 8 + 20  # opcode, length, summary_start, summary_offset_start, summary_crc
_DEFINITION_ENCODINGS = ("ros2msg", "ros2idl", "omgidl", "")
_EXPECTED = "an intact ROS 2 bag"


def located(files: Sequence[Path]) -> LogError | None:
    """The error naming the first schema/channel record (MCAP) or table row (sqlite3) of a ROS 2
    bag's storage ``files`` that rosbags cannot open, else None."""
    for file in files:
        try:
            found = mcap_problem(file) if file.suffix == ".mcap" else sqlite_problem(file)
        except (OSError, sqlite3.Error):
            continue
        if found is not None:
            return found
    return None


# ------------------------------------------------------------------------------------------ MCAP


def mcap_problem(path: Path) -> LogError | None:
    """The first schema or channel record rosbags refuses (offset, id, what is wrong), else None.

    Walks the summary section (where rosbags reads them), else the data section's top-level records.
    """
    data = path.read_bytes()
    if len(data) < len(MAGIC) * 2 + _FOOTER or not data.startswith(MAGIC):
        return None
    footer = len(data) - len(MAGIC) - _FOOTER
    if data[footer] != Opcode.FOOTER:
        return None
    (summary_start,) = struct.unpack_from("<Q", data, footer + 9)
    try:
        for op, pos, body, nxt in records(data, summary_start if 0 < summary_start < footer else 8, footer):
            if op == Opcode.DATA_END:
                break
            if op not in (Opcode.SCHEMA, Opcode.CHANNEL):
                continue
            try:
                problem = (_schema_problem if op == Opcode.SCHEMA else _channel_problem)(data[body:nxt])
            except (ValueError, struct.error, UnicodeDecodeError) as exc:
                problem = (
                    f"a {'schema' if op == Opcode.SCHEMA else 'channel'} record that cannot be read ({exc})"
                )
            if problem is not None:
                return LogError(path, problem, offset=pos, expected=_EXPECTED)
    except RecordOverrun:  # the walk of the storage file names it
        pass
    return None


def _schema_problem(record: bytes) -> str | None:
    sid, schema = read_schema(record, 0, len(record))
    name, encoding, text = schema.name, schema.encoding, schema.data.decode("utf-8")
    if encoding not in _DEFINITION_ENCODINGS:
        return (
            f"schema {sid} ({name!r}) has encoding {encoding!r}, which ROS 2 bags do not use "
            "(ros2msg, ros2idl or omgidl expected)"
        )
    if encoding == "ros2msg" and text:
        return _parse_problem(f"schema {sid}", name, text, idl=False)
    return None


def _channel_problem(record: bytes) -> str | None:
    from rosbags.rosbag2.storage_mcap import get_qos

    (cid,) = struct.unpack_from("<H", record, 0)
    topic, pos = read_string(record, 4, len(record))
    _encoding, pos = read_string(record, pos, len(record))
    (n,) = struct.unpack_from("<I", record, pos)
    try:
        get_qos(record[pos + 4 : pos + 4 + n])
    except Exception as exc:  # rosbags' YAML reading of the profiles raises anything
        return f"channel {cid} (topic {topic!r}): its offered_qos_profiles metadata is not QoS profiles ({_short(exc)})"
    return None


# --------------------------------------------------------------------------------------- sqlite3


def sqlite_problem(path: Path) -> LogError | None:
    """The first topic whose type hash is not that of its definition, or a definition rosbags
    cannot parse (table, row, type), else None."""
    con = sqlite3.connect(f"file:{path}?mode=ro", uri=True)
    try:
        tables = {r[0] for r in con.execute("SELECT name FROM sqlite_master WHERE type='table'")}
        if "message_definitions" not in tables or "topics" not in tables:
            return None
        definitions = {
            row[1]: row
            for row in con.execute(
                "SELECT id, topic_type, encoding, encoded_message_definition FROM message_definitions ORDER BY id"
            )
        }
        topics = con.execute(
            "SELECT id, name, type, type_description_hash FROM topics ORDER BY id"
        ).fetchall()
    finally:
        con.close()
    for tid, name, msgtype, digest in topics:
        found = definitions.get(msgtype)
        if found is None:
            continue
        did, _type, encoding, text = found
        where = f"table message_definitions, row {did} (type {msgtype!r})"
        if encoding not in ("ros2msg", "ros2idl"):  # rosbags knows no other (KeyError)
            return LogError(
                path, f"{where}: encoding {encoding!r} (ros2msg or ros2idl expected)", expected=_EXPECTED
            )
        if digest and not (text or "").strip():
            return LogError(
                path,
                f"{where}: the definition is empty (topic {name!r} states its type hash)",
                expected=_EXPECTED,
            )
        problem = _parse_problem(where, msgtype, text, idl=encoding != "ros2msg")
        if problem is not None:
            return LogError(path, problem, expected=_EXPECTED)
        if not digest:
            continue
        have = _rihs01(msgtype, text, idl=encoding != "ros2msg")
        if have is not None and have != digest:
            return LogError(
                path,
                f"table topics, row {tid} (topic {name!r}): type_description_hash {digest} is not that of "
                f"the definition of {msgtype!r} in table message_definitions, row {did} ({have})",
                expected=_EXPECTED,
            )
    return None


def _types(msgtype: str, text: str, *, idl: bool) -> dict[str, Any]:
    from rosbags.typesys import get_types_from_idl, get_types_from_msg

    if not idl:
        return dict(get_types_from_msg(text, msgtype))
    sep = "=" * 80 + "\n"
    if text.startswith(f"{sep}IDL: "):
        types: dict[str, Any] = {}
        for part in text.split(sep)[1:]:
            types.update(get_types_from_idl(part.split("\n", 1)[1]))
        return types
    return dict(get_types_from_idl(text))


def _parse_problem(who: str, msgtype: str, text: str, *, idl: bool) -> str | None:
    try:
        _types(msgtype, text, idl=idl)
    except Exception as exc:  # rosbags' parsers raise their own and generic errors
        return f"{who}: the definition of {msgtype!r} cannot be parsed ({_short(exc)})"
    return None


def _rihs01(msgtype: str, text: str, *, idl: bool) -> str | None:
    """The type hash rosbags computes for ``msgtype`` from this one definition (None: it cannot)."""
    from rosbags.typesys import Stores, get_typestore

    try:
        store = get_typestore(Stores.EMPTY)
        store.register(_types(msgtype, text, idl=idl))
        return str(store.hash_rihs01(msgtype))
    except Exception:  # a type the definition uses is not in it: rosbags' own error stands
        return None
