"""The track table contract on hostile tables: columns Arrow allows but the contract does not,
bad metadata, impossible values and times that disagree with the frame rate are refused, naming
the file, row and column."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from conftest import _highd, _set_row, convert_refused, no_output, refused, track_table_copy

from lanecast.io_adapters.contracts import track_table
from lanecast.io_adapters.datasets.highd import reader as highd
from lanecast.io_adapters.errors import TrackTableError
from lanecast.io_adapters.formats import registry


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
