"""Semantically malformed inputs through the real commands: syntactically valid files whose
content cannot be right. Each gets exit status 2 and one line naming the file, the line or offset
and what was expected, and leaves no output behind; or, where the input is valid, a correct one.

Size: one test (or parametrised case) per defect found by running the commands on hostile inputs,
grouped by input kind (highD, NGSIM, Parquet, windows datasets, logs, outputs, options), each with
the input that showed it; the byte-level and per-format unit cases stay in test_hostile_inputs.py.
"""

from __future__ import annotations

import gzip
import json
import os
import shutil
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from lanecast.workflows.cli import main

REPO = Path(__file__).resolve().parents[1]
HIGHD = REPO / "tests" / "data" / "highd"


def run(args: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str]:
    """Exit status and the last line of stderr (progress lines come before it)."""
    status = main(args)
    err = capsys.readouterr().err.strip()
    assert "Traceback" not in err
    return status, err.splitlines()[-1] if err else ""


def refused(args: list[str], capsys: pytest.CaptureFixture[str], *names: str) -> str:
    """Run a command that must refuse its input: status 2, one error line naming ``names``."""
    status, line = run(args, capsys)
    assert status == 2, line
    assert line.startswith(f"lanecast {args[0]}: error: "), line
    for name in names:
        assert name in line, line
    return line


def highd_copy(tmp_path: Path, kind: str = "", edit: Callable[[list[str]], list[str]] | None = None) -> Path:
    """The highD fixture in ``tmp_path/rec`` with ``01_<kind>.csv`` edited line by line."""
    rec = tmp_path / "rec"
    rec.mkdir()
    for src in HIGHD.glob("01_*.csv"):
        shutil.copy(src, rec / src.name)
    if edit is not None:
        path = rec / f"01_{kind}.csv"
        path.write_text("".join(line + "\n" for line in edit(path.read_text().splitlines())))
    return rec


def set_cell(
    column: str, value: str | Callable[[str], str], lines: set[int] | None = None
) -> Callable[[list[str]], list[str]]:
    """An edit setting ``column`` on the given 1-based ``lines`` (every data line by default)."""

    def edit(rows: list[str]) -> list[str]:
        index = rows[0].split(",").index(column)
        out = [rows[0]]
        for number, row in enumerate(rows[1:], start=2):
            cells = row.split(",")
            if lines is None or number in lines:
                cells[index] = value(cells[index]) if callable(value) else value
            out.append(",".join(cells))
        return out

    return edit


def no_output(out: Path) -> None:
    assert not out.exists()
    assert not [p for p in out.parent.iterdir() if p.name.startswith(f".{out.name}")]


def convert_refused(source: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str], *names: str) -> str:
    """``lanecast convert SOURCE --out tmp_path/out.parquet`` must refuse its input (see
    :func:`refused`) and leave no output, not even a temporary one."""
    out = tmp_path / "out.parquet"
    line = refused(["convert", str(source), "--out", str(out)], capsys, *names)
    no_output(out)
    return line


# ------------------------------------------------------------------------------------------ highD


