"""highD reader checks: values out of range, velocities against the motion of x, bad ids, lane
markings, frame rates and classes, damaged or missing files of a recording, the sister datasets;
each refused at its file, line and column, or read unchanged where the input is valid."""

from __future__ import annotations

import gzip
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from conftest import HIGHD, _highd, _highd_variant, convert_refused, highd_copy, no_output, refused, set_cell

from lanecast.io_adapters.datasets.highd import reader as highd
from lanecast.io_adapters.datasets.highd import stream as highd_stream
from lanecast.io_adapters.errors import InputError
from lanecast.io_adapters.formats import registry


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


def test_a_highd_integer_written_with_a_plus_sign_is_named_at_its_line(tmp_path: Path) -> None:
    """precedingId '+3' failed pyarrow's int64 parse while the diagnosis took it for an integer:
    "cannot parse as CSV: In CSV column #16 …", no line. Now its line and column are named."""
    path = _highd(tmp_path)
    _edit_csv(path, 7, "precedingId", "+3")
    with pytest.raises(InputError) as err:
        highd.read([path])
    assert err.value.path == str(path) and err.value.line == 8 and err.value.column == "precedingId"
    assert "cell '+3' is not an integer" in str(err.value)


def test_driving_direction_against_the_motion(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Vehicle 2 drives towards +x (xVelocity 20 m/s) but tracksMeta says drivingDirection 1: it
    was converted into a vehicle driving backwards in the upper recording's road frame."""
    rec = highd_copy(tmp_path, "tracksMeta", set_cell("drivingDirection", "1", {3}))
    out = tmp_path / "out.parquet"
    line = refused(
        ["convert", str(rec), "--out", str(out)],
        capsys,
        f"{rec / '01_tracksMeta.csv'}, line 3, column 'drivingDirection'",
        "vehicle 2",
        "20.00 m/s",
    )
    assert "expected 2" in line
    no_output(out)


@pytest.mark.parametrize(
    ("damage", "message"),
    [
        (lambda data: b"", "line 1: empty file"),
        (lambda data: data.decode().encode("utf-16"), "offset 0: the file is UTF-16 text"),
        (lambda data: gzip.compress(data), "offset 0: the file is gzip-compressed"),
        (lambda data: data.replace(b",", b";"), "line 1: the header is separated by ';'"),
        (lambda data: data.replace(b",", b"\t"), "line 1: the header is separated by tabs"),
    ],
)
def test_damaged_tracks_file_of_a_highd_directory_is_named(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], damage: Callable[[bytes], bytes], message: str
) -> None:
    """A recording directory whose 01_tracks.csv is empty, UTF-16, compressed or not comma-separated
    was 'format not recognised' for the directory; its companions make it highD, and the reader
    names the file and what is wrong with it."""
    rec = highd_copy(tmp_path)
    tracks = rec / "01_tracks.csv"
    tracks.write_bytes(damage(tracks.read_bytes()))
    out = tmp_path / "out.parquet"
    for target in (rec, tracks):
        refused(["convert", str(target), "--out", str(out)], capsys, f"{tracks}, {message}")
        no_output(out)


@pytest.mark.parametrize("replace", ["nothing", "a directory"])
def test_a_highd_directory_without_its_tracks_file_names_it(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], replace: str
) -> None:
    """A highD directory holding 01_tracksMeta.csv and 01_recordingMeta.csv but no 01_tracks.csv
    file (missing, or a directory of that name) was 'format not recognised' or 'no highD
    recording in this directory', naming neither the recording nor the file it lacks."""
    rec = highd_copy(tmp_path)
    (rec / "01_tracks.csv").unlink()
    if replace == "a directory":
        (rec / "01_tracks.csv").mkdir()
    line = convert_refused(rec, tmp_path, capsys, f"error: {rec / '01_tracks.csv'}: ")
    assert line.endswith("(expected the highD tracks CSV file)"), line


