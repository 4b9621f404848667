"""Seeded structural and semantic mutations of real drive logs, through the real ``convert``.

Small logs (MCAP protobuf and JSON, ROS 1, ROS 2 sqlite3 and mcap) are written by lanecast's writers;
each case applies one mutation drawn by its seed from a family and runs ``lanecast convert``. The
family says what a right answer is: ``same`` (exit 0 and the clean conversion), ``same_or_refuse``
(exit 0 only with the clean conversion), ``no_loss`` (exit 0 only with every row), ``refuse`` or
``either``. A refusal is one line ``lanecast convert: error:`` naming the file and a place in it,
with no traceback and no output left behind. Never exit 0 with rows silently lost or changed.
"""

from __future__ import annotations

import json
import random
import re
import shutil
import sqlite3
import struct
import zlib
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pyarrow as pa
import pytest
from conftest import channel_record, mcap_contents, mcap_record_spans, staggered_cars

from lanecast.io_adapters.contracts import track_table
from lanecast.io_adapters.logs.mcap import writer as mcap_writer
from lanecast.io_adapters.logs.rosbag import writer as rosbag_writer
from lanecast.workflows.cli import main

RATE = 10.0


PLACES = ("offset ", "line ", "column ", "row ", "record ", "message ", "chunk ", "field ", "topic ", "key ")


OBJECTS = "/tracked_objects"


def small_table() -> pa.Table:
    """3 cars × 30 frames at 10 Hz, staggered starts."""
    return staggered_cars(3, 30, stagger=4, step_m=2.5, speed=25.0, rate=RATE)


@pytest.fixture(scope="module")
def bases(tmp_path_factory: pytest.TempPathFactory) -> dict[str, tuple[Path, pa.Table]]:
    """Clean logs of each kind and their clean conversions."""
    root = tmp_path_factory.mktemp("fuzz-bases")
    table = small_table()
    logs = {
        "mcap": mcap_writer.write(table, root / "pb.mcap", "mcap", chunk_size=1500),
        "json": mcap_writer.write(table, root / "js.mcap", "mcap", encoding="json", chunk_size=4000),
        "ros1": rosbag_writer.write(table, root / "b1.bag", "ros1"),
        "sqlite3": rosbag_writer.write(table, root / "sq", "ros2", storage="sqlite3"),
        "ros2mcap": rosbag_writer.write(table, root / "r2", "ros2", storage="mcap"),
    }
    out = {}
    for kind, path in logs.items():
        assert main(["convert", str(path), "--out", str(root / f"{kind}.parquet")]) == 0
        out[kind] = (path, track_table.read_parquet(root / f"{kind}.parquet"))
    return out


# ------------------------------------------------------------------------------------ MCAP bytes


def fix_crcs(d: bytearray) -> None:
    """The DataEnd and summary CRCs recomputed (a writer that meant the change)."""
    for o, op, _n in mcap_record_spans(bytes(d)):
        if op == 0x0F:
            struct.pack_into("<I", d, o + 9, zlib.crc32(bytes(d[:o])))
        if op == 0x02:
            (start,) = struct.unpack_from("<Q", d, o + 9)
            if 0 < start <= o:
                struct.pack_into("<I", d, o + 25, zlib.crc32(bytes(d[start : o + 25])))


def chunk_span(b: bytes, rng: random.Random) -> tuple[int, int]:
    """A chunk with its message indexes, as (start, end)."""
    recs = mcap_record_spans(b)
    k = rng.choice([i for i, r in enumerate(recs) if r[1] == 0x06])
    start, end = recs[k][0], recs[k][0] + 9 + recs[k][2]
    while k + 1 < len(recs) and recs[k + 1][1] == 0x07:
        k += 1
        end = recs[k][0] + 9 + recs[k][2]
    return start, end


