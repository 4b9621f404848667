"""Parquet track tables and datasets on hostile input: metadata of wrong types or nesting, flipped
data bytes, page checksums, a part that is no Parquet, rows named in a table read in pieces."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
from conftest import HIGHD, _parquet, _set_row, assert_one_line_error, cli, refused

from lanecast.io_adapters.errors import InputError, LanecastError, TrackTableError
from lanecast.io_adapters.formats import registry


@pytest.mark.slow
def test_rows_named_in_a_large_table_are_rows_of_the_file(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A table of more than a million rows is read in pieces: NaN at row 1,050,000 was reported at
    the row of its piece ('row 50,000' or so), not of the file."""
    from conftest import make_track_table

    from lanecast.io_adapters.contracts import track_table

    tracks, frames = 1100, 1000
    frame = np.tile(np.arange(frames), tracks)
    x = frame * 3.0
    table = make_track_table(
        {
            "track_id": np.repeat(np.arange(tracks), frames),
            "frame": frame,
            "x": x,
            "y": np.zeros(x.size),
            "lane_id": np.ones(x.size),
        }
    )
    path = track_table.write_parquet(table, tmp_path / "table.parquet")
    pq.write_table(_set_row("x", 1_050_000, np.nan)(pq.read_table(path)), path, row_group_size=1 << 17)
    for command in ("convert", "windows"):
        refused(
            [command, str(path), "--out", str(tmp_path / command)],
            capsys,
            f"{path}: row 1050000: column 'x' is nan",
        )


@pytest.mark.parametrize(
    ("edit", "match"),
    [
        (lambda d: d["recordings"]["src"].update(frame_rate="abc"), "recordings.src.frame_rate"),
        (lambda d: d["recordings"]["src"].update(frame_rate=1e-9), r"recordings.src.frame_rate.*0.1 to 1000"),
        (
            lambda d: d["recordings"]["src"].update(frame_rate=1e308),
            r"recordings.src.frame_rate.*0.1 to 1000",
        ),
        (lambda d: d.update(source_files=1), "source_files"),
        (lambda d: d.pop("source_format"), "source_format"),
        (lambda d: d["recordings"].update(src=[]), "recordings.src"),
    ],
)
def test_parquet_metadata_with_wrong_types(tmp_path: Path, edit: object, match: str) -> None:
    path, table = _parquet(tmp_path)
    doc = json.loads(table.schema.metadata[b"lanecast"])
    edit(doc)  # type: ignore[operator]
    bad = table.replace_schema_metadata({b"lanecast": json.dumps(doc).encode()})
    pq.write_table(bad, path)
    with pytest.raises(TrackTableError, match=match) as err:
        registry.read_any([path])
    assert str(path) in str(err.value)


def test_parquet_metadata_deeply_nested(tmp_path: Path) -> None:
    path, table = _parquet(tmp_path)
    pq.write_table(table.replace_schema_metadata({b"lanecast": b"[" * 50_000 + b"]" * 50_000}), path)
    with pytest.raises(TrackTableError, match="nested 50000 levels"):
        registry.read_any([path])


def test_parquet_flipped_data_byte_is_detected(tmp_path: Path) -> None:
    """Every byte of the first column chunk's pages flipped in turn: refused or (header bytes the
    checksum does not cover) read back equal; never a different table."""
    path, _ = _parquet(tmp_path)
    good = registry.read_any([path])
    data = path.read_bytes()
    meta = pq.ParquetFile(path).metadata.row_group(0).column(4)  # x
    start = meta.data_page_offset
    refused = 0
    for offset in range(start, start + meta.total_compressed_size, 7):
        bad = bytearray(data)
        bad[offset] ^= 0x5A
        out = tmp_path / "flipped.parquet"
        out.write_bytes(bytes(bad))
        try:
            back = registry.read_any([out])
        except LanecastError:
            refused += 1
            continue
        assert back.equals(good)
    assert refused > 0


def test_parquet_written_with_page_checksums(tmp_path: Path) -> None:
    path, _ = _parquet(tmp_path)
    data = bytearray(path.read_bytes())
    col = pq.ParquetFile(path).metadata.row_group(0).column(4)
    end = col.data_page_offset + col.total_compressed_size
    data[end - 3] ^= 0xFF  # inside the compressed page body
    path.write_bytes(bytes(data))
    with pytest.raises(InputError, match=r"(?i)checksum|crc|corrupt|not a readable"):
        registry.read_any([path])


def test_values_are_identical_after_reading(tmp_path: Path) -> None:
    path, table = _parquet(tmp_path)
    back = registry.read_any([path])
    assert np.array_equal(back.column("x").to_numpy(), table.column("x").to_numpy())


@pytest.mark.parametrize("command", ["convert", "info"])
def test_a_dataset_part_that_is_no_parquet_is_named(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], command: str
) -> None:
    """A CSV saved under a part's name in a dataset directory made the whole directory "format not
    recognised", naming neither the part nor what is wrong with it."""
    dataset = tmp_path / "dataset"
    dataset.mkdir()
    _parquet(dataset)[0].rename(dataset / "part-00000.parquet")
    (dataset / "src.mcap").unlink()
    (dataset / "part-00001.parquet").write_bytes((HIGHD / "01_tracks.csv").read_bytes())
    args = [command, str(dataset)] + (
        ["--out", str(tmp_path / "out.parquet")] if command == "convert" else []
    )
    status, err = cli(args, capsys)
    assert_one_line_error(status, err, command, str(dataset / "part-00001.parquet"))
    assert "Parquet" in err and not (tmp_path / "out.parquet").exists()
