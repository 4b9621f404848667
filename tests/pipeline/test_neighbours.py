"""Neighbour selection: hand-built scenes with known neighbours for each method (source ids, lanes,
lateral bands), lane numbering in either direction, alongside vs front at the overlap boundary, a
rotated world frame, and agreement with the neighbours SUMO reported on a simulated recording."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyarrow as pa
import pytest
from conftest import LANE, SEVEN, SEVEN_EXPECTED, make_track_table

from lanecast.io_adapters.contracts.track_table import RecordingMeta, TableMeta, build_table
from lanecast.io_adapters.errors import TrackTableError
from lanecast.pipeline import neighbour_columns as ncols
from lanecast.pipeline import neighbours as nbm


def scene(
    vehicles: dict[int, tuple[int, float]],
    *,
    n_frames: int = 5,
    lane_sign: int = 1,
    lengths: dict[int, float] | None = None,
    rotate: float = 0.0,
    lanes: bool = True,
    extra: dict[str, np.ndarray] | None = None,
) -> pa.Table:
    """Vehicles {track id: (lane, x at frame 0)} at 30 m/s along x, lane k at y = (k-2)*3.75*lane_sign.

    ``lane_sign`` -1 numbers lanes towards -y; ``rotate`` turns the whole scene into a world frame.
    """
    rows: dict[str, list] = {k: [] for k in ("track_id", "frame", "x", "y", "lane", "length")}
    for tid, (lane, x0) in vehicles.items():
        f = np.arange(n_frames)
        rows["track_id"] += [tid] * n_frames
        rows["frame"] += list(f)
        rows["x"] += list(x0 + 3.0 * f)
        rows["y"] += [(lane - 2) * LANE * lane_sign] * n_frames
        rows["lane"] += [lane] * n_frames
        rows["length"] += [(lengths or {}).get(tid, 4.5)] * n_frames
    n = len(rows["track_id"])
    x, y = np.asarray(rows["x"]), np.asarray(rows["y"])
    c, s = np.cos(rotate), np.sin(rotate)
    cols: dict[str, object] = {
        "recording": ["r"] * n,
        "track_id": np.asarray(rows["track_id"]),
        "frame": np.asarray(rows["frame"]),
        "time_ns": np.asarray(rows["frame"]) * 100_000_000,
        "x": c * x - s * y,
        "y": s * x + c * y,
        "heading": np.full(n, rotate),
        "vx": np.full(n, 30.0 * c),
        "vy": np.full(n, 30.0 * s),
        "ax": np.zeros(n),
        "ay": np.zeros(n),
        "length": np.asarray(rows["length"]),
        "width": np.full(n, 2.0),
        "lane_id": np.asarray(rows["lane"]) if lanes else np.full(n, np.nan),
        "object_class": ["car"] * n,
    }
    cols.update(extra or {})
    return make_track_table(cols, coordinate_frame="road" if rotate == 0.0 else "map")


def ids_of(table: pa.Table, track: int, method: str = "auto") -> np.ndarray:
    ids = nbm.neighbour_ids(table, method=method)
    rows = np.flatnonzero(table.column("track_id").to_numpy() == track)
    return ids[rows]


def test_seven_slots_from_lanes() -> None:
    table = scene(SEVEN)
    ids = ids_of(table, 1)
    assert ids.shape == (5, 7)
    np.testing.assert_array_equal(ids, np.tile(SEVEN_EXPECTED, (5, 1)))
    # as seen from the left-alongside car 4: T is its right alongside, 3 ahead in its lane, 2
    # front-right; its right lane (T's) has nobody behind, and lane 1 is not adjacent to it
    np.testing.assert_array_equal(ids_of(table, 4)[0], [-1, 3, 2, -1, 1, -1, -1])
    # the front car 2 has nobody ahead; its rear-left is 3 (25 < 30 - 4.5), rear-right 6
    np.testing.assert_array_equal(ids_of(table, 2)[0], [-1, -1, -1, -1, -1, 3, 6])


def test_lane_numbering_towards_minus_y_gives_the_same_slots() -> None:
    """Lanes numbered the other way (lane 3 now on the right): left/right come from positions."""
    table = scene(SEVEN, lane_sign=-1)
    np.testing.assert_array_equal(ids_of(table, 1)[0], [6, 2, 3, 7, 4, 8, 5])


@pytest.mark.parametrize(("dx", "slot"), [(4.49, "L"), (4.51, "FL"), (-4.49, "L"), (-4.51, "RL")])
def test_alongside_is_longitudinal_overlap(dx: float, slot: str) -> None:
    """Two 4.5 m cars overlap while |dx| < 4.5 m."""
    table = scene({1: (2, 0.0), 2: (3, dx)})
    got = dict(zip(ncols.SLOTS, ids_of(table, 1)[0], strict=True))
    assert got[slot] == 2
    assert sum(v == 2 for v in got.values()) == 1


def test_truck_alongside_overlap_uses_both_lengths() -> None:
    """A 16 m truck overlaps a 4.5 m car while |dx| < 10.25 m; the nearest overlapping one is L."""
    lengths = {1: 16.0}
    table = scene({1: (2, 0.0), 2: (3, 10.0), 3: (3, 3.0), 4: (3, -10.3)}, lengths=lengths)
    got = dict(zip(ncols.SLOTS, ids_of(table, 1)[0], strict=True))
    assert (got["L"], got["FL"], got["RL"]) == (3, -1, 4)


def test_nearest_front_and_rear_in_a_crowded_adjacent_lane() -> None:
    vehicles = {1: (2, 0.0)} | {10 + i: (3, float(x)) for i, x in enumerate([-60, -30, -12, 15, 40, 70])}
    table = scene(vehicles)
    got = dict(zip(ncols.SLOTS, ids_of(table, 1)[0], strict=True))
    assert (got["FL"], got["L"], got["RL"]) == (13, -1, 12)


def test_bands_match_lanes_without_lane_ids() -> None:
    table = scene(SEVEN, lanes=False)
    assert nbm.recording_methods(table, ncols.columns(table)) == {"r": "bands"}
    np.testing.assert_array_equal(ids_of(table, 1)[0], SEVEN_EXPECTED)


@pytest.mark.parametrize("method", ["lanes", "bands"])
def test_rotated_world_frame(method: str) -> None:
    """A log in a world frame (travel at 2.2 rad): same neighbours as in the road frame."""
    table = scene(SEVEN, rotate=2.2)
    np.testing.assert_array_equal(ids_of(table, 1, method)[0], SEVEN_EXPECTED)


def test_source_columns_are_used_when_present() -> None:
    vehicles = {1: (2, 0.0), 2: (2, 30.0), 3: (3, 0.0)}
    tid = scene(vehicles).column("track_id").to_numpy()
    # Every column has ids somewhere (car 3 claims 1 everywhere); for car 1 the source claims 3 is
    # ahead (deliberately unlike the geometry) and 9 (not in the table) is its left alongside: 3
    # is taken as given, the unknown id becomes "none", the empty slots stay empty.
    extra = {name: np.where(tid == 3, 1, np.nan) for name in ncols.SOURCE_COLUMNS.values()}
    extra["preceding_id"] = np.where(tid == 1, 3, np.nan)
    extra["left_alongside_id"] = np.where(tid == 1, 9, np.where(tid == 3, 1, np.nan))
    table = scene(vehicles, extra=extra)
    assert nbm.recording_methods(table, ncols.columns(table)) == {"r": "source"}
    np.testing.assert_array_equal(ids_of(table, 1)[0], [-1, 3, -1, -1, -1, -1, -1])
    # computed from lanes even though the source gives them
    np.testing.assert_array_equal(ids_of(table, 1, "lanes")[0], [-1, 2, -1, 3, -1, -1, -1])


def test_partial_source_columns_are_not_enough() -> None:
    """NGSIM gives only preceding/following: all seven are computed from the lanes instead."""
    vehicles = {1: (2, 0.0), 2: (2, 30.0), 3: (3, 0.0)}
    tid = scene(vehicles).column("track_id").to_numpy()
    extra = {"preceding_id": np.where(tid == 1, 2, np.nan), "following_id": np.where(tid == 2, 1, np.nan)}
    table = scene(vehicles, extra=extra)
    assert nbm.recording_methods(table, ncols.columns(table)) == {"r": "lanes"}
    np.testing.assert_array_equal(ids_of(table, 1)[0], [-1, 2, -1, 3, -1, -1, -1])


def test_bands_ignore_opposing_traffic() -> None:
    """In a world frame without lanes, a car driving the other way 3 m to the left is nobody's L."""
    base = scene({1: (2, 0.0), 2: (3, 1.0), 3: (3, 40.0)}, lanes=False)
    heading = base.column("heading").to_numpy().copy()
    tid = base.column("track_id").to_numpy()
    heading[tid == 2] = np.pi
    table = base.set_column(
        base.schema.get_field_index("heading"), base.schema.field("heading"), pa.array(heading, pa.float32())
    )
    np.testing.assert_array_equal(ids_of(table, 1)[0], [3, -1, -1, -1, -1, -1, -1])


