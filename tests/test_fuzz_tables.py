"""Inputs found by fuzzing the dataset adapters (/tmp/tab/fuzz.py): the same file read whole and
piece by piece gives the same table or the same error; odd but real exports and track tables
written by other tools are read right or refused with one error naming the file and where."""

from __future__ import annotations

import shutil
import zipfile
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from lanecast.io_adapters.contracts import track_table
from lanecast.io_adapters.datasets.highd import reader as highd
from lanecast.io_adapters.datasets.highd import stream as highd_stream
from lanecast.io_adapters.datasets.ngsim import reader as ngsim
from lanecast.io_adapters.datasets.ngsim import stream as ngsim_stream
from lanecast.io_adapters.errors import InputError, TrackTableError
from lanecast.io_adapters.formats import registry, streaming
from lanecast.models import card
from lanecast.workflows.cli import main

HEADER = (
    "Vehicle_ID,Frame_ID,Total_Frames,Global_Time,Local_X,Local_Y,Global_X,Global_Y,v_length,v_Width,"
    "v_Class,v_Vel,v_Acc,Lane_ID,O_Zone,D_Zone,Int_ID,Section_ID,Direction,Movement,Preceding,Following,"
    "Space_Headway,Time_Headway,Location"
)
EPOCH = 1118846980000  # US-101's first period (ms)


def _rows(
    vehicle: int, frames: range, y0: float, step: float, epoch: int = EPOCH, loc: str = "us-101"
) -> list[str]:
    """CSV-export rows of one vehicle whose Local_Y moves ``step`` ft per frame."""
    return [
        f"{vehicle},{f},{len(frames)},{epoch + 100 * f},18.0,{y0 + step * (f - frames[0]):.3f},"
        f"6451155.641,1873444.255,15.0,6.0,2,40.0,0.0,2,,,,,,,0,0,0.0,0.0,{loc}"
        for f in frames
    ]


def _export(tmp_path: Path, rows: list[str]) -> Path:
    path = tmp_path / "export.csv"
    path.write_text("\n".join([HEADER, *rows]) + "\n")
    return path


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


HIGHD = Path(__file__).parent / "data" / "highd"
HIGHD_HEADER = (
    "frame,id,x,y,width,height,xVelocity,yVelocity,xAcceleration,yAcceleration,frontSightDistance,"
    "backSightDistance,dhw,thw,ttc,precedingXVelocity,precedingId,followingId,leftPrecedingId,"
    "leftAlongsideId,leftFollowingId,rightPrecedingId,rightAlongsideId,rightFollowingId,laneId"
)


def _highd(tmp_path: Path, *, velocity: float = 1.0, position: float = 1.0, frame_rate: str = "25") -> Path:
    """A highD recording of two cars, 2.4 s at 30 m/s each way (25 Hz), velocities scaled by
    ``velocity``, positions by ``position``, recordingMeta's frameRate ``frame_rate``."""
    rows = []
    for vid, vx, y, lane in ((1, 30.0, 15.2, 6), (2, -30.0, 5.0, 2)):
        for k in range(60):
            x = (100.0 + vx * k / 25) * position
            rows.append(
                f"{k + 1},{vid},{x:.3f},{y * position:.3f},4.50,2.00,{vx * velocity:.3f},0.00,0.00,0.00,"
                f"0,0,0,0,0,0,0,0,0,0,0,0,0,0,{lane}"
            )
    (tmp_path / "01_tracks.csv").write_text("\n".join([HIGHD_HEADER, *rows]) + "\n")
    meta = (HIGHD / "01_tracksMeta.csv").read_text().splitlines()[0]
    (tmp_path / "01_tracksMeta.csv").write_text(
        f"{meta}\n1,4.50,2.00,1,60,60,Car,2,58.8,30,30,30,0,0,-1,0\n2,4.50,2.00,1,60,60,Car,1,58.8,-30,-30,-30,0,0,-1,0\n"
    )
    recording_meta = (HIGHD / "01_recordingMeta.csv").read_text().splitlines()
    cells = recording_meta[1].split(",")
    cells[1] = frame_rate
    (tmp_path / "01_recordingMeta.csv").write_text("\n".join([recording_meta[0], ",".join(cells)]) + "\n")
    return tmp_path / "01_tracks.csv"


