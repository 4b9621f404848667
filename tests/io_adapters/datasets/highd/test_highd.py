"""highD adapter: road-frame values computed by hand on a 4-vehicle fixture, sniffing, the CLI,
and one precise InputError (file, line, column) per kind of bad input.

Fixture ``tests/data/highd/01_*.csv`` (25 Hz, frames 1-based): lines of ``01_tracks.csv``
2–6 vehicle 1 (car, lower, frames 1–5, lane 5 → 6 at frame 5), 7–9 vehicle 2 (truck, lower,
frames 2–4), 10–12 vehicle 3 (car, upper, frames 1–3), 13–15 vehicle 4 (car, upper, frames 1–3,
nearly stopped at frame 3).
"""

from __future__ import annotations

import gzip
import math
import os
import shutil
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pyarrow as pa
import pytest
from conftest import TESTS

from lanecast.io_adapters.contracts import track_table
from lanecast.io_adapters.datasets.highd import reader as highd
from lanecast.io_adapters.errors import InputError
from lanecast.io_adapters.formats import registry
from lanecast.workflows import cli

DATA = TESTS / "data" / "highd"


FILES = ("01_tracks.csv", "01_tracksMeta.csv", "01_recordingMeta.csv")


def _rows(table: pa.Table, recording: str, track: int) -> dict[str, list]:
    """The columns of one track as Python lists (rows sorted by frame)."""
    names = np.asarray(table.column("recording").cast(pa.string()).to_pylist())
    mask = (names == recording) & (table.column("track_id").to_numpy() == track)
    return table.filter(pa.array(mask)).to_pydict()


@pytest.fixture(scope="module")
def table() -> pa.Table:
    return highd.read([DATA])


# ------------------------------------------------------------------ values computed by hand


def test_lower_car_with_lane_change_in_road_frame(table: pa.Table) -> None:
    # Lower lanes drive towards +x: road = (x_img, -y_img). Vehicle 1: box 4.50 x 2.00 at
    # x = 10.00 + 1.20 k, y = 15.20 + 0.40 k -> centre (12.25 + 1.2 k, 16.2 + 0.4 k).
    r = _rows(table, "highd-01-lower", 1)
    assert r["frame"] == [1, 2, 3, 4, 5]
    assert r["time_ns"] == [40_000_000, 80_000_000, 120_000_000, 160_000_000, 200_000_000]
    assert r["x"] == pytest.approx([12.25, 13.45, 14.65, 15.85, 17.05], abs=1e-9)
    assert r["y"] == pytest.approx([-16.2, -16.6, -17.0, -17.4, -17.8], abs=1e-9)
    assert r["vx"] == pytest.approx([30.0] * 5)
    assert r["vy"] == pytest.approx([-1.0] * 5)  # yVelocity +1.00 (image down) = to the right
    assert r["ax"] == pytest.approx([0.5] * 5)
    assert r["ay"] == pytest.approx([-0.1] * 5)
    # atan2(-1, 30) = -atan(1/30)
    assert r["heading"] == pytest.approx([-0.0333209958782472] * 5, rel=1e-6)
    assert r["length"] == pytest.approx([4.5] * 5)
    assert r["width"] == pytest.approx([2.0] * 5)
    assert r["lane_id"] == [5, 5, 5, 5, 6]
    assert r["object_class"] == ["car"] * 5
    assert r["right_preceding_id"] == [None, 2, 2, 2, None]  # highD 0 -> null
    assert r["preceding_id"] == [None] * 5
    assert r["left_alongside_id"] == [None] * 5


