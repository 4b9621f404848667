"""MCAP index and summary checks: an index that disagrees with the data is named and the data read,
a consistent index says nothing, a chunk deleted under an intact summary is refused."""

from __future__ import annotations

import struct
import zlib
from pathlib import Path

import pyarrow as pa
import pytest
from conftest import (
    OP_CHUNK_INDEX,
    OP_MESSAGE_INDEX,
    OP_SUMMARY_OFFSET,
    _summary_channel,
    chunks,
    fix_crcs,
    mcap_record_spans,
)
from conftest import mcap_record_spans as records

from lanecast.io_adapters.contracts import track_table
from lanecast.io_adapters.errors import LogError
from lanecast.io_adapters.logs.mcap import reader as mcap_reader
from lanecast.workflows.cli import main


def _chunk_index_start(d: bytearray) -> tuple[int, str]:
    recs = mcap_record_spans(bytes(d))
    at = [o for o, op, _ in recs if op == OP_CHUNK_INDEX][1]
    struct.pack_into("<Q", d, at + 9 + 16, chunks(bytes(d))[0])  # the second chunk's index → the first
    return at, "where no chunk starts|other message times|bytes, it has"


def _chunk_index_length(d: bytearray) -> tuple[int, str]:
    at = next(o for o, op, _ in mcap_record_spans(bytes(d)) if op == OP_CHUNK_INDEX)
    (length,) = struct.unpack_from("<Q", d, at + 9 + 24)
    struct.pack_into("<Q", d, at + 9 + 24, length + 16)
    return at, f"{length + 16} bytes, it has {length}"


def _chunk_index_message_index(d: bytearray) -> tuple[int, str]:
    at = next(o for o, op, _ in mcap_record_spans(bytes(d)) if op == OP_CHUNK_INDEX)
    struct.pack_into("<Q", d, at + 9 + 32 + 4 + 2, 8)  # its first channel's MessageIndex → the header
    return at, "where no MessageIndex record is"


def _message_index_entry(d: bytearray) -> tuple[int, str]:
    at = [o for o, op, _ in mcap_record_spans(bytes(d)) if op == OP_MESSAGE_INDEX][2]
    (offset,) = struct.unpack_from("<Q", d, at + 9 + 6 + 8)
    struct.pack_into("<Q", d, at + 9 + 6 + 8, offset + 1)
    return at, "points at no message of that channel"


def _summary_offset(d: bytearray) -> tuple[int, str]:
    at = next(o for o, op, _ in mcap_record_spans(bytes(d)) if op == OP_SUMMARY_OFFSET)
    (start,) = struct.unpack_from("<Q", d, at + 9 + 1)
    struct.pack_into("<Q", d, at + 9 + 1, start + 3)
    return at, "where no such group is"


def _footer_offsets(d: bytearray) -> tuple[int, str]:
    at = mcap_record_spans(bytes(d))[-1][0]
    (offsets,) = struct.unpack_from("<Q", d, at + 9 + 8)
    struct.pack_into("<Q", d, at + 9 + 8, offsets - 10)
    return at, "the footer puts the summary offsets at"


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


def test_a_chunk_deleted_under_an_intact_summary_is_refused_not_read_short(
    log: Path, table: pa.Table, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A chunk (with its message indexes) deleted and the summary's pointers moved to match: every
    CRC holds, so the file was read without that chunk's frames, exit 0 (fuzz2 family
    m_stale_summary). The summary's Statistics record counts the messages written: a data section
    holding another number is refused at that record; --salvage reads the chunks there are."""
    from lanecast.workflows.cli import main

    data = log.read_bytes()
    recs = mcap_record_spans(data)
    k = next(i for i, (_o, op, _n) in enumerate(recs) if op == 0x06 and i > 3)
    start, end = recs[k][0], recs[k][0] + 9 + recs[k][2]
    while recs[k + 1][1] == 0x07:
        k += 1
        end = recs[k][0] + 9 + recs[k][2]
    cut = bytearray(data[:start] + data[end:])
    footer = len(cut) - 8 - 29
    summary_start, offsets_start = struct.unpack_from("<QQ", cut, footer + 9)
    struct.pack_into("<QQ", cut, footer + 9, summary_start - (end - start), offsets_start - (end - start))
    pos = summary_start - (end - start)
    while pos < footer:  # summary offset records point into the summary
        op, n = struct.unpack_from("<BQ", cut, pos)
        if op == 0x0E:
            (group,) = struct.unpack_from("<Q", cut, pos + 10)
            struct.pack_into("<Q", cut, pos + 10, group - (end - start))
        pos += 9 + n
    data_end = next(o for o, op, _ in mcap_record_spans(bytes(cut)) if op == 0x0F)
    struct.pack_into("<I", cut, data_end + 9, zlib.crc32(bytes(cut[:data_end])))
    struct.pack_into(
        "<I", cut, footer + 25, zlib.crc32(bytes(cut[summary_start - (end - start) : footer + 25]))
    )
    bad = tmp_path / "stale.mcap"
    bad.write_bytes(bytes(cut))
    with pytest.raises(LogError, match="Statistics record counts") as err:
        mcap_reader.read(bad)
    assert err.value.offset is not None and err.value.offset > start
    out = tmp_path / "t.parquet"
    assert main(["convert", str(bad), "--out", str(out)]) == 2 and not out.exists()
    assert main(["convert", str(bad), "--salvage", "--out", str(out)]) == 0
    assert "Statistics record counts" in capsys.readouterr().err
    assert 0 < track_table.read_parquet(out).num_rows < table.num_rows