@pytest.mark.parametrize(
    ("edit", "vehicle", "said", "moved"),
    [
        ({"velocity": 3.6}, 1, "108.00", "30.00"),  # velocities in km/h
        ({"position": 3.2808}, 1, "30.00", "98.42"),  # positions in feet
        ({"frame_rate": "50"}, 1, "30.00", "60.00"),  # a 25 Hz recording said to be 50 Hz
    ],
)
def test_highd_velocities_that_disagree_with_the_motion_of_x_are_refused(
    tmp_path: Path, edit: dict[str, Any], vehicle: int, said: str, moved: str
) -> None:
    """xVelocity in km/h (or x in feet, or a wrong frameRate) was converted as it came: a track
    table whose vx is 3.6 times the speed its x moves at (a 108 m/s car), exit 0. Now refused at
    the track's first line, whole and in pieces."""
    path = _highd(tmp_path, **edit)
    with pytest.raises(InputError) as whole:
        highd.read([path])
    err = whole.value
    assert err.path == str(path) and err.line == 2 and err.column == "xVelocity"
    assert f"vehicle {vehicle}: xVelocity averages {said} m/s but its x moves {moved} m/s" in str(err)
    with pytest.raises(InputError) as pieces:
        highd_stream.split_tracks(highd.recordings([path])[0], tmp_path / "spill", block_bytes=1 << 10)
    assert str(pieces.value) == str(err)


def test_highd_tracks_whose_velocity_agrees_with_x_are_read(tmp_path: Path) -> None:
    table = highd.read([_highd(tmp_path)])
    assert table.num_rows == 120
    np.testing.assert_allclose(table.column("vx").to_numpy(), 30.0)


def test_an_export_zipped_without_compression_under_a_csv_name_is_named_a_zip(tmp_path: Path) -> None:
    """A zip archive that stores its member uncompressed starts with the member's header line: it
    was taken for an NGSIM CSV and refused as "missing column 'vehicle_id'" (a column it has); now
    the format is not recognised and the file is named a zip archive."""
    inner = _export(tmp_path, _rows(1, range(10, 50), 100.0, 4.0)).read_bytes()
    path = tmp_path / "us-101.csv"
    with zipfile.ZipFile(path, "w") as archive:  # ZIP_STORED
        archive.writestr(zipfile.ZipInfo("ngsim-export.csv", (2005, 6, 15, 7, 50, 0)), inner)
    assert inner.splitlines()[0] in path.read_bytes().splitlines()[0]  # the header on the first line
    with pytest.raises(InputError) as err:
        registry.read_any([path])
    assert err.value.path == str(path) and err.value.offset == 0
    assert "format not recognised: the file is a zip archive" in str(err.value)


def test_a_missing_direction_written_as_blanks_is_read_as_missing(tmp_path: Path) -> None:
    """A CSV export written with a space after each comma has `` `` for an empty Direction: it was
    refused as "cannot parse: In CSV column #18 …" (no line, no column name); now read as a missing
    Direction, the same table as the export without the spaces."""
    rows = _rows(1, range(10, 50), 100.0, 4.0) + _rows(2, range(10, 50), 300.0, 5.0)
    plain = ngsim.read([_export(tmp_path, rows)])
    spaced = tmp_path / "spaced" / "export.csv"
    spaced.parent.mkdir()
    spaced.write_text("\n".join(", ".join(line.split(",")) for line in [HEADER, *rows]) + "\n")
    table = ngsim.read([spaced])
    for name in ("x", "y", "vx", "heading", "track_id", "frame"):
        np.testing.assert_array_equal(
            table.column(name).to_numpy(), plain.column(name).to_numpy(), err_msg=name
        )


@pytest.mark.parametrize(("sep", "named"), [(";", "';'"), ("\t", "tabs")])
def test_an_export_saved_with_semicolons_or_tabs_is_named_as_such(
    tmp_path: Path, sep: str, named: str
) -> None:
    """A spreadsheet in a European locale saves the export with ';' and decimal commas (or as
    tab-separated text): it was "format not recognised" with no hint; now the header's separator
    is named at line 1."""
    lines = [HEADER, *_rows(1, range(10, 50), 100.0, 4.0)]
    path = tmp_path / "export.csv"
    path.write_text("\n".join(line.replace(",", sep) for line in lines).replace(".", ",") + "\n")
    with pytest.raises(InputError) as err:
        registry.read_any([path])
    assert err.value.path == str(path) and err.value.line == 1
    assert f"the header is separated by {named}" in str(err.value)