def test_lower_truck(table: pa.Table) -> None:
    # Vehicle 2: box 12.00 x 2.50 at x = 30.00, 30.80, 31.60, y = 18.50.
    r = _rows(table, "highd-01-lower", 2)
    assert r["frame"] == [2, 3, 4]
    assert r["x"] == pytest.approx([36.0, 36.8, 37.6], abs=1e-9)
    assert r["y"] == pytest.approx([-19.75] * 3, abs=1e-9)
    assert r["vx"] == pytest.approx([20.0] * 3)
    assert r["vy"] == [0.0] * 3
    assert r["ax"] == pytest.approx([-0.2] * 3)
    assert r["heading"] == [0.0] * 3
    assert [math.copysign(1.0, h) for h in r["heading"]] == [1.0] * 3  # no negative zero
    assert (r["length"], r["width"]) == ([12.0] * 3, [2.5] * 3)
    assert r["object_class"] == ["truck"] * 3  # "Truck" lower-cased
    assert r["left_following_id"] == [1, 1, 1]
    assert r["lane_id"] == [6, 6, 6]


def test_upper_vehicles_rotated_by_180_degrees(table: pa.Table) -> None:
    # Upper lanes drive towards -x: road = (-x_img, +y_img).
    # Vehicle 3: box 4.00 x 1.80 at x = 100.00, 98.80, 97.60, y = 6.00 -> centre (102.0 - 1.2 k, 6.9).
    r = _rows(table, "highd-01-upper", 3)
    assert r["frame"] == [1, 2, 3]
    assert r["time_ns"] == [40_000_000, 80_000_000, 120_000_000]
    assert r["x"] == pytest.approx([-102.0, -100.8, -99.6], abs=1e-9)
    assert r["y"] == pytest.approx([6.9] * 3, abs=1e-9)
    assert r["vx"] == pytest.approx([30.0] * 3)  # xVelocity -30.00
    assert r["vy"] == pytest.approx([0.5] * 3)  # yVelocity +0.50 (image down) = to the left
    assert r["ax"] == pytest.approx([0.4] * 3)  # xAcceleration -0.40
    assert r["heading"] == pytest.approx([0.016665123713940] * 3, rel=1e-6)  # atan(0.5 / 30)
    assert r["preceding_id"] == [4, 4, 4]
    assert r["following_id"] == [None] * 3
    assert r["lane_id"] == [2, 2, 2]
    # Vehicle 4: box 5.00 x 2.00 at x = 80, 79, 78, y = 5.80; at frame 3 it crawls at
    # (-0.30, 0.20) m/s: speed 0.36 < 0.5 m/s, so heading 0.
    r = _rows(table, "highd-01-upper", 4)
    assert r["x"] == pytest.approx([-82.5, -81.5, -80.5], abs=1e-9)
    assert r["y"] == pytest.approx([6.8] * 3, abs=1e-9)
    assert r["vx"] == pytest.approx([25.0, 25.0, 0.3])
    assert r["vy"] == pytest.approx([0.0, 0.0, 0.2])
    assert r["ax"] == pytest.approx([-0.3] * 3)
    assert r["ay"] == pytest.approx([-0.2] * 3)  # yAcceleration -0.20, upper: unchanged sign
    assert r["heading"] == [0.0, 0.0, 0.0]
    assert r["following_id"] == [3, 3, 3]


def test_recordings_and_metadata(table: pa.Table) -> None:
    track_table.validate(table)
    assert table.num_rows == 14
    assert set(table.column("recording").cast(pa.string()).to_pylist()) == {
        "highd-01-lower",
        "highd-01-upper",
    }
    meta = track_table.read_meta(table)
    assert meta.source_format == "highd"
    assert meta.frame_rate == 25.0
    assert sorted(meta.recordings) == ["highd-01-lower", "highd-01-upper"]
    assert sorted(Path(p).name for p in meta.source_files) == sorted(FILES)
    lower, upper = meta.recordings["highd-01-lower"], meta.recordings["highd-01-upper"]
    assert (lower.frame_rate, lower.coordinate_frame) == (25.0, "road")
    # lower markings 14.00;17.50;21.00 -> -y, sorted right to left
    assert lower.extra["lane_markings_y"] == [-21.0, -17.5, -14.0]
    assert lower.extra["lane_markings_raw"] == [14.0, 17.5, 21.0]
    assert upper.extra["lane_markings_y"] == [4.0, 7.5, 11.0]
    assert (lower.extra["driving_direction"], upper.extra["driving_direction"]) == (2, 1)
    assert lower.extra["speed_limit_mps"] is None  # -1.00 = no limit
    assert lower.extra["location_id"] == 2
    assert upper.extra["road_from_image"] == [[-1.0, 0.0], [0.0, 1.0]]
    units = {f.name: f.metadata[b"unit"].decode() for f in table.schema if f.metadata}
    assert units["x"] == "m" and units["vx"] == "m/s" and units["ax"] == "m/s^2"
    assert units["heading"] == "rad" and units["time_ns"] == "ns"
    # the vehicle in lane 5 between markings -17.5 and -14.0, its lane change where it crosses -17.5
    assert list(track_table.lane_change_rows(table)) == [4]


