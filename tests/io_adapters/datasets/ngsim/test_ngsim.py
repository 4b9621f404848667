"""NGSIM adapter: real Peachtree rows and a hand-written US-101 .txt fixture, checked against hand
computations from the raw feet; bad input gives InputError at the right line and column."""

from __future__ import annotations

import math
import shutil
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pytest
from conftest import TESTS

from lanecast.io_adapters.contracts import track_table
from lanecast.io_adapters.contracts.track_summary import summarise
from lanecast.io_adapters.datasets.ngsim import reader as ngsim
from lanecast.io_adapters.errors import InputError
from lanecast.io_adapters.formats import registry
from lanecast.workflows import cli

DATA = TESTS / "data" / "ngsim"


SAMPLE = DATA / "peachtree_sample.csv"


TXT = DATA / "us-101" / "trajectories-fixture.txt"


FT = 0.3048


def _row(table: pa.Table, recording: str, track: int, frame: int) -> dict[str, Any]:
    rec = np.asarray(table.column("recording").cast(pa.string()).to_pylist())
    track_ids = table.column("track_id").to_numpy()
    frames = table.column("frame").to_numpy()
    (index,) = np.flatnonzero((rec == recording) & (track_ids == track) & (frames == frame))
    return {name: table.column(name)[int(index)].as_py() for name in table.column_names}


def _heading_by_hand(vehicle: int, frame: int, epoch: int) -> float:
    """The arterial heading from the raw CSV: the direction of the front bumper's motion over ±5
    rows (here every row moves faster than 1 m/s, so all count), averaged as a direction over the
    rows ±5 around ``frame`` (sin and cos means)."""
    import pandas as pd

    raw = pd.read_csv(SAMPLE)
    rows = raw[(raw.Vehicle_ID == vehicle) & (raw.Global_Time - 100 * raw.Frame_ID == epoch)]
    rows = rows.sort_values("Frame_ID").reset_index(drop=True)
    x, y = rows.Local_Y.to_numpy() * FT, -rows.Local_X.to_numpy() * FT
    last = len(rows) - 1
    angles = []
    for i in range(len(rows)):
        lo, hi = max(i - 5, 0), min(i + 5, last)
        angles.append(math.atan2(y[hi] - y[lo], x[hi] - x[lo]))
    at = int(np.flatnonzero(rows.Frame_ID.to_numpy() == frame)[0])
    window = angles[max(at - 5, 0) : min(at + 5, last) + 1]
    return math.atan2(float(np.mean(np.sin(window))), float(np.mean(np.cos(window))))


def _lines(path: Path) -> list[str]:
    return path.read_text().splitlines()


# ------------------------------------------------------------------------------- real Peachtree rows


@pytest.fixture(scope="module")
def peachtree() -> pa.Table:
    return ngsim.read([SAMPLE])


def test_sniff_recognises_both_forms_and_not_others(tmp_path: Path) -> None:
    other = tmp_path / "tracks.csv"
    other.write_text("id,frame,x,y\n1,1,0.0,0.0\n")
    assert ngsim.sniff(SAMPLE) and ngsim.sniff(TXT)
    assert not ngsim.sniff(other) and not ngsim.sniff(tmp_path)
    assert registry.detect(SAMPLE) == "ngsim" and registry.detect(TXT) == "ngsim"


def test_peachtree_periods_become_recordings(peachtree: pa.Table) -> None:
    # The sample mixes Peachtree's two periods (Global_Time - 100*Frame_ID = 1163018600 and
    # 1163030300); their vehicle ids and frames overlap (vehicle 70), so each is its own recording.
    meta = track_table.read_meta(peachtree)
    assert sorted(meta.recordings) == [
        "ngsim-peachtree-peachtree_sample-p1",
        "ngsim-peachtree-peachtree_sample-p2",
    ]
    p1 = meta.recordings["ngsim-peachtree-peachtree_sample-p1"]
    p2 = meta.recordings["ngsim-peachtree-peachtree_sample-p2"]
    assert (p1.extra["global_time_epoch"], p2.extra["global_time_epoch"]) == (1163018600, 1163030300)
    assert (p1.extra["rows_read"], p2.extra["rows_read"]) == (4017, 983)
    assert p1.extra["conflicting_duplicates_dropped"] == 0 and p1.extra["duplicate_rows_dropped"] == 0
    assert p1.coordinate_frame == "local" and p1.frame_rate == 10.0 and p1.extra["location"] == "peachtree"
    assert meta.frame_rate == 10.0 and meta.source_format == "ngsim"
    assert peachtree.num_rows == 5000
    track_table.validate(peachtree)


