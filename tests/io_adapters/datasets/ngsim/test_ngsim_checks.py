"""NGSIM reader checks: values out of range, ids beyond 2^53, stray times, duplicates, open quotes,
units, columns twice or missing, damaged files of a folder; each refused at its file, line and
column, or read as the valid input it is."""

from __future__ import annotations

import gzip
import os
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pyarrow as pa
import pytest
from conftest import (
    HEADER,
    HIGHD,
    PEACHTREE,
    US101,
    _export,
    _parquet,
    _quoted,
    _rows,
    _txt_variant,
    convert_refused,
    highd_copy,
    refused,
    set_cell,
)

from lanecast.io_adapters.datasets.ngsim import reader as ngsim
from lanecast.io_adapters.datasets.ngsim.columns import TXT_COLUMNS
from lanecast.io_adapters.errors import InputError
from lanecast.io_adapters.formats import registry
from lanecast.workflows.cli import main


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


@pytest.mark.parametrize(
    ("content", "message"),
    [
        (b"", "line 1: empty file"),
        (b"\n  \n", "line 1: empty file"),
        (US101.read_text().encode("utf-16"), "offset 0: the file is UTF-16 text"),
        (gzip.compress(US101.read_bytes()), "offset 0: the file is gzip-compressed"),
        (b"Vehicle_ID Frame_ID\n1 2\n", "line 1: not an NGSIM file"),
    ],
)
def test_damaged_file_in_an_ngsim_folder_is_refused_not_left_out(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], content: bytes, message: str
) -> None:
    """Beside a good file, an empty, UTF-16, compressed or garbled trajectories-b.txt was silently
    left out of the folder: the table lacked a third of the data and nothing said so."""
    folder = tmp_path / "us-101"
    folder.mkdir()
    (folder / "trajectories-a.txt").write_bytes(US101.read_bytes())
    (folder / "trajectories-b.txt").write_bytes(content)
    convert_refused(folder, tmp_path, capsys, f"{folder / 'trajectories-b.txt'}, {message}")


def test_other_text_files_in_an_ngsim_folder_are_named_on_stderr(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    folder = tmp_path / "us-101"
    folder.mkdir()
    (folder / "trajectories-a.txt").write_bytes(US101.read_bytes())
    (folder / "README.txt").write_text("US-101, 2005-06-15\n")
    out = tmp_path / "out.parquet"
    assert main(["convert", str(folder), "--out", str(out)]) == 0
    assert f"{folder / 'README.txt'}: not an NGSIM file, left out" in capsys.readouterr().err
    assert out.is_file()


@pytest.mark.parametrize(("extra", "named"), [("Local_Y", "Local_Y"), ("vehicle_id", "vehicle_id")])
def test_ngsim_csv_with_a_column_twice(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], extra: str, named: str
) -> None:
    """A second Local_Y (zeros) was ignored in favour of the first without a word: which one holds
    the data cannot be known, as highD's reader already says."""
    lines = PEACHTREE.read_text().splitlines()[:200]
    path = tmp_path / "peachtree.csv"
    path.write_text("".join(f"{line},{extra if i == 0 else '0'}\n" for i, line in enumerate(lines)))
    convert_refused(path, tmp_path, capsys, f"{path}, line 1, column '{named}'", "appears twice")


