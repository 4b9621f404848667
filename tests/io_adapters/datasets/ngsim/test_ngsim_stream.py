"""The NGSIM reader of large exports (read in pieces) applies the checks of the whole read: wrong-way
vehicles, rows in periods of their own, locations on one row; a clean export reads the same."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from conftest import EPOCH, _export, _rows

from lanecast.io_adapters.contracts import track_table
from lanecast.io_adapters.datasets.ngsim import reader as ngsim
from lanecast.io_adapters.datasets.ngsim import stream as ngsim_stream
from lanecast.io_adapters.errors import InputError
from lanecast.io_adapters.formats import streaming


def _streamed(path: Path, tmp_path: Path, **options: object) -> list[streaming.Piece]:
    """The pieces of ``path`` as the reader of large exports cuts it (threshold 0 bytes)."""
    return streaming.plan([path], spill_dir=tmp_path / "spill", stream_bytes=0, options=options)


def _same_error(path: Path, tmp_path: Path) -> InputError:
    with pytest.raises(InputError) as whole:
        ngsim.read([path])
    with pytest.raises(InputError) as pieces:
        _streamed(path, tmp_path)
    assert str(pieces.value) == str(whole.value)
    return whole.value


def test_a_wrong_way_freeway_vehicle_is_refused_by_the_reader_of_large_exports(tmp_path: Path) -> None:
    """A US-101 CSV export of 256 MiB and more (read in pieces) with a vehicle whose Local_Y falls
    4 ft a frame was converted (x falling at 12 m/s, vx +12 m/s) where the same file under 256 MiB
    was refused; now both refuse it at the vehicle's first line."""
    path = _export(tmp_path, _rows(1, range(10, 50), 100.0, 4.0) + _rows(2, range(10, 50), 900.0, -4.0))
    err = _same_error(path, tmp_path)
    assert err.line == 42 and err.column == "Local_Y"
    assert "vehicle 2 drives backwards on a one-way freeway" in str(err)


def test_a_row_in_a_period_of_its_own_is_refused_by_the_reader_of_large_exports(tmp_path: Path) -> None:
    """One Global_Time 9 s off its vehicle's epoch made a phantom one-row recording ``…-p2`` when
    the export was read in pieces (the whole read refused it); now both refuse it at its line."""
    rows = _rows(1, range(10, 50), 100.0, 4.0)
    rows[20] = rows[20].replace(f",{EPOCH + 100 * 30},", f",{EPOCH + 9000 + 100 * 30},")
    err = _same_error(_export(tmp_path, rows), tmp_path)
    assert err.line == 22 and err.column == "Global_Time" and "recording period of its own" in str(err)


def test_a_stray_row_next_to_its_frames_in_another_period_is_refused_in_pieces(tmp_path: Path) -> None:
    """Two real periods; one row of vehicle 1 carries the second period's epoch between its own
    frames: in pieces it became a one-row track of the second recording; now refused as whole."""
    second = EPOCH + 3_600_000
    rows = _rows(1, range(10, 50), 100.0, 4.0) + _rows(7, range(10, 50), 100.0, 4.0, epoch=second)
    rows[20] = rows[20].replace(f",{EPOCH + 100 * 30},", f",{second + 100 * 30},")
    err = _same_error(_export(tmp_path, rows), tmp_path)
    assert err.line == 22 and err.column == "Global_Time"
    assert "another recording period than its neighbouring frame (line 21)" in str(err)


def test_a_location_kept_by_option_has_the_same_periods_read_whole_or_in_pieces(tmp_path: Path) -> None:
    """--location us-101 on an export whose Peachtree epochs lie between US-101's two periods: in
    pieces the periods were clustered over every location's epochs (one US-101 recording of two
    periods, frames repeated), whole over the kept rows (two recordings); now both give two."""
    gap = ngsim.PERIOD_GAP
    rows = _rows(1, range(10, 50), 100.0, 4.0) + _rows(2, range(10, 50), 100.0, 4.0, epoch=EPOCH + 3 * gap)
    bridge = [
        row
        for k in (1, 2)
        for row in _rows(10 + k, range(10, 50), 100.0, 4.0, epoch=EPOCH + k * gap, loc="peachtree")
    ]
    path = _export(tmp_path, rows + bridge)
    whole = ngsim.read([path], location="us-101")
    pieces = _streamed(path, tmp_path, location="us-101")
    names = [track_table.recording_codes(p.read())[0].tolist() for p in pieces]
    assert names == [["ngsim-us-101-export-p1"], ["ngsim-us-101-export-p2"]]
    streamed = track_table.concat(p.read() for p in pieces)
    assert track_table.recording_codes(whole)[0].tolist() == [n[0] for n in names]
    np.testing.assert_array_equal(streamed.column("x").to_numpy(), whole.column("x").to_numpy())


def test_a_clean_freeway_export_reads_the_same_in_pieces(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The checks added to the reader of large exports keep clean files as they were."""
    monkeypatch.setattr(ngsim_stream, "BLOCK_BYTES", 1 << 12)  # several blocks
    second = EPOCH + 3_600_000
    rows = _rows(1, range(10, 50), 100.0, 4.0) + _rows(1, range(10, 13), 100.0, 4.0, epoch=second)
    path = _export(tmp_path, rows)
    whole = ngsim.read([path])
    streamed = track_table.concat(p.read() for p in _streamed(path, tmp_path))
    assert streamed.num_rows == whole.num_rows == 43
    np.testing.assert_array_equal(streamed.column("x").to_numpy(), whole.column("x").to_numpy())


def test_a_location_on_one_row_only_is_refused_whole_and_in_pieces(tmp_path: Path) -> None:
    """One row's Location gone bad ('mars' amid US-101 rows) made a phantom recording
    'ngsim-mars-export' of one row and cut a frame out of its vehicle's track; now refused at
    its line, whole and in pieces."""
    rows = _rows(1, range(10, 50), 100.0, 4.0) + _rows(2, range(10, 50), 300.0, 5.0)
    rows[20] = rows[20].rsplit(",", 1)[0] + ",mars"
    err = _same_error(_export(tmp_path, rows), tmp_path)
    assert err.line == 22 and err.column == "Location"
    assert "Location 'mars' on 1 row(s) only" in str(err) and "us-101" in (err.expected or "")