def test_any_file_of_a_recording_or_its_directory(table: pa.Table) -> None:
    for paths in ([DATA / FILES[0]], [DATA / FILES[1]], [DATA / f for f in FILES], [DATA, DATA / FILES[2]]):
        assert highd.read(paths).equals(table, check_metadata=True)


def test_several_recordings(tmp_path: Path) -> None:
    for prefix in ("01", "02"):
        for name in FILES:
            shutil.copy(DATA / name, tmp_path / name.replace("01", prefix))
    meta = tmp_path / "02_recordingMeta.csv"  # recording 2's own id, as highD writes it
    head, row, *rest = meta.read_text().splitlines(keepends=True)
    meta.write_text("".join([head, "2" + row[row.index(",") :], *rest]))
    t = highd.read([tmp_path])
    names = sorted(set(t.column("recording").cast(pa.string()).to_pylist()))
    assert names == ["highd-01-lower", "highd-01-upper", "highd-02-lower", "highd-02-upper"]
    assert t.num_rows == 28
    assert len(track_table.read_meta(t).source_files) == 6


def test_identical_duplicate_rows_are_dropped(tmp_path: Path, table: pa.Table) -> None:
    def duplicate(lines: list[str]) -> list[str]:
        return [*lines[:5], lines[3], *lines[5:], lines[11]]

    t = highd.read([_variant(tmp_path, "01_tracks.csv", duplicate)])
    assert t.equals(table, check_metadata=False)


def test_one_direction_only(tmp_path: Path) -> None:
    """A recording whose vehicles all drive one way (e.g. a simulation) gives one recording."""
    edits = {
        "01_tracks.csv": lambda lines: lines[:9],
        "01_tracksMeta.csv": lambda lines: lines[:3],
        "01_recordingMeta.csv": lambda lines: [lines[0], lines[1].replace("4.00;7.50;11.00", "")],
    }
    for name, edit in edits.items():
        _variant(tmp_path, name, edit)
    t = highd.read([tmp_path])
    assert sorted(track_table.read_meta(t).recordings) == ["highd-01-lower"]
    assert t.num_rows == 8
    parts = _parts([tmp_path], 100)
    assert len(parts) == 1 and parts[0][0].equals(t, check_metadata=True)


def _parts(paths: list[Path], part_rows: int) -> list[tuple[pa.Table, bool]]:
    return list(highd.read_parts(paths, part_rows=part_rows))


@pytest.mark.parametrize("part_rows", [1, 2, 3, 5, 8, 100])
def test_parts_hold_the_table_read_gives_in_its_order(table: pa.Table, part_rows: int) -> None:
    """Parts of whole tracks of one recording each, at most part_rows rows but for a longer track,
    the first of each recording not continuing: put together, read's table, row for row."""
    parts = _parts([DATA], part_rows)
    joined = pa.concat_tables([t for t, _ in parts]).combine_chunks()
    assert joined.equals(table.combine_chunks())
    recordings = []
    for part, continues in parts:
        names = track_table.read_meta(part).recordings
        assert len(names) == 1 and set(part.column("recording").cast(pa.string()).to_pylist()) == set(names)
        recordings.append(next(iter(names)))
        tracks = len(track_table.track_boundaries(part)) - 1
        assert part.num_rows <= part_rows or tracks == 1
        assert continues == (len(recordings) > 1 and recordings[-2] == recordings[-1])
    assert sorted(set(recordings)) == recordings[:1] + recordings[-1:] == ["highd-01-lower", "highd-01-upper"]