def test_windows_of_tracks_without_a_10hz_sample(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """At 1 kHz every track of the fixture lasts milliseconds: no sample at 10 Hz, so no windows
    (resampling gave an empty table, which crashed the lane-change labels)."""
    rec = highd_copy(tmp_path, "recordingMeta", set_cell("frameRate", "1000"))
    out = tmp_path / "win"
    refused(["windows", str(rec), "--out", str(out)], capsys, "no windows", "no rows at 10 Hz")
    no_output(out)


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


# ------------------------------------------------------------------------------------------ NGSIM

US101 = REPO / "tests" / "data" / "ngsim" / "us-101" / "trajectories-fixture.txt"


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


def test_error_is_the_last_line_after_progress(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The second file of a folder is cut short: the error line ends stderr (the abandoned progress
    used to print its count after it, when the reader's generator was collected)."""
    folder = tmp_path / "us-101"
    folder.mkdir()
    (folder / "trajectories-a.txt").write_bytes(US101.read_bytes())
    (folder / "trajectories-b.txt").write_bytes(US101.read_bytes()[:-40])
    convert_refused(folder, tmp_path, capsys, "trajectories-b.txt, line 15", "truncated")


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


@pytest.mark.parametrize(
    ("content", "message"),
    [
        (b"", "offset 0: empty file"),
        (
            "Vehicle_ID,Frame_ID\n".encode("utf-16"),
            "offset 0: format not recognised: the file is UTF-16 text",
        ),
        (
            gzip.compress(b"Vehicle_ID,Frame_ID\n"),
            "offset 0: format not recognised: the file is gzip-compressed",
        ),
    ],
)
def test_unrecognised_file_says_what_it_is(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], content: bytes, message: str
) -> None:
    path = tmp_path / "trajectories.csv"
    path.write_bytes(content)
    out = tmp_path / "out.parquet"
    for command in (["convert", str(path), "--out", str(out)], ["info", str(path)]):
        refused(command, capsys, f"{path}, {message}")
    no_output(out)


PEACHTREE = REPO / "tests" / "data" / "ngsim" / "peachtree_sample.csv"


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


# ---------------------------------------------------------------------------------------- Parquet


def track_table_copy(tmp_path: Path, edit: Callable[[pa.Table], pa.Table] | None = None) -> Path:
    """The highD fixture as a Parquet track table (``edit``ed, written as is) in ``tmp_path``."""
    from lanecast.io_adapters.formats import registry

    table = registry.read_any([HIGHD])
    path = tmp_path / "table.parquet"
    pq.write_table(table if edit is None else edit(table), path)
    return path


@pytest.mark.parametrize("partition", [False, True])
def test_a_table_without_rows_leaves_no_output(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], partition: bool
) -> None:
    """A track table of zero rows: 'no rows to write', but the empty temporary output was renamed
    into place anyway (the writer's own refusal did not reach the atomic write)."""
    path = track_table_copy(tmp_path, lambda t: t.slice(0, 0))
    out = tmp_path / ("out" if partition else "out.parquet")
    refused(
        ["convert", str(path), "--out", str(out), *(["--partition"] if partition else [])],
        capsys,
        f"error: {path}: no rows",  # the input that has none, not the output never written
    )
    no_output(out)


def _null_recording(table: pa.Table) -> pa.Table:
    names = table.column("recording").to_pylist()
    names[2] = None
    field = table.schema.field("recording").with_nullable(True)
    return table.set_column(0, field, pa.array(names, pa.string()).dictionary_encode())


@pytest.mark.parametrize(
    ("edit", "words"),
    [
        (lambda t: t.append_column(t.schema.field("x"), t.column("x")), "column 'x' appears twice"),
        (_null_recording, "row 2: column 'recording' is null"),
        (  # rows in another order are put in order: the repeated row is named
            lambda t: pa.concat_tables([t, t.slice(0, 1)]),
            "row 14: duplicate (recording, track_id, frame) = (highd-01-lower, 1, 1)",
        ),
    ],
    ids=["column twice", "null recording", "recording twice"],
)
def test_track_table_columns_arrow_allows_but_the_contract_does_not(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], edit: Callable[[pa.Table], pa.Table], words: str
) -> None:
    """A column twice (KeyError) and a null recording (TypeError in the streaming planner) were
    tracebacks; a recording whose rows come back later named no row."""
    path = track_table_copy(tmp_path, edit)
    convert_refused(path, tmp_path, capsys, f"error: {path}: {words}")


@pytest.mark.parametrize(
    ("edit", "words"),
    [
        (lambda t: t.replace_schema_metadata(None), "no 'lanecast' schema metadata"),
        (lambda t: t.replace_schema_metadata({b"lanecast": b"{"}), "not JSON"),
        (
            lambda t: t.replace_schema_metadata(
                {
                    b"lanecast": t.schema.metadata[b"lanecast"].replace(
                        b'"frame_rate": 25.0', b'"frame_rate": 0'
                    )
                }
            ),
            "frame_rate': 0",
        ),
    ],
)
def test_bad_metadata_of_a_track_table_names_the_file(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], edit: Callable[[pa.Table], pa.Table], words: str
) -> None:
    """Through convert's streaming reader the metadata errors named no file."""
    path = track_table_copy(tmp_path, edit)
    convert_refused(path, tmp_path, capsys, f"error: {path}: ", words)


def test_no_windows_names_the_table_given(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A converted table without windows blamed the highD CSVs it was once converted from (its
    metadata's source files), which may not even exist here; an empty one said '<input>'."""
    for name, edit in (("short", None), ("empty", lambda t: t.slice(0, 0))):
        (tmp_path / name).mkdir()
        path = track_table_copy(tmp_path / name, edit)
        out = tmp_path / name / "win"
        line = refused(["windows", str(path), "--out", str(out)], capsys, f"error: {path}: no windows")
        assert "01_tracks.csv" not in line
        no_output(out)


def _set_row(name: str, row: int, value: float) -> Callable[[pa.Table], pa.Table]:
    def edit(table: pa.Table) -> pa.Table:
        values = table.column(name).to_numpy().copy()
        values[row] = value
        index = table.schema.get_field_index(name)
        return table.set_column(
            index, table.schema.field(name), pa.array(values, table.schema.field(name).type)
        )

    return edit


@pytest.mark.parametrize(
    ("name", "value", "expected"),
    [
        ("x", 1e300, "a finite position within ±1e+09 m"),
        ("y", -1e12, "a finite position within ±1e+09 m"),
        ("width", -1.8, "a size >= 0 m"),
    ],
)
def test_impossible_values_in_a_track_table_are_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], name: str, value: float, expected: str
) -> None:
    """x = 1e300 in one row of a Parquet table (finite, so accepted) became inf in the windows'
    inputs.npy with exit 0; a negative width was taken as it was."""
    path = track_table_copy(tmp_path, _set_row(name, 3, value))
    for command in ("convert", "windows"):
        out = tmp_path / f"{command}-out"
        refused(
            [command, str(path), "--out", str(out)],
            capsys,
            f"{path}: row 3: column '{name}'",
            f"expected {expected}",
        )
        no_output(out)