def test_source_method_needs_source_columns() -> None:
    with pytest.raises(TrackTableError, match="neighbour id columns"):
        nbm.neighbour_ids(scene(SEVEN), method="source")


def test_mixed_recordings_choose_their_own_method() -> None:
    a = scene(SEVEN)
    b = scene(SEVEN, lanes=False)
    cols = {
        name: np.concatenate(
            [a.column(name).to_numpy(zero_copy_only=False), b.column(name).to_numpy(zero_copy_only=False)]
        )
        for name in a.column_names
        if name != "lane_id"
    }
    cols["recording"] = np.r_[["a"] * a.num_rows, ["b"] * b.num_rows]
    lane = np.r_[a.column("lane_id").to_numpy().astype(float), np.full(b.num_rows, np.nan)]
    cols["lane_id"] = lane
    table = build_table(cols, TableMeta("test", {"a": RecordingMeta(10.0), "b": RecordingMeta(10.0)}))
    result = nbm.neighbour_rows(table)
    assert result.methods == {"a": "lanes", "b": "bands"}
    ids = nbm.neighbour_ids(table)
    rec = table.column("recording").cast(pa.string()).to_numpy(zero_copy_only=False)
    tid = table.column("track_id").to_numpy()
    for name in ("a", "b"):
        rows = np.flatnonzero((rec == name) & (tid == 1))
        np.testing.assert_array_equal(ids[rows], np.tile(SEVEN_EXPECTED, (5, 1)))
        # neighbours never cross recordings
        nb_rows = result.rows[rows]
        assert np.all(rec[nb_rows[nb_rows >= 0]] == name)