def rewrite(
    src: Path, dst: Path, *, msgs: Callable[[list[Any]], list[Any]] | None = None, **edit: Any
) -> None:
    """``src`` rewritten by the mcap library: the message list [(channel, log time, data)] through
    ``msgs``, schema encodings and channel message encodings replaced as ``edit`` says; with
    ``redefine`` (unchunked), a Channel record half-way giving the next message's channel id
    another topic."""
    from mcap.writer import Writer

    summary, messages, metadata = mcap_contents(src)
    with dst.open("wb") as f:
        w = Writer(f, chunk_size=1500, use_chunking="redefine" not in edit)
        w.start()
        sids = {
            i: w.register_schema(s.name, edit.get("schema_encoding", s.encoding), s.data)
            for i, s in summary.schemas.items()
        }
        cids = {
            i: w.register_channel(
                c.topic,
                edit.get("message_encoding", c.message_encoding)
                if c.topic.startswith(OBJECTS)
                else c.message_encoding,
                sids.get(c.schema_id, 0),
                c.metadata,
            )
            for i, c in summary.channels.items()
        }
        listed = msgs(messages) if msgs else messages
        for k, (cid, log_time, data) in enumerate(listed):
            if "redefine" in edit and k == len(listed) // 2:
                first = summary.channels[cid]
                f.write(
                    channel_record(cids[cid], sids.get(first.schema_id, 0), "/other", first.message_encoding)
                )
            w.add_message(cids[cid], log_time, data, log_time)
        for m in metadata:
            w.add_metadata(m.name, m.metadata)
        w.finish()