def test_ngsim_in_metres_is_refused(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A metric re-export (lengths, widths, positions and speeds in m) was read as feet: every car
    1.4 m long and every speed 3.3 times too low, with exit 0."""
    rows = [line.split() for line in US101.read_text().splitlines()]
    for row in rows:
        for i in (4, 5, 8, 9, 11, 12):  # Local_X, Local_Y, v_Length, v_Width, v_Vel, v_Acc
            row[i] = f"{float(row[i]) * 0.3048:.3f}"
    path = tmp_path / "us-101" / "trajectories-0750am-0805am.txt"
    path.parent.mkdir()
    path.write_text("".join("  ".join(row) + "\n" for row in rows))
    convert_refused(
        path,
        tmp_path,
        capsys,
        f"{path}, line 1, column 'v_Length'",
        "look like metres",
        "expected NGSIM's feet",
    )


def test_ngsim_csv_with_quoted_fields_reads_as_unquoted(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """Every field in double quotes (a valid CSV) was 'format not recognised'."""
    import pyarrow.parquet as pq

    from lanecast.io_adapters.formats import streaming

    lines = PEACHTREE.read_text().splitlines()[:300]
    plain, quoted = tmp_path / "plain" / "peachtree.csv", tmp_path / "quoted" / "peachtree.csv"
    for path, text in (
        (plain, lines),
        (quoted, [",".join(f'"{c}"' for c in line.split(",")) for line in lines]),
    ):
        path.parent.mkdir()
        path.write_text("".join(line + "\n" for line in text))
    assert main(["convert", str(plain), "--out", str(tmp_path / "plain.parquet")]) == 0
    expected = pq.read_table(tmp_path / "plain.parquet")
    for stream_bytes in (streaming.STREAM_BYTES, 0):  # whole, and the streaming reader of large exports
        monkeypatch.setattr(streaming, "STREAM_BYTES", stream_bytes)
        out = tmp_path / f"quoted-{stream_bytes}.parquet"
        assert main(["convert", str(quoted), "--out", str(out)]) == 0, capsys.readouterr().err
        assert pq.read_table(out).to_pydict() == expected.to_pydict()  # the streaming spill chunks differ


@pytest.mark.parametrize("column", ["Vehicle_ID", "Local_Y"])
def test_ngsim_csv_without_a_key_column_names_it(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], column: str
) -> None:
    """A CSV export without Vehicle_ID (or with Local_Y misnamed) was 'format not recognised'."""
    lines = PEACHTREE.read_text().splitlines()[:50]
    path = tmp_path / "peachtree.csv"
    path.write_text("".join(line.replace(column, f"{column}X", 1) + "\n" for line in lines))
    convert_refused(path, tmp_path, capsys, f"{path}, line 1, column '{column.lower()}'", "missing column")


def test_impossible_vehicle_sizes_are_refused_at_their_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """v_Length 1e30 ft (within float32, so accepted) failed later as 'row 2: column 'x' is -1.5e29'
    (a row of the table, not a line of the file); a highD width of 1e6 m converted."""
    rows = [line.split() for line in US101.read_text().splitlines()]
    rows[2][8] = "1e30"
    path = tmp_path / "us-101" / "trajectories-0750am-0805am.txt"
    path.parent.mkdir()
    path.write_text("".join("  ".join(row) + "\n" for row in rows))
    refused(
        ["convert", str(path), "--out", str(tmp_path / "a.parquet")],
        capsys,
        f"{path}, line 3, column 'v_Length'",
        "<= 1000 ft",
    )
    rec = highd_copy(tmp_path, "tracks", set_cell("width", "1e6", {5}))
    refused(
        ["convert", str(rec), "--out", str(tmp_path / "b.parquet")],
        capsys,
        "01_tracks.csv, line 5, column 'width'",
        "<= 300 m",
    )


def test_ngsim_ids_beyond_2_53_stay_distinct(tmp_path: Path) -> None:
    """Vehicles 2^53 and 2^53 + 1 are two vehicles (float64 would merge them and drop rows)."""
    lines = US101.read_text().splitlines()
    ids = {line.split()[0] for line in lines}
    edits = {}
    for i, line in enumerate(lines, start=1):
        vid = line.split()[0]
        if vid == "1":
            edits[(i, 0)] = str(2**53)
        elif vid == "2":
            edits[(i, 0)] = str(2**53 + 1)
    table = registry.read_any([_txt_variant(tmp_path, edits)])
    original = registry.read_any([US101])
    got = set(table.column("track_id").to_pylist())
    assert {2**53, 2**53 + 1} <= got and len(got) == len(ids)
    assert table.num_rows == original.num_rows


@pytest.mark.parametrize(
    ("field", "value", "column", "expected"),
    [
        (1, str(2**62), "Frame_ID", "0 to"),
        (1, "-5", "Frame_ID", "0 to"),
        (3, "1e30", "Global_Time", "below 2^53"),
        (3, str(2**60), "Global_Time", "0 to 2^53"),
        (8, "0.0", "v_Length", "a length > 0"),
        (9, "-6.0", "v_Width", "a width > 0"),
        (11, "-40.0", "v_Vel", "a speed >= 0"),
        (13, str(2**33), "Lane_ID", "within int32"),
        (0, "9.3e18", "Vehicle_ID", "below 2^53"),
        (0, "-2", "Vehicle_ID", "a vehicle id >= 0"),  # was a phantom one-row track -2
        (14, "-5", "Preceding", "a vehicle id >= 0"),  # 0 is "none"; a negative id reached the table
        (15, "-1", "Following", "a vehicle id >= 0"),
    ],
)
def test_ngsim_values_out_of_range(
    tmp_path: Path, field: int, value: str, column: str, expected: str
) -> None:
    path = _txt_variant(tmp_path, {(5, field): value})
    with pytest.raises(InputError) as err:
        registry.read_any([path])
    assert err.value.path == str(path) and err.value.line == 5 and err.value.column == column
    assert expected in (err.value.expected or "")


def test_ngsim_stray_global_time_makes_no_phantom_recording(tmp_path: Path) -> None:
    path = _txt_variant(tmp_path, {(5, 3): "1118846990000"})  # one row 9 s off its vehicle's epoch
    with pytest.raises(InputError, match=r"recording period of its own|another recording period") as err:
        registry.read_any([path])
    assert err.value.line == 5 and err.value.column == "Global_Time"


def test_ngsim_conflicting_duplicates_are_reported(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = _txt_variant(tmp_path, {(4, 5): "109.000"})  # line 4 repeats line 3's (vehicle, frame)
    original = registry.read_any([US101])
    before = capsys.readouterr().err
    table = registry.read_any([path])
    after = capsys.readouterr().err
    assert "rows repeat a (Vehicle_ID, Frame_ID)" in after and after != before
    assert table.column("x").equals(original.column("x"))  # the first in file order is kept


@pytest.mark.parametrize(
    ("victim", "edit"),
    [
        ("peachtree.csv", lambda text: text.replace(",peachtree", ',"peachtree')),  # the Location
        ("peachtree.csv", lambda text: '"' + text),  # the first value
        ("peachtree.csv", lambda text: text.replace(",", ',"', 3)),  # numbers
        ("01_tracksMeta.csv", lambda text: text.replace(",Truck", ',"Truck')),  # highD's class
        ("01_tracks.csv", lambda text: '"' + text),
    ],
)
def test_an_open_quote_that_swallows_the_lines_after_it_is_refused_at_its_line(
    tmp_path: Path, victim: str, edit: Callable[[str], str]
) -> None:
    """A quoted value that runs on over line ends: the CSV parser read the rest of the file as one
    value and kept a single row, silently (the fuzzer found it in NGSIM's Location column). No
    dataset lanecast reads quotes across lines."""
    for kind in ("tracks", "tracksMeta", "recordingMeta"):
        (tmp_path / f"01_{kind}.csv").write_bytes((HIGHD / f"01_{kind}.csv").read_bytes())
    source = PEACHTREE if victim == "peachtree.csv" else HIGHD / victim
    path = _quoted(source, tmp_path / victim, 3, edit)
    with pytest.raises(InputError, match="double quote opens a value") as err:
        registry.read_any([path])
    assert err.value.path == str(path) and err.value.line == 3


def test_an_open_quote_in_a_location_is_refused_by_the_streaming_reader_too(tmp_path: Path) -> None:
    from lanecast.io_adapters.datasets.ngsim import stream as ngsim_stream

    path = _quoted(
        PEACHTREE, tmp_path / "peachtree.csv", 3, lambda text: text.replace(",peachtree", ',"peachtree')
    )
    with pytest.raises(InputError, match="double quote opens a value") as err:
        ngsim_stream.split_csv(path, tmp_path / "spill")
    assert err.value.line == 3


def test_peachtree_vehicle_570_heading_does_not_flip() -> None:
    """Its front bumper first runs 4 m backwards (a tracking glitch), then it stops and drives
    north: the heading stays north through the stop, so the centre does not jump a vehicle length
    when it moves off (it did: 8.86 m between frames 3389 and 3390)."""
    import pandas as pd

    table = registry.read_any([PEACHTREE])
    rows = table.filter(pa.compute.equal(table.column("track_id"), 570)).to_pandas()
    rows = rows[rows.recording == rows.recording.iloc[0]].sort_values("frame")
    assert rows.frame.iloc[0] == 3345 and rows.frame.iloc[-1] == 3439
    heading = np.degrees(rows.heading.to_numpy())
    assert np.abs(heading).max() < 30  # north (+x) all along
    centre_step = np.hypot(np.diff(rows.x.to_numpy()), np.diff(rows.y.to_numpy()))
    source = pd.read_csv(PEACHTREE)
    src = source[source.Vehicle_ID == 570].sort_values("Frame_ID")
    bumper_step = 0.3048 * np.hypot(np.diff(src.Local_X.to_numpy()), np.diff(src.Local_Y.to_numpy()))
    frames = rows.frame.to_numpy()
    at_3389 = int(np.flatnonzero(frames == 3389)[0])
    assert centre_step[at_3389] < 0.5
    # Per frame the centre moves < 0.5 m beyond what the front bumper itself moves (the source's
    # own first steps are 2.3 m: the glitch) and < 0.5 m wherever the bumper moves < 0.45 m.
    assert (centre_step - bumper_step).max() < 0.5
    assert (centre_step[bumper_step < 0.45] < 0.5).all()


def _folder_with(tmp_path: Path, form: str) -> tuple[Path, str]:
    """An input folder of ``form`` with one good file, and the name under which to plant an entry."""
    folder = tmp_path / "in"
    folder.mkdir()
    if form == "ngsim":
        (folder / US101.name).write_bytes(US101.read_bytes())
        return folder, "x.txt"
    if form == "highd":
        for kind in ("tracks", "tracksMeta", "recordingMeta"):
            (folder / f"01_{kind}.csv").write_bytes((HIGHD / f"01_{kind}.csv").read_bytes())
        return folder, "02_tracks.csv"
    _parquet(tmp_path)[0].rename(folder / "part-00000.parquet")
    return folder, "part-00001.parquet"


@pytest.mark.parametrize("form", ["ngsim", "highd", "parquet"])
@pytest.mark.parametrize("entry", ["fifo", "device", "dangling link"])
def test_an_entry_of_an_input_folder_that_is_no_file_is_named(tmp_path: Path, form: str, entry: str) -> None:
    """A FIFO, a link to /dev/zero or a link to nothing under a data file's name in an NGSIM folder,
    a highD folder or a Parquet dataset was left out without a word (its rows silently missing);
    it is refused naming it, and never opened (a FIFO would block the run)."""
    folder, name = _folder_with(tmp_path, form)
    planted = folder / name
    if entry == "fifo":
        os.mkfifo(planted)
    else:
        planted.symlink_to("/dev/zero" if entry == "device" else tmp_path / "gone.txt")
    with pytest.raises(InputError) as err:
        registry.read_any([folder])
    assert err.value.path == str(planted)
    words = "a symbolic link to a missing file" if entry == "dangling link" else "not a regular file"
    assert words in str(err.value)


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (lambda rows: [r + "  0" for r in rows], "19 whitespace-separated fields in the first row"),
        (lambda rows: [" ".join(r.split()[:17]) for r in rows], "17 whitespace-separated fields"),
        (lambda rows: [",".join(r.split()) for r in rows], "18 comma-separated fields"),
        (lambda rows: [" ".join(TXT_COLUMNS), *rows], "a header line of NGSIM's column names"),
    ],
)
def test_a_txt_that_is_ngsim_but_for_its_layout_is_named_with_its_line(
    tmp_path: Path, edit: Callable[[list[str]], list[str]], message: str
) -> None:
    """Such files were refused as 'format not recognised' with no line and nothing about NGSIM."""
    path = tmp_path / "trajectories-0750am-0805am.txt"
    path.write_text("\n".join(edit([r for r in US101.read_text().splitlines() if r.strip()])) + "\n")
    with pytest.raises(InputError, match=message) as err:
        registry.read_any([path])
    assert err.value.line == 1 and "18 whitespace-separated numbers" in (err.value.expected or "")
