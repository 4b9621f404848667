"""The one MCAP record walk, its opcode names, and the kinds of error a damaged file raises."""

from __future__ import annotations

import itertools
import struct
import zlib
from pathlib import Path

import pytest
from conftest import make_mcap, mcap_record_spans
from mcap.opcode import Opcode

from lanecast.io_adapters.errors import LogError
from lanecast.io_adapters.logs.mcap import reader as mcap_reader
from lanecast.io_adapters.logs.mcap.definitions import Definitions, parsed
from lanecast.io_adapters.logs.mcap.errors import (
    CorruptRecord,
    CrcMismatch,
    IndexMismatch,
    LogDamage,
    McapError,
    NotMcap,
    TruncatedFile,
)
from lanecast.io_adapters.logs.mcap.records import (
    ChannelRecord,
    RecordOverrun,
    SchemaRecord,
    op_name,
    read_channel,
    read_schema,
    records,
)
from lanecast.io_adapters.logs.mcap.walk import check_file


def test_the_walk_yields_the_records_of_a_real_file_in_order_each_ending_where_the_next_starts(
    tmp_path: Path,
) -> None:
    data = make_mcap(tmp_path / "a.mcap").read_bytes()
    found = list(records(data, 8, len(data) - 8))
    assert found[0][0] == Opcode.HEADER and found[-1][0] == Opcode.FOOTER
    assert [(pos, op, nxt - body) for op, pos, body, nxt in found] == mcap_record_spans(data)
    assert all(a[3] == b[1] for a, b in itertools.pairwise(found))
    assert {Opcode.CHUNK, Opcode.MESSAGE_INDEX, Opcode.DATA_END, Opcode.ATTACHMENT} <= {
        op for op, *_ in found
    }


def test_a_record_past_the_end_of_its_region_is_an_overrun_naming_its_place_in_the_region(
    tmp_path: Path,
) -> None:
    data = make_mcap(tmp_path / "a.mcap").read_bytes()
    _header, (second, op, length) = mcap_record_spans(data)[:2]
    with pytest.raises(
        RecordOverrun, match=f"record at {second - 8} declares {length} bytes, only 3 left"
    ) as err:
        list(records(data, 8, second + 9 + 3))
    assert (err.value.pos, err.value.op, err.value.length) == (second, op, length)
    with pytest.raises(RecordOverrun, match=f"record header at {second - 8} runs past the end") as err:
        list(records(data, 8, second + 4))
    assert err.value.op is None


def test_every_opcode_has_the_name_the_specification_gives_it() -> None:
    assert op_name(Opcode.CHUNK_INDEX) == "ChunkIndex" and op_name(0x06) == "Chunk"
    assert op_name(Opcode.DATA_END) == "DataEnd" and op_name(Opcode.SUMMARY_OFFSET) == "SummaryOffset"
    assert len({op_name(op) for op in Opcode}) == 15
    assert op_name(0x42) == "opcode 0x42"


def test_a_redefined_channel_and_a_message_on_no_channel_are_damage_and_a_chunk_is_checked_on_a_copy() -> (
    None
):
    defs = Definitions()
    defs.schema(0, 1, SchemaRecord("a.B", "jsonschema", b"{}"))
    defs.channel(0, 3, ChannelRecord("/x", 1, "json"))
    defs.channel(0, 3, ChannelRecord("/x", 1, "json"))  # a repeat of the same content is fine
    with pytest.raises(LogDamage, match=r"channel 3 defined again with other content") as err:
        defs.channel(77, 3, ChannelRecord("/y", 1, "json"))
    assert err.value.offset == 77 and not err.value.resync and err.value.kind is CorruptRecord
    with pytest.raises(LogDamage, match="message on channel 4, which was never defined"):
        defs.channel_of(0, 4)
    body = struct.pack("<HHI", 4, 1, 2) + b"/z" + struct.pack("<I", 4) + b"json" + struct.pack("<I", 0)
    channel = struct.pack("<BQ", Opcode.CHANNEL, len(body)) + body
    chunk = channel + struct.pack("<BQ", Opcode.MESSAGE, 22) + struct.pack("<HIQQ", 5, 0, 1, 1)
    with pytest.raises(LogDamage, match=f"message at byte {len(channel)} of the chunk on channel 5"):
        defs.check_chunk(parsed(chunk, 0, len(chunk), read_schema, read_channel), 99)
    assert 4 not in defs.channels  # the chunk's own definitions went to a copy


def _rewrite_summary_crc(data: bytearray) -> None:
    """The footer's summary CRC made that of the summary as it now is (after a test edited it)."""
    footer = mcap_record_spans(bytes(data))[-1][0]
    (start,) = struct.unpack_from("<Q", data, footer + 9)
    struct.pack_into("<I", data, footer + 9 + 16, zlib.crc32(bytes(data[start : footer + 9 + 16])))


def test_damage_raises_the_error_of_its_kind_all_of_them_log_errors(tmp_path: Path) -> None:
    log = make_mcap(tmp_path / "a.mcap", json_only=True)
    data = log.read_bytes()
    spans = mcap_record_spans(data)
    cases: dict[str, tuple[bytes, type[McapError], int]] = {"empty": (b"", NotMcap, 0)}
    cases["cut"] = (data[: len(data) // 2], TruncatedFile, -1)
    chunk = next(o for o, op, _ in spans if op == Opcode.CHUNK)
    flipped = bytearray(data)
    flipped[chunk + 9 + 40 + 20] ^= 0xFF  # inside the chunk's compressed records
    cases["crc"] = (bytes(flipped), CrcMismatch, chunk)
    stats_at = next(o for o, op, _ in spans if op == Opcode.STATISTICS)
    stale = bytearray(data)
    struct.pack_into("<Q", stale, stats_at + 9, 3)  # the message count
    _rewrite_summary_crc(stale)
    cases["stale"] = (bytes(stale), IndexMismatch, stats_at)
    for name, (content, kind, offset) in cases.items():
        path = tmp_path / f"{name}.mcap"
        path.write_bytes(content)
        with pytest.raises(kind) as err:
            mcap_reader.read(path)
        assert isinstance(err.value, LogError) and err.value.path == str(path), name
        assert offset < 0 or err.value.offset == offset, name


def test_a_summary_that_indexes_a_chunk_where_none_starts_is_named_by_the_checked_walk(
    tmp_path: Path,
) -> None:
    data = bytearray(make_mcap(tmp_path / "a.mcap").read_bytes())
    spans = mcap_record_spans(bytes(data))
    at = next(o for o, op, _ in spans if op == Opcode.CHUNK_INDEX)
    struct.pack_into("<Q", data, at + 9 + 16, 12345)  # the chunk start offset
    _rewrite_summary_crc(data)
    path = tmp_path / "index.mcap"
    path.write_bytes(bytes(data))
    assert (at, "a ChunkIndex points at offset 12345, where no chunk starts") in check_file(path)
    assert check_file(make_mcap(tmp_path / "clean.mcap")) == []