def test_times_a_log_cannot_hold(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Negative times (valid int64) crashed the MCAP writer with struct.error; times after 2038
    crashed the ROS bag writers (a header's seconds are int32). Refused before writing."""
    early = track_table_copy(tmp_path, lambda t: _set_row("time_ns", 0, -1)(t))
    out = tmp_path / "out.mcap"
    refused(
        ["convert", str(early), "--out", str(out)],
        capsys,
        f"{early}: row 0: column 'time_ns' is -1",
        ">= 0 ns",
    )
    no_output(out)
    late = tmp_path / "late"
    late.mkdir()
    later = pa.scalar(2**62, pa.int64())

    def shifted(table: pa.Table) -> pa.Table:
        index = table.schema.get_field_index("time_ns")
        return table.set_column(
            index, table.schema.field("time_ns"), pa.compute.add(table.column("time_ns"), later)
        )

    path = track_table_copy(late, shifted)
    for target in (["--out", str(tmp_path / "out.bag")], ["--to", "ros2", "--out", str(tmp_path / "bag2")]):
        refused(
            ["convert", str(path), *target],
            capsys,
            f"{target[-1]}, column 'time_ns': cannot be a ROS bag: row 0",
        )
        no_output(Path(target[-1]))


# -------------------------------------------------------------------------------- windows datasets


def windows_copy(tmp_path: Path, damage: Callable[[Path], object]) -> Path:
    """A small windows dataset in ``tmp_path/win``, then ``damage``d."""
    from conftest import synthetic_windows

    from lanecast.io_adapters.windows_store.dataset import save_windows

    directory = save_windows(synthetic_windows(60), tmp_path / "win")
    damage(directory)
    return directory


def _edit_npy(name: str, edit: Callable[[np.ndarray], np.ndarray]) -> Callable[[Path], None]:
    def damage(directory: Path) -> None:
        path = directory / f"{name}.npy"
        np.save(path, edit(np.load(path)))

    return damage


def _set_first(value: float) -> Callable[[np.ndarray], np.ndarray]:
    def edit(array: np.ndarray) -> np.ndarray:
        array.reshape(-1)[7] = value
        return array

    return edit


def _drop_split(directory: Path) -> None:
    pq.write_table(
        pq.read_table(directory / "windows.parquet").drop_columns(["split"]), directory / "windows.parquet"
    )


def _manifest_set(directory: Path, **fields: object) -> None:
    manifest = json.loads((directory / "manifest.json").read_text())
    (directory / "manifest.json").write_text(json.dumps({**manifest, **fields}))


WINDOWS_DAMAGE: dict[str, tuple[Callable[[Path], object], str, str]] = {
    # case: (damage, file named, words): each was a traceback, a silent result or named no file
    "empty inputs.npy": (lambda d: (d / "inputs.npy").write_bytes(b""), "inputs.npy", "not a readable .npy array"),
    "manifest a list": (lambda d: (d / "manifest.json").write_text("[]"), "manifest.json", "not a JSON object"),
    "index without split": (_drop_split, "windows.parquet, column 'split'", "no column 'split'"),
    "maneuver 7": (_edit_npy("maneuver", _set_first(7)), "maneuver.npy", "window 1 holds 7"),
    "NaN input": (_edit_npy("inputs", _set_first(np.nan)), "inputs.npy", "window 0 holds nan"),
    "infinite future": (_edit_npy("future", _set_first(np.inf)), "future.npy", "window 0 holds inf"),
    "inputs short": (_edit_npy("inputs", lambda a: a[:-5]), "inputs.npy", "float32[55, 4, 8, 30]"),
    "no labelled windows": (_edit_npy("future", lambda a: a * np.nan), "win: no labelled", "known futures"),
    # no target in its own window: a ValueError drawing the report's scenes
    "target absent": (_edit_npy("present", np.zeros_like), "present.npy", "the target (row 4) is absent"),
    # a dataset of a newer format: read as if it were this one
    "format_version 99": (lambda d: _manifest_set(d, format_version=99), "manifest.json", "format_version 99"),
}  # fmt: skip


@pytest.mark.parametrize("case", sorted(WINDOWS_DAMAGE))
def test_damaged_windows_dataset(tmp_path: Path, capsys: pytest.CaptureFixture[str], case: str) -> None:
    damage, named, words = WINDOWS_DAMAGE[case]
    directory = windows_copy(tmp_path, damage)
    out = tmp_path / "report"
    refused(["evaluate", str(directory), "--out", str(out), "--split", "all"], capsys, named, words)
    no_output(out)


def test_training_on_a_bad_label_is_refused(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """maneuver 7 crashed training with an IndexError in the loss (exit 1, a traceback)."""
    directory = windows_copy(tmp_path, _edit_npy("maneuver", _set_first(7)))
    out = tmp_path / "model"
    refused(
        ["train", str(directory), "--out", str(out), "--epochs", "1"],
        capsys,
        "maneuver.npy",
        "window 1 holds 7",
    )
    no_output(out)


def test_training_on_a_huge_finite_input_is_refused_at_its_window(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """An input of 1e30 (finite; the fuzzer's seed 300135) overflowed the normalisation statistics
    to inf: train ran an epoch, then said "bad normalisation statistics {...}", naming no file."""
    directory = windows_copy(tmp_path, _edit_npy("inputs", _set_first(1e30)))
    out = tmp_path / "model"
    refused(
        ["train", str(directory), "--out", str(out), "--epochs", "1"],
        capsys,
        "inputs.npy",
        "window 0 holds 1.0000000150474662e+30 (expected finite inputs within ±1e+09",
    )
    no_output(out)


# ------------------------------------------------------------------------------------------- logs


@pytest.mark.parametrize("chunked", [True, False])
def test_log_times_beyond_int64_are_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], chunked: bool
) -> None:
    """MCAP log times are uint64: 2^63 ns (valid MCAP) ended in 'OverflowError: Python int too large
    to convert to C long' (exit 1) when the track table's int64 times were built."""
    from mcap.writer import Writer
    from test_hostile_inputs import _entity

    schema = (REPO / "io_adapters/data/foxglove/jsonschema/SceneUpdate.json").read_bytes()
    path = tmp_path / "late.mcap"
    with path.open("wb") as f:
        writer = Writer(f, use_chunking=chunked)
        writer.start()
        channel = writer.register_channel(
            "/objects", "json", writer.register_schema("foxglove.SceneUpdate", "jsonschema", schema)
        )
        for i in range(5):
            data = json.dumps({"entities": [_entity(1, 2.0 * i)]}).encode()
            writer.add_message(channel, log_time=2**63 + i, data=data, publish_time=0)
        writer.finish()
    convert_refused(path, tmp_path, capsys, f"{path}, offset ", "log time 9223372036854775808 ns")


def test_a_position_is_blamed_before_the_speed_derived_from_it(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """x = 1e300 in one SceneUpdate was reported as 'column 'vx' is inf' (the speed derived from it)."""
    from test_hostile_inputs import _entity, json_log, straight_messages

    messages = straight_messages(n=30)
    messages[10][2][0] = _entity(1, 1e300)
    path = json_log(tmp_path / "far.mcap", messages)
    refused(
        ["convert", str(path), "--out", str(tmp_path / "o.parquet")],
        capsys,
        f"{path}: topic '/objects', the object of track 1 stamped ",  # where it is in the log
        "column 'x' is 1e+300",
    )


# ---------------------------------------------------------------------------------------- outputs


@pytest.mark.parametrize(
    "command",
    [["windows", "--split", "none"], ["convert", "--partition"], ["convert", "--to", "ros2"]],
    ids=["windows", "partition", "ros2"],
)
def test_a_directory_output_never_deletes_a_users_files(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], command: list[str]
) -> None:
    """--out naming an existing directory of one's own files: the atomic rename replaced it whole,
    deleting thesis.txt with exit 0. Refused; a previous output of the command is still replaced."""
    from test_hostile_inputs import json_log, straight_messages

    log = json_log(tmp_path / "in.mcap", straight_messages(n=120))
    out = tmp_path / "mine"
    out.mkdir()
    (out / "thesis.txt").write_text("precious\n")
    name, *options = command
    refused([name, str(log), "--out", str(out), *options], capsys, f"{out}: the directory holds 'thesis.txt'")
    assert (out / "thesis.txt").read_text() == "precious\n" and len(list(out.iterdir())) == 1
    again = tmp_path / "again"
    for _ in range(2):
        assert main([name, str(log), "--out", str(again), *options]) == 0
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]


def test_a_report_appears_whole_or_not_at_all(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """evaluate wrote metrics.json straight into --out, then the report: interrupted (Ctrl-C) or
    failing in between, --out kept a metrics.json without its report. Here report.html cannot be
    written (a directory of that name is in the way): nothing of the run may appear."""
    directory = windows_copy(tmp_path, lambda d: None)
    out = tmp_path / "report"
    (out / "report.html").mkdir(parents=True)
    refused(
        ["evaluate", str(directory), "--out", str(out), "--split", "all"],
        capsys,
        "report.html",
        "is a directory",
    )
    assert [p.name for p in out.iterdir()] == ["report.html"]
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]
    (out / "report.html").rmdir()
    (out / "mine.txt").write_text("kept\n")
    assert main(["evaluate", str(directory), "--out", str(out), "--split", "all"]) == 0
    assert {"metrics.json", "report.html", "mine.txt"} <= {p.name for p in out.iterdir()}


@pytest.mark.parametrize(
    ("argv", "blocker"),
    [
        (["train", "{missing}", "--epochs", "1"], "file"),
        (["evaluate", "{missing}"], "file"),
        (["explain", "{missing}", "--track", "1", "--time", "5"], "file"),
        (["ablate", "{missing}", "--epochs", "1"], "file"),
        (["annotate", "{missing}"], "file"),
        (["windows", "{missing}"], "file"),
        (["windows", "{missing}"], "users"),
        (["convert", "{missing}", "--to", "ros2"], "users"),
        (["simulate", "--minutes", "1", "--seed", "1"], "parent"),
        (["train", "{missing}", "--epochs", "1"], "weights dir"),
    ],
    ids=lambda v: v if isinstance(v, str) else v[0],
)
def test_an_output_that_cannot_be_written_is_refused_before_the_work(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], argv: list[str], blocker: str
) -> None:
    """train --out naming a file trained ~17 s, then failed with a bare 'File exists' (annotate,
    simulate under a file the same); windows and convert into a directory of one's own files did all
    their work before refusing. Each output is now checked first: with a missing input, the output
    is what the error names."""
    taken = tmp_path / "taken"
    out = taken
    if blocker == "file":
        taken.write_text("keep\n")
        said = f"{taken}: exists and is not a directory"
    elif blocker == "parent":
        taken.write_text("keep\n")
        out = taken / "sim"
        said = f"{out}: cannot write here"
    elif blocker == "users":
        (taken / "thesis.txt").parent.mkdir()
        (taken / "thesis.txt").write_text("keep\n")
        said = f"{taken}: the directory holds 'thesis.txt'"
    else:
        (taken / "stcnn.safetensors").mkdir(parents=True)
        said = f"{taken / 'stcnn.safetensors'}: is a directory"
    before = sorted((p.relative_to(tmp_path), p.is_dir()) for p in tmp_path.rglob("*"))
    missing = str(tmp_path / "missing")
    refused([*(a.format(missing=missing) for a in argv), "--out", str(out)], capsys, said)
    assert sorted((p.relative_to(tmp_path), p.is_dir()) for p in tmp_path.rglob("*")) == before