def test_peachtree_without_period_split_keeps_first_of_conflicting_duplicates() -> None:
    table = ngsim.read([SAMPLE], split_periods=False)
    meta = track_table.read_meta(table)
    (name,) = meta.recordings
    assert name == "ngsim-peachtree-peachtree_sample"
    # vehicle 70 appears in both periods at frames 397..415: 19 (vehicle, frame) collisions
    assert meta.recordings[name].extra["conflicting_duplicates_dropped"] == 19
    assert table.num_rows == 5000 - 19
    # first in file order at frame 397 is line 188 (Total_Frames 775, Local_Y 24.058, v_length 17.5)
    row = _row(table, name, 70, 397)
    assert row["length"] == pytest.approx(17.5 * FT)


def test_peachtree_northbound_vehicle_values_by_hand(peachtree: pa.Table) -> None:
    # Vehicle 21, frame 100 (CSV line 1516): Local_X 23.518, Local_Y 47.663, v_length 18.0,
    # v_Width 7.0, v_Class 2, v_Vel 21.68, v_Acc 9.34, Lane_ID 2, Preceding 0, Following 0.
    row = _row(peachtree, "ngsim-peachtree-peachtree_sample-p2", 21, 100)
    # heading: front bumper motion over ±5 rows (frames 95 (23.569, 38.472) and 105 (23.610,
    # 57.413) at frame 100), averaged over frames 95..105
    assert math.atan2(-(23.610 - 23.569), 57.413 - 38.472) == pytest.approx(-0.0021646, abs=1e-6)
    heading = _heading_by_hand(21, 100, 1163030300)
    assert heading == pytest.approx(-0.0021646, abs=0.005)
    assert row["heading"] == pytest.approx(heading, abs=1e-6)
    assert row["x"] == pytest.approx(47.663 * FT - 9.0 * FT * math.cos(heading), abs=1e-6)
    assert row["x"] == pytest.approx(11.78449, abs=1e-4)  # ≈ (47.663 - 18/2) * 0.3048
    assert row["y"] == pytest.approx(-23.518 * FT - 9.0 * FT * math.sin(heading), abs=1e-6)
    assert row["y"] == pytest.approx(-7.15666, abs=1e-4)
    assert row["length"] == pytest.approx(5.4864) and row["width"] == pytest.approx(2.1336)
    assert math.hypot(row["vx"], row["vy"]) == pytest.approx(21.68 * FT, rel=1e-6)  # 6.608064
    assert row["vx"] == pytest.approx(6.608064 * math.cos(heading), rel=1e-6)
    assert row["ax"] == pytest.approx(9.34 * FT * math.cos(heading), rel=1e-6)  # 2.846832
    assert row["ay"] == pytest.approx(9.34 * FT * math.sin(heading), rel=1e-5)
    assert row["time_ns"] == 100 * 100_000_000
    assert (row["lane_id"], row["object_class"]) == (2, "car")
    assert row["preceding_id"] is None and row["following_id"] is None


