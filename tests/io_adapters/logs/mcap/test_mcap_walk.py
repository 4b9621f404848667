"""The MCAP record walk on damaged logs: truncation, flipped bytes, chunks too large or expanding
past their size, undefined or redefined channels, records of another kind in a chunk, damaged
attachments; refused at the record and offset, or salvaged chunk by chunk."""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pytest
from conftest import (
    US101,
    _record,
    _s,
    channel_record,
    chunk_layout,
    chunk_records,
    chunks,
    fix_crcs,
    mcap_contents,
    mcap_record_spans,
    message_times,
    rewrite_mcap,
)

from lanecast.io_adapters.contracts import track_table
from lanecast.io_adapters.errors import LogError
from lanecast.io_adapters.formats import registry
from lanecast.io_adapters.logs.mcap import reader as mcap_reader
from lanecast.io_adapters.logs.mcap import writer as mcap_writer


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


def raw_log(path: Path, records: bytes) -> Path:
    """An unchunked MCAP: header, the given records, data end, footer, magic."""
    header = _record(0x01, _s("") + _s("test"))
    footer = _record(0x02, struct.pack("<QQI", 0, 0, 0))
    path.write_bytes(
        mcap_reader.MAGIC
        + header
        + records
        + _record(0x0F, struct.pack("<I", 0))
        + footer
        + mcap_reader.MAGIC
    )
    return path


@pytest.mark.parametrize(
    ("name", "records", "match"),
    [
        (
            "string past record",
            _record(0x03, struct.pack("<H", 1) + struct.pack("<I", 999) + b"abc"),
            "runs past",
        ),
        (
            "non-UTF-8 schema name",
            _record(0x03, struct.pack("<H", 1) + _s(b"\xff\xfe") + _s("jsonschema") + _s("{}")),
            "not UTF-8",
        ),
        (
            "non-UTF-8 topic",
            _record(0x04, struct.pack("<HH", 1, 0) + _s(b"/a\xc3") + _s("json") + struct.pack("<I", 0)),
            "not UTF-8",
        ),
        ("metadata map past record", _record(0x0C, _s("lanecast") + struct.pack("<I", 1 << 20)), "runs past"),
        ("message shorter than its header", _record(0x05, b"\x01\x00"), "shorter than its header"),
        ("statistics too short", _record(0x0B, b"\x01"), "fewer than its fields"),
    ],
)
def test_unchunked_records_with_bad_fields(tmp_path: Path, name: str, records: bytes, match: str) -> None:
    path = raw_log(tmp_path / "bad.mcap", records)
    with pytest.raises(LogError, match=match) as err:
        mcap_reader.read(path)
    assert (
        err.value.path == str(path) and err.value.offset == 8 + 9 + 4 + 8
    )  # the first record after the header


def _chunk(records: bytes, size: int, compression: str, compressed: bytes) -> bytes:
    body = (
        struct.pack("<QQQI", 0, 0, size, 0)
        + _s(compression)
        + struct.pack("<Q", len(compressed))
        + compressed
    )
    return _record(0x06, body)


def test_chunk_claiming_a_terabyte_is_refused_before_allocating(tmp_path: Path) -> None:
    import lz4.frame
    import zstandard

    records = _record(0x03, struct.pack("<H", 1) + _s("x") + _s("y") + _s(""))
    for compression, data in (
        ("zstd", zstandard.ZstdCompressor().compress(records)),
        ("lz4", lz4.frame.compress(records)),
        ("", records),
    ):
        path = raw_log(tmp_path / f"big-{compression}.mcap", _chunk(records, 1 << 40, compression, data))
        with pytest.raises(LogError, match="declares 1,099,511,627,776 uncompressed bytes") as err:
            mcap_reader.read(path)
        assert err.value.offset == 29


def test_lz4_frame_that_expands_past_the_declared_size(tmp_path: Path) -> None:
    """A frame whose own header claims 2^40 bytes, and a zero bomb: decompression stops at the chunk's size."""
    import lz4.frame

    bomb = lz4.frame.compress(bytes(64 << 20))
    path = raw_log(tmp_path / "bomb.mcap", _chunk(b"", 1000, "lz4", bomb))
    with pytest.raises(LogError, match="more than the 1000 bytes the chunk says"):
        mcap_reader.read(path)
    frame = bytearray(lz4.frame.compress(b"abc", store_size=True))
    frame[6:14] = struct.pack("<Q", 1 << 40)  # content size in the frame descriptor
    path = raw_log(tmp_path / "lie.mcap", _chunk(b"", 3, "lz4", bytes(frame)))
    with pytest.raises(LogError, match="corrupt chunk"):
        mcap_reader.read(path)