@pytest.mark.slow
@pytest.mark.parametrize("signal_name", ["SIGTERM", "SIGINT"])
def test_a_signal_while_writing_leaves_nothing(tmp_path: Path, signal_name: str) -> None:
    """SIGTERM (a batch system ending the job) while a ROS 2 bag was being written killed the
    process outright: its temporary directory (.bag.tmp-*, the half-written storage) stayed beside
    the output. Now it is handled as Ctrl-C: exit 143 (SIGINT 130), one line, nothing left."""
    import signal
    import subprocess
    import sys

    from conftest import make_track_table

    from lanecast.io_adapters.contracts import track_table

    frames = np.tile(np.arange(3000), 10)
    table = make_track_table(
        {
            "track_id": np.repeat(np.arange(1, 11), 3000),
            "frame": frames,
            "x": frames * 3.0,
            "y": np.zeros(30000),
            "lane_id": np.ones(30000),
        }
    )
    source = track_table.write_parquet(table, tmp_path / "t.parquet")
    out = tmp_path / "bag"
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    command = [sys.executable, "-m", "lanecast", "convert", str(source), "--to", "ros2", "--out", str(out)]
    # SIGINT as a terminal's Ctrl-C delivers it: a pytest started in the background (`nohup … &`)
    # passes SIGINT on ignored, and a Python started with SIGINT ignored rightly keeps ignoring it.
    with subprocess.Popen(
        command,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    ) as process:
        assert process.stderr is not None
        for line in process.stderr:  # the first progress line: the bag is being written
            if line.startswith("writing bag"):
                break
        process.send_signal(getattr(signal, signal_name))
        rest = process.stderr.read()
        status = process.wait(timeout=60)
    # SIGINT: 130, or (seen once in a loaded full CI run, not reproduced alone) the process ending by
    # the signal itself after the message, which a shell reports as 130 all the same
    assert status in ((143,) if signal_name == "SIGTERM" else (130, -signal.SIGINT)), rest
    assert (
        rest.strip().splitlines()[-1]
        == f"lanecast convert: {'terminated' if signal_name == 'SIGTERM' else 'interrupted'}"
    )
    assert "Traceback" not in rest
    assert sorted(p.name for p in tmp_path.iterdir()) == ["t.parquet"]