def _edit_csv(path: Path, row: int, column: str, value: str) -> None:
    lines = path.read_text().splitlines()
    names = lines[0].split(",")
    cells = lines[row].split(",")
    cells[names.index(column)] = value
    lines[row] = ",".join(cells)
    path.write_text("\n".join(lines) + "\n")


def test_a_highd_vehicle_id_0_is_refused(tmp_path: Path) -> None:
    """Vehicle ids from 0 (a user's own export) were converted, but 0 is "no vehicle" in the
    neighbour columns: every vehicle behind vehicle 0 lost its precedingId. Now refused at the
    first row of vehicle 0."""
    path = _highd(tmp_path)
    lines = path.read_text().splitlines()
    path.write_text(
        "\n".join([lines[0], *(line.replace(",1,", ",0,", 1) for line in lines[1:61]), *lines[61:]])
    )
    _edit_csv(tmp_path / "01_tracksMeta.csv", 1, "id", "0")
    with pytest.raises(InputError) as err:
        highd.read([path])
    assert err.value.path == str(path) and err.value.line == 2 and err.value.column == "id"
    assert "id is 0" in str(err.value) and ">= 1" in (err.value.expected or "")


@pytest.mark.parametrize("markings", ["11.00;4.00;7.50", "4.00;4.00;11.00"])
def test_highd_lane_markings_out_of_order_are_refused(tmp_path: Path, markings: str) -> None:
    """Lane markings out of order (or one twice) were kept as given in the recording's metadata
    (lane_markings_y), where the lanes between them are upside down or of zero width; now
    refused at recordingMeta's line 2, naming the column."""
    path = _highd(tmp_path)
    meta = tmp_path / "01_recordingMeta.csv"
    _edit_csv(meta, 1, "upperLaneMarkings", markings)
    with pytest.raises(InputError) as err:
        highd.read([path])
    assert err.value.path == str(meta) and err.value.line == 2 and err.value.column == "upperLaneMarkings"
    assert "not in increasing order" in str(err.value)


@pytest.mark.parametrize(("kept", "missing"), [(".json", ".safetensors"), (".safetensors", ".json")])
def test_a_model_directory_with_one_half_of_a_model_names_the_missing_file(
    tmp_path: Path, kept: str, missing: str
) -> None:
    """A model directory holding the card but not the weights (or the reverse: one file copied)
    said "found none" as if it held nothing of a model; now it names the file without its pair."""
    stem = card.SHIPPED_STEM
    shutil.copy(card.WEIGHTS_DIR / f"{stem}{kept}", tmp_path / f"{stem}{kept}")
    with pytest.raises(InputError) as err:
        card.resolve(tmp_path)
    assert err.value.path == str(tmp_path)
    assert f"found {stem}{kept} without {stem}{missing}" in str(err.value)


@pytest.mark.parametrize(
    ("rate", "time_scale", "implied"),
    [(50.0, 1, "(25 Hz), but the recording's frame_rate is 50 Hz"), (25.0, 1000, "(2.5e+04 Hz)")],
)
def test_a_track_table_whose_times_disagree_with_its_frame_rate_is_refused(
    tmp_path: Path, rate: float, time_scale: int, implied: str
) -> None:
    """A Parquet track table written by another tool with a recording's frame_rate 50 over times of
    frame / 25 (or time_ns in microseconds) was read, converted and summarised; `windows` then
    failed with "longest gap-free track is 1 frame(s)". Now refused at the track's first row."""
    table = highd.read([_highd(tmp_path)])
    meta = track_table.read_meta(table)
    for rec in meta.recordings.values():
        rec.frame_rate = rate
    time = table.column("time_ns").to_numpy() // time_scale
    i = table.schema.get_field_index("time_ns")
    table = table.set_column(i, table.schema.field("time_ns"), pa.array(time)).replace_schema_metadata(
        {track_table.META_KEY: meta.to_json().encode()}
    )
    path = tmp_path / "other-tool.parquet"
    pq.write_table(table, path)
    with pytest.raises(TrackTableError) as err:
        registry.read_any([path])
    message = str(err.value)
    assert message.startswith(f"{path}: row 0: track 1 of recording 'highd-01-lower' advances 59 frames")
    assert implied in message and "expected time_ns = frame / frame_rate" in message