def test_parts_of_rows_of_one_track_each_and_of_several_recordings(tmp_path: Path) -> None:
    # 4 tracks of 5, 3, 3 and 3 rows: 3 rows a part gives one track a part
    assert [t.num_rows for t, _ in _parts([DATA], 3)] == [5, 3, 3, 3]
    assert [t.num_rows for t, _ in _parts([DATA], 8)] == [8, 6]
    for prefix in ("01", "02"):
        for name in FILES:
            shutil.copy(DATA / name, tmp_path / name.replace("01", prefix))
    meta = tmp_path / "02_recordingMeta.csv"
    head, row, *rest = meta.read_text().splitlines(keepends=True)
    meta.write_text("".join([head, "2" + row[row.index(",") :], *rest]))
    parts = _parts([tmp_path], 100)
    assert [next(iter(track_table.read_meta(t).recordings)) for t, _ in parts] == [
        "highd-01-lower", "highd-01-upper", "highd-02-lower", "highd-02-upper"
    ]  # fmt: skip
    assert [c for _, c in parts] == [False] * 4


def test_parts_refuse_bad_input_as_read_does(tmp_path: Path) -> None:
    name, edit, culprit, line, column, words = BAD_INPUTS["numFrames disagrees"]
    _variant(tmp_path, name, edit)
    with pytest.raises(InputError) as info:
        _parts([tmp_path], 3)
    assert (Path(info.value.path or "").name, info.value.line, info.value.column) == (culprit, line, column)
    assert words in str(info.value)


# ------------------------------------------------------------------ sniff and CLI


def test_sniff(tmp_path: Path) -> None:
    for name in FILES:
        assert highd.sniff(DATA / name)
    assert highd.sniff(DATA)
    assert registry.detect(DATA / FILES[0]) == "highd"
    (tmp_path / "01_tracks.csv").write_text("a,b,c\n1,2,3\n")  # right name, wrong header
    (tmp_path / "tracks.csv").write_text((DATA / FILES[0]).read_text())  # right header, wrong name
    assert not highd.sniff(tmp_path / "01_tracks.csv")
    assert not highd.sniff(tmp_path / "tracks.csv")
    assert not highd.sniff(tmp_path)
    assert not highd.sniff(tmp_path / "absent_tracks.csv")