@pytest.mark.parametrize("suffix", [".parquet", ".mcap", ".bag"])
def test_an_output_onto_a_fifo_is_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], suffix: str
) -> None:
    """--out naming an existing FIFO (or, as root, /dev/full) exited 0 having renamed the output onto
    it: the FIFO (the device node) was replaced by a regular file."""
    import stat

    source = track_table_copy(tmp_path)
    fifo = tmp_path / f"out{suffix}"
    os.mkfifo(fifo)
    refused(["convert", str(source), "--out", str(fifo)], capsys, f"{fifo}: not a regular file")
    assert stat.S_ISFIFO(fifo.lstat().st_mode)
    link = tmp_path / f"link{suffix}"
    link.symlink_to(fifo)
    refused(["convert", str(source), "--out", str(link)], capsys, f"{link}: not a regular file")
    assert stat.S_ISFIFO(fifo.lstat().st_mode) and link.is_symlink()


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


# ---------------------------------------------------------------------------------------- options


@pytest.mark.parametrize(
    ("options", "config", "named"),
    [
        (["--epochs", "0"], None, "--epochs: 0 (expected an integer from 1 to 100000)"),
        (["--lr", "nan"], None, "--lr: nan (expected a number from 0.0 to 10.0)"),
        (["--lr", "-1"], None, "--lr: -1.0 (expected a number from 0.0 to 10.0)"),
        (["--batch-size", "0"], None, "--batch-size: 0"),
        (["--threads", "0"], None, "--threads: 0"),
        (["--device", "tpu9"], None, "--device: 'tpu9'"),
        (["--position-noise", "-1"], None, "position_noise_m must be >= 0"),
        ([], '{"epochs": "three"}', "epochs: 'three' (expected an integer from 1 to 100000)"),
        # a JSON list trained 30 epochs with the defaults; 10**12 epochs ran until killed; a seed
        # beyond int64 (or below 0) failed in numpy once the data was loaded
        ([], "[]", "config.json, column 'config': bad training config: [] (expected a JSON object)"),
        ([], '[["epochs", 3]]', "bad training config: [['epochs', 3]] (expected a JSON object)"),
        ([], '{"epochs": 1000000000000}', "epochs: 1000000000000 (expected an integer from 1 to 100000)"),
        ([], '{"seed": 1180591620717411303424}', "seed: 1180591620717411303424 (expected an integer from 0"),
        ([], '{"seed": -1}', "seed: -1 (expected an integer from 0"),
        (
            ["--batch-size", str(2**40)],
            None,
            "--batch-size: 1099511627776 (expected an integer from 1 to 1048576)",
        ),
    ],
)
def test_training_options_of_the_wrong_type_or_range(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], options: list[str], config: str | None, named: str
) -> None:
    """--epochs 0 saved an untrained model with exit 0; the others ended in tracebacks from torch
    (ValueError: Invalid learning rate, ZeroDivisionError, RuntimeError: Invalid device string, a
    TypeError adding a str epoch count)."""
    directory = windows_copy(tmp_path, lambda d: None)
    if config is not None:
        (tmp_path / "config.json").write_text(config)
        options = ["--config", str(tmp_path / "config.json")]
    out = tmp_path / "model"
    refused(["train", str(directory), "--out", str(out), *options], capsys, named)
    no_output(out)