def test_peachtree_southbound_centre_is_behind_the_front_bumper(peachtree: pa.Table) -> None:
    # Vehicle 352, frame 3361 (line 4474): Local_X -4.204, Local_Y 60.265, v_length 15, drives
    # towards -Local_Y (frame 3366: Local_X -4.173, Local_Y 45.047), so its centre is at +L/2.
    row = _row(peachtree, "ngsim-peachtree-peachtree_sample-p2", 352, 3361)
    heading = _heading_by_hand(352, 3361, 1163030300)
    assert abs(heading - math.atan2(-(-4.173 - -4.204), 45.047 - 60.265)) < 0.01
    assert row["heading"] == pytest.approx(heading, abs=1e-6)
    assert abs(row["heading"]) == pytest.approx(math.pi, abs=0.01)
    assert row["x"] == pytest.approx((60.265 + 7.5 * -math.cos(heading)) * FT, abs=1e-6)
    assert row["x"] == pytest.approx(20.65477, abs=1e-4)  # ≈ (60.265 + 15/2) * 0.3048
    assert row["vx"] == pytest.approx(-30.43 * FT, rel=1e-4)
    assert row["following_id"] == 419 and row["preceding_id"] is None


# --------------------------------------------------------------------------- hand-written US-101 txt


@pytest.fixture(scope="module")
def us101() -> pa.Table:
    return ngsim.read([TXT])


def test_txt_recording_location_from_directory_and_duplicates(us101: pa.Table) -> None:
    meta = track_table.read_meta(us101)
    assert list(meta.recordings) == ["ngsim-us-101-trajectories-fixture"]
    rec = meta.recordings["ngsim-us-101-trajectories-fixture"]
    assert rec.coordinate_frame == "road"
    assert (rec.extra["location"], rec.extra["location_source"]) == ("us-101", "path")
    assert rec.extra["rows_read"] == 15
    assert rec.extra["duplicate_rows_dropped"] == 1  # vehicle 1, frame 12 repeated exactly
    assert rec.extra["conflicting_duplicates_dropped"] == 1  # vehicle 2, frame 14 with Local_Y 72.5
    assert rec.extra["global_time_start"] == 1118846980700
    assert us101.num_rows == 13
    assert us101.column("track_id").to_pylist() == [1] * 5 + [2] * 5 + [3] * 3


def test_txt_straight_car_values_by_hand(us101: pa.Table) -> None:
    # vehicle 1 frame 10: Local_X 18.0, Local_Y 100.0, 15.0 x 6.0 ft, class 2, 40 ft/s, lane 2
    row = _row(us101, "ngsim-us-101-trajectories-fixture", 1, 10)
    assert row["x"] == pytest.approx((100.0 - 7.5) * FT)  # 28.194
    assert row["x"] == pytest.approx(28.194)
    assert row["y"] == pytest.approx(-5.4864)
    assert (row["vx"], row["vy"], row["heading"]) == (pytest.approx(12.192), 0.0, 0.0)
    assert (row["ax"], row["ay"]) == (0.0, 0.0)
    assert row["length"] == pytest.approx(4.572) and row["width"] == pytest.approx(1.8288)
    assert (row["lane_id"], row["object_class"], row["time_ns"]) == (2, "car", 1_000_000_000)
    assert row["preceding_id"] is None and row["following_id"] == 2
    assert row["left_preceding_id"] is None and row["right_following_id"] is None


def test_txt_lane_changing_truck_values_by_hand(us101: pa.Table) -> None:
    # vehicle 2: Local_X 18.0 → 20.0 ft in 0.5 ft steps per frame (to the right), Local_Y 60 + 3/frame,
    # 40 ft truck, 30 ft/s, 2 ft/s², lane 2 → 3 at frame 12; vy = -0.5 ft / 0.1 s = -1.524 m/s
    heading = math.atan2(-1.524, 9.144)  # -0.16515 rad
    rows = [_row(us101, "ngsim-us-101-trajectories-fixture", 2, f) for f in range(10, 15)]
    mid = rows[2]
    assert mid["x"] == pytest.approx((66.0 - 20.0) * FT)  # 14.0208
    assert mid["y"] == pytest.approx(-19.0 * FT)  # -5.7912
    for r in rows:
        assert r["vx"] == pytest.approx(9.144) and r["vy"] == pytest.approx(-1.524)
        assert r["heading"] == pytest.approx(heading, abs=1e-6)
        assert r["ax"] == pytest.approx(0.6096 * math.cos(heading), rel=1e-6)
        assert r["ay"] == pytest.approx(0.6096 * math.sin(heading), rel=1e-6)
        assert r["object_class"] == "truck" and r["length"] == pytest.approx(12.192)
    assert rows[4]["x"] == pytest.approx((72.0 - 20.0) * FT)  # the first of the two frame-14 rows
    assert [r["lane_id"] for r in rows] == [2, 2, 3, 3, 3]
    assert [r["preceding_id"] for r in rows] == [1, 1, None, None, None]
    changes = track_table.lane_change_rows(us101)
    assert [int(us101.column("frame")[int(i)].as_py()) for i in changes] == [12]