def test_a_blank_highd_class_is_refused(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """class '   ' (not empty, so not null) became a vehicle of class '' in the table."""
    rec = highd_copy(tmp_path, "tracksMeta", set_cell("class", "   ", {4}))
    convert_refused(rec, tmp_path, capsys, f"{rec / '01_tracksMeta.csv'}, line 4, column 'class'", "blank")


@pytest.mark.parametrize("rate", ["1e-9", "0.05", "1000000", "-25"])
def test_an_implausible_frame_rate_is_refused_at_its_cell(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], rate: str
) -> None:
    """frameRate 1e-9 Hz put frame 5 beyond int64 nanoseconds and was blamed on a frame of the
    tracks ('column frame: expected a frame from 0 to 4.612'); 1 MHz converted. The rate itself is
    refused at its line and column of the recordingMeta, with the range a rate may have."""
    rec = highd_copy(tmp_path, "recordingMeta", set_cell("frameRate", rate))
    convert_refused(
        rec,
        tmp_path,
        capsys,
        f"{rec / '01_recordingMeta.csv'}, line 2, column 'frameRate'",
        "highD's 25 Hz, or any rate from 0.1 to 1000 Hz",
    )


@pytest.mark.parametrize(
    ("column", "value", "expected"),
    [
        ("laneId", str(2**31), "within int32"),
        ("laneId", str(2**40), "within int32"),
        # lane changes are changes of laneId: -1, 0 or beyond the lower road edge (7) was a lane change
        # that never happened
        *(("laneId", lane, "a highD lane id, 1 to 7") for lane in ("-1", "0", "8")),
        ("width", "0.0", "a length > 0"),
        ("height", "-1.5", "a width > 0"),
        ("frame", "-3", "a frame from 0"),
        ("frame", str(2**62), "a frame from 0"),
        ("id", str(2**63), "within int64"),
        ("precedingId", "-3", "a vehicle id >= 0"),  # 0 is "none"; a negative id reached the table
        ("rightAlongsideId", "-1", "a vehicle id >= 0"),
    ],
)
def test_highd_values_out_of_range(tmp_path: Path, column: str, value: str, expected: str) -> None:
    path = _highd_variant(tmp_path, 3, column, value)
    with pytest.raises(InputError) as err:
        registry.read_any([path])
    assert err.value.path == str(path) and err.value.line == 3 and err.value.column == column
    assert expected in (err.value.expected or "")


@pytest.mark.parametrize("lane", ["1", "4", "2", "7"])
def test_highd_edge_median_and_other_carriageway_lanes_are_kept(tmp_path: Path, lane: str) -> None:
    """The road edges (1, 7), the median (4) or the other carriageway's lane (2) are areas of highD's
    numbering a real recording may place a vehicle in: read as given, not refused."""
    table = registry.read_any([_highd_variant(tmp_path, 3, "laneId", lane)])
    original = registry.read_any([HIGHD / "01_tracks.csv"])
    assert table.num_rows == original.num_rows
    changed = table.column("lane_id").to_numpy() != original.column("lane_id").to_numpy()
    assert changed.sum() == 1 and table.column("lane_id").to_numpy()[changed][0] == int(lane)


def test_a_recording_of_highds_sister_datasets_is_named_as_one(tmp_path: Path) -> None:
    """inD/rounD/exiD files (recordingId, trackId, xCenter; same file names as highD) were refused as
    a highD recordingMeta without column 'id', as if one column were missing."""
    (tmp_path / "00_tracks.csv").write_text(
        "recordingId,trackId,frame,trackLifetime,xCenter,yCenter,heading,width,length,xVelocity,yVelocity\n"
        "0,0,0,0,10.0,-5.0,90.0,1.8,4.5,0.0,2.0\n"
    )
    (tmp_path / "00_tracksMeta.csv").write_text(
        "recordingId,trackId,initialFrame,finalFrame,numFrames,width,length,class\n0,0,0,0,1,1.8,4.5,car\n"
    )
    (tmp_path / "00_recordingMeta.csv").write_text(
        "recordingId,locationId,frameRate,speedLimit,weekday,startTime,duration\n0,1,25,13.89,monday,8,1000\n"
    )
    with pytest.raises(InputError, match="highD's sister datasets \\(inD, rounD, exiD") as err:
        registry.read_any([tmp_path])
    assert err.value.path == str(tmp_path / "00_recordingMeta.csv") and err.value.line == 1