def test_damaged_zstd_chunks_of_a_log_are_a_clean_error(tmp_path: Path) -> None:
    """Flipped bytes inside a zstd-compressed chunk (lanecast's own MCAP logs are zstd) are refused
    as a LogError naming the file, whether zstd or the chunk CRC notices first."""
    table = registry.read_any([US101])
    log = registry.write_any(table, tmp_path / "log.mcap", "mcap")
    data = log.read_bytes()
    pos = 8  # after the magic: walk the records (opcode u8, length u64) to the first chunk
    while data[pos] != 0x06:
        pos += 9 + struct.unpack_from("<Q", data, pos + 1)[0]
    (length,) = struct.unpack_from("<Q", data, pos + 1)
    assert data[pos + 9 + 28 : pos + 9 + 32] == b"\x04\x00\x00\x00"  # the compression string "zstd"
    assert data[pos + 9 + 32 : pos + 9 + 36] == b"zstd"
    records_start = pos + 9 + 36 + 8
    for at in np.linspace(records_start + 8, pos + 9 + length - 8, 6).astype(int):
        bad = bytearray(data)
        bad[at] ^= 0xFF
        damaged = tmp_path / f"damaged-{at}.mcap"
        damaged.write_bytes(bytes(bad))
        with pytest.raises(LogError) as err:
            registry.read_any([damaged])
        assert err.value.path == str(damaged)


def rows_at(table: pa.Table, times: set[int]) -> pa.Table:
    return table.filter(pc.is_in(table.column("time_ns"), pa.array(sorted(times), pa.int64())))


@pytest.mark.parametrize("fraction", [0.001, 0.3, 0.55, 0.9, 0.999])
def test_truncated_log_names_offset(log: Path, tmp_path: Path, fraction: float) -> None:
    data = log.read_bytes()
    cut = max(int(len(data) * fraction), 5)
    path = tmp_path / "cut.mcap"
    path.write_bytes(data[:cut])
    with pytest.raises(LogError, match=r"truncated|does not end with the MCAP magic") as err:
        mcap_reader.read(path)
    assert err.value.path == str(path)
    assert err.value.offset is not None and 0 <= err.value.offset <= cut
    assert err.value.expected is not None