def test_txt_motorcycle_with_frame_gap(us101: pa.Table) -> None:
    rows = [_row(us101, "ngsim-us-101-trajectories-fixture", 3, f) for f in (11, 12, 14)]
    assert [r["x"] for r in rows] == pytest.approx([(y - 3.5) * FT for y in (30.0, 32.0, 36.0)])
    assert all(r["object_class"] == "motorcycle" and r["vy"] == 0.0 for r in rows)


def test_txt_location_option_and_unknown_location(tmp_path: Path) -> None:
    table = ngsim.read([TXT], location="I-80")
    (name,) = track_table.read_meta(table).recordings
    assert name == "ngsim-i-80-trajectories-fixture"
    plain = tmp_path / "trajectories-0900-0915.txt"
    shutil.copy(TXT, plain)
    meta = track_table.read_meta(ngsim.read([plain]))
    rec = meta.recordings["ngsim-unknown-trajectories-0900-0915"]
    assert (rec.extra["location"], rec.extra["location_source"], rec.coordinate_frame) == (
        "unknown",
        "default",
        "road",
    )


@pytest.mark.parametrize(
    ("name", "location"),
    [
        ("trajectories-0750am-0805am.txt", "us-101"),
        ("trajectories-0805am-0820am.txt", "us-101"),
        ("trajectories-0820am-0835am.txt", "us-101"),
        ("trajectories-0400-0415.txt", "i-80"),
        ("trajectories-0500-0515.txt", "i-80"),
        ("trajectories-0515-0530.txt", "i-80"),
    ],
)
def test_ngsims_own_file_names_say_the_location(tmp_path: Path, name: str, location: str) -> None:
    shutil.copy(TXT, tmp_path / name)
    (recording,) = track_table.read_meta(ngsim.read([tmp_path / name])).recordings.values()
    assert (recording.extra["location"], recording.coordinate_frame) == (location, "road")