def test_cli_convert_and_info(tmp_path: Path, table: pa.Table, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "highd-01.parquet"
    assert cli.main(["convert", str(DATA), "--out", str(out)]) == 0
    assert "14 rows, 4 tracks" in capsys.readouterr().out
    written = track_table.read_parquet(out)
    assert written.equals(table, check_metadata=True)
    assert cli.main(["info", str(DATA / FILES[0])]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert "format: highd" in lines[1]
    lower = next(line for line in lines if "highd-01-lower" in line).split()
    upper = next(line for line in lines if "highd-01-upper" in line).split()
    # recording, tracks, frames, duration (frames 1..5 at 25 Hz = 0.2 s), rate, lane changes, classes (rows)
    assert lower[:6] == ["highd-01-lower", "2", "5", "0.2s", "25Hz", "1"]
    assert upper[:6] == ["highd-01-upper", "2", "3", "0.1s", "25Hz", "0"]
    assert "car 1, truck 1" in next(line for line in lines if "highd-01-lower" in line)


def test_cli_reports_bad_input(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = _variant(tmp_path, "01_tracks.csv", lambda lines: _set(lines, 4, "x", "12.4O"))
    assert cli.main(["convert", str(path), "--out", str(tmp_path / "o.parquet")]) == 2
    err = capsys.readouterr().err
    assert "01_tracks.csv, line 4, column 'x'" in err and "'12.4O' is not a number" in err
    assert not (tmp_path / "o.parquet").exists()


# ------------------------------------------------------------------ bad input


def _variant(tmp_path: Path, name: str, edit: Callable[[list[str]], list[str]]) -> Path:
    """Copy the fixture into ``tmp_path`` with ``name`` edited line by line; return its path."""
    for other in FILES:
        if not (tmp_path / other).exists():
            shutil.copy(DATA / other, tmp_path / other)
    lines = (DATA / name).read_text().splitlines()
    (tmp_path / name).write_text("".join(line + "\n" for line in edit(lines)))
    return tmp_path / name


def _set(lines: list[str], line: int, column: str, value: str) -> list[str]:
    """Set one cell (``line`` 1-based as in an editor)."""
    header = lines[0].split(",")
    cells = lines[line - 1].split(",")
    cells[header.index(column)] = value
    return [*lines[: line - 1], ",".join(cells), *lines[line:]]


def _drop_column(lines: list[str], column: str) -> list[str]:
    index = lines[0].split(",").index(column)
    return [",".join(c for i, c in enumerate(line.split(",")) if i != index) for line in lines]


T, M, R = FILES


BAD_INPUTS: dict[str, tuple[str, Callable[[list[str]], list[str]], str, int | None, str | None, str]] = {
    # case: (file, edit, file named in the error, line, column, words in the message)
    "misnamed column": (T, lambda ls: [ls[0].replace("xVelocity", "xVelocty"), *ls[1:]], T, 1, "xVelocity", "found 'xVelocty'"),
    "missing column": (T, lambda ls: _drop_column(ls, "laneId"), T, 1, "laneId", "no column 'laneId'"),
    "missing meta column": (M, lambda ls: _drop_column(ls, "drivingDirection"), M, 1, "drivingDirection", "no column"),
    "non-numeric cell": (T, lambda ls: _set(ls, 4, "x", "12.4O"), T, 4, "x", "'12.4O' is not a number"),
    "non-integer id": (T, lambda ls: _set(ls, 3, "laneId", "5.5"), T, 3, "laneId", "'5.5' is not an integer"),
    "NaN cell": (T, lambda ls: _set(ls, 6, "yVelocity", "NaN"), T, 6, "yVelocity", "empty or NaN"),
    "empty cell": (T, lambda ls: _set(ls, 10, "xAcceleration", ""), T, 10, "xAcceleration", "empty or NaN"),
    "infinite cell": (T, lambda ls: _set(ls, 8, "y", "inf"), T, 8, "y", "infinite"),
    "blank lines keep line numbers": (T, lambda ls: [*ls[:4], "", *_set(ls, 10, "x", "?")[4:]], T, 11, "x", "'?' is not a number"),
    "truncated last line": (T, lambda ls: [*ls[:-1], ls[-1][:30]], T, 15, "yVelocity", "truncated last line"),
    "too many fields": (T, lambda ls: [*ls[:2], ls[2] + ",7", *ls[3:]], T, 3, None, "26 fields"),
    "empty file": (T, lambda ls: [], T, 1, None, "empty file"),
    "header only": (M, lambda ls: ls[:1], M, 2, None, "no data rows"),
    "duplicate with other values": (T, lambda ls: [*ls, _set(ls, 4, "x", "12.50")[3]], T, 16, "x", "duplicate (id, frame) = (1, 3)"),
    "vehicle missing from meta": (M, lambda ls: ls[:4], T, 13, "id", "vehicle id 4 has no row"),
    "vehicle missing from tracks": (M, lambda ls: [*ls, ls[4].replace("4,", "5,", 1)], M, 6, "id", "vehicle id 5 has no rows"),
    "duplicate meta id": (M, lambda ls: [*ls, ls[4]], M, 6, "id", "appears twice"),
    "initialFrame disagrees": (M, lambda ls: _set(ls, 3, "initialFrame", "1"), M, 3, "initialFrame", "frames 2..4"),
    "finalFrame disagrees": (M, lambda ls: _set(ls, 4, "finalFrame", "4"), M, 4, "finalFrame", "disagrees"),
    "numFrames disagrees": (M, lambda ls: _set(ls, 2, "numFrames", "6"), M, 2, "numFrames", "5 rows"),
    "drivingDirection not 1 or 2": (M, lambda ls: _set(ls, 5, "drivingDirection", "3"), M, 5, "drivingDirection", "drivingDirection is 3"),
    "speed beyond the table's bound": (T, lambda ls: _set(ls, 7, "yVelocity", "1e12"), T, 7, "yVelocity", "a speed (m/s) within ±1e+09"),
    "bad frame rate": (R, lambda ls: _set(ls, 2, "frameRate", "fast"), R, 2, "frameRate", "not a number"),
    "bad lane markings": (R, lambda ls: _set(ls, 2, "lowerLaneMarkings", "14.00;x"), R, 2, "lowerLaneMarkings", "not numbers"),
}  # fmt: skip


@pytest.mark.parametrize("case", sorted(BAD_INPUTS))
def test_bad_input_names_file_line_and_column(tmp_path: Path, case: str) -> None:
    name, edit, culprit, line, column, words = BAD_INPUTS[case]
    _variant(tmp_path, name, edit)
    with pytest.raises(InputError) as info:
        highd.read([tmp_path])
    error = info.value
    assert Path(error.path or "").name == culprit, str(error)
    assert (error.line, error.column) == (line, column), str(error)
    assert words in str(error)


def test_missing_companion_file(tmp_path: Path) -> None:
    shutil.copy(DATA / T, tmp_path / T)
    shutil.copy(DATA / R, tmp_path / R)
    with pytest.raises(InputError, match="missing companion file") as info:
        highd.read([tmp_path / T])
    assert Path(info.value.path or "").name == M


def test_not_a_highd_name_or_empty_directory(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="no highD recording"):
        highd.read([tmp_path])
    (tmp_path / "tracks.csv").write_text("frame,id\n")
    with pytest.raises(InputError, match="not a highD file name"):
        highd.read([tmp_path / "tracks.csv"])


def test_truncated_file_without_final_newline(tmp_path: Path) -> None:
    _variant(tmp_path, T, lambda ls: ls)
    text = (DATA / T).read_text()
    last = text.rindex("\n", 0, len(text) - 1) + 1
    # the last line cut to "3,4,78.00,5.80,5.00,2.00,-0.30": 7 fields, the 8th (yVelocity) missing
    (tmp_path / T).write_text(text[: last + 30])
    with pytest.raises(InputError, match="truncated last line: 7 fields") as info:
        highd.read([tmp_path])
    assert (info.value.line, info.value.column) == (15, "yVelocity")


@pytest.mark.parametrize("name", FILES)
def test_header_only_without_line_end_is_no_data_rows(tmp_path: Path, name: str) -> None:
    # The fuzzer's seed 100180 (recordingMeta's data line deleted, the header's line end with it):
    # pyarrow's "Could not skip initial 1 rows from CSV file, … header is larger than block size".
    _variant(tmp_path, name, lambda ls: ls)
    (tmp_path / name).write_text((DATA / name).read_text().splitlines()[0])
    with pytest.raises(InputError, match="no data rows") as info:
        highd.read([tmp_path])
    assert (Path(info.value.path or "").name, info.value.line) == (name, 2)


def test_windows_line_endings(tmp_path: Path, table: pa.Table) -> None:
    for name in FILES:
        (tmp_path / name).write_bytes((DATA / name).read_bytes().replace(b"\n", b"\r\n"))
    assert highd.read([tmp_path]).equals(table, check_metadata=False)
    lines = (DATA / T).read_text().splitlines()
    (tmp_path / T).write_bytes("".join(f"{line}\r\n" for line in _set(lines, 12, "id", "x3")).encode())
    with pytest.raises(InputError, match="'x3' is not an integer") as info:
        highd.read([tmp_path])
    assert (info.value.line, info.value.column) == (12, "id")


def test_same_recording_number_in_two_directories_is_kept_apart(tmp_path: Path) -> None:
    """Two simulations with the default recording id 1 read together: the second's recordings are
    qualified by its folder (they were refused, and no rename of a file could help)."""
    for sub in ("a", "b"):
        (tmp_path / sub).mkdir()
        for name in FILES:
            shutil.copy(DATA / name, tmp_path / sub / name)
    table = highd.read([tmp_path / "a", tmp_path / "b"])
    names = set(track_table.read_meta(table).recordings)
    assert {"highd-01-lower", "highd-01-lower@b"} <= names
    rows = table.column("recording").cast(pa.string()).to_pylist()
    assert rows.count("highd-01-lower") == rows.count("highd-01-lower@b") > 0


# ------------------------------------------------------------------ the SUMO simulator's highD output


def _neighbour_offsets(table: pa.Table, column: str) -> tuple[np.ndarray, np.ndarray]:
    """(dx, dy) [K] from each row to its neighbour in ``column`` at the same frame (where given)."""
    rec = np.unique(
        table.column("recording").cast(pa.string()).to_numpy(zero_copy_only=False), return_inverse=True
    )[1]
    track, frame = table.column("track_id").to_numpy(), table.column("frame").to_numpy()
    key = (rec.astype(np.int64) << 40) | (track << 20) | frame  # sorted like the rows
    other = table.column(column)
    given = ~np.asarray(other.is_null())
    target = (
        (rec[given].astype(np.int64) << 40) | (np.asarray(other.fill_null(0))[given] << 20) | frame[given]
    )
    at = np.searchsorted(key, target)
    found = (at < key.size) & (key[np.minimum(at, key.size - 1)] == target)
    rows, at = np.flatnonzero(given)[found], at[found]
    x, y = table.column("x").to_numpy(), table.column("y").to_numpy()
    return x[at] - x[rows], y[at] - y[rows]


def test_reads_the_sumo_simulators_recordings(sim_recording_dir: Path) -> None:
    t = highd.read([sim_recording_dir])
    meta = track_table.read_meta(t)
    assert sorted(meta.recordings) == ["highd-01-lower", "highd-01-upper"]
    names = np.asarray(t.column("recording").cast(pa.string()).to_pylist())
    lane, y = t.column("lane_id").to_numpy(), t.column("y").to_numpy()
    for name, lanes_left_to_right in (("highd-01-lower", [6, 7, 8]), ("highd-01-upper", [4, 3, 2])):
        rows = names == name
        assert t.column("vx").to_numpy()[rows].mean() > 10.0  # x along the direction of travel
        assert np.abs(t.column("heading").to_numpy()[rows]).max() < 0.3
        marks = meta.recordings[name].extra["lane_markings_y"]
        assert marks[0] < y[rows].min() and y[rows].max() < marks[-1]
        # lanes nearer the median are further left (larger y) in both road frames
        mean_y = [y[rows & (lane == k)].mean() for k in lanes_left_to_right]
        assert mean_y == sorted(mean_y, reverse=True)
    assert track_table.lane_change_rows(t).size > 0
    # neighbour ids follow the road frame: preceding ahead (+x), left alongside to the left (+y)
    dx, _ = _neighbour_offsets(t, "preceding_id")
    assert dx.size > 0 and (dx > 0).all()
    _, dy = _neighbour_offsets(t, "left_alongside_id")
    assert dy.size > 0 and (dy > 0).all()
    _, dy = _neighbour_offsets(t, "right_following_id")
    assert dy.size > 0 and (dy < 0).all()


@pytest.mark.parametrize(
    ("victim", "make", "words"),
    [
        (T, lambda p: os.mkfifo(p), "not a regular file"),
        (M, lambda p: os.symlink("/dev/zero", p), "not a regular file"),
        (
            T,
            lambda p: p.with_name(p.name + ".gz").write_bytes(gzip.compress((DATA / T).read_bytes())),
            ".gz beside",
        ),
        (
            R,
            lambda p: p.with_name(p.name + ".xz").write_bytes(b"\xfd7zXZ\x00"),
            ".xz beside it is compressed",
        ),
    ],
)
def test_a_recording_file_that_is_no_regular_file_says_what_it_is(
    tmp_path: Path, victim: str, make: Callable[[Path], object], words: str
) -> None:
    """A FIFO or /dev/zero under a recording's file name was "no such file"; a file left compressed
    beside its name was "no such file" without a word of the compressed one."""
    for name in (T, M, R):
        if name != victim:
            shutil.copy(DATA / name, tmp_path / name)
    make(tmp_path / victim)
    with pytest.raises(InputError, match=words) as info:
        highd.read([tmp_path])
    assert Path(info.value.path or "").name == victim


@pytest.mark.parametrize("rec_id", ["2", "0", "60"])
def test_a_recording_meta_of_another_recording_is_refused(tmp_path: Path, rec_id: str) -> None:
    """01_recordingMeta.csv saying recording 2 is another recording's file put under 01's name:
    its frame rate and lane markings would be applied to 01's tracks. Before: converted, exit 0."""
    path = _variant(tmp_path, "01_recordingMeta.csv", lambda lines: _set(lines, 2, "id", rec_id))
    with pytest.raises(InputError) as err:
        highd.read([tmp_path])
    assert err.value.path == str(path) and err.value.line == 2 and err.value.column == "id"
    assert f"recording id {rec_id} disagrees with the file name's 01" in str(err.value)


def test_a_recording_meta_id_of_an_unnumbered_name_or_written_with_zeros_is_read(
    tmp_path: Path, table: pa.Table
) -> None:
    """The id is checked against a numbered name only (01 and 1 are one number)."""
    _variant(tmp_path, "01_recordingMeta.csv", lambda lines: _set(lines, 2, "id", "01"))
    assert highd.read([tmp_path]).equals(table, check_metadata=False)
    named = tmp_path / "named"
    named.mkdir()
    for name in FILES:
        shutil.copy(DATA / name, named / name.replace("01", "a"))
    meta = named / "a_recordingMeta.csv"
    meta.write_text("\n".join(_set(meta.read_text().splitlines(), 2, "id", "7")) + "\n")
    assert highd.read([named / "a_tracks.csv"]).num_rows == table.num_rows


def test_dropping_identical_duplicate_rows_is_reported(
    tmp_path: Path, table: pa.Table, capsys: pytest.CaptureFixture[str]
) -> None:
    """A repeated line is dropped (the same data) and said so on stderr with its line; before, the
    repair was silent."""

    def duplicate(lines: list[str]) -> list[str]:
        return [*lines[:5], lines[3], *lines[5:]]

    path = _variant(tmp_path, "01_tracks.csv", duplicate)
    capsys.readouterr()
    assert highd.read([tmp_path]).equals(table, check_metadata=False)
    assert (
        f"{path}: dropped 1 row(s) repeating an earlier (id, frame) with the same values (the first at line 6)"
        in (capsys.readouterr().err)
    )


def test_highd_recording_start_from_month_weekday_and_time() -> None:
    """highD gives 09.2017, Tue, 08:38: the first Tuesday of September 2017 at 08:38 in Germany."""
    from lanecast.io_adapters.datasets.highd.start_time import meta_fields, recording_start, start_ns

    start = recording_start("09.2017", "Tue", "08:38")
    assert start is not None and start.isoformat() == "2017-09-05T08:38:00+02:00"
    assert start_ns(start) == 1504593480 * 10**9
    assert recording_start("01.2000", "Sat", "12:00").isoformat() == "2000-01-01T12:00:00+01:00"  # type: ignore[union-attr]
    for bad in (
        ("13.2017", "Tue", "08:38"),
        ("09.2017", "Xyz", "08:38"),
        ("09.2017", "Tue", "25:00"),
        (None, "Tue", "8:00"),
    ):
        assert recording_start(*bad) is None
    assert meta_fields(start) == {"month": "09.2017", "weekDay": "Tue", "startTime": "08:38"}
    assert (
        recording_start(
            **{
                k: v
                for k, v in zip(("month", "week_day", "start_time"), meta_fields(start).values(), strict=True)
            }
        )
        == start
    )
