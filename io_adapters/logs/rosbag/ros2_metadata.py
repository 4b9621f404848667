"""Check a ROS 2 bag's ``metadata.yaml`` before rosbags reads it.

rosbags' errors about a bag's metadata name the bag directory and say neither which file nor which
line is wrong ("Invalid bag metadata: 'NoneType' object is not subscriptable", "Rosbag2 version 99
not supported"), and a storage file listed twice is read twice. :func:`check_metadata` reads the
small YAML file itself (ruamel, rosbags' own library, with line numbers) and refuses, naming
``metadata.yaml``, the line and the key: text that is not UTF-8 or not YAML, no
``rosbag2_bagfile_information`` mapping, a version rosbags cannot read, a storage plugin other than
sqlite3 and mcap, storage files missing, listed twice, copies of one another or of the other
plugin's format, topics serialized as anything but CDR, and offered QoS profiles rosbags cannot
parse.
"""

from __future__ import annotations

from pathlib import Path, PurePath
from typing import Any

from lanecast.io_adapters.errors import LogError
from lanecast.io_adapters.logs.rosbag.damage import message_offset

VERSIONS = range(1, 10)  # the rosbag2 metadata versions rosbags reads
STORAGE_MAGIC = {"sqlite3": b"SQLite format 3\x00", "mcap": b"\x89MCAP0\r\n"}
INFO = "rosbag2_bagfile_information"
MAX_VALUES = 200_000  # a metadata.yaml holds some 20 values per topic and file; an alias bomb, billions
ZSTD_MAGIC = b"\x28\xb5\x2f\xfd"
TEXT_TABLES = ("topics", "message_definitions", "metadata")  # small tables rosbags reads as text