@pytest.mark.parametrize(
    ("command", "option", "value", "expected"),
    [
        # tracebacks: "OverflowError: Python int too large to convert to C long" (stride, workers),
        # "ValueError: Maximum allowed dimension exceeded" (top-k)
        ("windows", "--stride", "99999999999999999999", "an integer from 1 to 36000"),
        ("windows", "--workers", "99999999999999999999", "an integer from 1 to 1024"),
        ("convert", "--workers", "99999999999999999999", "an integer from 1 to 1024"),
        ("evaluate", "--top-k", "99999999999999999999", "an integer from 1 to 243"),
        ("annotate", "--top-k", "244", "an integer from 1 to 243"),
        # taken with exit 0: no example scenes, no retries, no neighbour range, a seed out of range
        ("evaluate", "--examples", "-1", "an integer from 0 to 100"),
        ("report", "--examples", "-1", "an integer from 0 to 100"),
        ("convert", "--retries", "-1", "an integer from 0 to 100"),
        ("windows", "--neighbour-range", "inf", "a number above 0, at most 10000 m"),
        ("windows", "--seed", "-1", "an integer from 0 to 2147483647"),
        ("annotate", "--every", "nan", "a number above 0, at most 86400 s"),
        ("windows", "--stride", "ten", "an integer from 1 to 36000"),
        # earlier checks, now where the option is parsed: --batch-size 0 was 'ValueError: range() arg 3
        # must not be zero', --top-k 0 reported minADE@1, --every nan and --time nan 'ValueError:
        # cannot convert float NaN to integer' (--every in every log's task)
        ("evaluate", "--batch-size", "0", "an integer from 1 to 1048576"),
        ("evaluate", "--top-k", "0", "an integer from 1 to 243"),
        ("annotate", "--every", "inf", "a number above 0, at most 86400 s"),
        ("explain", "--time", "nan", "a number from -9.2e+09 to 9.2e+09 s"),
        ("explain", "--time", "1e300", "a number from -9.2e+09 to 9.2e+09 s"),
    ],
)
def test_numeric_options_out_of_range_are_usage_errors(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], command: str, option: str, value: str, expected: str
) -> None:
    """Every numeric option is checked where it is parsed: argparse's one line, exit 2, naming the
    option, the value and the range, before any input is read or output made."""
    out = tmp_path / "out"
    with pytest.raises(SystemExit) as exit_info:
        main([command, str(tmp_path / "input"), "--out", str(out), option, value])
    assert exit_info.value.code == 2
    line = capsys.readouterr().err.strip().splitlines()[-1]
    assert line.startswith(f"lanecast {command}: error: argument {option}: {value}"), line
    assert line.endswith(f"(expected {expected})"), line
    assert not out.exists()


