"""Streaming convert and windows: pieces of whole recordings, datasets grown on disk, workers."""

from __future__ import annotations

import functools
import shutil
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq
import pytest
from conftest import TESTS, _export, _rows

from lanecast.io_adapters.contracts import track_table
from lanecast.io_adapters.contracts.normalisation import compute_stats
from lanecast.io_adapters.contracts.windows import Windows
from lanecast.io_adapters.datasets.highd import reader as highd
from lanecast.io_adapters.datasets.ngsim import reader as ngsim
from lanecast.io_adapters.datasets.ngsim import stream as ngsim_stream
from lanecast.io_adapters.errors import InputError, TrackTableError
from lanecast.io_adapters.formats import registry, streaming
from lanecast.io_adapters.windows_store.dataset import load_windows
from lanecast.io_adapters.windows_store.npy_append import NpyAppender
from lanecast.pipeline.make_windows import make_windows
from lanecast.pipeline.write_windows import WindowOptions, write_windows
from lanecast.workflows.cli import main

ARRAYS = ("inputs", "present", "future", "maneuver")


@pytest.fixture(scope="module")
def dataset(sim_recording_dir: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Three highD recordings (01, 02, 03): the simulated one, its first and its last vehicles."""
    out = tmp_path_factory.mktemp("multi")
    lines = (sim_recording_dir / "01_tracks.csv").read_text().splitlines(keepends=True)
    header, rows = lines[0], lines[1:]
    vehicle = np.array([int(line.split(",", 2)[1]) for line in rows])
    middle = int(np.median(vehicle))
    parts = {"01": vehicle > 0, "02": vehicle <= middle, "03": vehicle > middle}
    meta_lines = (sim_recording_dir / "01_tracksMeta.csv").read_text().splitlines(keepends=True)
    rec_lines = (sim_recording_dir / "01_recordingMeta.csv").read_text().splitlines(keepends=True)
    for prefix, keep in parts.items():
        ids = {str(v) for v in np.unique(vehicle[keep])}
        (out / f"{prefix}_tracks.csv").write_text(header + "".join(np.array(rows)[keep]))
        kept = [m for m in meta_lines[1:] if m.split(",", 1)[0] in ids]
        (out / f"{prefix}_tracksMeta.csv").write_text(meta_lines[0] + "".join(kept))
        rec = rec_lines[1].split(",", 1)
        (out / f"{prefix}_recordingMeta.csv").write_text(rec_lines[0] + f"{int(prefix)},{rec[1]}")
    return out


def _assert_same_windows(a: Windows, b: Windows) -> None:
    for name in ARRAYS:
        np.testing.assert_array_equal(
            np.asarray(getattr(a, name)), np.asarray(getattr(b, name)), err_msg=name
        )
    assert a.index.equals(b.index.cast(a.index.schema))
    skip = {"timings", "sources"}
    assert {k: v for k, v in a.manifest.items() if k not in skip} == {
        k: v for k, v in b.manifest.items() if k not in skip
    }


def test_pieces_of_a_highd_directory_are_its_recordings(dataset: Path) -> None:
    pieces = streaming.plan([dataset])
    assert [Path(p.paths[0]).name for p in pieces] == ["01_tracks.csv", "02_tracks.csv", "03_tracks.csv"]
    names = [track_table.recording_codes(p.read())[0].tolist() for p in pieces]
    assert names == [[f"highd-{n}-lower", f"highd-{n}-upper"] for n in ("01", "02", "03")]


def test_windows_streamed_in_pieces_equal_the_in_memory_result(dataset: Path, tmp_path: Path) -> None:
    table = registry.read_any([dataset])
    expected = make_windows(table)
    # one Parquet file with small row groups that cut through recordings, pieces of one recording
    path = tmp_path / "all.parquet"
    pq.write_table(table, path, row_group_size=10_000)
    pieces = streaming.parquet_pieces(path, max_rows=1)
    assert len(pieces) == 6 and all(len(p.row_groups) >= 1 for p in pieces)
    streamed = write_windows(pieces, tmp_path / "w")
    assert isinstance(streamed.inputs, np.memmap)  # loaded in one call, memory-mapped
    _assert_same_windows(expected, streamed)
    _assert_same_windows(expected, load_windows(tmp_path / "w"))
    assert sorted(p.name for p in (tmp_path / "w").iterdir()) == sorted(
        ["inputs.npy", "present.npy", "future.npy", "maneuver.npy", "windows.parquet", "manifest.json"]
    )


@pytest.mark.parametrize(
    "options",
    [WindowOptions(), WindowOptions(neighbours="lanes", stride=3, require_future=False, split="hash")],
    ids=["default", "lanes-stride3-nofuture"],
)
def test_a_long_recording_windowed_in_chunks_equals_the_one_call_result(
    sim_recording_dir: Path, tmp_path: Path, options: WindowOptions
) -> None:
    table = registry.read_any([sim_recording_dir])
    expected = make_windows(
        table,
        stride=options.stride,
        require_future=options.require_future,
        split=options.split,
        neighbours=options.neighbours,
    )
    path = tmp_path / "one.parquet"
    pq.write_table(table, path, row_group_size=7_000)  # chunks' context spans row groups
    per_recording = max(table.num_rows // 10, 1)
    pieces = streaming.plan([path], max_rows=per_recording, long="context")
    assert len(pieces) > 2 * 4 and all(p.chunk is not None for p in pieces)
    targets = [p.chunk.targets for p in pieces if p.chunk is not None]
    assert all(a <= b for a, b in targets)
    for piece in pieces:  # context: other tracks, cut to the targets' lifetime
        assert piece.chunk is not None
        context = piece.read_with_context()
        assert context.num_rows > piece.read().num_rows
        t = context.column("time_ns").to_numpy()
        lo, hi = piece.chunk.context_ns
        track = context.column("track_id").to_numpy()
        other = (track < piece.chunk.targets[0]) | (track > piece.chunk.targets[1])
        assert ((t[other] >= lo) & (t[other] <= hi)).all()
    streamed = write_windows(pieces, tmp_path / "w", options)
    _assert_same_windows(expected, streamed)  # arrays, index (order included), manifest
    assert [p.chunk.recording for p in pieces if p.chunk] == sorted(
        p.chunk.recording for p in pieces if p.chunk
    )


def _rotated_to_a_world_frame(table: pa.Table, degrees: float) -> pa.Table:
    """``table`` turned by ``degrees`` about the origin and declared a world (``map``) frame."""
    from dataclasses import replace

    a = np.deg2rad(degrees)
    c, s = np.cos(a), np.sin(a)

    def put(t: pa.Table, name: str, values: np.ndarray) -> pa.Table:
        i = t.schema.get_field_index(name)
        return t.set_column(i, t.schema.field(i), pa.array(values).cast(t.schema.field(i).type))

    for u_name, v_name in (("x", "y"), ("vx", "vy"), ("ax", "ay")):
        u = table.column(u_name).to_numpy().astype(float)
        v = table.column(v_name).to_numpy().astype(float)
        table = put(put(table, u_name, c * u - s * v), v_name, s * u + c * v)
    heading = table.column("heading").to_numpy().astype(float) + a
    table = put(table, "heading", (heading + np.pi) % (2 * np.pi) - np.pi)
    meta = track_table.read_meta(table)
    recordings = {k: replace(r, coordinate_frame="map") for k, r in meta.recordings.items()}
    return table.replace_schema_metadata(
        {track_table.META_KEY: replace(meta, recordings=recordings).to_json().encode()}
    )


@pytest.mark.parametrize("neighbours", ["bands", "lanes"])
def test_a_long_world_frame_recording_windowed_in_chunks_equals_the_one_call_result(
    sim_recording_dir: Path, tmp_path: Path, neighbours: str
) -> None:
    table = _rotated_to_a_world_frame(registry.read_any([sim_recording_dir]), 30.0)
    track_table.validate(table)
    expected = make_windows(table, neighbours=neighbours)
    path = tmp_path / "world.parquet"
    pq.write_table(table, path, row_group_size=7_000)
    pieces = streaming.plan([path], max_rows=table.num_rows // 8, long="context")
    assert sum(p.chunk is not None for p in pieces) >= 8
    # lanes off a road frame follow the recording's mean direction: read whole, not in chunks
    streamed = write_windows(pieces, tmp_path / "w", WindowOptions(neighbours=neighbours))
    _assert_same_windows(expected, streamed)


@pytest.mark.parametrize("workers", [1, pytest.param(2, marks=pytest.mark.slow)])  # processes: seconds
@pytest.mark.parametrize("directory", [False, True], ids=["file", "partition"])
def test_a_long_highd_recording_converts_block_by_block_in_whole_tracks(
    sim_recording_dir: Path, tmp_path: Path, directory: bool, workers: int
) -> None:
    from lanecast.io_adapters.datasets.highd import stream as highd_stream
    from lanecast.workflows.bulk import backends as engines

    expected = registry.read_any([sim_recording_dir])
    with streaming.spill_directory(tmp_path / "out") as spill:
        block = highd_stream.BLOCK_BYTES
        highd_stream.BLOCK_BYTES = 64 << 10  # many blocks, tracks held back across them
        try:
            pieces = streaming.plan(
                [sim_recording_dir],
                spill_dir=spill.path,
                stream_bytes=0,
                max_rows=expected.num_rows // 7,
                long="tracks",
            )
        finally:
            highd_stream.BLOCK_BYTES = block
        assert sum(p.continues for p in pieces) >= 4  # each direction cut in whole tracks
        ordered_map = None if workers == 1 else functools.partial(engines.ordered_map, workers=workers)
        rows, tracks = streaming.convert(
            pieces, tmp_path / "out", directory=directory, ordered_map=ordered_map
        )
    assert (rows, tracks) == (expected.num_rows, len(track_table.track_boundaries(expected)) - 1)
    assert not list(tmp_path.glob(".out.*"))  # spills and parts removed
    got = registry.read_any([tmp_path / "out"])
    _assert_same_tracks(expected, got)
    if directory:  # one part per recording: a recording is never split over files
        assert len(list((tmp_path / "out").glob("part-*.parquet"))) == 2


def test_a_long_highd_recording_windowed_from_its_csv_equals_the_one_call_result(
    sim_recording_dir: Path, tmp_path: Path
) -> None:
    table = registry.read_any([sim_recording_dir])
    expected = make_windows(table)
    with streaming.spill_directory(tmp_path / "w") as spill:
        pieces = streaming.plan(
            [sim_recording_dir],
            spill_dir=spill.path,
            stream_bytes=0,
            max_rows=table.num_rows // 5,
            long="context",
        )
        assert sum(p.chunk is not None for p in pieces) >= 4
        streamed = write_windows(pieces, tmp_path / "w")
    _assert_same_windows(expected, streamed)


def test_an_unsorted_or_damaged_highd_file_read_in_blocks_goes_the_whole_file_way(
    sim_recording_dir: Path, tmp_path: Path
) -> None:
    from lanecast.io_adapters.datasets.highd import stream as highd_stream

    lines = (sim_recording_dir / "01_tracks.csv").read_text().splitlines(keepends=True)
    for kind in ("tracksMeta", "recordingMeta"):
        shutil.copy(sim_recording_dir / f"01_{kind}.csv", tmp_path / f"01_{kind}.csv")
    # unsorted: the last vehicle's rows first; read whole, spilled all the same
    last = lines[-1].split(",", 2)[1]
    tail = [line for line in lines[1:] if line.split(",", 2)[1] == last]
    body = [line for line in lines[1:] if line.split(",", 2)[1] != last]
    (tmp_path / "01_tracks.csv").write_text(lines[0] + "".join(tail + body))
    rec = highd.recordings([tmp_path])[0]
    spill = tmp_path / "spill"
    spill.mkdir()
    spills = highd_stream.split_tracks(rec, spill, block_bytes=64 << 10)
    got = track_table.concat([track_table.read_parquet(p) for p in spills])
    _assert_same_tracks(registry.read_any([tmp_path / "01_tracks.csv"]), got)
    # a bad cell deep in the file is named by its line, as the whole-file reader names it
    bad = len(lines) - 5
    fields = lines[bad].split(",")
    fields[2] = "oops"
    lines[bad] = ",".join(fields)
    (tmp_path / "01_tracks.csv").write_text("".join(lines))
    with pytest.raises(InputError) as info:
        highd_stream.split_tracks(rec, spill, block_bytes=64 << 10)
    assert info.value.line == bad + 1


def test_a_failing_piece_leaves_no_half_written_dataset(dataset: Path, tmp_path: Path) -> None:
    good = registry.read_any([dataset])
    bad = tmp_path / "bad.parquet"  # structurally fine, one NaN position deep inside
    x = good.column("x").to_numpy().copy()
    x[len(x) // 2] = np.nan
    pq.write_table(good.set_column(good.schema.get_field_index("x"), "x", pa.array(x)), bad)
    good_path = tmp_path / "good.parquet"
    pq.write_table(good, good_path)
    pieces = streaming.plan([good_path]) + streaming.plan([bad])
    with pytest.raises((InputError, TrackTableError)) as info:
        write_windows(pieces, tmp_path / "w")
    assert "bad.parquet" in str(info.value)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.parquet", "good.parquet"]


def test_hash_split_and_no_future_stream_the_same(dataset: Path, tmp_path: Path) -> None:
    table = registry.read_any([dataset])
    expected = make_windows(table, split="hash", seed=3, require_future=False, stride=7)
    options = WindowOptions(split="hash", seed=3, require_future=False, stride=7)
    streamed = write_windows(streaming.plan([dataset]), tmp_path / "w", options)
    _assert_same_windows(expected, streamed)


def test_windows_with_two_workers_equal_one_process(dataset: Path, tmp_path: Path) -> None:
    assert main(["windows", str(dataset), "--out", str(tmp_path / "one")]) == 0
    assert main(["windows", str(dataset), "--out", str(tmp_path / "two"), "--workers", "2"]) == 0
    for name in ("inputs.npy", "present.npy", "future.npy", "maneuver.npy"):
        assert (tmp_path / "one" / name).read_bytes() == (tmp_path / "two" / name).read_bytes(), name
    one, two = load_windows(tmp_path / "one"), load_windows(tmp_path / "two")
    _assert_same_windows(one, two)
    assert not list((tmp_path / "two").glob("_shards*"))


def _interrupting_map(after: int) -> Callable[..., Iterator[Any]]:
    def ordered_map(fn: Callable[[Any], Any], items: Sequence[Any]) -> Iterator[Any]:
        for i, item in enumerate(items):
            if i == after:
                raise KeyboardInterrupt
            yield fn(item)

    return ordered_map


def test_an_interrupted_windows_run_leaves_no_half_written_dataset(dataset: Path, tmp_path: Path) -> None:
    pieces = streaming.plan([dataset])
    with pytest.raises(KeyboardInterrupt):
        write_windows(pieces, tmp_path / "w", ordered_map=_interrupting_map(2))
    assert list(tmp_path.iterdir()) == []  # neither the dataset nor a temporary
    # an existing dataset is left as it was
    first = write_windows(pieces[:1], tmp_path / "w")
    before = {p.name: p.read_bytes() for p in (tmp_path / "w").iterdir()}
    with pytest.raises(KeyboardInterrupt):
        write_windows(pieces, tmp_path / "w", ordered_map=_interrupting_map(1))
    assert {p.name: p.read_bytes() for p in (tmp_path / "w").iterdir()} == before
    assert [p.name for p in tmp_path.iterdir()] == ["w"]
    assert len(load_windows(tmp_path / "w")) == len(first)


def test_convert_streams_into_one_file_or_a_dataset_directory(dataset: Path, tmp_path: Path) -> None:
    expected = registry.read_any([dataset])
    assert main(["convert", str(dataset), "--out", str(tmp_path / "one.parquet")]) == 0
    assert (
        main(["convert", str(dataset), "--out", str(tmp_path / "parts"), "--partition", "--workers", "2"])
        == 0
    )
    assert sorted(p.name for p in (tmp_path / "parts").iterdir()) == [
        "part-00000.parquet",
        "part-00001.parquet",
        "part-00002.parquet",
    ]
    one = registry.read_any([tmp_path / "one.parquet"])
    parts = registry.read_any([tmp_path / "parts"])  # a dataset directory reads as one table
    assert track_table.read_meta(one) == track_table.read_meta(expected)
    for table in (one, parts):  # equal values (dictionaries are per piece)
        assert table.num_rows == expected.num_rows
        assert track_table.read_meta(table).recordings == track_table.read_meta(expected).recordings
        for name in expected.column_names:
            assert table.column(name).to_pylist() == expected.column(name).to_pylist(), name
    # the windows of the directory equal those of the single file
    assert main(["windows", str(tmp_path / "parts"), "--out", str(tmp_path / "wp")]) == 0
    assert main(["windows", str(tmp_path / "one.parquet"), "--out", str(tmp_path / "wo")]) == 0
    _assert_same_windows(load_windows(tmp_path / "wo"), load_windows(tmp_path / "wp"))


def test_a_streamed_file_shows_its_metadata_to_arrow_readers_and_survives_a_pyarrow_filter(
    dataset: Path, tmp_path: Path
) -> None:
    """pyarrow reads a file's schema from its ``ARROW:schema`` entry, written when the file is
    opened; the metadata a streamed file learns at its end must reach it too, or a table read,
    filtered and written back with pyarrow is refused as 'not a lanecast track table'."""
    out = tmp_path / "one.parquet"
    assert main(["convert", str(dataset), "--out", str(out)]) == 0
    plain = pq.read_table(out)  # pyarrow alone, as a user's script reads it
    expected = track_table.read_meta(registry.read_any([dataset]))
    assert track_table.read_meta(plain) == expected
    assert plain.schema.field("x").metadata == {b"unit": b"m"}
    assert pa.types.is_dictionary(plain.schema.field("recording").type)
    subset = plain.filter(pc.equal(plain["recording"], "highd-02-upper"))
    pq.write_table(subset, tmp_path / "subset.parquet")
    read_back = registry.read_any([tmp_path / "subset.parquet"])
    assert read_back.num_rows == subset.num_rows > 0
    assert track_table.read_meta(read_back) == expected
    assert main(["windows", str(tmp_path / "subset.parquet"), "--out", str(tmp_path / "w")]) == 0


def test_a_dataset_directory_holding_a_part_twice_is_refused_naming_both_parts(
    dataset: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """windows named the original highD CSVs of a part copied under another name, files the user
    never gave it; convert and info named the parts."""
    parts = tmp_path / "parts"
    assert main(["convert", str(dataset), "--out", str(parts), "--partition"]) == 0
    shutil.copy(parts / "part-00001.parquet", parts / "part-00009.parquet")
    capsys.readouterr()
    for argv in (
        ["windows", str(parts), "--out", str(tmp_path / "w")],
        ["convert", str(parts), "--out", str(tmp_path / "c.parquet")],
    ):
        assert main(argv) == 2
        err = capsys.readouterr().err
        assert (
            f"{parts / 'part-00009.parquet'}" in err and f"also in {parts / 'part-00001.parquet'}" in err
        ), err
        assert "occur in more than one input" in err and "_tracks.csv" not in err
    assert not (tmp_path / "w").exists() and not (tmp_path / "c.parquet").exists()


def _without_neighbours(dataset: Path, path: Path) -> Path:
    """Recording 01 without neighbour columns, its recordings renamed ``x-…``, written to ``path``."""
    table = registry.read_any([dataset / "01_tracks.csv"])
    without = table.drop_columns(list(track_table.NEIGHBOUR_COLUMNS))
    meta = track_table.read_meta(without)
    renamed = {f"x-{k}": v for k, v in meta.recordings.items()}
    recs = without.column("recording").cast("string")
    without = without.set_column(
        0, "recording", pc.dictionary_encode(pc.binary_join_element_wise("x-", recs, ""))
    )
    without = without.replace_schema_metadata(
        {
            track_table.META_KEY: track_table.TableMeta(meta.source_format, renamed, meta.source_files)
            .to_json()
            .encode()
        }
    )
    pq.write_table(without, path)
    return path


def test_convert_of_mixed_neighbour_columns_into_one_file_is_refused_clearly(
    dataset: Path, tmp_path: Path
) -> None:
    first = _without_neighbours(dataset, tmp_path / "a.parquet")
    # neighbour-less first, then with neighbours: the file's schema cannot take them
    with pytest.raises(InputError, match="neighbour columns"):
        streaming.convert(
            streaming.plan([first, dataset / "02_tracks.csv"]), tmp_path / "o.parquet", directory=False
        )
    assert not (tmp_path / "o.parquet").exists()


def test_a_write_that_fails_is_named_before_a_later_piece_that_does_not_read(
    dataset: Path, tmp_path: Path
) -> None:
    """A piece is written while the next one is read: the earlier piece's error comes first, as
    when one piece was read and written after the other."""
    first = _without_neighbours(dataset, tmp_path / "a.parquet")
    with_neighbours = track_table.write_parquet(
        registry.read_any([dataset / "02_tracks.csv"]), tmp_path / "b.parquet"
    )
    good = registry.read_any([dataset / "03_tracks.csv"])
    x = good.column("x").to_numpy().copy()
    x[len(x) // 2] = np.nan  # found when the piece is read, not when it is planned
    damaged = tmp_path / "damaged.parquet"
    pq.write_table(good.set_column(good.schema.get_field_index("x"), "x", pa.array(x)), damaged)
    pieces = streaming.plan([first, with_neighbours, damaged])
    with pytest.raises(InputError, match="neighbour columns") as info:
        streaming.convert(pieces, tmp_path / "o.parquet", directory=False)
    assert "damaged.parquet" in str(info.value.__context__)  # the later read failed too, after it
    assert not (tmp_path / "o.parquet").exists()


def test_npy_appender_grows_a_file_numpy_memory_maps(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    blocks = [rng.normal(size=(n, 4, 8, 30)).astype(np.float32) for n in (3, 0, 5)]
    np.save(tmp_path / "shard.npy", blocks[2])
    app = NpyAppender(tmp_path / "a.npy", np.dtype(np.float32), (4, 8, 30))
    app.append(blocks[0])
    app.append(blocks[1])
    assert app.append_npy(tmp_path / "shard.npy") == 5
    app.close()
    loaded = np.load(tmp_path / "a.npy", mmap_mode="r")
    assert loaded.shape == (8, 4, 8, 30)
    np.testing.assert_array_equal(loaded, np.concatenate(blocks))


def test_statistics_over_selected_rows_equal_the_masked_ones() -> None:
    rng = np.random.default_rng(1)
    inputs = rng.normal(3.0, 2.0, size=(3000, 4, 8, 30)).astype(np.float32)
    present = rng.random((3000, 8, 30)) < 0.6
    rows = np.flatnonzero(rng.random(3000) < 0.3)
    by_rows = compute_stats(inputs, present, rows=rows)
    by_copy = compute_stats(inputs[rows], present[rows])
    np.testing.assert_allclose(by_rows.mean, by_copy.mean, rtol=1e-6)
    np.testing.assert_allclose(by_rows.std, by_copy.std, rtol=1e-6)
    assert not np.allclose(by_rows.mean, compute_stats(inputs, present).mean, rtol=1e-3)


@pytest.mark.slow
def test_windows_on_a_local_ray_equal_one_process(dataset: Path, tmp_path: Path) -> None:
    pytest.importorskip("ray")
    assert main(["windows", str(dataset), "--out", str(tmp_path / "one")]) == 0
    args = ["windows", str(dataset), "--out", str(tmp_path / "ray"), "--engine", "ray", "--workers", "2"]
    assert main(args) == 0
    _assert_same_windows(load_windows(tmp_path / "one"), load_windows(tmp_path / "ray"))
    shutil.rmtree(tmp_path / "ray")


NGSIM_SAMPLE = TESTS / "data" / "ngsim" / "peachtree_sample.csv"


def _assert_same_tracks(expected: pa.Table, table: pa.Table) -> None:
    meta, want = track_table.read_meta(table), track_table.read_meta(expected)
    assert meta.recordings == want.recordings and meta.source_format == want.source_format
    assert set(meta.source_files) == set(want.source_files)
    assert table.num_rows == expected.num_rows
    for name in expected.column_names:
        a, b = expected.column(name), table.column(name)
        if pa.types.is_floating(a.type):  # per-recording smoothing: equal up to float rounding
            np.testing.assert_allclose(b.to_numpy(), a.to_numpy(), rtol=0, atol=1e-9, err_msg=name)
        else:
            assert b.to_pylist() == a.to_pylist(), name


def test_ngsim_csv_export_read_block_by_block_equals_the_whole_read(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(ngsim_stream, "BLOCK_BYTES", 1 << 16)  # the sample spans several blocks
    pieces = streaming.plan([NGSIM_SAMPLE], spill_dir=tmp_path / "spill", stream_bytes=0)
    assert [track_table.recording_codes(p.read())[0].tolist() for p in pieces] == [
        ["ngsim-peachtree-peachtree_sample-p1"],
        ["ngsim-peachtree-peachtree_sample-p2"],
    ]
    _assert_same_tracks(ngsim.read([NGSIM_SAMPLE]), track_table.concat(p.read() for p in pieces))
    # through the command, on two workers, the spills beside the output removed at the end
    monkeypatch.setattr(streaming, "STREAM_BYTES", 0)
    out = tmp_path / "out" / "ngsim.parquet"
    assert main(["convert", str(NGSIM_SAMPLE), "--out", str(out), "--workers", "2"]) == 0
    _assert_same_tracks(ngsim.read([NGSIM_SAMPLE]), registry.read_any([out]))
    assert [p.name for p in out.parent.iterdir()] == ["ngsim.parquet"]


def test_a_bad_cell_deep_in_a_streamed_export_is_named_by_line(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(ngsim_stream, "BLOCK_BYTES", 1 << 16)
    lines = NGSIM_SAMPLE.read_text().splitlines(keepends=True)
    cells = lines[4000].split(",")
    cells[5] = "-x-"  # Local_Y
    lines[4000] = ",".join(cells)
    bad = tmp_path / "bad.csv"
    bad.write_text("".join(lines))
    with pytest.raises(InputError) as err:
        streaming.plan([bad], spill_dir=tmp_path / "spill", stream_bytes=0)
    assert "line 4001" in str(err.value) and "Local_Y" in str(err.value)


def test_freed_memory_is_kept_for_the_next_piece_on_glibc() -> None:
    import platform

    from lanecast.workflows.bulk import freed_memory as heap

    if platform.libc_ver()[0] != "glibc":
        pytest.skip("mallopt is glibc's")
    assert heap.keep_freed_memory() is True  # both thresholds accepted
    assert heap.keep_freed_memory() is True  # once per process, then cached
    assert heap.keep_freed_memory(arrow=True) is True
    assert pa.default_memory_pool().backend_name == "system"  # Arrow's buffers on the same heap


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


def test_a_parquet_table_without_its_recording_column_is_named_as_validate_names_it(
    dataset: Path, tmp_path: Path
) -> None:
    """Pieces look the column up before the table is validated: Arrow's KeyError text reached the user."""
    path = tmp_path / "norec.parquet"
    pq.write_table(registry.read_any([dataset]).drop_columns(["recording"]), path)
    with pytest.raises(TrackTableError, match=r"norec\.parquet: missing column 'recording'$"):
        streaming.parquet_pieces(path)