def test_a_directory_of_ngsim_files_and_the_location_option(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    folder = tmp_path / "downloads"
    (folder / "more").mkdir(parents=True)
    shutil.copy(TXT, folder / "trajectories-0750am-0805am.txt")
    shutil.copy(TXT, folder / "more" / "trajectories-0900-0915.txt")
    (folder / "README.txt").write_text("NGSIM US-101 data\n")  # not an NGSIM file: left out
    out = tmp_path / "all.parquet"
    assert cli.main(["convert", str(folder), "--out", str(out)]) == 0
    names = sorted(track_table.read_meta(track_table.read_parquet(out)).recordings)
    assert names == ["ngsim-unknown-trajectories-0900-0915", "ngsim-us-101-trajectories-0750am-0805am"]
    assert cli.main(["convert", str(folder), "--location", "i-80", "--out", str(out)]) == 0
    names = sorted(track_table.read_meta(track_table.read_parquet(out)).recordings)
    assert names == ["ngsim-i-80-trajectories-0750am-0805am", "ngsim-i-80-trajectories-0900-0915"]
    capsys.readouterr()
    assert cli.main(["info", str(folder / "more"), "--location", "us-101"]) == 0
    assert "ngsim-us-101-trajectories-0900-0915" in capsys.readouterr().out


def test_csv_mixing_locations_separates_reused_vehicle_ids(tmp_path: Path) -> None:
    # The first 30 lines of the sample, once as peachtree and once relabelled us-101 (same ids).
    lines = _lines(SAMPLE)
    mixed = tmp_path / "mixed.csv"
    body = lines[1:31]
    mixed.write_text(
        "\n".join(
            [
                lines[0].replace("v_length", "V_LENGTH"),
                *body,
                *(b.replace("peachtree", "US-101") for b in body),
            ]
        )
        + "\n"
    )
    table = ngsim.read([mixed])
    meta = track_table.read_meta(table)
    assert sorted(meta.recordings) == ["ngsim-peachtree-mixed", "ngsim-us-101-mixed"]
    assert meta.recordings["ngsim-us-101-mixed"].coordinate_frame == "road"
    assert table.num_rows == 60
    # first data line: vehicle 352, frame 3380, Local_X -5.359, Local_Y 0.0, v_length 15, 33.96 ft/s
    road = _row(table, "ngsim-us-101-mixed", 352, 3380)
    assert (road["x"], road["y"], road["vx"]) == (
        pytest.approx(-7.5 * FT),
        pytest.approx(5.359 * FT),
        pytest.approx(33.96 * FT),
    )
    only = ngsim.read([mixed], location="us101")
    assert list(track_table.read_meta(only).recordings) == ["ngsim-us-101-mixed"]


# --------------------------------------------------------------------------------------------- CLI


def test_cli_convert_and_info(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "ngsim.parquet"
    assert cli.main(["convert", str(SAMPLE), str(TXT), "--out", str(out)]) == 0
    table = track_table.read_parquet(out)
    assert table.num_rows == 5000 + 13
    assert len(track_table.read_meta(table).recordings) == 3
    capsys.readouterr()
    assert cli.main(["info", str(TXT)]) == 0
    text = capsys.readouterr().out
    assert "ngsim-us-101-trajectories-fixture" in text and "format: ngsim" in text
    (summary,) = summarise(ngsim.read([TXT]))
    assert (summary["tracks"], summary["rows"], summary["lane_changes"]) == (3, 13, 1)
    bad = tmp_path / "bad.txt"
    bad.write_text("1 2 3\n")
    assert cli.main(["info", "--format", "ngsim", str(bad)]) == 2
    assert "line 1" in capsys.readouterr().err


# ------------------------------------------------------------------------------------- bad input


def _write(tmp_path: Path, name: str, lines: list[str], end: str = "\n") -> Path:
    path = tmp_path / name
    path.write_text("\n".join(lines) + end)
    return path


def _error(path: Path) -> InputError:
    with pytest.raises(InputError) as info:
        ngsim.read([path])
    assert info.value.path == str(path)
    return info.value


def _set_field(line: str, index: int, value: str, sep: str | None) -> str:
    cells = line.split(sep)
    cells[index] = value
    return (sep or "  ").join(cells)


@pytest.fixture
def csv_lines() -> list[str]:
    return _lines(SAMPLE)[:8]


@pytest.fixture
def txt_lines() -> list[str]:
    return _lines(TXT)[:6]


def test_bad_csv_missing_column(tmp_path: Path, csv_lines: list[str]) -> None:
    csv_lines[0] = csv_lines[0].replace("v_Vel", "speed")
    err = _error(_write(tmp_path, "a.csv", csv_lines))
    assert (err.line, err.column) == (1, "v_vel")


def test_bad_csv_non_numeric_cell(tmp_path: Path, csv_lines: list[str]) -> None:
    csv_lines[3] = _set_field(csv_lines[3], 4, "x12", ",")  # Local_X on line 4
    err = _error(_write(tmp_path, "a.csv", csv_lines))
    assert (err.line, err.column, err.expected) == (4, "Local_X", "a finite number")
    assert "'x12' is not a finite number" in err.reason


@pytest.mark.parametrize("cell", ["NaN", "", "inf"])
def test_bad_csv_missing_values(tmp_path: Path, csv_lines: list[str], cell: str) -> None:
    csv_lines[5] = _set_field(csv_lines[5], 12, cell, ",")  # v_Acc on line 6
    err = _error(_write(tmp_path, "a.csv", csv_lines))
    assert (err.line, err.column) == (6, "v_Acc")


def test_bad_csv_fractional_lane(tmp_path: Path, csv_lines: list[str]) -> None:
    csv_lines[2] = _set_field(csv_lines[2], 13, "1.5", ",")
    err = _error(_write(tmp_path, "a.csv", csv_lines))
    assert (err.line, err.column, err.expected) == (3, "Lane_ID", "an integer")


def test_bad_csv_truncated_last_line(tmp_path: Path, csv_lines: list[str]) -> None:
    csv_lines[-1] = csv_lines[-1][:40]
    err = _error(_write(tmp_path, "a.csv", csv_lines, end=""))
    assert err.line == 8 and "truncated last line" in err.reason


def test_bad_csv_header_only_and_empty_files(tmp_path: Path, csv_lines: list[str]) -> None:
    err = _error(_write(tmp_path, "a.csv", csv_lines[:1]))
    assert err.line == 2
    empty = tmp_path / "empty.csv"
    empty.write_bytes(b"")
    err = _error(empty)
    assert err.line == 1 and "empty" in err.reason
    blank = tmp_path / "blank.txt"
    blank.write_text("\n  \n")
    assert "empty" in _error(blank).reason


def test_bad_txt_wrong_number_of_fields(tmp_path: Path, txt_lines: list[str]) -> None:
    txt_lines[2] = txt_lines[2].rsplit(maxsplit=1)[0]  # 17 fields on line 3
    err = _error(_write(tmp_path, "a.txt", txt_lines))
    assert (err.line, err.column) == (3, "Time_Headway")
    assert "wrong number of fields: 17" in err.reason
    txt_lines[2] = _lines(TXT)[2] + " 7"  # 19 fields
    err = _error(_write(tmp_path, "b.txt", txt_lines))
    assert err.line == 3 and "19 fields" in err.reason


def test_bad_txt_blank_lines_do_not_shift_line_numbers(tmp_path: Path, txt_lines: list[str]) -> None:
    txt_lines.insert(1, "")
    txt_lines[4] = _set_field(txt_lines[4], 5, "abc", None)  # Local_Y on line 5
    err = _error(_write(tmp_path, "a.txt", txt_lines))
    assert (err.line, err.column) == (5, "Local_Y") and "'abc'" in err.reason


def test_bad_txt_nan_and_truncation(tmp_path: Path, txt_lines: list[str]) -> None:
    nan = list(txt_lines)
    nan[1] = _set_field(nan[1], 11, "NaN", None)  # v_Vel on line 2
    err = _error(_write(tmp_path, "a.txt", nan))
    assert (err.line, err.column) == (2, "v_Vel")
    txt_lines[-1] = txt_lines[-1][:50]
    err = _error(_write(tmp_path, "b.txt", txt_lines, end=""))
    assert err.line == 6 and "truncated last line" in err.reason


def test_csv_header_case_spaces_and_bom(tmp_path: Path) -> None:
    lines = _lines(SAMPLE)[:4]
    header = "\ufeff" + lines[0].upper().replace(",LOCAL_X,", ", Local_X ,")
    path = tmp_path / "upper.csv"
    path.write_text("\r\n".join([header, *lines[1:]]) + "\r\n", encoding="utf-8")
    assert ngsim.sniff(path)
    table = ngsim.read([path])
    assert table.num_rows == 3
    row = _row(table, "ngsim-peachtree-upper", 352, 3380)
    assert row["length"] == pytest.approx(15.0 * FT) and row["lane_id"] == 1


def test_arterial_heading_is_held_through_a_stop(peachtree: pa.Table) -> None:
    # Vehicle 70 of period 1 creeps north, stops at Local_Y 21.836 and 24.334 for ~30 s (v_Vel 0):
    # the heading of its last motion above 0.5 m/s is kept, so the centre stays put.
    rows = [_row(peachtree, "ngsim-peachtree-peachtree_sample-p1", 70, f) for f in range(261, 562, 20)]
    assert len({r["heading"] for r in rows}) == 1
    assert abs(rows[0]["heading"]) < 0.1
    stopped = _row(peachtree, "ngsim-peachtree-peachtree_sample-p1", 70, 345)  # line 1122
    h = stopped["heading"]
    assert stopped["x"] == pytest.approx((24.334 - 8.25 * math.cos(h)) * FT, abs=1e-6)
    assert stopped["y"] == pytest.approx(-14.597 * FT - 8.25 * FT * math.sin(h), abs=1e-6)
    assert (stopped["vx"], stopped["vy"]) == (0.0, 0.0)


def test_arterial_vehicle_that_never_moves_takes_its_heading_from_direction(tmp_path: Path) -> None:
    header, line = _lines(SAMPLE)[:2]  # vehicle 352, Local_X -5.359, Local_Y 0.0, Direction 4 (south)
    cells = line.split(",")
    rows = []
    for frame in range(3380, 3385):
        cells[1], cells[11], cells[12] = str(frame), "0.0", "0.0"
        rows.append(",".join(cells))
    path = _write(tmp_path, "parked.csv", [header, *rows])
    row = _row(ngsim.read([path]), "ngsim-peachtree-parked", 352, 3382)
    assert row["heading"] == pytest.approx(math.pi)
    assert row["x"] == pytest.approx(7.5 * FT) and row["y"] == pytest.approx(5.359 * FT)


def test_compressed_files_in_a_folder_are_not_left_out_without_a_word(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A folder of NGSIM's .txt.gz downloads was "format not recognised"; one beside a decompressed
    file was left out silently."""
    import gzip

    folder = tmp_path / "ngsim"
    folder.mkdir()
    packed = folder / "trajectories-0400-0415.txt.gz"
    packed.write_bytes(gzip.compress(TXT.read_bytes()))
    with pytest.raises(InputError, match="gzip-compressed") as err:
        registry.read_any([folder])
    assert err.value.path == str(packed) and "decompress" in (err.value.expected or "")
    shutil.copy(TXT, folder / "trajectories-0500-0515.txt")
    table = registry.read_any([folder])
    assert table.num_rows == registry.read_any([TXT]).num_rows
    assert f"{packed}: gzip-compressed, left out" in capsys.readouterr().err


def test_bad_txt_byte_that_is_not_utf8_gives_its_line_and_offset(
    tmp_path: Path, txt_lines: list[str]
) -> None:
    # A byte overwritten inside a cell (the fuzzer's seed 100088): the parser's own message said
    # "can't decode byte 0x9b in position 4" of some block, naming no line.
    data = bytearray("\n".join(txt_lines).encode() + b"\n")
    at = data.index(b"104.000") + 1  # Local_Y of line 2
    data[at] = 0x9B
    path = tmp_path / "a.txt"
    path.write_bytes(bytes(data))
    err = _error(path)
    assert (err.line, err.offset) == (2, at) and "not UTF-8" in err.reason


def test_txt_beginning_with_blank_lines_is_read_as_without_them(tmp_path: Path) -> None:
    # The fuzzer's seed 200140: whitespace lines inserted before the first row made the file
    # "format not recognised" (no line, no reason), though the reader skips blank lines elsewhere.
    path = tmp_path / "us-101" / TXT.name  # the location and recording names come from the path
    path.parent.mkdir()
    path.write_bytes(b"   \n\n\t\n" + TXT.read_bytes())
    assert registry.detect(path) == "ngsim"
    assert registry.read_any([path]).equals(registry.read_any([TXT]), check_metadata=False)


@pytest.mark.parametrize(
    ("field", "column", "words"), [(11, "v_Vel", "a speed within"), (12, "v_Acc", "an acceleration")]
)
def test_bad_txt_speed_beyond_the_tables_bound(
    tmp_path: Path, txt_lines: list[str], field: int, column: str, words: str
) -> None:
    # 1e12 ft/s was read (finite in float32), and the track table or train refused it later with no line of the file
    txt_lines[3] = _set_field(txt_lines[3], field, "1e12", None)
    err = _error(_write(tmp_path, "a.txt", txt_lines))
    assert (err.line, err.column) == (4, column) and words in str(err)


def _freeway_vehicle(vehicle: int, first: int, n: int, y0: float, step: float) -> list[str]:
    """``n`` .txt rows of one US-101 vehicle whose Local_Y moves ``step`` ft per frame."""
    return [
        f"{vehicle} {f} {n} {1118846980000 + 100 * f} 18.0 {y0 + step * (f - first):.3f} 6451155.641 "
        f"1873444.255 15.0 6.0 2 40.0 0.0 2 0 0 0.0 0.0"
        for f in range(first, first + n)
    ]


def test_a_freeway_vehicle_driving_backwards_is_refused(tmp_path: Path) -> None:
    """On US-101 and I-80 (one-way, x = Local_Y) a vehicle whose Local_Y falls 4 ft per frame drove
    backwards at 12 m/s while v_Vel said forwards: converted with vx = +12 m/s and x falling (exit
    0). Now refused at the vehicle's first line; stop-and-go jitter and short tracks are kept."""
    ahead = _freeway_vehicle(1, 10, 40, 100.0, 4.0)
    backwards = _freeway_vehicle(2, 10, 40, 900.0, -4.0)
    path = _write(tmp_path, "us-101-trajectories.txt", ahead + backwards)
    with pytest.raises(InputError) as err:
        ngsim.read([path])
    assert err.value.line == 41 and err.value.column == "Local_Y"
    assert "vehicle 2 drives backwards on a one-way freeway" in str(err.value)
    jitter = [
        line.replace(f" {y} ", f" {float(y) + (-0.5 if k % 2 else 0.5):.3f} ")
        for k, line in enumerate(_freeway_vehicle(3, 10, 40, 200.0, 0.0))
        for y in [line.split()[5]]
    ]
    short = _freeway_vehicle(4, 10, 8, 500.0, -4.0)  # under a second: no direction to tell
    ok = _write(tmp_path, "us-101-ok.txt", ahead + jitter + short)
    assert ngsim.read([ok]).num_rows == 40 + 40 + 8


def test_a_negative_lane_id_is_refused(tmp_path: Path) -> None:
    """Lane_ID -1 on one row was kept (exit 0): two lane changes that never happened in the
    labels. NGSIM numbers lanes from 1 (0 and >= 10 on the arterials), so it is refused at its line."""
    lines = _freeway_vehicle(1, 10, 40, 100.0, 4.0)
    cells = lines[20].split()
    cells[13] = "-1"
    lines[20] = " ".join(cells)
    path = _write(tmp_path, "us-101-lanes.txt", lines)
    with pytest.raises(InputError) as err:
        ngsim.read([path])
    assert err.value.line == 21 and err.value.column == "Lane_ID" and "Lane_ID is -1" in str(err.value)


def test_a_log_of_ngsim_starts_at_global_time_where_it_is_a_date(tmp_path: Path) -> None:
    """US-101's Global_Time is Unix milliseconds: a log of it begins on 15 June 2005; the CSV
    export's Peachtree values are no date, so its log keeps the table's clock."""
    from datetime import datetime, timezone

    from mcap.reader import make_reader

    us101 = registry.read_any([TXT.parent])
    log = registry.write_any(us101, tmp_path / "us101.mcap", "mcap")
    with log.open("rb") as fh:
        first = next(iter(make_reader(fh).iter_messages()))[2].log_time
    assert datetime.fromtimestamp(first / 1e9, timezone.utc).date().isoformat() == "2005-06-15"
    first_row = int(us101.column("time_ns").to_numpy().min())
    assert first - first_row == 1118846979700 * 1_000_000  # Global_Time − 100 ms × Frame_ID
    peachtree = registry.read_any([SAMPLE])
    assert not any("start_time_ns" in r.extra for r in track_table.read_meta(peachtree).recordings.values())