def test_row_index_lookup() -> None:
    table = scene({5: (2, 0.0), 9: (3, 0.0)}, n_frames=4)
    cols = ncols.columns(table)
    index = ncols.RowIndex(cols)
    rows = index.rows(np.zeros(5, np.int64), np.array([5, 9, 9, 7, 5]), np.array([0, 3, 4, 0, -1]))
    np.testing.assert_array_equal(rows, [0, 7, -1, -1, -1])


@pytest.mark.parametrize("big_ids", [False, True])
def test_row_index_lookup_with_gaps(big_ids: bool) -> None:
    """Track 5 has frames 0-3 and 10-13 (rows 0-7), track 9 frames 0-3 (rows 8-11); with ids far
    apart the sparse (searchsorted) path is taken."""
    frames = np.r_[np.arange(4), np.arange(10, 14)]
    tracks = {5: frames, 9: np.arange(4)}
    far = 10**12 if big_ids else 0  # added to track 9's id
    n = 12
    cols_in = {
        "recording": ["r"] * n,
        "track_id": np.r_[np.full(8, 5), np.full(4, 9 + far)],
        "frame": np.r_[tracks[5], tracks[9]],
        "time_ns": np.r_[tracks[5], tracks[9]] * 100_000_000,
        "lane_id": np.full(n, 1),
        "object_class": ["car"] * n,
    }
    for name in ("x", "y", "heading", "vx", "vy", "ax", "ay", "length", "width"):
        cols_in[name] = np.zeros(n)
    table = build_table(cols_in, TableMeta("test", {"r": RecordingMeta(10.0)}))
    index = ncols.RowIndex(ncols.columns(table))
    assert (index.dense is None) == big_ids
    q_track = np.array([5, 5, 5, 5, 5, 9 + far, 9 + far, 7])
    q_frame = np.array([0, 3, 5, 12, 13, 3, 10, 0])
    rows = index.rows(np.zeros(8, np.int64), q_track, q_frame)
    np.testing.assert_array_equal(rows, [0, 3, -1, 6, 7, 11, -1, -1])