def test_location_given_for_a_log_is_ignored_as_for_other_readers(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """--location (NGSIM's) with an MCAP input: 'TypeError: read_log() got an unexpected keyword
    argument 'location'' (exit 1); the other readers are never given the options of another."""
    from test_hostile_inputs import json_log, straight_messages

    log = json_log(tmp_path / "in.mcap", straight_messages())
    assert main(["convert", str(log), "--location", "us-101", "--out", str(tmp_path / "o.parquet")]) == 0
    assert "Traceback" not in capsys.readouterr().err


@pytest.mark.parametrize("every", ["0.01", "0.04"])
def test_annotate_every_outside_the_grid_is_one_error_up_front(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], every: str
) -> None:
    """0.01 s failed as 'FAILED <log>: <input>: --every 0.01', exit 1 (nan and inf: in
    test_numeric_options_out_of_range_are_usage_errors)."""
    from test_hostile_inputs import json_log, straight_messages

    log = json_log(tmp_path / "in.mcap", straight_messages(n=60))
    out = tmp_path / "out"
    refused(
        ["annotate", str(log), "--every", every, "--out", str(out)], capsys, "--every: ", "at least 0.1 s"
    )
    assert not out.exists()


def test_a_log_that_fails_in_annotate_ends_stderr_with_its_error(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A truncated log given to annotate: exit 1 with its error only on stdout (in the summary)
    and a progress line last on stderr; now the error is the last line on stderr, as for every
    other command, and the good log beside it is still annotated."""
    from test_hostile_inputs import json_log, straight_messages

    logs = tmp_path / "logs"
    logs.mkdir()
    good = json_log(logs / "good.mcap", straight_messages(n=60))
    data = good.read_bytes()
    (logs / "cut.mcap").write_bytes(data[: len(data) // 2])
    out = tmp_path / "out"
    status = main(["annotate", str(logs), "--out", str(out)])
    err = capsys.readouterr().err.strip().splitlines()
    assert status == 1 and "Traceback" not in "".join(err)
    assert err[-1].startswith(f"lanecast annotate: error: {logs / 'cut.mcap'}, offset "), err[-1]
    assert (out / "good.mcap").is_file() and not (out / "cut.mcap").exists()


def test_annotate_of_only_a_damaged_log_is_refused_and_leaves_nothing(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """One truncated log: exit 1 and an OUT_DIR holding only a manifest of the failure. Now exit 2
    (a refused input, as every command) and no OUT_DIR; an OUT_DIR that existed keeps its manifest
    (the resume state of earlier runs); exit 1 is for a run where other logs were annotated."""
    from test_hostile_inputs import json_log, straight_messages

    good = json_log(tmp_path / "good.mcap", straight_messages(n=60))
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(good.read_bytes()[: good.stat().st_size // 2])
    out = tmp_path / "out"
    assert main(["annotate", str(cut), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith(f"lanecast annotate: error: {cut}, offset "), err[-1]
    assert not out.exists()
    assert main(["annotate", str(good), "--out", str(out)]) == 0
    assert main(["annotate", str(cut), "--out", str(out)]) == 2  # this run annotated nothing
    assert (out / "good.mcap").is_file() and (out / "manifest.jsonl").is_file()
    assert not (out / "cut.mcap").exists()


@pytest.mark.parametrize("missing", ["inputs.npy", "manifest.json"])
def test_explain_on_a_windows_dataset_missing_a_file_names_it(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], missing: str
) -> None:
    """Without inputs.npy or manifest.json a windows dataset was read as a Parquet track table
    (its windows.parquet): 'win/windows.parquet: missing column 'frame''."""
    directory = windows_copy(tmp_path, lambda d: (d / missing).unlink())
    out = tmp_path / "explain"
    refused(
        ["explain", str(directory), "--track", "1", "--time", "5", "--out", str(out)],
        capsys,
        f"error: {directory / missing}: missing file of a windows dataset",
    )
    no_output(out)


def test_report_on_a_truncated_log_names_the_damage(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """`report` read /lanecast/prediction with the mcap library before the tracks: a log cut in half
    was a RecordLengthLimitExceeded traceback (and, for one log, 'no log could be scored' hid the
    reason). Now the log's own error, with its offset, is the command's."""
    from test_hostile_inputs import json_log, straight_messages

    log = json_log(tmp_path / "cut.mcap", straight_messages(n=120))
    log.write_bytes(log.read_bytes()[: log.stat().st_size // 2])
    out = tmp_path / "rep"
    refused(["report", str(log), "--out", str(out)], capsys, f"{log}, offset ", "truncated")
    no_output(out)


@pytest.mark.parametrize("damage", ["nan point", "null point", "garbage", "no x"])
def test_annotate_with_a_bad_forecasts_table_is_one_error_up_front(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], damage: str
) -> None:
    """--forecasts with a NaN point was written into the log as a line that draws nothing; a file
    that is not Parquet failed each log as 'ArrowInvalid: …' and a missing column as '<input>,
    column …', both after OUT_DIR got a manifest and a lock. Now the table is checked before."""
    from conftest import forecasts_for, make_mcap

    log = make_mcap(tmp_path / "drive.mcap", n=60)
    table = forecasts_for("drive", [1, 2], [1, 2])
    fc = tmp_path / "fc.parquet"
    x = table.column("x").to_pylist()
    if damage == "garbage":
        fc.write_bytes(b"PAR1garbagePAR1")
        said: tuple[str, ...] = (f"{fc}: unreadable forecasts table",)
    elif damage == "no x":
        pq.write_table(table.drop_columns(["x"]), fc)
        said = (f"{fc}, column 'x': forecasts table lacks a column",)
    else:
        x[2][3] = float("nan") if damage == "nan point" else None
        pq.write_table(table.set_column(table.column_names.index("x"), "x", pa.array(x)), fc)
        said = (f"{fc}, column 'x': row 2: forecast point", "expected finite coordinates")
    out = tmp_path / "ann"
    refused(["annotate", str(log), "--forecasts", str(fc), "--out", str(out)], capsys, *said)
    assert not out.exists()


def test_a_manifest_that_is_a_directory_is_named(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """OUT_DIR/manifest.jsonl being a directory was reported as '4: Is a directory' (a file
    descriptor for a file name)."""
    from conftest import forecasts_for, make_mcap

    log = make_mcap(tmp_path / "drive.mcap", n=60)
    fc = tmp_path / "fc.parquet"
    pq.write_table(forecasts_for("drive", [1, 2], [1, 2]), fc)
    out = tmp_path / "ann"
    (out / "manifest.jsonl").mkdir(parents=True)
    refused(
        ["annotate", str(log), "--forecasts", str(fc), "--out", str(out)],
        capsys,
        f"{out / 'manifest.jsonl'}: not a regular file",
    )


def test_convert_never_replaces_a_file_of_another_kind(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """`convert … --out notes` replaced a text file of the user's with Parquet bytes (exit 0); an
    earlier run's output of the same format is still replaced, as a rerun expects."""
    for name, notes in (("notes", b"my notes\n"), ("log.mcap", b"not a log"), ("old.bag", b"{}")):
        out = tmp_path / name
        out.write_bytes(notes)
        to = ["--to", "ros1"] if name.endswith(".bag") else []
        refused(
            ["convert", str(HIGHD), "--out", str(out), *to],
            capsys,
            str(out),
            "exists and is not",
            "not replaced",
        )
        assert out.read_bytes() == notes
    table = tmp_path / "sim.parquet"
    for _ in range(2):  # the second run replaces the first one's Parquet
        status, line = run(["convert", str(HIGHD), "--out", str(table)], capsys)
        assert status == 0, line
    assert pq.read_metadata(table).num_rows > 0