def test_a_highd_companion_that_is_a_symlink_loop_is_named_a_loop(tmp_path: Path) -> None:
    """01_tracksMeta.csv as a link to itself was "a symbolic link to a missing file"; now "a
    symbolic link loop" (what the user has to untangle)."""
    path = _highd(tmp_path)
    meta = tmp_path / "01_tracksMeta.csv"
    meta.unlink()
    meta.symlink_to(meta.name)
    with pytest.raises(InputError) as err:
        highd.read([path])
    assert err.value.path == str(meta) and "a symbolic link loop" in str(err.value)


def test_a_highd_row_moved_to_the_end_reads_the_same_in_pieces(tmp_path: Path) -> None:
    """One row of vehicle 1 moved to the end of the file: the whole read sorts it back; read in
    pieces (a recording of 256 MiB and more) the block with vehicle 1's other rows was refused
    ("numFrames 60 … disagrees … 59 rows") although the whole file reads cleanly. Now the pieces
    read gives the whole read's table."""
    path = _highd(tmp_path)
    lines = path.read_text().splitlines()
    path.write_text("\n".join([*lines[:10], *lines[11:], lines[10]]) + "\n")
    whole = highd.read([path])
    (tmp_path / "spill").mkdir()
    spills = highd_stream.split_tracks(highd.recordings([path])[0], tmp_path / "spill", block_bytes=1 << 10)
    streamed = track_table.concat([track_table.read_parquet(p) for p in spills])
    assert streamed.num_rows == whole.num_rows == 120
    for name in ("x", "vx", "track_id", "frame"):
        np.testing.assert_array_equal(streamed.column(name).to_numpy(), whole.column(name).to_numpy())


def test_a_highd_integer_written_with_a_plus_sign_is_named_at_its_line(tmp_path: Path) -> None:
    """precedingId '+3' failed pyarrow's int64 parse while the diagnosis took it for an integer:
    "cannot parse as CSV: In CSV column #16 …", no line. Now its line and column are named."""
    path = _highd(tmp_path)
    _edit_csv(path, 7, "precedingId", "+3")
    with pytest.raises(InputError) as err:
        highd.read([path])
    assert err.value.path == str(path) and err.value.line == 8 and err.value.column == "precedingId"
    assert "cell '+3' is not an integer" in str(err.value)


def test_recordings_read_in_pieces_come_in_the_whole_reads_order(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Locations 'i' and 'i-80' in one export: the whole read orders recordings by name
    (ngsim-i-80-… first), the pieces came in location order ('i' first), so `convert` wrote the
    same rows in another order for a file of 256 MiB and more. Now the pieces come in the whole
    read's order and both files hold the rows in one order."""
    rows = _rows(1, range(10, 50), 100.0, 4.0, loc="i") + _rows(2, range(10, 50), 100.0, 4.0, loc="i-80")
    path = _export(tmp_path, rows)
    written = []
    for stream_bytes in (streaming.STREAM_BYTES, 0):
        monkeypatch.setattr(streaming, "STREAM_BYTES", stream_bytes)
        out = tmp_path / f"out-{stream_bytes}.parquet"
        assert main(["convert", str(path), "--out", str(out)]) == 0
        written.append(pq.read_table(out))
    whole, pieces = written
    assert whole.column("recording").to_pylist()[0] == "ngsim-i-80-export"
    assert pieces.column("recording").to_pylist() == whole.column("recording").to_pylist()
    np.testing.assert_array_equal(pieces.column("x").to_numpy(), whole.column("x").to_numpy())


def test_a_location_on_one_row_only_is_refused_whole_and_in_pieces(tmp_path: Path) -> None:
    """One row's Location gone bad ('mars' amid US-101 rows) made a phantom recording
    'ngsim-mars-export' of one row and cut a frame out of its vehicle's track; now refused at
    its line, whole and in pieces."""
    rows = _rows(1, range(10, 50), 100.0, 4.0) + _rows(2, range(10, 50), 300.0, 5.0)
    rows[20] = rows[20].rsplit(",", 1)[0] + ",mars"
    err = _same_error(_export(tmp_path, rows), tmp_path)
    assert err.line == 22 and err.column == "Location"
    assert "Location 'mars' on 1 row(s) only" in str(err) and "us-101" in (err.expected or "")