def check_metadata(bag: Path) -> list[Path]:
    """The storage files ``bag/metadata.yaml`` lists (the files rosbags reads, whatever else the
    directory holds); LogError naming it (line, key) for metadata rosbags would misread."""
    from ruamel.yaml import YAML
    from ruamel.yaml.error import MarkedYAMLError, YAMLError

    path = bag / "metadata.yaml"
    raw = path.read_bytes()
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise LogError(
            path, f"not UTF-8 text ({exc.reason})", offset=exc.start, expected="YAML text"
        ) from exc
    try:
        doc = YAML(typ="rt").load(text)
    except YAMLError as exc:
        mark = exc.problem_mark if isinstance(exc, MarkedYAMLError) else None
        line = mark.line + 1 if mark is not None else None
        problem = getattr(exc, "problem", None) or str(exc)
        raise LogError(path, f"not YAML: {problem}", line=line, expected="a rosbag2 metadata.yaml") from exc
    if _expanded_size(doc, MAX_VALUES) > MAX_VALUES:  # before anything walks or copies it
        raise LogError(
            path,
            f"expands to more than {MAX_VALUES:,} values (YAML aliases repeating one another)",
            expected="a rosbag2 metadata.yaml (a few values per topic and file)",
        )
    info = doc.get(INFO) if isinstance(doc, dict) else None
    if not isinstance(info, dict):
        raise LogError(path, f"no {INFO} mapping", line=1, expected="a rosbag2 metadata.yaml")

    def fail(node: Any, key: str, message: str, expected: str) -> LogError:
        line = node.lc.key(key)[0] + 1 if key in node and hasattr(node, "lc") else None
        return LogError(path, message, line=line, column=key, expected=expected)

    version = info.get("version")
    if type(version) is not int or version not in VERSIONS:
        raise fail(info, "version", f"rosbag2 metadata version {version!r}", "a version from 1 to 9")
    storage = info.get("storage_identifier")
    if storage not in STORAGE_MAGIC:
        raise fail(info, "storage_identifier", f"storage plugin {storage!r}", "sqlite3 or mcap")
    files = info.get("relative_file_paths")
    if not isinstance(files, list) or not files or not all(isinstance(f, str) for f in files):
        raise fail(info, "relative_file_paths", "no list of storage files", "the bag's storage files")
    names = [PurePath(f).name for f in files]
    mode, compression = (info.get("compression_mode") or "").lower(), info.get("compression_format") or ""
    for i, name in enumerate(names):
        if name in names[:i]:
            raise fail(info, "relative_file_paths", f"lists {name!r} twice", "each storage file once")
        file = bag / name
        if not file.is_file():
            raise fail(
                info,
                "relative_file_paths",
                f"lists {files[i]!r}, which is not in {bag}",
                "the bag's storage files",
            )
        if mode != "file":
            with open(file, "rb") as f:
                head = f.read(16)
            wrong = [s for s, magic in STORAGE_MAGIC.items() if s != storage and head.startswith(magic)]
            if wrong:
                raise fail(
                    info,
                    "storage_identifier",
                    f"storage plugin {storage!r}, but {name} is a {wrong[0]} file",
                    f"storage_identifier: {wrong[0]}",
                )
    same = _same_bytes([bag / name for name in names])
    if same is not None:
        raise fail(
            info,
            "relative_file_paths",
            f"lists {same[0]} and {same[1]}, which hold the same bytes (every message would be read twice)",
            "each storage file once",
        )
    if mode in ("file", "message") and compression != "zstd":
        raise fail(info, "compression_format", f"compression {compression!r}", "zstd (what rosbag2 writes)")
    if mode == "file":
        for name in names:
            with open(bag / name, "rb") as f:
                if f.read(4) != ZSTD_MAGIC:
                    raise fail(
                        info,
                        "compression_mode",
                        f"compression_mode {info['compression_mode']!r}, but {name} is not zstd-compressed",
                        "a zstd file, or no compression_mode",
                    )
    for entry in info.get("topics_with_message_count") or []:
        topic = entry.get("topic_metadata") if isinstance(entry, dict) else None
        if isinstance(topic, dict) and topic.get("serialization_format", "cdr") != "cdr":
            raise fail(
                topic,
                "serialization_format",
                f"topic {topic.get('name')!r} is serialized as {topic['serialization_format']!r}",
                "cdr (lanecast reads ROS 2 messages in CDR)",
            )
        problem = _qos_problem(topic.get("offered_qos_profiles")) if isinstance(topic, dict) else None
        if problem is not None and isinstance(topic, dict):
            raise fail(
                topic,
                "offered_qos_profiles",
                f"topic {topic.get('name')!r}: offered QoS profiles that do not parse ({problem})",
                "a list of QoS profiles (history, depth, reliability, durability, deadline, lifespan, "
                "liveliness, ...), a YAML string of one, or []",
            )
    return [bag / name for name in names]


def _same_bytes(files: list[Path]) -> tuple[str, str] | None:
    """Names of two storage files with the same bytes (a copy listed beside its original), or None;
    only files of equal size are compared."""
    import filecmp

    sizes = [f.stat().st_size for f in files]
    for i, a in enumerate(files):
        for j in range(i):
            if sizes[i] == sizes[j] and filecmp.cmp(files[j], a, shallow=False):
                return files[j].name, a.name
    return None


def _qos_problem(value: Any) -> str | None:
    """Why rosbags cannot parse a topic's ``offered_qos_profiles`` (it refuses the whole bag with
    neither the file nor the line: 'Invalid bag metadata: string indices must be integers'), or None."""
    from rosbags.rosbag2.errors import ReaderError
    from rosbags.rosbag2.metadata import parse_qos

    try:
        parse_qos(_plain(value) if value is not None else [])
    except (ReaderError, KeyError, TypeError, ValueError, AttributeError, IndexError) as exc:
        return f"{type(exc).__name__}: {exc}"[:200]
    return None


def _plain(node: Any) -> Any:
    """ruamel's round-trip containers as plain lists and dicts."""
    if isinstance(node, dict):
        return {str(k): _plain(v) for k, v in node.items()}
    if isinstance(node, list):
        return [_plain(v) for v in node]
    return node


