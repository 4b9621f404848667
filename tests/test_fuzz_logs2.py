"""Drive logs whose CRCs all hold but whose records lie: the classes of damage a structure-aware
fuzzer (records walked, one field changed, every CRC recomputed) found beyond tests/test_fuzz_logs.py.

The data section is the truth: an index or summary that disagrees with it (chunk indexes, message
indexes, summary offsets, the footer, the summary's schemas and channels) is named on stderr and
the log read by the linear scan lanecast always does; a chunk whose records lack something (a
message on a channel never defined) is refused at its offset, and with ``--salvage`` skipped whole
while the walk goes on after it.
"""

from __future__ import annotations

import struct
import zlib
from pathlib import Path
from typing import Any

import pyarrow as pa
import pytest
from conftest import staggered_cars

from lanecast.io_adapters.contracts import track_table
from lanecast.io_adapters.errors import LogError
from lanecast.io_adapters.logs.mcap import reader as mcap_reader
from lanecast.io_adapters.logs.mcap import writer as mcap_writer
from lanecast.io_adapters.logs.rosbag import reader as rosbag_reader
from lanecast.io_adapters.logs.rosbag import writer as rosbag_writer
from lanecast.workflows.cli import main

OP_CHUNK, OP_MESSAGE_INDEX, OP_CHUNK_INDEX, OP_SUMMARY_OFFSET, OP_FOOTER = 0x06, 0x07, 0x08, 0x0E, 0x02


def records(d: bytes) -> list[tuple[int, int, int]]:
    """(offset, opcode, body length) of every top-level record up to and with the footer."""
    out, pos = [], 8
    while pos + 9 <= len(d):
        op, n = struct.unpack_from("<BQ", d, pos)
        out.append((pos, op, n))
        if op == OP_FOOTER:
            break
        pos += 9 + n
    return out


def chunk_records(d: bytes, chunk: int) -> tuple[int, list[tuple[int, int, int]]]:
    """(file offset of the records, [(offset in the records, opcode, body length)]) of an
    uncompressed chunk at ``chunk``."""
    (comp,) = struct.unpack_from("<I", d, chunk + 9 + 28)
    assert comp == 0, "the test logs are written uncompressed"
    start = chunk + 9 + 32 + 8
    (n,) = struct.unpack_from("<Q", d, start - 8)
    out, pos = [], 0
    while pos < n:
        op, length = struct.unpack_from("<BQ", d, start + pos)
        out.append((pos, op, length))
        pos += 9 + length
    return start, out


def fix_crcs(d: bytearray) -> None:
    """Every CRC recomputed (chunks, data section, summary): a writer that meant the change."""
    for o, op, _n in records(bytes(d)):
        if op == OP_CHUNK:
            start, _ = chunk_records(bytes(d), o)
            (n,) = struct.unpack_from("<Q", d, start - 8)
            struct.pack_into("<I", d, o + 9 + 24, zlib.crc32(bytes(d[start : start + n])))
        if op == 0x0F:
            struct.pack_into("<I", d, o + 9, zlib.crc32(bytes(d[:o])))
        if op == OP_FOOTER:
            (start,) = struct.unpack_from("<Q", d, o + 9)
            struct.pack_into("<I", d, o + 25, zlib.crc32(bytes(d[start : o + 25])))


def uncompressed(src: Path, dst: Path) -> Path:
    """``src`` written again by the mcap library with small uncompressed chunks and every index."""
    from mcap.records import Channel, Header, Message, Metadata, Schema
    from mcap.stream_reader import StreamReader
    from mcap.writer import CompressionType, Writer

    with src.open("rb") as f, dst.open("wb") as out:
        w = Writer(out, chunk_size=2000, compression=CompressionType.NONE, enable_data_crcs=True)
        seen: set[int] = set()  # schema ids, and channel ids negated
        for r in StreamReader(f).records:
            if isinstance(r, Header):
                w.start(r.profile, r.library)
            elif isinstance(r, Schema) and r.id not in seen:  # ids 1, 2, … as in the source
                seen.add(r.id)
                w.register_schema(r.name, r.encoding, r.data)
            elif isinstance(r, Channel) and -r.id not in seen:
                seen.add(-r.id)
                w.register_channel(r.topic, r.message_encoding, r.schema_id, r.metadata)
            elif isinstance(r, Message):
                w.add_message(r.channel_id, r.log_time, r.data, r.publish_time, r.sequence)
            elif isinstance(r, Metadata):
                w.add_metadata(r.name, r.metadata)
        w.finish()
    return dst


@pytest.fixture(scope="module")
def logs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, tuple[Path, pa.Table]]:
    """A protobuf log and a ROS 2 (CDR) MCAP, uncompressed, and their clean conversions."""
    root = tmp_path_factory.mktemp("lying-logs")
    table = staggered_cars(3, 30, stagger=4, step_m=2.5, speed=25.0, rate=10.0)
    pb = uncompressed(mcap_writer.write(table, root / "pb0.mcap", "mcap"), root / "pb.mcap")
    bag = rosbag_writer.write(table, root / "r2", "ros2", storage="mcap")
    cdr = uncompressed(next(bag.glob("*.mcap")), root / "cdr.mcap")
    return {kind: (p, mcap_reader.read(p)) for kind, p in (("pb", pb), ("cdr", cdr))}


