"""csp writer: conv-social-pooling's TrainSet/ValSet/TestSet.mat from raw NGSIM files and highD.

The fixture tests/data/csp holds six small NGSIM .txt files (simulated traffic) and the three sets
that conv-social-pooling's own preprocess_data.m wrote from them under GNU Octave
(benchmarks/csp_equality.py --fixture made them); lanecast's sets must equal them element for
element. The loader test indexes the written files as the research code's ngsimDataset does.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

from lanecast.io_adapters.datasets.csp import fields, inputs, sets
from lanecast.io_adapters.datasets.csp.sets import Dataset
from lanecast.io_adapters.datasets.csp.writer import write_csp
from lanecast.io_adapters.errors import InputError, OutputError
from lanecast.pipeline.resample import resample
from lanecast.workflows import cli

loadmat = pytest.importorskip("scipy.io").loadmat

FIXTURE = Path(__file__).resolve().parents[3] / "data" / "csp"
FIXTURE_FILES = sorted(FIXTURE.glob("*.txt"))
SETS = ("TrainSet", "ValSet", "TestSet")


def _f32(*values: float) -> np.ndarray:
    return np.array(values, dtype=np.float32)


def _write_txt(path: Path, rows: list[tuple[int, int, float, float, int]]) -> Path:
    """A raw NGSIM .txt of (vehicle, frame, local x, local y, lane) rows, other columns plausible."""
    lines = []
    for vehicle, frame, x, y, lane in rows:
        lines.append(
            f"{vehicle} {frame} 100 {1113433136100 + 100 * frame} {x:.3f} {y:.3f} 6042842.000 2133117.000 "
            f"15.0 6.0 2 30.00 0.00 {lane} 0 0 0.00 0.00"
        )
    path.write_text("\n".join(lines) + "\n")
    return path


def _straight(vehicle: int, frames: range, lane: int, y0: float = 100.0, x: float = 6.0) -> list:
    return [(vehicle, f, x, y0 + 5.0 * f, lane) for f in frames]


# ------------------------------------------------------------------------------------------ fields


def test_lateral_maneuver_from_the_lane_40_rows_before_and_after() -> None:
    frame = np.arange(1, 101, dtype=np.float32)
    lane = np.where(frame <= 60, 2, 3).astype(np.float32)
    vehicle = np.ones(100, np.float32)
    lat, lon = fields.maneuvers(fields.vehicles(vehicle), frame, frame * 10, lane)
    # a row sees the change once it is within 40 rows ahead (frame 21) and still 40 rows after it
    assert (lat[frame <= 20] == 1).all() and (lat[frame >= 21] == 3).all()
    falling = np.where(frame <= 60, 3, 2).astype(np.float32)
    lat, _ = fields.maneuvers(fields.vehicles(vehicle), frame, frame * 10, falling)
    assert (lat[frame <= 20] == 1).all() and (lat[frame >= 21] == 2).all()
    assert (lon == 1).all()  # constant speed


def test_longitudinal_maneuver_by_speed_ratio_over_30_rows_back_and_50_ahead() -> None:
    frame = np.arange(1, 101, dtype=np.float32)
    y = np.where(frame <= 50, 10 * frame, 500 + 5 * (frame - 50)).astype(np.float32)
    _, lon = fields.maneuvers(fields.vehicles(np.ones(100, np.float32)), frame, y, np.ones(100, np.float32))
    assert lon[0] == 1  # no history: normal
    assert lon[39] == 2  # frame 40: 10 ft a frame behind, (750-400)/50 = 6 ahead... 6/10 < 0.8
    assert lon[89] == 1  # frame 90: 5 behind, 5 ahead
    assert lon[99] == 1  # last row: no future


def test_grid_cells_rounding_reach_and_the_later_row_winning() -> None:
    # (vehicle, y, lane): ego 1 in lane 2 at y 100
    rows = [
        (1, 100.0, 2),
        (2, 107.5, 2),  # +7.5 ft: (97.5/15 = 6.5) rounds away from zero to 7: own-lane cell 13 + 7
        (3, 10.0, 1),  # -90 ft: outside (|y| < 90 only)
        (4, 189.9, 3),  # +89.9 ft: right lane, last cell
        (5, 100.0, 2),  # same y as the ego: never in its own lane's grid (y ~= 0)
        (7, 55.0, 1),  # -45 ft: left cell round(45/15) = 3
        (6, 56.0, 1),  # -44 ft: the same cell, later in the file: kept
    ]
    vehicle = _f32(*(r[0] for r in rows))
    y = _f32(*(r[1] for r in rows))
    lane = _f32(*(r[2] for r in rows))
    frame = np.ones(len(rows), np.float32)
    grid = fields.neighbour_grid(vehicle, frame, y, lane, np.arange(len(rows)))
    ego = grid[0]
    assert ego[13 + 7] == 2
    assert ego[26 + 12] == 4
    assert ego[3] == 6
    assert np.count_nonzero(ego) == 3
    assert grid[4][13 + 6] == 0 and grid[4][13 + 7] == 2  # vehicle 5 sees 2 but not 1 (same y)


def test_round_half_away_is_exact_in_float32() -> None:
    x = _f32(0.49999997, 0.5, 2.5, 6.5, 11.499999)
    assert fields.round_half_away(x).tolist() == [0.0, 1.0, 3.0, 7.0, 11.0]


def test_split_thresholds_round_halves_up() -> None:
    which = sets.set_of_rows(np.arange(1, 16, dtype=np.float32))  # 0.7 * 15 = 10.5 -> 11; 0.8 * 15 = 12
    assert which.tolist() == [0] * 11 + [1] + [2] * 3


def test_filter_keeps_rows_with_30_rows_before_and_a_frame_beyond_t_plus_1() -> None:
    frame = np.arange(1, 41, dtype=np.float32)
    kept = fields.kept_rows(fields.vehicles(np.ones(40, np.float32)), frame)
    assert np.flatnonzero(kept).tolist() == list(range(30, 38))  # frames 31..38 (40 > t + 1)
    short = fields.kept_rows(fields.vehicles(np.ones(30, np.float32)), frame[:30])
    assert not short.any()  # 30 rows: none (the research script stops with an index error there)


# ------------------------------------------------------------------------------------------- files


def test_dataset_ids_follow_the_scripts_order_and_us101_lanes_merge(tmp_path: Path) -> None:
    src = tmp_path / "in"
    src.mkdir()
    _write_txt(src / "trajectories-0400-0415.txt", _straight(1, range(1, 41), 7))  # I-80: lane 7 stays
    _write_txt(src / "us-101-b.txt", _straight(2, range(1, 41), 3))
    _write_txt(src / "trajectories-0750am-0805am.txt", _straight(3, range(1, 41), 8))  # US-101: 8 -> 6
    record = write_csp([src], tmp_path / "out")
    ids = {Path(d["file"]).name: d["id"] for d in record["datasets"]}
    assert ids == {"trajectories-0750am-0805am.txt": 1, "us-101-b.txt": 2, "trajectories-0400-0415.txt": 3}
    # one vehicle a dataset, so each in another set (ids 1, 2, 3: train, validation, test)
    traj = np.concatenate([loadmat(tmp_path / "out" / f"{s}.mat")["traj"] for s in SETS])
    lanes = {int(d): set(traj[traj[:, 0] == d, 5].tolist()) for d in (1, 2, 3)}
    assert lanes == {1: {6.0}, 2: {3.0}, 3: {7.0}}


def test_cli_writes_sets_and_refuses_a_users_file(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    src = _write_txt(tmp_path / "us-101.txt", _straight(1, range(1, 41), 2) + _straight(2, range(1, 41), 3))
    out = tmp_path / "csp"
    assert cli.main(["convert", str(src), "--to", "csp", "--out", str(out)]) == 0
    assert "dataset 1: " in capsys.readouterr().out
    assert sorted(p.name for p in out.iterdir()) == [
        "TestSet.mat",
        "TrainSet.mat",
        "ValSet.mat",
        "lanecast-csp.json",
    ]
    assert cli.main(["convert", str(src), "--to", "csp", "--out", str(out)]) == 0  # its own: replaced
    (out / "ValSet.mat").write_bytes(b"my notes")
    before = (out / "TrainSet.mat").read_bytes()
    assert cli.main(["convert", str(src), "--to", "csp", "--out", str(out)]) == 2
    assert "ValSet.mat" in capsys.readouterr().err
    assert (out / "ValSet.mat").read_bytes() == b"my notes" and (out / "TrainSet.mat").read_bytes() == before
    other = tmp_path / "mine"
    other.mkdir()
    (other / "TrainSet.mat").write_bytes(b"x")
    with pytest.raises(OutputError, match="not written by lanecast"):
        write_csp([src], other)


def test_vehicle_id_zero_is_refused_with_its_line(tmp_path: Path) -> None:
    src = _write_txt(tmp_path / "us-101.txt", _straight(1, range(1, 5), 2) + _straight(0, range(1, 5), 3))
    with pytest.raises(InputError, match="line 5") as err:
        write_csp([src], tmp_path / "out")
    assert "Vehicle_ID" in str(err.value)
    assert not (tmp_path / "out").exists()


def test_short_vehicles_keep_their_tracks_but_no_rows(tmp_path: Path) -> None:
    src = _write_txt(tmp_path / "i-80.txt", _straight(1, range(1, 41), 2) + _straight(2, range(1, 11), 2))
    write_csp([src], tmp_path / "out")
    train = loadmat(tmp_path / "out" / "TrainSet.mat")  # ids 1, 2: round(1.4) = 1 train, round(1.6) = 2 val
    val = loadmat(tmp_path / "out" / "ValSet.mat")
    assert train["traj"][:, 2].tolist() == list(range(31, 39))
    assert val["traj"].shape == (0, 47)
    assert val["tracks"][0, 1].shape == (3, 10) and val["tracks"][0, 0].shape == (0, 0)
    assert loadmat(tmp_path / "out" / "TestSet.mat")["tracks"].shape == (0, 0)


# ------------------------------------------------------------------------ against the research script


def _mats(directory: Path) -> dict[str, dict[str, np.ndarray]]:
    return {s: loadmat(directory / f"{s}.mat") for s in SETS}


@pytest.mark.skipif(not FIXTURE_FILES, reason="tests/data/csp is missing")
def test_fixture_equals_the_research_scripts_output_element_for_element(tmp_path: Path) -> None:
    write_csp(FIXTURE_FILES, tmp_path / "out")
    ours, theirs = _mats(tmp_path / "out"), _mats(FIXTURE)
    for name in SETS:
        a, b = ours[name]["traj"], theirs[name]["traj"]
        assert a.dtype == b.dtype == np.float32 and a.shape == b.shape, name
        assert np.array_equal(a, b), f"{name}: {np.argwhere(a != b)[:5].tolist()}"
        ca, cb = ours[name]["tracks"], theirs[name]["tracks"]
        assert ca.shape == cb.shape, name
        for index in np.ndindex(ca.shape):
            x, y = ca[index], cb[index]
            assert x.dtype == y.dtype and x.shape == y.shape and np.array_equal(x, y), (name, index)
    assert (theirs["TrainSet"]["traj"][:, 6] > 1).any() and (theirs["TrainSet"]["traj"][:, 7] == 2).any()


# ----------------------------------------------------------------------------------- the loader's view


def _history(tracks: np.ndarray, veh: int, t: float, ref: int, ds: int, t_h: int, d_s: int) -> np.ndarray:
    """A neighbour's (or the target's) history relative to the target at t, as ngsimDataset takes it."""
    if veh == 0 or tracks.shape[1] <= veh - 1:
        return np.empty((0, 2))
    ref_track, track = tracks[ds - 1, ref - 1].T, tracks[ds - 1, veh - 1].T
    ref_pos = ref_track[ref_track[:, 0] == t][0, 1:3]
    at = np.flatnonzero(track[:, 0] == t) if track.size else np.zeros(0, int)
    if at.size == 0:
        return np.empty((0, 2))
    (i,) = at  # one row at t, else the loader's .item() fails
    hist = track[max(0, i - t_h) : i + 1 : d_s, 1:3] - ref_pos
    return hist if len(hist) >= t_h // d_s + 1 else np.empty((0, 2))


def _iterate_like_ngsim_dataset(path: Path, t_h: int = 30, t_f: int = 50, d_s: int = 2) -> int:
    """Index every sample of one set as ngsimDataset does (13 × 3 grid); the samples seen."""
    mat = loadmat(path)
    traj, tracks = mat["traj"], mat["tracks"]
    for row in traj:
        ds, veh, t = int(row[0]), int(row[1]), row[2]
        hist = _history(tracks, veh, t, veh, ds, t_h, d_s)
        assert hist.shape == (t_h // d_s + 1, 2)  # the filter guarantees a full history
        track = tracks[ds - 1, veh - 1].T
        (i,) = np.flatnonzero(track[:, 0] == t)
        fut = track[i + d_s : min(len(track), i + t_f + 1) : d_s, 1:3] - track[i, 1:3]
        assert 1 <= len(fut) <= t_f // d_s
        assert len(row[8:]) == 13 * 3
        for nbr in row[8:]:
            _history(tracks, int(nbr), t, veh, ds, t_h, d_s)
        np.zeros(2)[int(row[7] - 1)] = 1  # lon_enc
        np.zeros(3)[int(row[6] - 1)] = 1  # lat_enc
    return len(traj)


@pytest.mark.skipif(not FIXTURE_FILES, reason="tests/data/csp is missing")
def test_a_loader_indexing_as_ngsim_dataset_reads_every_sample(tmp_path: Path) -> None:
    write_csp(FIXTURE_FILES, tmp_path / "out")
    seen = {s: _iterate_like_ngsim_dataset(tmp_path / "out" / f"{s}.mat") for s in SETS}
    assert all(seen.values()), seen


# ------------------------------------------------------------------------------------------- highD


def test_highd_directions_are_datasets_by_pips_convention(tmp_path: Path) -> None:
    rec = tmp_path / "sim"
    assert cli.main(["simulate", "--out", str(rec), "--minutes", "0.5", "--seed", "4"]) == 0
    record = write_csp([rec], tmp_path / "out", fmt="highd", resample=resample)
    assert [(d["id"], d["source"].rsplit("-", 1)[1]) for d in record["datasets"]] == [
        (1, "lower"),
        (2, "upper"),
    ]
    datasets = {ds.ident: ds for _, _, ds in inputs.highd_datasets([rec], resample)}
    for ds in datasets.values():
        assert np.diff(ds.frame[ds.vehicle == ds.vehicle[0]]).tolist() == [1.0] * (
            int((ds.vehicle == ds.vehicle[0]).sum()) - 1
        )
        lanes = np.unique(ds.lane)
        assert lanes[0] == 1 and (np.diff(lanes) == 1).all()
        # lane 1 is the leftmost: the smallest Local_X (positive to the right)
        assert ds.x[ds.lane == 1].mean() < ds.x[ds.lane == lanes[-1]].mean()
        # feet along the direction of travel: ~ speed in ft per 0.1 s frame
        one = ds.vehicle == ds.vehicle[0]
        speed_ft_s = np.diff(ds.y[one]).mean() * 10
        assert 30 < speed_ft_s < 200
    seen = {s: _iterate_like_ngsim_dataset(tmp_path / "out" / f"{s}.mat") for s in SETS}
    assert seen["TrainSet"] > 0


def test_dataset_parts_keep_dataset_order(tmp_path: Path) -> None:
    one = Dataset(2, "b", *(np.zeros(0, np.float32) for _ in range(5)))
    parts = sets.dataset_parts(one)
    assert [p.rows() for p in parts] == [0, 0, 0]
    assert sets.tracks_cell([]).shape == (0, 0)


def test_fixture_copy_reads_the_same(tmp_path: Path) -> None:
    """The dataset ids come from the names, not the order given."""
    if not FIXTURE_FILES:
        pytest.skip("tests/data/csp is missing")
    for f in FIXTURE_FILES:
        shutil.copy(f, tmp_path / f.name)
    reversed_order = sorted(tmp_path.glob("*.txt"), reverse=True)
    ids = [d["id"] for d in write_csp(reversed_order, tmp_path / "out")["datasets"]]
    names = [Path(d["file"]).name for d in write_csp(reversed_order, tmp_path / "out")["datasets"]]
    assert ids == [1, 2, 3, 4, 5, 6] and names[:3] == sorted(n for n in names if n.startswith("us"))


def test_workers_give_the_same_sets(tmp_path: Path) -> None:
    a = _write_txt(
        tmp_path / "us-101.txt", _straight(1, range(1, 45), 2) + _straight(2, range(1, 45), 3, 130.0)
    )
    b = _write_txt(tmp_path / "i-80.txt", _straight(5, range(3, 50), 1) + _straight(3, range(1, 40), 2, 90.0))
    one = write_csp([a, b], tmp_path / "one")
    two = write_csp([b, a], tmp_path / "two", workers=2)
    assert one["datasets"] == two["datasets"]
    for name in SETS:
        x, y = loadmat(tmp_path / "one" / f"{name}.mat"), loadmat(tmp_path / "two" / f"{name}.mat")
        assert np.array_equal(x["traj"], y["traj"]) and x["tracks"].shape == y["tracks"].shape