def object_messages(messages: list[Any], rng: random.Random) -> int:
    """The index of a random object message in the middle of the log."""
    n = len(messages)
    return rng.choice([k for k in range(n // 4, 3 * n // 4) if isinstance(messages[k][2], bytes)])


# ------------------------------------------------------------------------------------ mutations

Mutation = Callable[[random.Random, Path, Path], str]


def m_truncate(rng: random.Random, src: Path, dst: Path) -> str:
    b = src.read_bytes()
    o, op, n = rng.choice(mcap_record_spans(b))
    at = o if rng.random() < 0.5 else o + rng.randrange(1, 9 + n)
    dst.write_bytes(b[:at])
    return f"truncated at {at} (record opcode {op:#04x} at {o})"


def m_chunk_swap(rng: random.Random, src: Path, dst: Path) -> str:
    b = src.read_bytes()
    chunks = [(o, o + 9 + n) for o, op, n in mcap_record_spans(b) if op == 0x06]
    (s1, e1), (s2, e2) = sorted(rng.sample(chunks, 2))
    dst.write_bytes(b[:s1] + b[s2:e2] + b[e1:s2] + b[s1:e1] + b[e2:])
    return f"chunks at {s1} and {s2} swapped"


def m_chunk_dup(rng: random.Random, src: Path, dst: Path) -> str:
    b = src.read_bytes()
    s, e = chunk_span(b, rng)
    dst.write_bytes(b[:e] + b[s:e] + b[e:])
    return f"chunk at {s} duplicated"


def m_stale_summary(rng: random.Random, src: Path, dst: Path) -> str:
    """A chunk deleted, the summary (which lists it) kept, its pointers moved to where it now is."""
    b = src.read_bytes()
    s, e = chunk_span(b, rng)
    d = bytearray(b[:s] + b[e:])
    for o, op, _n in mcap_record_spans(bytes(d)):
        if op == 0x02:
            start, offsets = struct.unpack_from("<QQ", d, o + 9)
            struct.pack_into("<QQ", d, o + 9, start - (e - s), offsets - (e - s))
        if op == 0x0E:
            (group,) = struct.unpack_from("<Q", d, o + 10)
            struct.pack_into("<Q", d, o + 10, group - (e - s))
    fix_crcs(d)
    dst.write_bytes(bytes(d))
    return f"chunk at {s} deleted, summary kept"


def m_chunk_index(rng: random.Random, src: Path, dst: Path) -> str:
    d = bytearray(src.read_bytes())
    recs = mcap_record_spans(bytes(d))
    o = rng.choice([o for o, op, _ in recs if op == 0x08])
    value = rng.choice([o2 for o2, op, _ in recs if op == 0x06] + [0, 1, len(d) + 9])
    struct.pack_into("<Q", d, o + 25, value)
    fix_crcs(d)
    dst.write_bytes(bytes(d))
    return f"chunk index at {o} points at {value}"


def m_summary_offset(rng: random.Random, src: Path, dst: Path) -> str:
    d = bytearray(src.read_bytes())
    footer = mcap_record_spans(bytes(d))[-1][0]
    value = rng.choice([0, 8, rng.randrange(len(d)), len(d) + 5])
    struct.pack_into("<Q", d, footer + 9 + rng.choice([0, 8]), value)
    dst.write_bytes(bytes(d))
    return f"footer offset -> {value}"


def m_msg_dup(rng: random.Random, src: Path, dst: Path) -> str:
    def edit(m: list[Any]) -> list[Any]:
        k = object_messages(m, rng)
        return [*m[: k + 1], m[k], *m[k + 1 :]]

    rewrite(src, dst, msgs=edit)
    return "a message recorded twice"


def m_out_of_order(rng: random.Random, src: Path, dst: Path) -> str:
    how = rng.choice(["reverse", "pairs"])

    def edit(m: list[Any]) -> list[Any]:
        if how == "reverse":
            return m[::-1]
        m = list(m)
        for k in range(1, len(m), 2):
            m[k - 1], m[k] = m[k], m[k - 1]
        return m

    rewrite(src, dst, msgs=edit)
    return f"messages out of log-time order ({how})"


def m_log_time_repeats(rng: random.Random, src: Path, dst: Path) -> str:
    """Fuzz seed 1390: a message logged at the previous message's time, its objects stamped as before."""

    def edit(m: list[Any]) -> list[Any]:
        k = object_messages(m, rng)
        previous = max(t for c, t, _ in m if c == m[k][0] and t < m[k][1])
        return [*m[:k], (m[k][0], previous, m[k][2]), *m[k + 1 :]]

    rewrite(src, dst, msgs=edit)
    return "a message's log time repeats the previous one's"


def m_schema_encoding(rng: random.Random, src: Path, dst: Path) -> str:
    new = rng.choice(["ros2msg", "ros2idl", "jsonschema", "protobuf"])
    rewrite(src, dst, schema_encoding=new)
    return f"schema encodings -> {new}"


def m_message_encoding(rng: random.Random, src: Path, dst: Path) -> str:
    new = rng.choice(["cdr", "json", "protobuf", "ros1"])
    rewrite(src, dst, message_encoding=new)
    return f"object channels' message encoding -> {new}"


def m_channel_redefined(rng: random.Random, src: Path, dst: Path) -> str:
    rewrite(src, dst, redefine=True)
    return "a Channel record half-way gives an object channel's id another topic"


def m_zero_length(rng: random.Random, src: Path, dst: Path) -> str:
    def edit(m: list[Any]) -> list[Any]:
        k = object_messages(m, rng)
        return [*m[:k], (m[k][0], m[k][1], b""), *m[k + 1 :]]

    rewrite(src, dst, msgs=edit)
    return "a zero-length message"


def json_edit(change: Callable[[dict[str, Any]], None]) -> Mutation:
    """One JSON SceneUpdate in the middle of the log changed by ``change``."""

    def mutate(rng: random.Random, src: Path, dst: Path) -> str:
        def edit(m: list[Any]) -> list[Any]:
            k = object_messages(m, rng)
            doc = json.loads(m[k][2])
            change(doc)
            return [*m[:k], (m[k][0], m[k][1], json.dumps(doc).encode()), *m[k + 1 :]]

        rewrite(src, dst, msgs=edit)
        return change.__doc__ or change.__name__

    return mutate


def _stamps_back_a_frame(doc: dict[str, Any]) -> None:
    """entity stamps of a message one frame back (onto the previous frame's objects)"""
    for e in doc["entities"]:
        t = e["timestamp"]["sec"] * 10**9 + e["timestamp"]["nsec"] - int(1e9 / RATE)
        e["timestamp"] = {"sec": t // 10**9, "nsec": t % 10**9}


def _size_nan(doc: dict[str, Any]) -> None:
    """an entity's size NaN"""
    doc["entities"][0]["cubes"][0]["size"]["x"] = float("nan")


def _unknown_frame(doc: dict[str, Any]) -> None:
    """a frame id no transform reaches"""
    doc["entities"][0]["frame_id"] = "velodyne"


def _deletions(doc: dict[str, Any]) -> None:
    """deletions in a SceneUpdate"""
    doc["deletions"] = [{"timestamp": {"sec": 0, "nsec": 0}, "type": 0, "id": doc["entities"][0]["id"]}]


# ROS 1


def ros1_connection_field(rng: random.Random, src: Path, dst: Path) -> str:
    """A field of a connection record of the index section missing, empty or given twice."""
    b = src.read_bytes()
    index_pos = struct.unpack_from("<Q", b, b.index(b"index_pos=") + 10)[0]
    conns = [m.start() - 8 for m in re.finditer(rb"op=\x07", b) if m.start() > index_pos]
    o = rng.choice(conns)
    (hl,) = struct.unpack_from("<I", b, o)
    (dl,) = struct.unpack_from("<I", b, o + 4 + hl)
    fields, q, d = [], o + 8 + hl, o + 8 + hl
    while q < d + dl:
        (n,) = struct.unpack_from("<I", b, q)
        fields.append(b[q + 4 : q + 4 + n])
        q += 4 + n
    key = rng.choice([b"topic", b"type", b"md5sum", b"message_definition"])
    how = rng.choice(["missing", "empty", "twice"])
    if how == "missing":
        fields = [fl for fl in fields if not fl.startswith(key + b"=")]
    elif how == "empty":
        fields = [key + b"=" if fl.startswith(key + b"=") else fl for fl in fields]
    else:
        fields.append(key + b"=std_msgs/String")
    data = b"".join(struct.pack("<I", len(fl)) + fl for fl in fields)
    dst.write_bytes(b[: o + 4 + hl] + struct.pack("<I", len(data)) + data + b[d + dl :])
    return f"connection record at {o}: {key.decode()} {how}"


def ros1_md5(rng: random.Random, src: Path, dst: Path) -> str:
    b = src.read_bytes()
    md5 = re.findall(rb"md5sum=([0-9a-f]{32})", b)
    old = rng.choice(sorted(set(md5)))
    dst.write_bytes(b.replace(old, b"0123456789abcdef0123456789abcdef"))
    return f"md5sum {old[:8].decode()}… replaced everywhere"


def ros1_index_count(rng: random.Random, src: Path, dst: Path) -> str:
    d = bytearray(src.read_bytes())
    field = rng.choice([b"count=", b"conn_count=", b"chunk_count="])
    at = rng.choice([m.end() for m in re.finditer(re.escape(field), bytes(d))])
    (v,) = struct.unpack_from("<I", d, at)
    new = rng.choice([0, v + 1, max(v - 1, 0), 0xFFFFFFFF])
    struct.pack_into("<I", d, at, new)
    dst.write_bytes(bytes(d))
    return f"{field.decode()} at {at}: {v} -> {new}"


# ROS 2


def ros2_metadata(rng: random.Random, src: Path, dst: Path) -> str:
    shutil.copytree(src, dst)
    meta = dst / "metadata.yaml"
    text = meta.read_text()
    storage = next(p.name for p in dst.iterdir() if p.name != "metadata.yaml")
    what = rng.choice(["count", "version", "qos", "files_twice", "storage"])
    if what == "count":
        text = re.sub(r"message_count: \d+", f"message_count: {rng.choice([0, 1, 99999])}", text, count=2)
    elif what == "version":
        text = text.replace("version: 9", f"version: {rng.choice([4, 5, 6, 7, 8])}")
    elif what == "qos":
        text = text.replace("offered_qos_profiles: []", "offered_qos_profiles: 'junk'", 1)
    elif what == "files_twice":
        text = text.replace(
            f"relative_file_paths:\n  - {storage}", f"relative_file_paths:\n  - {storage}\n  - {storage}"
        )
    else:
        text = re.sub(
            r"storage_identifier: \S+", f"storage_identifier: {rng.choice(['mcap', 'sqlite3', 'x'])}", text
        )
    meta.write_text(text)
    return f"metadata.yaml: {what}"


def ros2_missing_file(rng: random.Random, src: Path, dst: Path) -> str:
    shutil.copytree(src, dst)
    meta = dst / "metadata.yaml"
    meta.write_text(
        re.sub(r"relative_file_paths:\n", "relative_file_paths:\n  - gone.db3\n", meta.read_text())
    )
    return "relative_file_paths names a missing file"


def ros2_duplicate_topic(rng: random.Random, src: Path, dst: Path) -> str:
    shutil.copytree(src, dst)
    with sqlite3.connect(next(dst.glob("*.db3"))) as con:
        row = con.execute("SELECT * FROM topics WHERE name LIKE ?", (OBJECTS + "%",)).fetchone()
        con.execute("INSERT INTO topics VALUES (99, ?, ?, ?, ?, ?)", row[1:])
        if rng.random() < 0.5:
            con.execute("UPDATE messages SET topic_id = 99 WHERE topic_id = ? AND id % 2 = 0", (row[0],))
    return "two topics of one name"


def ros2_serialization(rng: random.Random, src: Path, dst: Path) -> str:
    shutil.copytree(src, dst)
    with sqlite3.connect(next(dst.glob("*.db3"))) as con:
        con.execute("UPDATE topics SET serialization_format = ? WHERE name LIKE ?", ("json", OBJECTS + "%"))
    return "serialization_format json"


# family → (mutation, base kinds, expectation)
FAMILIES: dict[str, tuple[Mutation, tuple[str, ...], str]] = {
    "truncate": (m_truncate, ("mcap",), "same_or_refuse"),
    "chunk_swap": (m_chunk_swap, ("mcap",), "same_or_refuse"),
    "chunk_dup": (m_chunk_dup, ("mcap",), "same_or_refuse"),
    "stale_summary": (m_stale_summary, ("mcap",), "refuse"),
    "chunk_index": (m_chunk_index, ("mcap",), "same_or_refuse"),
    "summary_offset": (m_summary_offset, ("mcap",), "same_or_refuse"),
    "message_twice": (m_msg_dup, ("mcap", "json"), "same"),
    "out_of_order": (m_out_of_order, ("mcap", "json"), "same"),
    "log_time_repeats": (m_log_time_repeats, ("mcap", "json"), "same"),
    "schema_encoding": (m_schema_encoding, ("mcap", "json"), "same_or_refuse"),
    "message_encoding": (m_message_encoding, ("mcap", "json"), "same_or_refuse"),
    "zero_length": (m_zero_length, ("mcap", "json"), "either"),
    "channel_redefined": (m_channel_redefined, ("mcap", "json"), "same_or_refuse"),
    "stamps_back": (json_edit(_stamps_back_a_frame), ("json",), "no_loss"),
    "size_nan": (json_edit(_size_nan), ("json",), "either"),
    "unknown_frame": (json_edit(_unknown_frame), ("json",), "refuse"),
    "deletions": (json_edit(_deletions), ("json",), "same"),
    "ros1_connection": (ros1_connection_field, ("ros1",), "same_or_refuse"),
    "ros1_md5": (ros1_md5, ("ros1",), "same_or_refuse"),
    "ros1_index": (ros1_index_count, ("ros1",), "same_or_refuse"),
    "ros2_metadata": (ros2_metadata, ("sqlite3", "ros2mcap"), "same_or_refuse"),
    "ros2_missing_file": (ros2_missing_file, ("sqlite3",), "refuse"),
    "ros2_topic_twice": (ros2_duplicate_topic, ("sqlite3",), "same_or_refuse"),
    "ros2_serialization": (ros2_serialization, ("sqlite3",), "refuse"),
}


SEEDS = range(38)


def case_of(seed: int) -> tuple[str, str]:
    """(family, base kind) of a seed: every family once, then drawn at random."""
    names = sorted(FAMILIES)
    rng = random.Random(seed)
    family = names[seed] if seed < len(names) else rng.choice(names)
    return family, rng.choice(FAMILIES[family][1])


def same_rows(got: pa.Table, want: pa.Table) -> str | None:
    if got.num_rows != want.num_rows:
        return f"{got.num_rows} rows, the clean log gives {want.num_rows}"
    for name in want.column_names:
        a, b = got.column(name), want.column(name)
        if not a.cast(b.type).equals(b):
            return f"column {name} differs from the clean conversion"
    return None


@pytest.mark.parametrize("seed", SEEDS, ids=[f"{s}-{case_of(s)[0]}-{case_of(s)[1]}" for s in SEEDS])
def test_a_mutated_log_is_read_whole_or_refused_with_its_place(
    seed: int,
    bases: dict[str, tuple[Path, pa.Table]],
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
) -> None:
    family, kind = case_of(seed)
    mutate, _kinds, expect = FAMILIES[family]
    src, clean = bases[kind]
    target = tmp_path / src.name
    what = mutate(random.Random(seed * 7919 + 1), src, target)
    out = tmp_path / "out.parquet"
    capsys.readouterr()
    status = main(["convert", str(target), "--out", str(out)])  # a traceback fails the test here
    err = capsys.readouterr().err.strip()
    if status == 0:
        assert expect != "refuse", f"{what}: accepted, expected a refusal; stderr: {err}"
        got = track_table.read_parquet(out)
        if expect in ("same", "same_or_refuse"):
            assert same_rows(got, clean) is None, f"{what}: {same_rows(got, clean)}; stderr: {err}"
        if expect == "no_loss":
            assert got.num_rows >= clean.num_rows, f"{what}: rows lost with exit 0; stderr: {err}"
        return
    assert expect != "same", f"{what}: a valid log refused: {err}"
    lines = err.splitlines()
    assert status == 2 and lines, (status, err)
    assert lines[-1].startswith("lanecast convert: error: "), err
    message = lines[-1].split(": error: ", 1)[1]
    assert target.name in message and any(p in message for p in PLACES), f"{what}: {message}"
    assert not out.exists() and not list(tmp_path.glob("*.parquet*")), f"{what}: output left behind"