def check_sqlite_tables(db: Path) -> None:
    """LogError naming ``db`` for a rosbag2 sqlite3 file without its tables, or whose topics are
    stored in another serialization than CDR (rosbags then reads none of their messages)."""
    import sqlite3

    try:
        con = sqlite3.connect(f"file:{db}?mode=ro&immutable=1", uri=True)
        try:
            tables = {r[0] for r in con.execute("SELECT name FROM sqlite_master WHERE type = 'table'")}
            missing = sorted({"topics", "messages"} - tables)
            if missing:
                raise LogError(
                    db,
                    f"no table {missing[0]!r} (tables: {', '.join(sorted(tables)) or 'none'})",
                    expected="a rosbag2 sqlite3 file with the tables topics and messages",
                )
            try:
                rows = con.execute("SELECT id, name, serialization_format FROM topics").fetchall()
            except sqlite3.OperationalError as exc:  # a column missing (a damaged file is DatabaseError)
                raise LogError(
                    db, f"table topics: {exc}", expected="the columns name and serialization_format"
                ) from exc
            bad_text = _not_utf8(con, tables)
            # rosbags reads messages by topic: one whose topic_id is no topic would silently vanish
            orphan = con.execute(
                "SELECT id, topic_id FROM messages WHERE topic_id NOT IN (SELECT id FROM topics) LIMIT 1"
            ).fetchone()
        finally:
            con.close()
    except sqlite3.Error:
        return  # a damaged file: the reader's own path locates the damage
    if orphan is not None:
        raise LogError(
            db,
            f"table messages, row {orphan[0]}: topic_id {orphan[1]!r} is no topic of table topics",
            column="topic_id",
            expected="the id of a row of table topics",
        )
    if bad_text is not None:
        table, rowid, column, raw, reason = bad_text
        raise LogError(
            db,
            f"table {table}, row {rowid}: the text is not UTF-8 ({reason})",
            offset=message_offset(db, raw),
            column=column,
            expected="UTF-8 text",
        )
    for rowid, name, fmt in rows:
        if fmt != "cdr":
            raise LogError(
                db,
                f"table topics, row {rowid}: topic {name!r} is stored with serialization format {fmt!r}",
                column="serialization_format",
                expected="cdr (lanecast reads ROS 2 messages in CDR)",
            )


def _not_utf8(con: Any, tables: set[str]) -> tuple[str, int, str, bytes, str] | None:
    """(table, rowid, column, bytes, why) of the first text value of the small tables that is not
    UTF-8 (rosbags fails on it with a bare UnicodeDecodeError), or None."""
    for table in TEXT_TABLES:
        if table not in tables:
            continue
        columns = [r[1] for r in con.execute(f"PRAGMA table_info({table})")]
        for column in columns:
            query = f'SELECT rowid, CAST("{column}" AS BLOB) FROM {table} WHERE typeof("{column}") = \'text\''
            for rowid, raw in con.execute(query):
                try:
                    bytes(raw).decode("utf-8")
                except UnicodeDecodeError as exc:
                    return table, rowid, column, bytes(raw), f"{exc.reason} at byte {exc.start}"
    return None


def _expanded_size(node: Any, budget: int) -> int:
    """The values of a loaded YAML document as a walk that follows its aliases meets them, counted
    up to ``budget`` + 1 (nested aliases make a few lines billions of values)."""
    count, stack = 1, [node]
    while stack and count <= budget:
        item = stack.pop()
        values = item.values() if isinstance(item, dict) else item if isinstance(item, list) else ()
        count += len(values)
        stack.extend(v for v in values if isinstance(v, (dict, list)))
    return count


def topic_key_line(bag: Path, topic: str, key: str) -> int | None:
    """The line of ``key`` in the ``topic_metadata`` of ``topic`` in ``bag/metadata.yaml`` (the
    topic's name line when it has no such key), None if the topic is not listed."""
    from ruamel.yaml import YAML

    doc = YAML(typ="rt").load((bag / "metadata.yaml").read_text(encoding="utf-8"))
    for entry in doc[INFO].get("topics_with_message_count") or []:
        meta = entry.get("topic_metadata") if isinstance(entry, dict) else None
        if isinstance(meta, dict) and meta.get("name") == topic and hasattr(meta, "lc"):
            return int(meta.lc.key(key if key in meta else "name")[0]) + 1
    return None