@pytest.mark.slow
def test_agreement_with_sumo_neighbours(sim_recording_dir: Path) -> None:
    """lanecast's lane-based neighbours vs the ones SUMO wrote (highD columns), at 10 Hz."""
    from lanecast.io_adapters.datasets.highd import reader as highd
    from lanecast.pipeline.resample import resample

    table = resample(highd.read([sim_recording_dir]))
    cols = ncols.columns(table)
    source = nbm.neighbour_rows(table, cols, method="source").rows
    computed = nbm.neighbour_rows(table, cols, method="lanes").rows
    sid = np.where(source >= 0, cols.track[np.maximum(source, 0)], -1)
    cid = np.where(computed >= 0, cols.track[np.maximum(computed, 0)], -1)
    agree = sid == cid
    total = agree.mean()
    print(f"\nneighbour agreement with SUMO: {total:.4f} over {agree.size:,} (target, frame, slot) entries")
    for s, slot in enumerate(ncols.SLOTS):
        print(f"  {slot:>2}: {agree[:, s].mean():.4f}")
    kinds = {
        "SUMO has one, lanecast none": (sid >= 0) & (cid < 0),
        "lanecast has one, SUMO none": (sid < 0) & (cid >= 0),
        "different vehicles": (sid >= 0) & (cid >= 0) & ~agree,
    }
    for name, mask in kinds.items():
        print(f"  {name}: {mask.mean():.4f}")
    assert total >= 0.95
    assert (sid >= 0).mean() > 0.2  # the comparison is not between two empty sets


def test_each_recording_needs_ids_in_every_source_column_of_its_own_rows() -> None:
    """auto decides per recording: ids of one recording do not make another's column usable."""
    a = scene(SEVEN)
    tid = a.column("track_id").to_numpy()
    full = {name: np.where(tid == 1, 2.0, np.nan) for name in ncols.SOURCE_COLUMNS.values()}
    cols = {
        name: np.concatenate([a.column(name).to_numpy(zero_copy_only=False)] * 3) for name in a.column_names
    }
    cols["recording"] = np.r_[["a"] * a.num_rows, ["b"] * a.num_rows, ["c"] * a.num_rows]
    for name, ids in full.items():  # a: every column; b: all but one; c: none
        cols[name] = np.r_[
            ids, ids if name != "left_following_id" else np.full(a.num_rows, np.nan), ids * np.nan
        ]
    table = build_table(cols, TableMeta("test", {r: RecordingMeta(10.0) for r in "abc"}))
    assert nbm.recording_methods(table, ncols.columns(table)) == {"a": "source", "b": "lanes", "c": "lanes"}
    assert nbm.recording_methods(table.slice(0, 0), ncols.columns(table.slice(0, 0))) == {}