def chunks(d: bytes) -> list[int]:
    return [o for o, op, _ in records(d) if op == OP_CHUNK]


def message_times(d: bytes, chunk: int, channels: set[int] | None = None) -> list[int]:
    """The log times of the messages of an uncompressed chunk (on ``channels``: every channel)."""
    start, recs = chunk_records(d, chunk)
    heads = [struct.unpack_from("<HIQ", d, start + o + 9) for o, op, _ in recs if op == 0x05]
    return [t for cid, _seq, t in heads if channels is None or cid in channels]


def object_channels(src: Path) -> set[int]:
    """The ids of the channels with tracked objects (not marker companions or metadata)."""
    from mcap.reader import make_reader

    with src.open("rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None
    return {
        c.id
        for c in summary.channels.values()
        if c.topic.startswith("/tracked_objects") and "marker" not in c.topic
    }


def rows_not_at(table: pa.Table, times: list[int]) -> int:
    stamps = table.column("time_ns").to_pylist()
    return sum(1 for t in stamps if t not in set(times))


# ----------------------------------------------------------------- a chunk whose records lack something


@pytest.mark.parametrize(("kind", "which"), [("pb", "middle"), ("cdr", "middle"), ("cdr", "last")])
def test_a_message_on_an_undefined_channel_loses_its_chunk_and_the_walk_goes_on(
    tmp_path: Path, logs: dict[str, tuple[Path, pa.Table]], kind: str, which: str
) -> None:
    """A message of an intact chunk (CRC recomputed) moved to channel 999, which no Channel record
    defines. Before, --salvage stopped the whole walk there: every chunk after it lost, and the
    note said the file was truncated (fuzz: 'lost 0 chunks with an unknown number of messages ...
    the file ends without a footer'); a CDR chunk's messages before the bad one were in the table
    though the chunk was counted lost. Now: refused at the chunk's offset, and salvage skips exactly
    that chunk and reads every other."""
    src, clean = logs[kind]
    d = bytearray(src.read_bytes())
    objects = object_channels(src)
    offsets = [c for c in chunks(bytes(d)) if len(message_times(bytes(d), c)) > 1]
    offsets = [c for c in offsets if message_times(bytes(d), c, objects)[:-1]]  # objects before the last
    chunk = offsets[len(offsets) // 2] if which == "middle" else offsets[-1]
    start, recs = chunk_records(bytes(d), chunk)
    last = [o for o, op, _ in recs if op == 0x05][-1]  # the chunk's last message: others come first
    lost = len(message_times(bytes(d), chunk))
    lost_times = message_times(bytes(d), chunk, objects)  # lost markers lose no rows
    struct.pack_into("<H", d, start + last + 9, 999)
    fix_crcs(d)
    bad = tmp_path / f"undefined-{kind}.mcap"
    bad.write_bytes(bytes(d))

    with pytest.raises(LogError, match="on channel 999, which was never defined") as err:
        mcap_reader.read(bad)
    assert err.value.offset == chunk and err.value.path == str(bad)

    table, stats = mcap_reader.read_log(bad, salvage=True)
    assert stats.chunks_lost == 1 and stats.messages_lost == lost
    assert len(stats.damage) == 1 and f"offset {chunk}: corrupt chunk" in stats.damage[0]
    assert not any("truncated" in d for d in stats.damage)
    assert table.num_rows == rows_not_at(clean, lost_times) < clean.num_rows
    assert not set(table.column("time_ns").to_pylist()) & set(lost_times)


# ----------------------------------------------------------------- an index that disagrees with the data


def _chunk_index_start(d: bytearray) -> tuple[int, str]:
    recs = records(bytes(d))
    at = [o for o, op, _ in recs if op == OP_CHUNK_INDEX][1]
    struct.pack_into("<Q", d, at + 9 + 16, chunks(bytes(d))[0])  # the second chunk's index → the first
    return at, "where no chunk starts|other message times|bytes, it has"


def _chunk_index_length(d: bytearray) -> tuple[int, str]:
    at = next(o for o, op, _ in records(bytes(d)) if op == OP_CHUNK_INDEX)
    (length,) = struct.unpack_from("<Q", d, at + 9 + 24)
    struct.pack_into("<Q", d, at + 9 + 24, length + 16)
    return at, f"{length + 16} bytes, it has {length}"


def _chunk_index_message_index(d: bytearray) -> tuple[int, str]:
    at = next(o for o, op, _ in records(bytes(d)) if op == OP_CHUNK_INDEX)
    struct.pack_into("<Q", d, at + 9 + 32 + 4 + 2, 8)  # its first channel's MessageIndex → the header
    return at, "where no MessageIndex record is"


def _message_index_entry(d: bytearray) -> tuple[int, str]:
    at = [o for o, op, _ in records(bytes(d)) if op == OP_MESSAGE_INDEX][2]
    (offset,) = struct.unpack_from("<Q", d, at + 9 + 6 + 8)
    struct.pack_into("<Q", d, at + 9 + 6 + 8, offset + 1)
    return at, "points at no message of that channel"


def _summary_offset(d: bytearray) -> tuple[int, str]:
    at = next(o for o, op, _ in records(bytes(d)) if op == OP_SUMMARY_OFFSET)
    (start,) = struct.unpack_from("<Q", d, at + 9 + 1)
    struct.pack_into("<Q", d, at + 9 + 1, start + 3)
    return at, "where no such group is"


def _footer_offsets(d: bytearray) -> tuple[int, str]:
    at = records(bytes(d))[-1][0]
    (offsets,) = struct.unpack_from("<Q", d, at + 9 + 8)
    struct.pack_into("<Q", d, at + 9 + 8, offsets - 10)
    return at, "the footer puts the summary offsets at"


def _summary_channel(d: bytearray) -> tuple[int, str]:
    """The summary's copy of a channel given another topic of the same length."""
    recs = records(bytes(d))
    data_end = next(o for o, op, _ in recs if op == 0x0F)
    at = next(o for o, op, _ in recs if op == 0x04 and o > data_end)
    (n,) = struct.unpack_from("<I", d, at + 9 + 4)
    d[at + 9 + 8 + n - 1] ^= 0x01  # the topic's last character
    return at, "is not the data section's"


LIES = {
    "chunk_index_start": _chunk_index_start,
    "chunk_index_length": _chunk_index_length,
    "chunk_index_message_index": _chunk_index_message_index,
    "message_index_entry": _message_index_entry,
    "summary_offset": _summary_offset,
    "footer_summary_offsets": _footer_offsets,
    "summary_channel": _summary_channel,
}


@pytest.mark.parametrize("lie", sorted(LIES))
def test_an_index_that_disagrees_with_the_data_is_named_and_the_data_read(
    tmp_path: Path, logs: dict[str, tuple[Path, pa.Table]], lie: str, capsys: pytest.CaptureFixture[str]
) -> None:
    """An index or summary record changed with every CRC recomputed (a tool that rewrote the data
    and kept a stale index, or a lying writer). Before, the reader ignored all but the Statistics
    count: exit 0 and not a word, while any tool seeking by the index reads another log (a summary
    channel that differed was even refused as a redefinition). Now the conversion is the clean
    one (the data section is read linearly) and stderr names the record and what disagrees."""
    src, clean = logs["pb"]
    d = bytearray(src.read_bytes())
    at, what = LIES[lie](d)
    fix_crcs(d)
    bad = tmp_path / f"{lie}.mcap"
    bad.write_bytes(bytes(d))
    out = tmp_path / "out.parquet"
    capsys.readouterr()
    assert main(["convert", str(bad), "--out", str(out)]) == 0
    err = capsys.readouterr().err
    assert f"lanecast: {bad}: the file's index disagrees with its data section: " in err
    assert f"offset {at}" in err
    assert any(part in err for part in what.split("|")), err
    assert "read by a linear scan of the data section" in err
    got = track_table.read_parquet(out)
    assert got.num_rows == clean.num_rows
    assert got.column("x").equals(clean.column("x")) and got.column("time_ns").equals(clean.column("time_ns"))
    extra = next(iter(track_table.read_meta(got).recordings.values())).extra
    assert any(f"offset {at}" in note for note in extra["index_disagrees"])


def test_a_consistent_index_says_nothing(
    logs: dict[str, tuple[Path, pa.Table]], capsys: pytest.CaptureFixture[str]
) -> None:
    """Logs of every writer configuration the checks meet are not flagged (no false alarm)."""
    for src, _ in logs.values():
        capsys.readouterr()
        _, stats = mcap_reader.read_log(src)
        assert stats.index == [] and capsys.readouterr().err == ""


def test_report_reads_the_forecasts_of_the_data_section_not_of_a_lying_chunk_index(tmp_path: Path) -> None:
    """An annotated log whose second chunk index points at the first chunk (CRCs recomputed): the
    report's mcap reader seeks by the index, so it read the first forecast twice and never the
    second, scoring other forecasts than the log holds without a word. The documents are now read
    from the data section in file order."""
    import json

    from mcap.writer import CompressionType, Writer
    from test_log_errors import _prediction_doc

    from lanecast.workflows.annotation.log_scores import prediction_documents

    log = tmp_path / "annotated.mcap"
    with log.open("wb") as f:
        w = Writer(f, chunk_size=64, compression=CompressionType.NONE, enable_data_crcs=True)
        w.start()
        cid = w.register_channel("/lanecast/prediction", "json", 0)
        for i in range(4):
            doc = {**_prediction_doc(), "t0_ns": (i + 1) * 10**9}
            w.add_message(cid, log_time=(i + 1) * 10**9, data=json.dumps(doc).encode(), publish_time=0)
        w.finish()
    d = bytearray(log.read_bytes())
    first, second = chunks(bytes(d))[:2]
    at = [o for o, op, _ in records(bytes(d)) if op == OP_CHUNK_INDEX][1]
    assert struct.unpack_from("<Q", d, at + 9 + 16)[0] == second
    struct.pack_into("<Q", d, at + 9 + 16, first)
    fix_crcs(d)
    log.write_bytes(bytes(d))
    docs = prediction_documents(log)
    assert [doc["t0_ns"] for doc in docs] == [10**9, 2 * 10**9, 3 * 10**9, 4 * 10**9]


def _copied(src: Path, out: Path) -> list[tuple[int, int, bytes]]:
    """``src`` copied by annotate's MCAP copy (no forecasts added); the copy's messages as read back
    by the mcap library with every CRC checked."""
    from mcap.reader import make_reader

    from lanecast.io_adapters.logs.mcap import copy as mcap_copy

    with out.open("wb") as f:
        mcap_copy.copy_mcap(src, f)
    with out.open("rb") as f:
        reader = make_reader(f, validate_crcs=True)
        return [(c.id, m.log_time, m.data) for _s, c, m in reader.iter_messages(log_time_order=False)]


def test_annotate_copies_a_log_whose_summary_channel_differs_from_the_data(
    tmp_path: Path, logs: dict[str, tuple[Path, pa.Table]]
) -> None:
    """The summary's copy of a channel with another topic: annotate's copy put the summary's
    Channel record to the writer, which refused the redefinition; the check that should then name
    the damage counted no messages and blamed the Statistics record ('counts 750 messages, but the
    data section holds 0'). The copy now stops at DataEnd (the summary is written anew from the
    data section) and the output is the log's data, valid with every CRC."""
    src, _ = logs["pb"]
    d = bytearray(src.read_bytes())
    _summary_channel(d)
    fix_crcs(d)
    bad = tmp_path / "summary-channel.mcap"
    bad.write_bytes(bytes(d))
    assert _copied(bad, tmp_path / "out.mcap") == _copied(src, tmp_path / "clean.mcap")
    assert len(mcap_reader.read(tmp_path / "out.mcap")) == logs["pb"][1].num_rows


def test_an_index_the_mcap_library_cannot_read_is_named_by_annotate_and_read_by_convert(
    tmp_path: Path, logs: dict[str, tuple[Path, pa.Table]], capsys: pytest.CaptureFixture[str]
) -> None:
    """A MessageIndex record declaring 4 GiB of entries, and one whose entry points near 2**63:
    annotate's copy (the mcap library) failed with 'unpack requires a buffer of 8 bytes' at the
    offset of the end of the file, and the reader's check of message-index offsets wrapped around
    int64 (an IndexError). Convert now reads the data and names the index; annotate's error names
    the index record."""
    from lanecast.io_adapters.logs.mcap import copy as mcap_copy

    src, clean = logs["pb"]
    d = bytearray(src.read_bytes())
    indexes = [o for o, op, _ in records(bytes(d)) if op == OP_MESSAGE_INDEX]
    struct.pack_into("<I", d, indexes[1] + 9 + 2, 2**32 - 1)
    struct.pack_into("<Q", d, indexes[4] + 9 + 6 + 8, 2**63 - 1)
    fix_crcs(d)
    bad = tmp_path / "index.mcap"
    bad.write_bytes(bytes(d))
    capsys.readouterr()
    assert main(["convert", str(bad), "--out", str(tmp_path / "out.parquet")]) == 0
    err = capsys.readouterr().err
    assert f"offset {indexes[1]}: a MessageIndex record whose entries (4294967295 bytes) do not fit it" in err
    assert "(and 1 more)" in err
    assert track_table.read_parquet(tmp_path / "out.parquet").num_rows == clean.num_rows
    with (tmp_path / "copy.mcap").open("wb") as f, pytest.raises(LogError) as exc:
        mcap_copy.copy_mcap(bad, f)
    assert exc.value.offset == indexes[1] and exc.value.path == str(bad)
    assert "a MessageIndex record whose entries (4294967295 bytes) do not fit it" in str(exc.value)


QOS = (
    '"- history: 3\\n  depth: 0\\n  reliability: 1\\n  durability: 2\\n  deadline:\\n    sec: 2147483647\\n'
    "    nsec: 4294967295\\n  lifespan:\\n    sec: 2147483647\\n    nsec: 4294967295\\n  liveliness: 1\\n"
    "  liveliness_lease_duration:\\n    sec: 2147483647\\n    nsec: 4294967295\\n"
    '  avoid_ros_namespace_conventions: false"'
)


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_a_ros2_topic_metadata_yaml_describes_otherwise_is_named_at_its_line(
    tmp_path: Path, storage: str
) -> None:
    """metadata.yaml giving one object topic QoS profiles its storage file does not record (an
    edited or regenerated metadata.yaml): rosbags matches storage topics to metadata.yaml's by name,
    type, format and QoS and skips every message of a topic that differs, without a word; lanecast
    saw a topic with no messages (in a bag it wrote, a checksum mismatch that named no place). Now
    the error names metadata.yaml, the topic's line and the key that differs."""
    table = staggered_cars(3, 30, stagger=4, step_m=2.5, speed=25.0, rate=10.0)
    bag = rosbag_writer.write(table, tmp_path / "bag", "ros2", storage=storage)
    meta = bag / "metadata.yaml"
    lines = meta.read_text().splitlines()
    name = next(i for i, line in enumerate(lines) if line.strip() == "name: /tracked_objects")
    qos = next(i for i in range(name, len(lines)) if "offered_qos_profiles" in lines[i])
    lines[qos] = lines[qos].split(":")[0] + ": " + QOS
    meta.write_text("\n".join(lines) + "\n")
    with pytest.raises(
        LogError, match="topic '/tracked_objects' of the storage file has other offered QoS"
    ) as err:
        rosbag_reader.read(bag)
    assert err.value.path == str(meta) and err.value.line == qos + 1
    assert err.value.column == "offered_qos_profiles"


def _ros1_records(d: bytes) -> list[tuple[int, dict[bytes, tuple[int, bytes]]]]:
    """(offset, {field: (offset of its value, value)}) of the top-level records of a ROS 1 bag."""
    pos, out = d.index(b"\n") + 1, []
    while pos + 4 <= len(d):
        (hl,) = struct.unpack_from("<I", d, pos)
        fields, p = {}, pos + 4
        while p < pos + 4 + hl:
            (fl,) = struct.unpack_from("<I", d, p)
            key, _, value = d[p + 4 : p + 4 + fl].partition(b"=")
            fields[key] = (p + 4 + len(key) + 1, value)
            p += 4 + fl
        out.append((pos, fields))
        (dl,) = struct.unpack_from("<I", d, pos + 4 + hl)
        pos += 8 + hl + dl
    return out


def test_a_foreign_ros1_bag_whose_index_skips_messages_is_refused_at_the_index_record(
    tmp_path: Path,
) -> None:
    """A ROS 1 bag from another recorder (no lanecast checksum) whose index data record of one
    chunk names a connection the messages are not on: rosbags reads messages through the index
    only, so that chunk's objects vanished and convert exited 0 with the rows missing. The bag's
    structure is now checked before a foreign bag is read: the record's offset and what it lists."""
    from rosbags.rosbag1 import Reader, Writer

    table = staggered_cars(3, 30, stagger=4, step_m=2.5, speed=25.0, rate=10.0)
    own = rosbag_writer.write(table, tmp_path / "own.bag", "ros1")
    foreign = tmp_path / "foreign.bag"
    writer = Writer(foreign)
    writer.chunk_threshold = 2000
    with Reader(own) as r, writer as w:
        conns = {
            c.id: w.add_connection(c.topic, c.msgtype, msgdef=c.msgdef.data, md5sum=c.digest)
            for c in r.connections
            if c.topic != "/lanecast/metadata"
        }
        for c, t, raw in r.messages():
            if c.id in conns:
                w.write(conns[c.id], t, raw)
    clean = rosbag_reader.read(foreign)
    d = bytearray(foreign.read_bytes())
    index_data = [(o, f) for o, f in _ros1_records(bytes(d)) if f[b"op"][1] == b"\x04"]
    at, fields = index_data[len(index_data) // 2]
    d[fields[b"conn"][0] : fields[b"conn"][0] + 4] = struct.pack("<I", 99)
    foreign.write_bytes(bytes(d))
    with pytest.raises(
        LogError, match="an index data record of connection 99 lists the message at offset"
    ) as err:
        rosbag_reader.read(foreign)
    assert err.value.offset == at and err.value.path == str(foreign)
    assert clean.num_rows == table.num_rows


def _jittered_log(path: Path, jitter_ms: float, seed: int, twice_at: int | None = None) -> Path:
    """A foreign 10 Hz JSON log of 2 cars, 200 messages stamped ±jitter_ms (uniform); car k at
    x = 50 k + 2 i in message i. ``twice_at``: message i sent again 1 ms later with other x."""
    import numpy as np
    from test_hostile_inputs import _entity, json_log

    rng = np.random.default_rng(seed)
    stamps = 1_000_000_000 + np.arange(200) * 100_000_000 + rng.uniform(-jitter_ms, jitter_ms, 200) * 1e6
    messages = []
    for i, t in enumerate(stamps.astype(np.int64).tolist()):
        messages.append(
            ("/objects", t, [_entity(k, 50 * k + 2.0 * i, t // 10**9, t % 10**9) for k in (1, 2)])
        )
        if i == twice_at:
            t += 1_000_000
            messages.append(
                ("/objects", t, [_entity(k, 50 * k + 2.0 * i + 1, t // 10**9, t % 10**9) for k in (1, 2)])
            )
    return json_log(path, messages)


@pytest.mark.parametrize("seed", [0, 3])
def test_stamps_jittering_by_45_ms_at_10_hz_convert_every_row_on_its_frame(tmp_path: Path, seed: int) -> None:
    """A 10 Hz topic stamped ±45 ms (a recorder's clock; the grid laid through the stamps is a few
    ms off their mean phase): two stamps rounded onto one frame, its neighbour empty, and convert
    refused the log as 'track 1 has two different objects on frame 1'. Each stamp now takes the
    free frame beside it: every row converts, on the frame of its message."""
    import numpy as np

    out = tmp_path / "jitter.parquet"
    assert main(["convert", str(_jittered_log(tmp_path / "jitter.mcap", 45.0, seed)), "--out", str(out)]) == 0
    table = track_table.read_parquet(out).to_pandas()
    assert len(table) == 400
    for k, track in table.groupby("track_id"):
        track = track.sort_values("frame")
        np.testing.assert_array_equal(track["frame"].to_numpy(), np.arange(200))
        np.testing.assert_allclose(track["x"].to_numpy(), 50 * int(k) + 2.0 * np.arange(200))


def test_a_message_sent_twice_with_other_values_is_still_refused_not_spread(tmp_path: Path) -> None:
    """The spreading of jittered stamps does not hide a conflict: a message sent again 1 ms later
    with other positions is too far from the next frame to take it, and stays refused."""
    log = _jittered_log(tmp_path / "twice.mcap", 10.0, 0, twice_at=100)
    with pytest.raises(LogError, match="track 1 has two different objects on frame 100") as err:
        mcap_reader.read(log)
    import re

    stamps = re.search(r"stamped (\d+) ns and (\d+) ns", str(err.value))
    assert err.value.column == "time_ns" and stamps is not None
    assert int(stamps.group(2)) - int(stamps.group(1)) == 1_000_000


@pytest.mark.parametrize(
    ("edit", "says"),
    [
        (lambda e: {**e, "cubes": {"a": 1}}, "field 'entities[0].cubes': {'a': 1} (expected a list)"),
        (lambda e: {**e, "metadata": "car"}, "field 'entities[0].metadata': 'car' (expected a list)"),
    ],
)
def test_a_json_field_of_the_wrong_type_is_said_to_be_one(tmp_path: Path, edit: Any, says: str) -> None:
    """A JSON SceneUpdate whose entity has cubes as an object or metadata as a string: the error
    said only 'cannot be decoded: 0' (a KeyError's text) or an AttributeError's; it now names the
    field, what it holds and what was expected."""
    from test_hostile_inputs import _entity, json_log

    messages = [("/objects", t * 10**8, [_entity(1, 2.0 * t, 0, t * 10**8)]) for t in range(1, 20)]
    messages[5] = ("/objects", 6 * 10**8, [edit(_entity(1, 12.0, 0, 6 * 10**8))])
    log = json_log(tmp_path / "wrong-type.mcap", messages)
    with pytest.raises(LogError) as err:
        mcap_reader.read(log)
    assert f"message at log time {6 * 10**8} cannot be decoded: {says}" in str(err.value)
    assert err.value.path == str(log) and err.value.offset is not None


def _originals(path: Path) -> list[tuple[str, int, bytes]]:
    """(topic, log time, data) of every message not on lanecast's own topics, in file order, read
    by the mcap library with every CRC checked."""
    from mcap.reader import make_reader

    with path.open("rb") as f:
        reader = make_reader(f, validate_crcs=True)
        return [
            (c.topic, m.log_time, bytes(m.data))
            for _s, c, m in reader.iter_messages(log_time_order=False)
            if not c.topic.startswith("/lanecast/")
        ]


def test_annotate_salvage_writes_the_intact_chunks_of_a_damaged_log(
    tmp_path: Path, logs: dict[str, tuple[Path, pa.Table]], capsys: pytest.CaptureFixture[str]
) -> None:
    """`lanecast annotate --salvage` on an MCAP with a chunk whose CRC fails: the option did not
    exist (argparse's usage error), and without it the log is refused. Now the output is a complete
    MCAP (every CRC valid) holding every message of the intact chunks, byte for byte and in order,
    plus the forecasts; the loss is reported as convert --salvage reports it."""
    src, _ = logs["pb"]
    d = bytearray(src.read_bytes())
    chunk = [c for c in chunks(bytes(d)) if len(message_times(bytes(d), c)) > 1][3]
    start, recs = chunk_records(bytes(d), chunk)
    d[start + recs[-1][0] + 9 + 22] ^= 0xFF  # a payload byte: the chunk's CRC no longer holds
    bad = tmp_path / "damaged.mcap"
    bad.write_bytes(bytes(d))
    lost = set(message_times(bytes(d), chunk))
    capsys.readouterr()
    assert main(["annotate", str(bad), "--out", str(tmp_path / "out"), "--salvage"]) == 0
    err = capsys.readouterr().err
    assert f"lost 1 chunks with {len(lost)} messages (offset {chunk}: corrupt chunk: CRC mismatch" in err
    out = tmp_path / "out" / "damaged.mcap"
    intact = [m for m in _originals(src) if m[1] not in lost]
    assert _originals(out) == intact and len(intact) < len(_originals(src))
    table = mcap_reader.read(out)
    assert table.num_rows == mcap_reader.read_log(bad, salvage=True)[0].num_rows


def test_annotate_salvage_of_an_intact_log_copies_all_of_it(
    tmp_path: Path, logs: dict[str, tuple[Path, pa.Table]]
) -> None:
    """--salvage changes nothing for an intact log: the same original messages as without it."""
    src, _ = logs["cdr"]
    assert main(["annotate", str(src), "--out", str(tmp_path / "a"), "--salvage"]) == 0
    assert main(["annotate", str(src), "--out", str(tmp_path / "b")]) == 0
    salvaged, plain = tmp_path / "a" / src.name, tmp_path / "b" / src.name
    assert _originals(salvaged) == _originals(plain) == _originals(src)
    assert len(mcap_reader.read(salvaged)) == len(mcap_reader.read(plain))


def test_annotate_names_a_ros1_bag_of_another_version_as_convert_does(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A ROS 1 bag whose version line says 1.2: convert named offset 0 and the version, annotate
    said only 'cannot open the bag: Bag version 102 is not supported.' (rosbags' words)."""
    table = staggered_cars(3, 30, stagger=4, step_m=2.5, speed=25.0, rate=10.0)
    bag = rosbag_writer.write(table, tmp_path / "old.bag", "ros1")
    bag.write_bytes(b"#ROSBAG V1.2\n" + bag.read_bytes()[13:])
    capsys.readouterr()
    assert main(["annotate", str(bag), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert err == (
        f"lanecast annotate: error: {bag}, offset 0: a ROS 1 bag of another format version ('#ROSBAG V1.2') "
        "(expected '#ROSBAG V2.0' (the only ROS 1 bag version lanecast reads))"
    )


def _prediction_log(path: Path, docs: list[tuple[int, dict[str, Any]]]) -> Path:
    """An MCAP of /lanecast/prediction JSON documents at the given log times."""
    import json

    from mcap.writer import Writer

    with path.open("wb") as f:
        w = Writer(f)
        w.start()
        cid = w.register_channel("/lanecast/prediction", "json", 0)
        for log_time, doc in docs:
            w.add_message(cid, log_time=log_time, data=json.dumps(doc).encode(), publish_time=log_time)
        w.finish()
    return path


@pytest.mark.parametrize(
    ("edit", "column", "says"),
    [
        (
            lambda d: d.update(horizon_s=[0.5, 1, 1.5, 2, 2.5]),
            "horizon_s",
            "horizon_s is [0.5, 1, 1.5, 2, 2.5]",
        ),
        (
            lambda d: d.update(maneuver_names=["a", "b", "c"]),
            "maneuver_names",
            "maneuver_names is ['a', 'b', 'c']",
        ),
    ],
)
def test_a_forecast_of_another_layout_is_refused_not_scored(
    tmp_path: Path, edit: Any, column: str, says: str
) -> None:
    """A /lanecast/prediction document whose horizons or maneuver names are not lanecast's: the
    report scored its five points as 1-5 s and its classes as straight/left/right, exit 0."""
    from test_log_errors import _prediction_doc

    from lanecast.workflows.annotation.log_scores import prediction_documents

    good = _prediction_doc()
    bad = _prediction_doc()
    edit(bad)
    log = _prediction_log(tmp_path / "layout.mcap", [(good["t0_ns"], good), (bad["t0_ns"], bad)])
    with pytest.raises(LogError) as err:
        prediction_documents(log)
    assert err.value.column == column and err.value.path == str(log)
    assert f"/lanecast/prediction message 2 (log time {bad['t0_ns']} ns): {says}" in str(err.value)


def test_report_refuses_a_forecast_logged_at_another_time_than_its_t0(tmp_path: Path) -> None:
    """A document whose t0_ns is not its message's log time (edited, or one second off): the
    report scored it against the windows at t0_ns, other than the ones it was made for, exit 0;
    and a log whose every forecast has no targets was a ValueError traceback ('axes don't match')."""
    from test_log_errors import _prediction_doc

    from lanecast.io_adapters.errors import InputError
    from lanecast.workflows.annotation.log_scores import checked_forecast_times, prediction_documents

    doc = _prediction_doc()
    log = _prediction_log(tmp_path / "shifted.mcap", [(doc["t0_ns"], doc), (doc["t0_ns"] - 10**9, doc)])
    with pytest.raises(LogError) as err:
        checked_forecast_times(log, prediction_documents(log))
    assert err.value.column == "t0_ns" and str(
        f"/lanecast/prediction message 2 (log time {doc['t0_ns'] - 10**9} ns): t0_ns {doc['t0_ns']} is not "
        "the message's log time"
    ) in str(err.value)
    empty = _prediction_log(tmp_path / "empty.mcap", [(doc["t0_ns"], {**doc, "targets": []})] * 3)
    with pytest.raises(InputError, match="the 3 forecasts on /lanecast/prediction have no targets"):
        prediction_documents(empty)
    assert main(["report", str(empty), "--out", str(tmp_path / "r")]) == 2
    assert not (tmp_path / "r").exists()


def test_an_annotated_sqlite3_bag_of_an_older_schema_reads_back(tmp_path: Path) -> None:
    """A sqlite3 ROS 2 bag of rosbag2's schema before version 4 (no schema table, or version 2:
    no message definitions): annotate copied each topic with an empty definition and its type hash
    into a version 9 bag, which lanecast's own reader then refused ('the definition is empty').
    The copy now takes the definition of each type lanecast knows; the output converts to the
    same table as the input."""
    import sqlite3

    table = staggered_cars(3, 30, stagger=4, step_m=2.5, speed=25.0, rate=10.0)
    bag = rosbag_writer.write(table, tmp_path / "old", "ros2", storage="sqlite3")
    with sqlite3.connect(next(bag.glob("*.db3"))) as con:
        con.execute("UPDATE schema SET schema_version = 2")  # as rosbags reads it: no table, the same
    clean = rosbag_reader.read(bag)
    assert main(["annotate", str(bag), "--out", str(tmp_path / "out")]) == 0
    out = tmp_path / "out" / "old"
    annotated = rosbag_reader.read(out)
    assert annotated.num_rows == clean.num_rows
    assert annotated.column("x").equals(clean.column("x"))
    with sqlite3.connect(next(out.glob("*.db3"))) as con:
        empty = con.execute(
            "SELECT topic_type FROM message_definitions WHERE encoded_message_definition = ''"
        )
        assert not [t for (t,) in empty if t.startswith("autoware_perception_msgs")]


@pytest.fixture(scope="module")
def ros1_bag(tmp_path_factory: pytest.TempPathFactory) -> bytes:
    """The bytes of a ROS 1 bag lanecast wrote (3 cars, 30 frames)."""
    table = staggered_cars(3, 30, stagger=4, step_m=2.5, speed=25.0, rate=10.0)
    return rosbag_writer.write(table, tmp_path_factory.mktemp("ros1") / "b.bag", "ros1").read_bytes()


@pytest.mark.parametrize("damage", ["index_topic", "index_conn", "chunk_info_version"])
def test_a_ros1_index_record_that_disagrees_with_the_chunks_is_named(
    tmp_path: Path, damage: str, ros1_bag: bytes
) -> None:
    """The index's copy of a connection record renamed or renumbered (rosbags reads connections
    from the index: the chunk's messages went to another topic), or a chunk info record of version
    2: the error was a checksum mismatch naming no place, or rosbags' 'Bag index looks damaged'.
    Now the record's offset and what disagrees."""
    bag = tmp_path / "b.bag"
    d = bytearray(ros1_bag)
    recs = _ros1_records(bytes(d))
    index_pos = struct.unpack("<Q", recs[0][1][b"index_pos"][1])[0]
    if damage == "chunk_info_version":
        at, fields = next((o, f) for o, f in recs if f[b"op"][1] == b"\x06")
        d[fields[b"ver"][0]] = 2
        says = "a chunk info record of version 2"
    else:
        at, fields = next(
            (o, f)
            for o, f in recs
            if f[b"op"][1] == b"\x07" and o >= index_pos and b"/tracked" in f[b"topic"][1]
        )
        if damage == "index_topic":
            d[fields[b"topic"][0] + len(fields[b"topic"][1]) - 1] ^= 0x01
        else:
            (conn,) = struct.unpack("<I", fields[b"conn"][1])
            struct.pack_into("<I", d, fields[b"conn"][0], conn + 1 if conn + 1 < 3 else conn - 1)
        says = "connection record"
    bag.write_bytes(bytes(d))
    with pytest.raises(LogError) as err:
        rosbag_reader.read(bag)
    assert err.value.offset == at and err.value.path == str(bag) and says in str(err.value)


def test_a_ros2_bag_whose_mcap_index_disagrees_with_its_data_is_refused_at_the_index(tmp_path: Path) -> None:
    """A ROS 2 bag whose MCAP storage file has a chunk index pointing at another chunk (CRCs
    recomputed): rosbags reads the storage through its chunk indexes, so it read one chunk twice
    and another never (a lanecast bag failed its checksum naming no place; a foreign bag lost the
    rows without a word). The storage file's indexes are now checked before rosbags reads it."""
    table = staggered_cars(3, 30, stagger=4, step_m=2.5, speed=25.0, rate=10.0)
    bag = rosbag_writer.write(table, tmp_path / "bag", "ros2", storage="mcap")
    storage = next(bag.glob("*.mcap"))
    d = bytearray(storage.read_bytes())
    at = next(o for o, op, _ in records(bytes(d)) if op == OP_CHUNK_INDEX)
    (length,) = struct.unpack_from("<Q", d, at + 9 + 24)
    struct.pack_into("<Q", d, at + 9 + 24, length + 16)
    footer = records(bytes(d))[-1][0]
    (start,) = struct.unpack_from("<Q", d, footer + 9)
    struct.pack_into("<I", d, footer + 25, zlib.crc32(bytes(d[start : footer + 25])))
    storage.write_bytes(bytes(d))
    with pytest.raises(LogError, match="rosbags reads the bag through the index") as err:
        rosbag_reader.read(bag)
    assert err.value.path == str(storage) and err.value.offset == at
    assert f"{length + 16} bytes, it has {length}" in str(err.value)
    # annotate with precomputed forecasts copies the bag without reading its tracks: the same check
    from lanecast.io_adapters.logs.rosbag import copy as bag_copy

    with pytest.raises(LogError, match="rosbags reads the bag through the index") as err:
        bag_copy.copy_ros2_bag(bag, tmp_path / "copy")
    assert err.value.path == str(storage) and err.value.offset == at