def test_salvage_truncated_log_keeps_complete_chunks(
    log: Path, table: pa.Table, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    chunks = chunk_layout(log)
    data = log.read_bytes()
    offset, length, _ = chunks[5]
    path = tmp_path / "cut.mcap"
    path.write_bytes(data[: offset + length // 2])  # cut in the middle of the sixth chunk
    back, stats = mcap_reader.read_log(path, salvage=True)
    kept = set().union(*(times for _, _, times in chunks[:5]))
    expected = rows_at(table, kept)
    assert back.num_rows == expected.num_rows
    np.testing.assert_array_equal(back.column("time_ns").to_numpy(), expected.column("time_ns").to_numpy())
    np.testing.assert_allclose(back.column("x").to_numpy(), expected.column("x").to_numpy())
    assert (stats.chunks, stats.chunks_lost, stats.messages, stats.messages_lost) == (6, 1, len(kept), None)
    err = capsys.readouterr().err
    assert "salvaged" in err and "truncated" in err and str(path) in err
    # what followed the cut is not known: never "lost 0 chunks" where most of a log is gone
    assert "lost an unknown number of chunks and messages, at least 1 of them" in err
    cut_between = tmp_path / "cut-between.mcap"
    cut_between.write_bytes(data[:offset])  # just before the sixth chunk: nothing says what followed
    mcap_reader.read_log(cut_between, salvage=True)
    assert "; lost an unknown number of chunks and messages (" in capsys.readouterr().err


def test_flipped_byte_in_chunk(
    log: Path, table: pa.Table, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    chunks = chunk_layout(log)
    offset, length, lost_times = chunks[3]
    data = bytearray(log.read_bytes())
    data[offset + length // 2] ^= 0x5A  # inside the compressed records
    path = tmp_path / "flip.mcap"
    path.write_bytes(bytes(data))
    with pytest.raises(LogError, match="corrupt chunk") as err:
        mcap_reader.read(path)
    assert err.value.offset == offset and err.value.path == str(path)
    back, stats = mcap_reader.read_log(path, salvage=True)
    kept = set(table.column("time_ns").to_numpy().tolist()) - lost_times
    expected = rows_at(table, kept)
    np.testing.assert_array_equal(back.column("time_ns").to_numpy(), expected.column("time_ns").to_numpy())
    np.testing.assert_array_equal(back.column("track_id").to_numpy(), expected.column("track_id").to_numpy())
    assert stats.chunks == len(chunks) and stats.chunks_lost == 1
    assert stats.messages_lost == len(lost_times)
    assert track_table.read_meta(back).recordings["r"].extra["salvage"]["chunks_lost"] == 1
    assert "lost 1 chunks" in capsys.readouterr().err


def test_flipped_byte_in_chunk_length_resyncs(log: Path, table: pa.Table, tmp_path: Path) -> None:
    chunks = chunk_layout(log)
    offset, _, lost_times = chunks[2]
    data = bytearray(log.read_bytes())
    data[offset + 6] ^= 0x40  # the record length: the walk loses its place
    path = tmp_path / "flip.mcap"
    path.write_bytes(bytes(data))
    with pytest.raises(LogError, match="corrupt record") as err:
        mcap_reader.read(path)
    assert err.value.offset == offset
    back, stats = mcap_reader.read_log(path, salvage=True)
    kept = set(table.column("time_ns").to_numpy().tolist()) - lost_times
    assert back.num_rows == rows_at(table, kept).num_rows
    assert stats.chunks_lost == 1 and stats.messages_lost == len(lost_times)


def test_channel_with_undefined_schema(tmp_path: Path) -> None:
    """Hand-written records: a channel refers to schema 9, which the file never defines."""
    from mcap.writer import Writer

    path = tmp_path / "orphan.mcap"
    with path.open("wb") as f:
        w = Writer(f, use_chunking=False, repeat_schemas=False)
        w.start()
        body = struct.pack("<HH", 1, 9) + _s("/objects") + _s("protobuf") + struct.pack("<I", 0)
        f.write(bytes([0x04]) + struct.pack("<Q", len(body)) + body)
        w.add_message(1, log_time=5, data=b"", publish_time=5)
        w.finish()
    with pytest.raises(LogError, match=r"'/objects' refers to schema 9") as err:
        mcap_reader.read(path)
    assert err.value.offset is not None and err.value.offset > 8


@pytest.mark.parametrize("damage", ["name length", "data length", "crc"])
def test_damaged_attachment_is_named_by_convert_and_annotate(tmp_path: Path, damage: str) -> None:
    """An Attachment record whose fields do not fit it (or whose CRC is wrong) was read without a
    word by convert and refused by annotate's copy as 'cannot copy the MCAP: ' (no reason, the
    offset of the read buffer); now both name the record's offset and what is wrong."""
    import zlib

    import pyarrow.parquet as pq
    from conftest import forecasts_for, make_mcap

    from lanecast.workflows.annotation.annotate_log import AnnotateOptions, annotate_log

    log = make_mcap(tmp_path / "log.mcap", n=40)
    pq.write_table(forecasts_for("log", [1, 2], [1]), tmp_path / "fc.parquet")  # no track reading: the copy
    data = bytearray(log.read_bytes())
    at = next(o for o, op, _ in mcap_record_spans(bytes(data)) if op == 0x09)
    if damage == "name length":
        struct.pack_into("<I", data, at + 9 + 16, 10**6)
    elif damage == "data length":
        pos = at + 9 + 16
        pos += 4 + struct.unpack_from("<I", data, pos)[0]
        pos += 4 + struct.unpack_from("<I", data, pos)[0]
        struct.pack_into("<Q", data, pos, 10**9)
    else:
        n = struct.unpack_from("<Q", data, at + 1)[0]
        struct.pack_into("<I", data, at + 9 + n - 4, 0xDEADBEEF)
    end = next(
        o for o, op, _ in mcap_record_spans(bytes(data)) if op == 0x0F
    )  # the writer meant it: data CRC ok
    struct.pack_into("<I", data, end + 9, zlib.crc32(bytes(data[:end])))
    log.write_bytes(bytes(data))
    with pytest.raises(LogError, match="corrupt Attachment record") as err:
        mcap_reader.read_log(log)
    assert err.value.path == str(log) and err.value.offset == at
    if damage == "crc":  # the mcap library's copy checks no attachment CRC (the data section's is right)
        return
    with pytest.raises(LogError, match="corrupt Attachment record") as err:
        annotate_log(log, tmp_path / "out.mcap", AnnotateOptions(forecasts=tmp_path / "fc.parquet"))
    assert err.value.offset == at and not (tmp_path / "out.mcap").exists()


@pytest.mark.parametrize("opcode", [0x0F, 0x00, 0x06])
def test_a_record_of_another_kind_inside_a_chunk_is_refused(
    tmp_path: Path, table: pa.Table, opcode: int
) -> None:
    """A Message record inside an uncompressed chunk whose opcode became DataEnd (0x0f), 0x00 or
    Chunk, CRCs recomputed (a writer bug, or damage before the CRCs were written): the record was
    skipped and its vehicles' rows silently lost (fuzz seed 1151). A chunk holds only Schema,
    Channel and Message records; now the chunk's offset and the record's place in it."""
    import zlib

    from mcap.writer import CompressionType

    clean = mcap_writer.write(table, tmp_path / "clean.mcap", "mcap")
    log = tmp_path / "log.mcap"
    rewrite_mcap(clean, log, compression=CompressionType.NONE, chunk_size=4000)
    data = bytearray(log.read_bytes())
    chunk = [o for o, op, _n in mcap_record_spans(bytes(data)) if op == 0x06][1]
    body = chunk + 9
    (clen,) = struct.unpack_from("<I", data, body + 28)
    records_at = body + 32 + clen + 8
    (records_len,) = struct.unpack_from("<Q", data, records_at - 8)
    pos = records_at
    while data[pos] != 0x05:  # the chunk's first Message record
        pos += 9 + struct.unpack_from("<Q", data, pos + 1)[0]
    data[pos] = opcode
    struct.pack_into("<I", data, body + 24, zlib.crc32(bytes(data[records_at : records_at + records_len])))
    end = next(o for o, op, _ in mcap_record_spans(bytes(data)) if op == 0x0F)
    struct.pack_into("<I", data, end + 9, zlib.crc32(bytes(data[:end])))
    log.write_bytes(bytes(data))
    with pytest.raises(
        LogError, match=f"a record of opcode {opcode:#04x} at byte {pos - records_at} "
    ) as err:
        mcap_reader.read_log(log)
    assert err.value.path == str(log) and err.value.offset == chunk


@pytest.mark.parametrize("change", ["topic", "schema"])
def test_a_channel_defined_again_with_other_content_is_refused_at_its_record(
    tmp_path: Path, log: Path, change: str
) -> None:
    """A Channel record half-way through a log giving channel 1 another topic (or no schema): the
    messages after it were read as that topic's, not an object topic, and dropped: exit 0 with
    6,869 of 21,971 rows lost (fuzz2 seed 5043). MCAP channel ids are unique in a file: a record
    that repeats an id with other content is refused at its offset."""
    from mcap.writer import Writer

    summary, messages, metadata = mcap_contents(log)
    bad = tmp_path / "redefined.mcap"
    with bad.open("wb") as f:
        w = Writer(f, use_chunking=False)
        w.start()
        sids = {i: w.register_schema(s.name, s.encoding, s.data) for i, s in summary.schemas.items()}
        cids = {
            i: w.register_channel(c.topic, c.message_encoding, sids[c.schema_id], c.metadata)
            for i, c in summary.channels.items()
        }
        for m in metadata:
            w.add_metadata(m.name, m.metadata)
        for k, (cid, log_time, data) in enumerate(messages):
            if k == len(messages) // 2:
                first = summary.channels[cid]
                topic = "/other" if change == "topic" else first.topic
                schema = sids[first.schema_id] if change == "topic" else 0
                at = f.tell()
                f.write(channel_record(cids[cid], schema, topic, first.message_encoding))
            w.add_message(cids[cid], log_time, data, log_time)
        w.finish()
    with pytest.raises(LogError, match=rf"channel {cids[cid]} defined again with other content") as err:
        mcap_reader.read(bad)
    assert err.value.offset == at and err.value.path == str(bad)
