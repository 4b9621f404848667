"""Window tensors, value by value: a target with a vehicle in each of the seven slots, a slot that
empties and refills, a world frame, acceleration projection, strides and gaps, both highD driving
directions, bad input, the on-disk dataset, normalisation and the `lanecast windows` command."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pytest
from conftest import LANE, ROW_OF_ID, SEVEN, straight, table_of

from lanecast.io_adapters.contracts.normalisation import NormStats, compute_stats, denormalise, normalise
from lanecast.io_adapters.contracts.track_table import (
    concat,
    write_parquet,
)
from lanecast.io_adapters.contracts.window_frame import to_source_frame
from lanecast.io_adapters.contracts.windows import ROWS, Windows, concat_windows, subset
from lanecast.io_adapters.errors import InputError, TrackTableError
from lanecast.io_adapters.windows_store.dataset import load_windows, save_windows
from lanecast.pipeline.make_windows import make_windows
from lanecast.workflows.cli import main as cli_main


def test_seven_slots_every_value() -> None:
    frames = np.arange(120)
    speeds = {tid: 30.0 + tid for tid in SEVEN}  # the v channel reads the vx column
    accs = {tid: 0.1 * tid for tid in SEVEN}
    table = table_of(straight(SEVEN, frames, vx=speeds, ax=accs))
    w = make_windows(table, split="none")
    idx = w.index
    mine = np.flatnonzero(idx.column("track_id").to_numpy() == 1)
    t0_frames = idx.column("t0_ns").to_numpy()[mine] // 100_000_000
    assert t0_frames.tolist() == [29, 39, 49, 59, 69]
    back = 29 - np.arange(30)  # frames before t0, oldest first
    for i in mine:
        inputs, present = w.inputs[i], w.present[i]
        assert present.all()
        for tid, (lane, dx) in SEVEN.items():
            row = ROWS.index(ROW_OF_ID[tid])
            np.testing.assert_allclose(inputs[0, row], dx - 3.0 * back, atol=1e-4)
            np.testing.assert_allclose(inputs[1, row], (lane - 2) * LANE, atol=1e-5)
            np.testing.assert_allclose(inputs[2, row], 30.0 + tid, atol=1e-5)
            np.testing.assert_allclose(inputs[3, row], 0.1 * tid, atol=1e-6)
        np.testing.assert_allclose(w.future[i], [[30, 0], [60, 0], [90, 0], [120, 0], [150, 0]], atol=1e-4)
        np.testing.assert_array_equal(w.maneuver[i], 0)
        assert w.index.column("origin_x")[int(i)].as_py() == pytest.approx(
            3.0 * t0_frames[mine.tolist().index(int(i))]
        )


def test_slot_empties_and_refills_mid_window() -> None:
    """F is vehicle 2 (30 m ahead), except: 9 cuts in 15 m ahead during frames 40…49 and 2 is
    missing during frames 45…54. Window t0 = 59 (history frames 30…59): F = 2 for 30…39, 9 for
    40…49, nobody for 50…54, 2 again for 55…59; every other slot stays empty."""
    frames = np.arange(120)
    tracks = straight({1: (2, 0.0)}, frames)
    keep = (frames < 45) | (frames > 54)
    tracks[2] = {
        "frame": frames[keep],
        "x": 30.0 + 3.0 * frames[keep],
        "y": np.zeros(keep.sum()),
        "lane": np.full(keep.sum(), 2),
    }
    cut = np.arange(40, 50)
    tracks[9] = {
        "frame": cut,
        "x": 15.0 + 3.0 * cut,
        "y": np.zeros(cut.size),
        "lane": np.full(cut.size, 2),
        "vx": 25.0,
    }
    w = make_windows(table_of(tracks), split="none", stride=1, require_future=False)
    i = int(
        np.flatnonzero(
            (w.index.column("track_id").to_numpy() == 1)
            & (w.index.column("t0_ns").to_numpy() == 5_900_000_000)
        )[0]
    )
    f = 30 + np.arange(30)
    expected_dx = np.select([f < 40, f < 50, f < 55], [30.0, 15.0, 0.0], 30.0) - 3.0 * (59 - f)
    expected_present = ~((f >= 50) & (f <= 54))
    expected_v = np.select([f < 40, f < 50], [30.0, 25.0], 30.0) * expected_present
    row = ROWS.index("F")
    np.testing.assert_array_equal(w.present[i, row], expected_present)
    np.testing.assert_allclose(w.inputs[i, 0, row], np.where(expected_present, expected_dx, 0.0), atol=1e-4)
    np.testing.assert_allclose(w.inputs[i, 2, row], expected_v, atol=1e-5)
    others = [r for r in range(8) if r not in (row, ROWS.index("T"))]
    assert not w.present[i, others].any()
    assert np.all(w.inputs[i][:, others] == 0)


def test_world_frame_windows_equal_road_frame_windows() -> None:
    frames = np.arange(120)
    tracks = straight(SEVEN, frames, ax={1: 0.4}, vy={1: 0.0})
    road = make_windows(table_of(tracks), split="none")
    theta = 2.4
    world = make_windows(table_of(tracks, rotate=theta), split="none")
    np.testing.assert_allclose(world.inputs, road.inputs, atol=1e-4)
    np.testing.assert_array_equal(world.present, road.present)
    np.testing.assert_allclose(world.future, road.future, atol=1e-4)
    ox, oy, oh = world.origin()
    np.testing.assert_allclose(oh, theta, atol=1e-6)
    # offsets mapped back land on the target's world positions at t0 + 1 … 5 s
    back = to_source_frame(world.future, ox, oy, oh)
    mine = np.flatnonzero(world.index.column("track_id").to_numpy() == 1)
    t0 = world.index.column("t0_ns").to_numpy()[mine] / 1e8
    road_x = 3.0 * (t0[:, None] + 10 * np.arange(1, 6)[None, :])
    np.testing.assert_allclose(back[mine, :, 0], np.cos(theta) * road_x, atol=1e-3)
    np.testing.assert_allclose(back[mine, :, 1], np.sin(theta) * road_x, atol=1e-3)


def test_speed_and_longitudinal_acceleration_use_the_vehicles_own_heading() -> None:
    """Heading 0.5 rad, v = (3, 4), a = (1, 2): speed 5, a_lon = cos 0.5 + 2 sin 0.5."""
    frames = np.arange(90)
    tr = {
        1: {
            "frame": frames,
            "x": 3.0 * frames,
            "y": np.zeros(90),
            "lane": np.full(90, 2),
            "vx": 3.0,
            "vy": 4.0,
            "ax": 1.0,
            "ay": 2.0,
            "heading": 0.5,
        }
    }
    w = make_windows(table_of(tr), split="none")
    t = ROWS.index("T")
    np.testing.assert_allclose(w.inputs[0, 2, t], 5.0, atol=1e-5)
    np.testing.assert_allclose(w.inputs[0, 3, t], np.cos(0.5) + 2 * np.sin(0.5), atol=1e-5)
    # positions in the window frame (a road frame: translated, not rotated by the heading)
    assert w.inputs[0, 0, t, -1] == 0.0 and w.inputs[0, 1, t, -1] == 0.0
    dx = -3.0 * np.arange(29, -1, -1)
    np.testing.assert_allclose(w.inputs[0, 0, t], dx, atol=1e-4)
    np.testing.assert_allclose(w.inputs[0, 1, t], 0.0, atol=1e-4)
    np.testing.assert_allclose(w.origin()[2], 0.0)


def left_change(frames: np.ndarray, t_mid: float) -> dict[int, dict[str, Any]]:
    """T at 30 m/s changing from lane 2 to lane 3 (+y) with a smooth lateral profile over 4 s
    centred on frame ``t_mid``; its heading follows its motion (up to ~3° off the road)."""
    u = np.clip((frames - t_mid) / 40.0 + 0.5, 0.0, 1.0)
    y = LANE * (3 * u**2 - 2 * u**3)
    vy = LANE * (6 * u - 6 * u**2) / 4.0
    lane = np.where(y < LANE / 2, 2, 3)
    return {
        1: {
            "frame": frames,
            "x": 3.0 * frames,
            "y": y,
            "lane": lane,
            "vy": vy,
            "heading": np.arctan2(vy, 30.0),
        }
    }


def test_left_lane_change_under_way_ends_on_the_left() -> None:
    """Road frame, a left change under way at t0 (heading ~3° to the left): the future ends one
    lane to the left. Rotating by the instantaneous heading would end it ~5 m to the right."""
    frames = np.arange(100)
    w = make_windows(table_of(left_change(frames, 39.0)), split="none", t0_ns=[3.9e9])
    assert len(w) == 1
    assert w.maneuver[0, 0] == 1  # labelled left
    np.testing.assert_allclose(w.future[0, -1], [150.0, LANE / 2], atol=0.25)
    assert w.future[0, :, 1].min() > 0.0  # every future step on the left of t0's position
    np.testing.assert_allclose(w.inputs[0, 1, ROWS.index("T"), 0], -LANE / 2, atol=0.25)
    assert w.origin()[2][0] == 0.0


def test_left_lane_change_in_a_world_frame_ends_on_the_left() -> None:
    """World frame rotated by 0.7 rad, a left change starting at t0: the frame is the road's
    direction (the history's chord), so the future ends one lane to the left (+y)."""
    frames = np.arange(100)
    w = make_windows(table_of(left_change(frames, 59.0), rotate=0.7), split="none", t0_ns=[3.9e9])
    assert w.maneuver[0].tolist() == [1, 1, 1, 1, 0]
    np.testing.assert_allclose(w.future[0, -1], [150.0, LANE], atol=0.05)
    assert w.origin()[2][0] == pytest.approx(0.7, abs=1e-6)


def test_world_frame_follows_the_history_chord_not_a_noisy_heading() -> None:
    """Straight driving whose heading column is noisy (±10°): the frame is the history's chord."""
    frames = np.arange(100)
    rng = np.random.default_rng(0)
    tracks = {1: {"frame": frames, "x": 3.0 * frames, "y": np.zeros(100), "lane": np.full(100, 2),
                  "heading": rng.uniform(-0.17, 0.17, 100)}}  # fmt: skip
    w = make_windows(table_of(tracks, rotate=-2.0), split="none")
    np.testing.assert_allclose(w.origin()[2], -2.0, atol=1e-6)
    np.testing.assert_allclose(w.future[..., 1], 0.0, atol=1e-3)


def test_standing_target_falls_back_to_longer_chord_then_heading() -> None:
    """A target that moved 40 m along the world direction 1.0 rad, then stood for 3 s: its frame
    is the 10 s chord (1.0); one that never moved takes its mean heading."""
    frames = np.arange(120)
    x = np.minimum(frames, 40) * 1.0
    tracks = {
        1: {"frame": frames, "x": x, "y": np.zeros(120), "lane": np.full(120, 2), "vx": 0.0},
        2: {"frame": frames, "x": np.full(120, -50.0), "y": np.zeros(120), "lane": np.full(120, 2),
            "vx": 0.0, "heading": 0.3},
    }  # fmt: skip
    w = make_windows(table_of(tracks, rotate=1.0), split="none", t0_ns=[6.9e9])
    ids = w.index.column("track_id").to_numpy()
    heading = w.origin()[2]
    assert heading[ids == 1][0] == pytest.approx(1.0, abs=1e-6)
    assert heading[ids == 2][0] == pytest.approx(1.3, abs=1e-6)


def test_neighbour_range_drops_far_vehicles() -> None:
    """A vehicle 2,960 m ahead in T's lane is no neighbour (default 100 m); at 50 m it is F; the
    range is recorded in the manifest."""
    frames = np.arange(90)
    far = make_windows(table_of(straight({1: (2, 0.0), 2: (2, 2960.0)}, frames)), split="none")
    assert not far.present[:, ROWS.index("F")].any()
    assert far.manifest["parameters"]["neighbour_range_m"] == 100.0
    near = make_windows(table_of(straight({1: (2, 0.0), 2: (2, 50.0)}, frames)), split="none")
    assert near.present[near.index.column("track_id").to_numpy() == 1][:, ROWS.index("F")].all()
    wide = make_windows(
        table_of(straight({1: (2, 0.0), 2: (2, 2960.0)}, frames)), split="none", neighbour_range=3000.0
    )
    assert wide.present[wide.index.column("track_id").to_numpy() == 1][:, ROWS.index("F")].all()


def t0_of(w: Windows) -> list[int]:
    return (w.index.column("t0_ns").to_numpy() // 100_000_000).tolist()


def test_stride_future_and_explicit_times() -> None:
    table = table_of(straight({1: (2, 0.0)}, np.arange(120)))
    assert t0_of(make_windows(table, split="none")) == [29, 39, 49, 59, 69]
    assert t0_of(make_windows(table, split="none", stride=1)) == list(range(29, 70))
    w = make_windows(table, split="none", require_future=False)
    assert t0_of(w) == list(range(29, 120, 10))
    i = t0_of(w).index(79)  # 40 frames of future left: steps 1…4 known, step 5 not
    np.testing.assert_allclose(w.future[i, :4], [[30, 0], [60, 0], [90, 0], [120, 0]], atol=1e-4)
    assert np.isnan(w.future[i, 4]).all()
    np.testing.assert_array_equal(w.maneuver[i], [0, 0, 0, 0, -1])
    w = make_windows(table, split="none", t0_ns=np.array([3_000_000_000, 5_500_000_000, 11_000_000_000]))
    assert t0_of(w) == [30, 55]


def test_windows_never_span_a_gap() -> None:
    frames = np.r_[np.arange(0, 80), np.arange(90, 200)]
    w = make_windows(table_of(straight({1: (2, 0.0)}, frames)), split="none")
    assert t0_of(w) == [29, 119, 129, 139, 149]
    np.testing.assert_allclose(
        w.inputs[:, 0, ROWS.index("T")], np.tile(-3.0 * np.arange(29, -1, -1), (5, 1)), atol=1e-4
    )


def write_highd(directory: Path) -> Path:
    """A 10 s highD recording (25 Hz) with one left lane change per driving direction: lower car 1
    (towards +x) moves up the image from lane 6 to 5, upper car 3 (towards -x) down from lane 2 to 3;
    cars 2 and 4 drive 30 m ahead of them. The two directions mirror each other."""
    f = np.arange(1, 251)
    t = f / 25.0
    shift = np.clip((t - 4.0) / 2.0, 0.0, 1.0)  # lane change between 4 s and 6 s
    dshift = np.where((t > 4.0) & (t < 6.0), 0.5, 0.0) * 3.5
    lower_y = 19.25 - 3.5 * shift
    upper_y = 5.75 + 3.5 * shift
    cars = {
        1: (2, 10.0 + 30 * t, lower_y, 30.0, -dshift, np.where(lower_y < 17.5, 5, 6), 2),
        2: (2, 40.0 + 30 * t, np.full(250, 19.25), 30.0, 0 * t, np.full(250, 6), 0),
        3: (1, 400.0 - 30 * t, upper_y, -30.0, dshift, np.where(upper_y > 7.5, 3, 2), 4),
        4: (1, 370.0 - 30 * t, np.full(250, 5.75), -30.0, 0 * t, np.full(250, 2), 0),
    }
    header = (
        "frame,id,x,y,width,height,xVelocity,yVelocity,xAcceleration,yAcceleration,frontSightDistance,"
        "backSightDistance,dhw,thw,ttc,precedingXVelocity,precedingId,followingId,leftPrecedingId,"
        "leftAlongsideId,leftFollowingId,rightPrecedingId,rightAlongsideId,rightFollowingId,laneId"
    )
    lines = [header]
    for tid, (_, cx, cy, vx, vy, lane, pre) in cars.items():
        for k in range(250):
            lines.append(
                f"{f[k]},{tid},{cx[k] - 2.25:.4f},{cy[k] - 1.0:.4f},4.50,2.00,{vx:.2f},{vy[k]:.4f},0.00,0.00,"
                f"0,0,0,0,0,0,{pre},0,0,0,0,0,0,0,{lane[k]}"
            )
    (directory / "01_tracks.csv").write_text("\n".join(lines) + "\n")
    meta = [
        "id,width,height,initialFrame,finalFrame,numFrames,class,drivingDirection,traveledDistance,"
        "minXVelocity,maxXVelocity,meanXVelocity,minDHW,minTHW,minTTC,numLaneChanges"
    ]
    for tid, (direction, *_rest) in cars.items():
        meta.append(
            f"{tid},4.50,2.00,1,250,250,Car,{direction},300,30,30,30,0,0,-1,{1 if tid in (1, 3) else 0}"
        )
    (directory / "01_tracksMeta.csv").write_text("\n".join(meta) + "\n")
    (directory / "01_recordingMeta.csv").write_text(
        "id,frameRate,locationId,speedLimit,month,weekDay,startTime,duration,totalDrivenDistance,"
        "totalDrivenTime,numVehicles,numCars,numTrucks,upperLaneMarkings,lowerLaneMarkings\n"
        "1,25,2,-1.00,09.2017,Tue,08:38,10.00,1200,40,4,4,0,4.00;7.50;11.00,14.00;17.50;21.00\n"
    )
    return directory


def test_highd_directions_give_mirror_consistent_windows(tmp_path: Path) -> None:
    from lanecast.io_adapters.datasets.highd import reader as highd

    table = highd.read([write_highd(tmp_path)])
    w = make_windows(table, split="none", stride=1)
    rec = np.asarray(w.index.column("recording").to_pylist())
    tid = w.index.column("track_id").to_numpy()
    lower = np.flatnonzero((rec == "highd-01-lower") & (tid == 1))
    upper = np.flatnonzero((rec == "highd-01-upper") & (tid == 3))
    assert lower.size == upper.size > 0
    np.testing.assert_array_equal(
        w.index.column("t0_ns").to_numpy()[lower], w.index.column("t0_ns").to_numpy()[upper]
    )
    np.testing.assert_allclose(w.inputs[lower], w.inputs[upper], atol=1e-3)
    np.testing.assert_array_equal(w.present[lower], w.present[upper])
    np.testing.assert_allclose(w.future[lower], w.future[upper], atol=1e-3)
    np.testing.assert_array_equal(w.maneuver[lower], w.maneuver[upper])
    assert set(np.unique(w.maneuver[lower]).tolist()) == {0, 1}  # the left change is 1 in both
    assert w.present[lower, ROWS.index("F")].all()  # the car ahead (computed from the lanes)
    # the change moves the target to +y (left) in the window frame in both directions
    assert np.nanmax(w.future[lower, :, 1]) == pytest.approx(3.5, abs=0.05)


def one_frame_table() -> pa.Table:
    return table_of({1: {"frame": np.array([0]), "x": np.zeros(1), "y": np.zeros(1), "lane": np.array([1])}})


def test_bad_input() -> None:
    with pytest.raises(InputError, match=r"no windows: r: longest gap-free track is 1 frame"):
        make_windows(one_frame_table())
    assert len(make_windows(one_frame_table(), allow_empty=True)) == 0
    table = table_of(straight({1: (2, 0.0)}, np.arange(100)))
    x = table.column("x").to_numpy().copy()
    x[7] = np.nan
    bad = table.set_column(table.schema.get_field_index("x"), table.schema.field("x"), pa.array(x))
    with pytest.raises(TrackTableError, match="row 7: column 'x' is nan"):
        make_windows(bad)
    with pytest.raises(InputError, match="stride"):
        make_windows(table, stride=0)
    with pytest.raises(InputError, match="unknown split method"):
        make_windows(table, split="random")


def test_save_load_roundtrip(tmp_path: Path) -> None:
    table = table_of(straight(SEVEN, np.arange(150)))
    w = make_windows(table, split="hash", seed=2)
    out = save_windows(w, tmp_path / "ds")
    assert sorted(p.name for p in out.iterdir()) == sorted(
        ["inputs.npy", "present.npy", "future.npy", "maneuver.npy", "windows.parquet", "manifest.json"]
    )
    assert [p.name for p in tmp_path.iterdir()] == ["ds"]  # no temporary left behind
    back = load_windows(out)
    assert isinstance(back.inputs, np.memmap)
    for name in ("inputs", "present", "future", "maneuver"):
        np.testing.assert_array_equal(getattr(back, name), getattr(w, name))
    assert back.index.equals(w.index)
    m = back.manifest
    assert m["n_windows"] == len(w) == 8 * 8
    assert sum(m["counts"].values()) == len(w)
    assert m["parameters"]["stride"] == 10 and m["parameters"]["split"] == "hash"
    assert m["sources"]["recordings"]["r"]["neighbour_method"] == "lanes"
    assert m["label_distribution"] == {"straight": len(w) * 5, "left": 0, "right": 0, "unknown": 0}
    part = subset(back, back.index.column("track_id").to_numpy() == 1)
    assert len(part) == 8 and part.index.num_rows == 8
    np.testing.assert_array_equal(part.inputs, w.inputs[w.index.column("track_id").to_numpy() == 1])
    with pytest.raises(InputError, match="no such windows directory"):
        load_windows(tmp_path / "missing")


def test_normalisation_over_present_entries() -> None:
    inputs = np.zeros((2, 4, 8, 30), np.float32)
    present = np.zeros((2, 8, 30), bool)
    present[0, 4, :] = True  # 30 entries with x = 1, 30 with x = 3 -> mean 2, std 1
    present[1, 4, :] = True
    inputs[0, 0, 4] = 1.0
    inputs[1, 0, 4] = 3.0
    inputs[:, 2, 4] = 30.0  # constant speed -> std 0 -> 1
    inputs[0, 0, 0] = 99.0  # not present: ignored
    stats = compute_stats(inputs, present)
    np.testing.assert_allclose(stats.mean, [2.0, 0.0, 30.0, 0.0])
    np.testing.assert_allclose(stats.std, [1.0, 1.0, 1.0, 1.0])
    z = normalise(inputs, present, stats)
    np.testing.assert_allclose(z[0, 0, 4], -1.0)
    np.testing.assert_allclose(z[1, 0, 4], 1.0)
    assert np.all(z[:, :, [0, 1, 2, 3, 5, 6, 7]] == 0.0)
    np.testing.assert_allclose(denormalise(z, present, stats)[:, :, 4], inputs[:, :, 4])
    again = NormStats.from_dict(stats.to_dict())
    np.testing.assert_array_equal(again.mean, stats.mean)
    with pytest.raises(InputError):
        NormStats.from_dict({"mean": [0, 0, 0, 0], "std": [1, 0, 1, 1]})


def test_cli_windows(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = write_parquet(table_of(straight(SEVEN, np.arange(150))), tmp_path / "t.parquet")
    assert (
        cli_main(["windows", str(path), "--out", str(tmp_path / "w"), "--split", "hash", "--stride", "5"])
        == 0
    )
    out = capsys.readouterr().out
    w = load_windows(tmp_path / "w")
    assert len(w) == 8 * 15  # t0 = 29, 34, …, 99
    assert f"{len(w):,} windows" in out
    assert w.manifest["parameters"]["stride"] == 5
    one = write_parquet(one_frame_table(), tmp_path / "one.parquet")
    assert cli_main(["windows", str(one), "--out", str(tmp_path / "w1")]) == 2
    err = capsys.readouterr().err
    assert "no windows" in err and "longest gap-free track is 1 frame" in err
    assert not (tmp_path / "w1").exists()


def test_recordings_in_groups_and_a_skipped_short_recording() -> None:
    """Processing recording by recording (small max_rows, threads) gives the same dataset as all at once;
    a one-frame recording is skipped and named in the manifest."""
    a = table_of(straight(SEVEN, np.arange(120)), recording="a")
    b = table_of(straight({1: (2, 0.0), 2: (3, 3.0)}, np.arange(100)), recording="b")
    c = table_of(
        {1: {"frame": np.array([0]), "x": np.zeros(1), "y": np.zeros(1), "lane": np.array([1])}},
        recording="c",
    )
    table = concat([a, b, c])
    whole = make_windows(table, split="hash")
    grouped = make_windows(table, split="hash", max_rows=200)  # three groups, two batches
    single = make_windows(table, split="hash", workers=1)  # one group, no threads
    np.testing.assert_array_equal(single.inputs, whole.inputs)
    np.testing.assert_array_equal(single.present, whole.present)
    assert single.index.equals(whole.index)
    assert len(whole) == 8 * 5 + 2 * 3
    np.testing.assert_array_equal(grouped.inputs, whole.inputs)
    np.testing.assert_array_equal(grouped.maneuver, whole.maneuver)
    assert grouped.index.equals(whole.index)
    assert set(whole.manifest["skipped_recordings"]) == {"c"}
    assert whole.manifest["sources"]["recordings"]["a"]["neighbour_method"] == "lanes"


def test_cli_windows_reads_a_highd_directory(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    src = tmp_path / "highd"
    src.mkdir()
    write_highd(src)
    out = tmp_path / "w"
    assert (
        cli_main(["windows", str(src), "--out", str(out), "--split", "none", "--stride", "1", "--no-future"])
        == 0
    )
    w = load_windows(out)
    # 10 s at 10 Hz (0.04 … 10.0 s -> frames 1 … 100) per car: t0 from frame 30 to 100 = 71 windows
    assert len(w) == 4 * 71
    assert w.manifest["parameters"]["require_future"] is False
    assert np.isnan(w.future[w.index.column("t0_ns").to_numpy() == 10_000_000_000]).all()
    assert "neighbours from: lanes" in capsys.readouterr().out


@pytest.mark.parametrize(
    ("key", "value"),
    [
        ("format", "lanecast-tracks"),
        ("rows", ["RR", "RL", "R", "T", "L", "FR", "F", "FL"]),
        ("channels", ["y", "x", "v", "a"]),
        ("maneuvers", ["straight", "right", "left"]),
        ("horizons", 3),
        ("n_windows", 65),
        ("n_windows", "64"),
    ],
)
def test_a_manifest_that_does_not_describe_its_arrays_is_refused(
    tmp_path: Path, key: str, value: Any
) -> None:
    """A manifest of another format, with the vehicle rows, channels or maneuver classes in another
    order, or another window count than the arrays hold was read as if it described them (train and
    evaluate ran, exit 0): now refused naming manifest.json and the entry."""
    out = save_windows(make_windows(table_of(straight(SEVEN, np.arange(150))), split="hash"), tmp_path / "ds")
    manifest = json.loads((out / "manifest.json").read_text())
    manifest[key] = value
    (out / "manifest.json").write_text(json.dumps(manifest))
    with pytest.raises(InputError) as err:
        load_windows(out)
    assert err.value.path == str(out / "manifest.json") and err.value.column == key


def test_a_saved_subset_or_concatenation_states_its_own_count(tmp_path: Path) -> None:
    """subset and concat_windows keep the manifest they were made from; saved as it was, its
    n_windows described the parent, and load_windows refused the dataset (benchmarks/train_shipped's
    merged training windows: 'n_windows 7932, but the arrays … hold 443796 windows')."""
    whole = make_windows(table_of(straight(SEVEN, np.arange(150))), split="hash")
    part = subset(whole, np.arange(10))
    merged = concat_windows([whole, part])
    for name, windows in (("part", part), ("merged", merged)):
        loaded = load_windows(save_windows(windows, tmp_path / name))
        assert len(loaded) == loaded.manifest["n_windows"] == len(windows)
    assert len(merged) == len(whole) + 10


@pytest.mark.parametrize("command", ["info", "convert", "windows"])
def test_a_windows_dataset_given_as_a_track_table_is_named_as_such(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], command: str
) -> None:
    """`lanecast info win/` (or convert, windows) read win/windows.parquet as a track table:
    "win/windows.parquet: missing column 'frame'" or "no 'lanecast' schema metadata", about a
    file the user never named. Now one line saying the folder is a windows dataset."""
    out = save_windows(
        make_windows(table_of(straight(SEVEN, np.arange(150))), split="hash"), tmp_path / "win"
    )
    argv = {
        "info": [],
        "convert": ["--out", str(tmp_path / "t.parquet")],
        "windows": ["--out", str(tmp_path / "w2")],
    }
    assert cli_main([command, str(out), *argv[command]]) == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert err == (
        f"lanecast {command}: error: {out}: a windows dataset (the output of `lanecast windows`), not a track "
        "table (expected a track table, highD or NGSIM files, or a drive log; `lanecast train` and `lanecast "
        "evaluate` read windows datasets)"
    )
    assert sorted(p.name for p in tmp_path.iterdir()) == ["win"]
