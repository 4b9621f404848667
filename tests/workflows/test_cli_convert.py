"""`lanecast convert` on bad input and outputs: damage reported and salvaged, empty tables, times a
log cannot hold, options of another reader, outputs of another kind never replaced."""

from __future__ import annotations

from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from conftest import (
    HIGHD,
    US101,
    _set_row,
    chunk_layout,
    convert_refused,
    no_output,
    refused,
    run,
    track_table_copy,
)

from lanecast.workflows.cli import main


def test_error_is_the_last_line_after_progress(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The second file of a folder is cut short: the error line ends stderr (the abandoned progress
    used to print its count after it, when the reader's generator was collected)."""
    folder = tmp_path / "us-101"
    folder.mkdir()
    (folder / "trajectories-a.txt").write_bytes(US101.read_bytes())
    (folder / "trajectories-b.txt").write_bytes(US101.read_bytes()[:-40])
    convert_refused(folder, tmp_path, capsys, "trajectories-b.txt, line 15", "truncated")


@pytest.mark.parametrize(
    "out_args", [["out.parquet"], ["out", "--partition"], ["out.mcap"], ["out.bag"], ["out", "--to", "ros2"]]
)
def test_a_table_without_rows_leaves_no_output(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], out_args: list[str]
) -> None:
    """A track table of zero rows: 'no rows to write', but the empty temporary output was renamed
    into place anyway (the writer's own refusal did not reach the atomic write); as a drive log it
    was written, a log without objects that lanecast's own reader then refused."""
    path = track_table_copy(tmp_path, lambda t: t.slice(0, 0))
    out = tmp_path / out_args[0]
    refused(
        ["convert", str(path), "--out", str(out), *out_args[1:]],
        capsys,
        f"error: {path}: no rows",  # the input that has none, not the output never written
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


def test_location_given_for_a_log_is_ignored_as_for_other_readers(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """--location (NGSIM's) with an MCAP input: 'TypeError: read_log() got an unexpected keyword
    argument 'location'' (exit 1); the other readers are never given the options of another."""
    from conftest import json_log, straight_messages

    log = json_log(tmp_path / "in.mcap", straight_messages())
    assert main(["convert", str(log), "--location", "us-101", "--out", str(tmp_path / "o.parquet")]) == 0
    assert "Traceback" not in capsys.readouterr().err


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


def test_convert_cli_reports_damage_and_salvages(
    log: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from lanecast.workflows.cli import main

    chunks = chunk_layout(log)
    data = bytearray(log.read_bytes())
    data[chunks[1][0] + chunks[1][1] // 2] ^= 0xFF
    path = tmp_path / "damaged.mcap"
    path.write_bytes(bytes(data))
    assert main(["convert", str(path), "--out", str(tmp_path / "t.parquet")]) == 2
    err = capsys.readouterr().err
    assert "corrupt chunk" in err and f"offset {chunks[1][0]}" in err and str(path) in err
    assert main(["convert", str(path), "--salvage", "--out", str(tmp_path / "t.parquet")]) == 0
    captured = capsys.readouterr()
    assert "lost 1 chunks" in captured.err and "wrote" in captured.out
