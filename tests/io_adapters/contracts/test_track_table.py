"""The track-table contract: schema, units, validation, metadata, concatenation, atomic Parquet."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from lanecast.io_adapters.contracts import track_table
from lanecast.io_adapters.contracts.track_table import RecordingMeta, TableMeta
from lanecast.io_adapters.errors import InputError, TrackTableError
from lanecast.io_adapters.files import atomic_path


def _columns(n_tracks: int = 2, n_frames: int = 4, recording: str = "rec-a") -> dict[str, np.ndarray]:
    track = np.repeat(np.arange(1, n_tracks + 1), n_frames)
    frame = np.tile(np.arange(n_frames), n_tracks)
    return {
        "recording": np.full(track.size, recording),
        "track_id": track,
        "frame": frame,
        "time_ns": frame * 40_000_000,
        "x": frame * 1.2 + track * 10.0,
        "y": np.full(track.size, 1.75),
        "heading": np.zeros(track.size),
        "vx": np.full(track.size, 30.0),
        "vy": np.zeros(track.size),
        "ax": np.zeros(track.size),
        "ay": np.zeros(track.size),
        "length": np.full(track.size, 4.5),
        "width": np.full(track.size, 1.8),
        "lane_id": np.where(frame < 2, 2, 3),
        "object_class": np.where(track == 1, "car", "truck"),
    }


def _meta(*names: str, rate: float = 25.0) -> TableMeta:
    return TableMeta("test", {n: RecordingMeta(frame_rate=rate) for n in names}, ["memory"])


def test_build_table_has_schema_units_and_metadata() -> None:
    table = track_table.build_table(_columns(), _meta("rec-a"))
    track_table.validate(table)
    assert table.column_names == list(track_table.REQUIRED_COLUMNS)
    assert table.schema.field("x").metadata == {b"unit": b"m"}
    assert table.schema.field("vx").metadata == {b"unit": b"m/s"}
    assert table.schema.field("heading").metadata == {b"unit": b"rad"}
    assert table.schema.field("x").type == pa.float64()
    assert table.schema.field("vx").type == pa.float32()
    meta = track_table.read_meta(table)
    assert meta.frame_rate == 25.0
    assert meta.recordings["rec-a"].coordinate_frame == "road"


def test_neighbour_columns_are_nullable_and_partial_sets_filled() -> None:
    cols = _columns()
    cols["preceding_id"] = np.array([2, 2, np.nan, np.nan, np.nan, np.nan, np.nan, 1])
    table = track_table.build_table(cols, _meta("rec-a"))
    track_table.validate(table)
    assert table.column("preceding_id").to_pylist() == [2, 2, None, None, None, None, None, 1]
    assert table.column("right_following_id").null_count == table.num_rows


def test_build_table_sorts_rows() -> None:
    cols = {k: v[::-1].copy() for k, v in _columns().items()}
    table = track_table.build_table(cols, _meta("rec-a"))
    assert table.column("track_id").to_pylist() == [1, 1, 1, 1, 2, 2, 2, 2]
    assert table.column("frame").to_pylist() == [0, 1, 2, 3, 0, 1, 2, 3]


@pytest.mark.parametrize(
    ("column", "row", "value", "message"),
    [
        ("x", 3, np.nan, "row 3: column 'x' is nan"),
        ("vy", 5, np.inf, "row 5: column 'vy' is inf"),
        ("frame", 2, 1, "duplicate (recording, track_id, frame) = (rec-a, 1, 1)"),
        ("time_ns", 2, 40_000_000, "time_ns does not increase along track 1"),
        # finite in float32, but window inputs of such speeds overflowed train's statistics (fuzzer)
        ("vx", 6, 3e38, "row 6: column 'vx' is 3.0[0-9]*e.38, expected a speed within ±1e.09 m/s"),
        ("ay", 1, -2e9, "row 1: column 'ay' is -2000000000.0, expected an acceleration within ±1e.09 m/s"),
    ],
)
def test_validate_names_the_row_and_column(column: str, row: int, value: float, message: str) -> None:
    cols = _columns()
    cols[column] = cols[column].astype(float if column in {"x", "vy", "vx", "ay"} else np.int64)
    cols[column][row] = value
    table = track_table.build_table(cols, _meta("rec-a"))
    with pytest.raises(TrackTableError, match=message.replace("(", r"\(").replace(")", r"\)")):
        track_table.validate(table, source="t.parquet")


def test_validate_rejects_missing_column_wrong_type_and_unknown_recording() -> None:
    table = track_table.build_table(_columns(), _meta("rec-a"))
    with pytest.raises(TrackTableError, match="missing column 'width'"):
        track_table.validate(table.drop_columns(["width"]))
    wrong = table.set_column(table.schema.get_field_index("x"), "x", table.column("x").cast(pa.float32()))
    with pytest.raises(TrackTableError, match="column 'x' has type float, expected double"):
        track_table.validate(wrong)
    other = track_table.build_table(_columns(), _meta("rec-b"))
    with pytest.raises(TrackTableError, match=r"recordings \['rec-a'\] have no entry"):
        track_table.validate(other)


def test_a_null_recording_is_named_with_its_row_beside_an_unknown_one() -> None:
    table = track_table.concat(
        [track_table.build_table(_columns(recording=r), _meta(r)) for r in ("rec-a", "rec-b")]
    )
    i = table.schema.get_field_index("recording")
    col = table.column(i).combine_chunks()
    mask = np.zeros(table.num_rows, dtype=bool)
    mask[5] = True
    nulled = pa.DictionaryArray.from_arrays(pa.array(col.indices.to_numpy(), mask=mask), col.dictionary)
    with pytest.raises(TrackTableError, match=r"t.parquet: row 5: column 'recording' is null"):
        track_table.validate(table.set_column(i, table.schema.field(i), nulled), source="t.parquet")
    meta = TableMeta("test", {"rec-a": RecordingMeta(frame_rate=25.0)}, ["memory"])
    only_a = table.set_column(i, table.schema.field(i), nulled).replace_schema_metadata(
        {track_table.META_KEY: meta.to_json().encode()}
    )
    with pytest.raises(TrackTableError, match=r"recordings \['rec-b'\] have no entry"):
        track_table.validate(only_a)


def test_recording_codes_of_slices_and_chunks_with_other_dictionaries() -> None:
    """Codes index the sorted names of the recordings that have rows, whatever each chunk's
    dictionary holds (a slice keeps its parent's whole dictionary)."""
    rng = np.random.default_rng(3)
    pool = ["highd-02-lower", "highd-01-upper", "b", "a", "zz"]
    for _ in range(200):
        chunks = []
        for _ in range(int(rng.integers(0, 4))):
            entries = list(rng.choice(pool, size=int(rng.integers(1, 5)), replace=False))
            idx = rng.integers(0, len(entries), size=int(rng.integers(0, 20))).astype(np.int32)
            chunks.append(pa.DictionaryArray.from_arrays(pa.array(idx), pa.array(entries)))
        table = pa.table({"recording": pa.chunked_array(chunks, type=pa.dictionary(pa.int32(), pa.string()))})
        if table.num_rows and rng.random() < 0.5:
            lo = int(rng.integers(0, table.num_rows))
            table = table.slice(lo, int(rng.integers(0, table.num_rows - lo + 1)))
        values = [str(v) for v in table.column("recording").to_pylist()]
        names, codes = track_table.recording_codes(table)
        assert names.tolist() == sorted(set(values))
        assert codes.dtype == np.int64
        assert [names[c] for c in codes] == values


def test_lane_change_rows_are_first_frames_in_the_new_lane() -> None:
    table = track_table.build_table(_columns(), _meta("rec-a"))
    # lane 2 at frames 0-1, lane 3 at frames 2-3, for both tracks; rows 2 and 6.
    assert track_table.lane_change_rows(table).tolist() == [2, 6]
    assert track_table.track_boundaries(table).tolist() == [0, 4, 8]


def test_concat_merges_metadata_and_rejects_name_clashes() -> None:
    a = track_table.build_table(_columns(recording="rec-a"), _meta("rec-a"))
    b_cols = _columns(recording="rec-b")
    b_cols["preceding_id"] = np.full(8, 1)
    b = track_table.build_table(b_cols, TableMeta("other", {"rec-b": RecordingMeta(10.0)}, ["b.csv"]))
    merged = track_table.concat([a, b])
    track_table.validate(merged)
    meta = track_table.read_meta(merged)
    assert sorted(meta.recordings) == ["rec-a", "rec-b"]
    assert meta.frame_rate is None  # 25 Hz and 10 Hz mixed
    assert meta.source_format == "other+test"
    assert merged.column("preceding_id").null_count == 8
    with pytest.raises(TrackTableError, match="occur in more than one input"):
        track_table.concat([a, a])


def test_parquet_round_trip_keeps_everything(tmp_path: Path) -> None:
    table = track_table.build_table(_columns(), _meta("rec-a"))
    path = track_table.write_parquet(table, tmp_path / "t.parquet")
    back = track_table.read_parquet(path)
    assert back.equals(table)
    assert back.schema.metadata == table.schema.metadata
    assert pq.read_metadata(path).row_group(0).column(0).compression == "ZSTD"
    assert [p.name for p in tmp_path.iterdir()] == ["t.parquet"]


def test_read_parquet_names_the_file_on_garbage(tmp_path: Path) -> None:
    bad = tmp_path / "bad.parquet"
    bad.write_bytes(b"PAR1 not really")
    with pytest.raises(InputError, match=r"bad\.parquet: not a readable Parquet file"):
        track_table.read_parquet(bad)


def test_atomic_path_leaves_nothing_on_failure(tmp_path: Path) -> None:
    target = tmp_path / "out.bin"
    target.write_bytes(b"old")
    with pytest.raises(RuntimeError), atomic_path(target) as tmp:
        tmp.write_bytes(b"half")
        raise RuntimeError("boom")
    assert target.read_bytes() == b"old"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.bin"]
    with atomic_path(tmp_path / "dir", directory=True) as tmp_dir:
        (tmp_dir / "a").write_text("x")
    assert (tmp_path / "dir" / "a").read_text() == "x"
    with atomic_path(tmp_path / "new.bin") as tmp:
        tmp.write_bytes(b"new")
    mask = os.umask(0)
    os.umask(mask)
    assert (tmp_path / "new.bin").stat().st_mode & 0o777 == 0o666 & ~mask
    assert (tmp_path / "dir").stat().st_mode & 0o777 == 0o777 & ~mask


def test_cli_reports_project_errors_as_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from lanecast.workflows.cli import main

    missing = tmp_path / "nope.csv"
    assert main(["info", str(missing)]) == 2
    err = capsys.readouterr().err
    assert err.strip() == (
        f"lanecast info: error: {missing}: no such file or directory "
        "(expected PATH: highD, NGSIM, MCAP, ROS 1/2 bag or track-table files or directories)"
    )


def test_convert_and_info_on_a_track_table(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from lanecast.workflows.cli import main

    table = track_table.build_table(_columns(), _meta("rec-a"))
    src = track_table.write_parquet(table, tmp_path / "in.parquet")
    assert main(["convert", str(src), "--out", str(tmp_path / "out.parquet")]) == 0
    assert track_table.read_parquet(tmp_path / "out.parquet").equals(table)
    assert main(["info", str(tmp_path / "out.parquet")]) == 0
    out = capsys.readouterr().out
    assert "rec-a" in out
    assert "total: 1 recordings, 2 tracks, 8 rows, 2 lane changes" in out
    assert main(["convert", str(src), "--out", str(src)]) == 2


def test_input_errors_survive_pickling_between_processes() -> None:
    import pickle

    from lanecast.io_adapters.errors import LogError

    err = LogError("a.mcap", "truncated", offset=1234, expected="a complete chunk")
    back = pickle.loads(pickle.dumps(err))
    assert type(back) is LogError
    assert str(back) == str(err) == "a.mcap, offset 1234: truncated (expected a complete chunk)"
    assert back.offset == 1234


def test_a_track_table_in_another_row_order_is_read_in_the_contracts_order(tmp_path: Path) -> None:
    """A track table written by another tool with its rows in another order holds the same rows:
    read put in (recording, track_id, frame) order (before: refused, 'row 1: rows are not sorted
    by (recording, track_id, frame)'); an error after sorting names the row of the file."""
    table = track_table.build_table(_columns(n_tracks=3), _meta("rec-a"))
    shuffled = table.take(pa.array(np.random.default_rng(0).permutation(table.num_rows)))
    pq.write_table(shuffled, tmp_path / "t.parquet")
    assert track_table.read_parquet(tmp_path / "t.parquet").equals(table)
    twice = pa.concat_tables([shuffled.slice(0, 5), shuffled.slice(3, 1), shuffled.slice(5)])
    pq.write_table(twice, tmp_path / "d.parquet")
    with pytest.raises(TrackTableError, match=r"d\.parquet: row 5: duplicate \(recording, track_id, frame\)"):
        track_table.read_parquet(tmp_path / "d.parquet")


@pytest.mark.parametrize(
    ("column", "type_"),
    [
        ("recording", pa.string()),
        ("recording", pa.large_string()),
        ("object_class", pa.dictionary(pa.int8(), pa.string())),
        ("track_id", pa.uint32()),
        ("frame", pa.int32()),
        ("lane_id", pa.int16()),
        ("x", pa.float32()),
    ],
)
def test_a_column_in_a_type_holding_the_same_values_is_read_in_the_contracts_type(
    tmp_path: Path, column: str, type_: pa.DataType
) -> None:
    """Another tool's table with plain-string names, narrower integers or float32 positions (values
    the contract's types hold exactly) was refused ('column 'frame' has type int32, expected
    int64'); now read as the same table. A float id or an integer out of range is still refused."""
    columns = _columns()
    columns["x"] = columns["x"].astype(np.float32)  # values float32 holds: a float32 x is the same x
    table = track_table.build_table(columns, _meta("rec-a"))
    i = table.schema.get_field_index(column)
    other = table.set_column(i, table.schema.field(i).with_type(type_), table.column(i).cast(type_))
    pq.write_table(other, tmp_path / "t.parquet")
    assert track_table.read_parquet(tmp_path / "t.parquet").equals(table)
    for bad, words in ((pa.float64(), "has type double"), (pa.uint64(), "has type uint64")):
        values = table.column("track_id").cast(bad)
        if bad == pa.uint64():
            values = pa.array([2**63 + 1] * table.num_rows, pa.uint64())
        wrong = table.set_column(1, table.schema.field(1).with_type(bad), values)
        pq.write_table(wrong, tmp_path / "w.parquet")
        with pytest.raises(TrackTableError, match=words):
            track_table.read_parquet(tmp_path / "w.parquet")


def test_neighbour_ids_are_null_where_the_source_says_no_vehicle() -> None:
    from lanecast.io_adapters.contracts.track_schema import neighbour_ids

    ids = np.array([0, 5, 0, 2**62 + 1, 7], dtype=np.int64)
    column = neighbour_ids(ids)
    assert column.type == pa.int64() and column.null_count == 2
    assert column.to_pylist() == [None, 5, None, 2**62 + 1, 7]  # 64-bit ids stay exact
    assert neighbour_ids(np.array([3.0, 0.0])).to_pylist() == [3, None]  # NGSIM's float columns
    assert neighbour_ids(np.zeros(0, dtype=np.int64)).to_pylist() == []
