"""The SUMO highway simulator: highD files that the highD adapter reads back, deterministic per seed."""

from __future__ import annotations

import filecmp
import os
import stat
import subprocess
import sys
from datetime import datetime
from pathlib import Path
from zoneinfo import ZoneInfo

import numpy as np
import pyarrow as pa
import pyarrow.csv as pacsv
import pytest

from lanecast.io_adapters.contracts import track_table
from lanecast.io_adapters.datasets.highd import reader as highd
from lanecast.io_adapters.errors import InputError
from lanecast.io_adapters.sim import recording, sumo_run, to_highd
from lanecast.workflows import cli

FILES = ("01_tracks.csv", "01_tracksMeta.csv", "01_recordingMeta.csv")


def _csv(path: Path) -> pa.Table:
    return pacsv.read_csv(path)


@pytest.fixture(scope="module")
def table(sim_recording_dir: Path) -> pa.Table:
    return highd.read([sim_recording_dir])


def test_files_have_every_highd_column_in_order(sim_recording_dir: Path) -> None:
    headers = {name: (sim_recording_dir / name).open().readline().strip().split(",") for name in FILES}
    assert headers["01_tracks.csv"] == to_highd.TRACKS_COLUMNS
    assert headers["01_tracksMeta.csv"] == to_highd.TRACKS_META_COLUMNS
    assert headers["01_recordingMeta.csv"] == to_highd.RECORDING_META_COLUMNS
    assert "frontSightDistance" in headers["01_tracks.csv"] and "minTTC" in headers["01_tracksMeta.csv"]


def test_frames_ids_and_meta_are_consistent(sim_recording_dir: Path) -> None:
    tracks = _csv(sim_recording_dir / "01_tracks.csv")
    meta = _csv(sim_recording_dir / "01_tracksMeta.csv")
    rec = _csv(sim_recording_dir / "01_recordingMeta.csv")
    frame = tracks.column("frame").to_numpy()
    ids = tracks.column("id").to_numpy()
    # 2 simulated minutes at 25 Hz: frames 1 … 3000.
    assert frame.min() == 1 and frame.max() == 3000
    assert rec.column("frameRate")[0].as_py() == 25
    assert rec.column("duration")[0].as_py() == 120
    # Ids 1 … V consecutive, one meta row each; each track contiguous in frames.
    assert np.array_equal(np.unique(ids), np.arange(1, meta.num_rows + 1))
    assert np.array_equal(meta.column("id").to_numpy(), np.arange(1, meta.num_rows + 1))
    same = ids[1:] == ids[:-1]
    assert np.all(frame[1:][same] == frame[:-1][same] + 1)
    counts = np.bincount(ids)[1:]
    assert np.array_equal(meta.column("numFrames").to_numpy(), counts)
    first = meta.column("initialFrame").to_numpy()
    assert np.array_equal(meta.column("finalFrame").to_numpy(), first + counts - 1)
    classes = meta.column("class").to_pylist()
    assert set(classes) == {"Car", "Truck"}
    assert rec.column("numVehicles")[0].as_py() == meta.num_rows
    assert rec.column("numCars")[0].as_py() == classes.count("Car")
    assert rec.column("numTrucks")[0].as_py() == classes.count("Truck")
    # Lane changes counted per track agree with the laneId column.
    lane = tracks.column("laneId").to_numpy()
    assert meta.column("numLaneChanges").to_numpy().sum() == int(np.sum(same & (lane[1:] != lane[:-1])))


def test_read_back_by_the_highd_adapter(table: pa.Table, sim_recording_dir: Path) -> None:
    track_table.validate(table)
    meta = track_table.read_meta(table)
    assert set(meta.recordings) == {"highd-01-upper", "highd-01-lower"}
    names = np.asarray(table.column("recording").cast(pa.string()).to_pylist())
    tracks_meta = _csv(sim_recording_dir / "01_tracksMeta.csv")
    direction = tracks_meta.column("drivingDirection").to_numpy()
    n_upper = len(np.unique(table.column("track_id").to_numpy()[names == "highd-01-upper"]))
    n_lower = len(np.unique(table.column("track_id").to_numpy()[names == "highd-01-lower"]))
    assert n_upper == int(np.sum(direction == 1)) > 30
    assert n_lower == int(np.sum(direction == 2)) > 30
    # Class counts survive the read (per vehicle).
    starts = track_table.track_boundaries(table)[:-1]
    classes = table.column("object_class").cast(pa.string()).to_numpy(zero_copy_only=False)[starts]
    meta_classes = tracks_meta.column("class").to_pylist()
    assert int(np.sum(classes == "car")) == meta_classes.count("Car")
    assert int(np.sum(classes == "truck")) == meta_classes.count("Truck") > 0
    # Everyone drives forward along the road frame, at highway speeds.
    vx = table.column("vx").to_numpy()
    assert vx.min() > 5.0 and 20.0 < np.median(vx) < 40.0


def test_lane_changes_with_continuous_lateral_motion(table: pa.Table) -> None:
    changes = track_table.lane_change_rows(table)
    assert changes.size >= 10
    y = table.column("y").to_numpy()
    starts = track_table.track_boundaries(table)
    same = np.ones(table.num_rows, dtype=bool)
    same[starts[:-1]] = False
    jumps = np.abs(np.diff(y))[same[1:]]
    assert jumps.max() < 0.5  # no lateral jump over 0.5 m between consecutive frames
    # A lane change moves the vehicle by one lane width (3.75 m) within ±2 s of the lane-id change
    # (SUMO's lane change takes 3 s here), for those changes with 2 s of track on both sides.
    track = np.searchsorted(starts, changes, side="right") - 1
    inside = (starts[track] <= changes - 50) & (starts[track + 1] > changes + 50)
    lateral = np.abs(y[np.minimum(changes + 50, y.size - 1)] - y[np.maximum(changes - 50, 0)])
    assert inside.any()
    assert np.all(np.abs(lateral[inside] - 3.75) < 0.1)


def test_lane_ids_match_positions_and_markings(sim_recording_dir: Path) -> None:
    tracks = _csv(sim_recording_dir / "01_tracks.csv")
    rec = _csv(sim_recording_dir / "01_recordingMeta.csv")
    upper = [float(v) for v in rec.column("upperLaneMarkings")[0].as_py().split(";")]
    lower = [float(v) for v in rec.column("lowerLaneMarkings")[0].as_py().split(";")]
    assert len(upper) == len(lower) == 4
    assert np.allclose(np.diff(upper), 3.75, atol=0.011) and np.allclose(np.diff(lower), 3.75, atol=0.011)
    assert upper[0] == 8.0 and lower[0] - upper[-1] == pytest.approx(4.0, abs=0.011)  # median 4 m
    centre = tracks.column("y").to_numpy() + tracks.column("height").to_numpy() / 2
    lane = tracks.column("laneId").to_numpy()
    assert set(np.unique(lane)) == {2, 3, 4, 6, 7, 8}
    bounds = {2: upper[0:2], 3: upper[1:3], 4: upper[2:4], 6: lower[0:2], 7: lower[1:3], 8: lower[2:4]}
    lo = np.array([bounds[k][0] for k in lane])
    hi = np.array([bounds[k][1] for k in lane])
    assert np.all((centre >= lo - 0.1) & (centre <= hi + 0.1))


def test_highd_lane_numbering_by_hand() -> None:
    idx = np.array([0, 1, 2, 0, 1, 2])
    direction = np.array([1, 1, 1, 2, 2, 2])
    assert to_highd.highd_lane_id(idx, direction, 3).tolist() == [2, 3, 4, 8, 7, 6]
    assert to_highd.highd_lane_id(idx[:2], direction[:2], 2).tolist() == [2, 3]
    assert to_highd.highd_lane_id(np.array([0, 1]), np.array([2, 2]), 2).tolist() == [6, 5]


def test_velocity_matches_motion_and_travel_direction(sim_recording_dir: Path) -> None:
    tracks = _csv(sim_recording_dir / "01_tracks.csv")
    meta = _csv(sim_recording_dir / "01_tracksMeta.csv")
    ids = tracks.column("id").to_numpy()
    x = tracks.column("x").to_numpy()
    vx = tracks.column("xVelocity").to_numpy()
    direction = meta.column("drivingDirection").to_numpy()[ids - 1]
    assert np.all(vx[direction == 1] < 0) and np.all(vx[direction == 2] > 0)  # upper towards −x
    same = ids[1:] == ids[:-1]
    moved = np.diff(x)[same] / 0.04
    mean_v = (vx[1:] + vx[:-1])[same] / 2
    assert np.percentile(np.abs(moved - mean_v), 99) < 0.6  # positions rounded to 1 cm → ±0.5 m/s


def test_neighbours_from_sumo_agree_with_lanes_and_positions(sim_recording_dir: Path) -> None:
    """precedingId is ahead in the same lane; alongside ids overlap longitudinally in the next lane."""
    tracks = _csv(sim_recording_dir / "01_tracks.csv")
    meta = _csv(sim_recording_dir / "01_tracksMeta.csv")
    ids = tracks.column("id").to_numpy()
    frame = tracks.column("frame").to_numpy()
    lane = tracks.column("laneId").to_numpy()
    direction = meta.column("drivingDirection").to_numpy()[ids - 1]
    sign = np.where(direction == 2, 1.0, -1.0)
    x, length = tracks.column("x").to_numpy(), tracks.column("width").to_numpy()
    back = np.where(sign > 0, x, -(x + length))  # along the direction of travel
    front = back + length
    row_of = {(int(i), int(f)): r for r, (i, f) in enumerate(zip(ids, frame, strict=True))}

    def rows(column: str) -> tuple[np.ndarray, np.ndarray]:
        other = tracks.column(column).to_numpy()
        ego = np.flatnonzero(other > 0)
        return ego, np.array([row_of[(int(other[r]), int(frame[r]))] for r in ego])

    ego, pre = rows("precedingId")
    assert ego.size > 1000
    assert np.mean(lane[pre] == lane[ego]) > 0.99
    assert np.all(back[pre] >= front[ego] - 0.05)
    # left in the direction of travel: lower carriageway (+x) → smaller laneId, upper → larger.
    ego, along = rows("leftAlongsideId")
    assert ego.size > 20
    assert np.mean(lane[along] == lane[ego] - sign[ego].astype(int)) > 0.95
    assert np.all((front[along] > back[ego] - 0.02) & (back[along] < front[ego] + 0.02))  # 1 cm rounding
    ego, fol = rows("rightFollowingId")
    assert np.mean(lane[fol] == lane[ego] + sign[ego].astype(int)) > 0.95
    assert np.all(front[fol] <= back[ego] + 0.05)
    # dhw is the gap to the preceding vehicle (m), thw = dhw / speed.
    ego, pre = rows("precedingId")
    dhw = tracks.column("dhw").to_numpy()
    assert np.allclose(dhw[ego], back[pre] - front[ego], atol=0.03)
    thw = tracks.column("thw").to_numpy()
    speed = np.abs(tracks.column("xVelocity").to_numpy())
    assert np.allclose(thw[ego], dhw[ego] / speed[ego], atol=0.011)


def test_subscription_constants_are_tracis() -> None:
    from traci import constants as tc

    assert (sumo_run.VAR_LEADER, sumo_run.VAR_FOLLOWER) == (tc.VAR_LEADER, tc.VAR_FOLLOWER)


@pytest.mark.slow
def test_same_seed_same_bytes_through_the_command(tmp_path: Path) -> None:
    """One run through the API, one through `lanecast simulate` with SUMO's raw motion: identical files;
    another seed differs."""
    args = {
        "minutes": 0.2,
        "lanes_per_direction": 2,
        "density": "high",
        "section_length_m": 200.0,
        "approach_length_m": 200.0,
    }
    start = datetime(2026, 12, 5, 8, 30, tzinfo=ZoneInfo("Europe/Berlin"))
    a = recording.simulate(tmp_path / "a", seed=3, show_progress=False, start=start, **args)  # type: ignore[arg-type]
    c = recording.simulate(tmp_path / "c", seed=4, show_progress=False, start=start, **args)  # type: ignore[arg-type]
    b = tmp_path / "b"
    status = cli.main(
        ["simulate", "--out", str(b), "--start", "2026-12-05T08:30+01:00",
         "--minutes", "0.2", "--seed", "3", "--lanes-per-direction", "2",
         "--density", "high", "--section-length", "200", "--approach-length", "200",
         "--lane-change-duration", "3", "--lateral-smoothing", "0", "--weave", "0", "--drivers", "uniform"]
    )  # fmt: skip
    assert status == 0
    for name in FILES:
        assert filecmp.cmp(a / name, b / name, shallow=False)
    assert not filecmp.cmp(a / "01_tracks.csv", c / "01_tracks.csv", shallow=False)
    lanes = np.unique(_csv(a / "01_tracks.csv").column("laneId").to_numpy())
    assert set(lanes) <= {2, 3, 5, 6}  # 2 lanes per direction: upper 2, 3; lower 5, 6
    assert sorted(p.name for p in a.iterdir()) == sorted(FILES)  # no temporary left behind
    header, row = (a / "01_recordingMeta.csv").read_text().splitlines()
    fields = dict(zip(header.split(","), row.split(","), strict=True))
    assert [fields[k] for k in ("month", "weekDay", "startTime")] == ["12.2026", "Sat", "08:30"]


def test_a_log_of_a_simulated_recording_starts_when_it_was_simulated(tmp_path: Path) -> None:
    """Logs made from a simulation begin at the date and time of the run (highD's recordingMeta
    fields), not on 1 January 1970; the table read back from the log is the table written."""
    from conftest import assert_same_table
    from mcap.reader import make_reader

    from lanecast.io_adapters.formats import registry

    before = datetime.now().astimezone().replace(second=0, microsecond=0)
    assert cli.main(["simulate", "--out", str(tmp_path / "sim"), "--minutes", "0.2", "--seed", "1",
                     "--density", "low", "--section-length", "200", "--approach-length", "200"]) == 0  # fmt: skip
    table = registry.read_any([tmp_path / "sim"])
    log = registry.write_any(table, tmp_path / "sim.mcap", "mcap")
    with log.open("rb") as fh:
        first = next(iter(make_reader(fh).iter_messages()))[2].log_time
    after = datetime.now().astimezone()
    berlin = ZoneInfo("Europe/Berlin")
    first_day = datetime.fromtimestamp(first / 1e9, berlin)
    # highD gives month, weekday and time of day: the first such weekday of the month at that time
    starts = {
        (t.year, t.month, t.weekday(), t.hour, t.minute)
        for t in (before.astimezone(berlin), after.astimezone(berlin))
    }
    assert (first_day.year, first_day.month, first_day.weekday(), first_day.hour, first_day.minute) in starts
    assert first_day.day <= 7 and first_day.second == 0
    assert_same_table(table, registry.read_any([log]))


def test_the_command_smooths_lane_changes_by_default(tmp_path: Path) -> None:
    """`lanecast simulate` without a scenario drives as the scenarios do (scenarios.DRIVING): lane
    changes are S-curves, not SUMO's constant sideways speed with lateral-acceleration spikes at
    their ends, and drivers weave inside their lane."""
    common = ["--minutes", "1", "--seed", "2", "--density", "high", "--section-length", "400",
              "--approach-length", "300"]  # fmt: skip
    assert cli.main(["simulate", "--out", str(tmp_path / "smooth"), *common]) == 0
    raw = ["--lateral-smoothing", "0", "--weave", "0", "--drivers", "uniform"]
    assert cli.main(["simulate", "--out", str(tmp_path / "raw"), *common, *raw]) == 0
    tables = {k: _csv(tmp_path / k / "01_tracks.csv") for k in ("smooth", "raw")}
    lat_acc = {k: np.abs(t.column("yAcceleration").to_numpy()) for k, t in tables.items()}
    lat_vel = {k: np.abs(t.column("yVelocity").to_numpy()) for k, t in tables.items()}
    assert lat_acc["raw"].max() > 10.0  # SUMO's raw lane changes: spikes of 15-30 m/s^2
    assert lat_acc["smooth"].max() < 2.0
    assert np.median(lat_vel["raw"]) == 0.0 < np.median(lat_vel["smooth"])  # the weave
    for t in tables.values():  # both have lane changes (lane id changes within a track)
        same_track = np.diff(t.column("id").to_numpy()) == 0
        assert np.count_nonzero(same_track & (np.diff(t.column("laneId").to_numpy()) != 0)) > 0


def test_existing_directory_keeps_other_files_and_a_recording_is_never_overwritten(tmp_path: Path) -> None:
    out = tmp_path / "rec"
    out.mkdir()
    (out / "notes.txt").write_text("mine")
    args = {"minutes": 0.05, "seed": 1, "section_length_m": 100.0, "approach_length_m": 150.0}
    recording.simulate(out, show_progress=False, **args)  # type: ignore[arg-type]
    assert (out / "notes.txt").read_text() == "mine"
    assert all((out / name).is_file() for name in FILES)
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]
    before = {name: (out / name).read_bytes() for name in FILES}
    with pytest.raises(InputError, match=r"01_tracks\.csv: already exists"):
        recording.simulate(out, show_progress=False, **{**args, "seed": 2})  # type: ignore[arg-type]
    assert {name: (out / name).read_bytes() for name in FILES} == before
    assert cli.main(["simulate", "--out", str(out), "--minutes", "0.05", "--seed", "2"]) == 2


def test_a_new_output_directory_gets_ordinary_permissions(tmp_path: Path) -> None:
    old = os.umask(0o022)
    try:
        out = recording.simulate(
            tmp_path / "new" / "rec", minutes=0.05, seed=1, section_length_m=100.0,
            approach_length_m=150.0, show_progress=False,
        )  # fmt: skip
    finally:
        os.umask(old)
    assert stat.S_IMODE(out.stat().st_mode) == 0o755
    assert {stat.S_IMODE((out / name).stat().st_mode) for name in FILES} == {0o644}


@pytest.mark.parametrize(
    ("kwargs", "column"),
    [
        ({"density": "extreme"}, "--density 'extreme': invalid"),
        ({"minutes": 0.0}, "--minutes 0.0: invalid"),
        ({"truck_share": 1.5}, r"--truck-share 1\.5: invalid"),
        ({"lanes_per_direction": 0}, "--lanes-per-direction 0: invalid"),
        ({"seed": -1}, "--seed -1: invalid"),
        ({"recording_id": 100}, "recording id"),
        # SUMO's clock overflowed: "libsumo.TraCIException" / "OverflowError: cannot convert float infinity"
        (
            {"minutes": 1e30},
            r"--minutes 1e\+30: invalid \(expected a number of minutes above 0, at most 120\)",
        ),
        ({"minutes": float("inf")}, "--minutes inf: invalid"),
        ({"section_length_m": 1e30}, r"--section-length 1e\+30: invalid"),
        ({"approach_length_m": 1e30}, r"--approach-length 1e\+30: invalid"),
        ({"lane_change_duration_s": 1e30}, r"--lane-change-duration 1e\+30: invalid"),
    ],
)
def test_bad_parameters_raise_input_error(tmp_path: Path, kwargs: dict[str, object], column: str) -> None:
    args: dict[str, object] = {"minutes": 1.0, "seed": 1, **kwargs}
    with pytest.raises(InputError, match=column):
        recording.simulate(tmp_path / "x", show_progress=False, **args)  # type: ignore[arg-type]
    assert not (tmp_path / "x").exists()


@pytest.mark.slow
def test_libsumo_imported_before_pyarrow_works(tmp_path: Path) -> None:
    """libsumo bundles libarrow 23 and warns about pyarrow 26; with libsumo loaded first, a simulation,
    the highD read and a Parquet write still work in one process (a fresh interpreter)."""
    script = (
        "import libsumo, sys\n"
        "import pyarrow.parquet as pq\n"
        "from pathlib import Path\n"
        "from lanecast.io_adapters.datasets.highd import reader as highd\n"
        "from lanecast.io_adapters.sim import recording\n"
        "out = recording.simulate(Path(sys.argv[1]), minutes=0.05, seed=1, section_length_m=100.0,\n"
        "                            approach_length_m=150.0, show_progress=False)\n"
        "table = highd.read([out])\n"
        "pq.write_table(table, Path(sys.argv[1]) / 'x.parquet')\n"
        "print('rows', pq.read_table(Path(sys.argv[1]) / 'x.parquet').num_rows == table.num_rows > 0)\n"
    )
    done = subprocess.run([sys.executable, "-c", script, str(tmp_path / "o")], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    assert "rows True" in done.stdout


def test_output_path_that_is_a_file_is_refused(tmp_path: Path) -> None:
    target = tmp_path / "file"
    target.write_text("keep me")
    with pytest.raises(InputError, match="not a directory"):
        recording.simulate(target, minutes=0.1, seed=1, show_progress=False)
    assert target.read_text() == "keep me"


def test_help_has_an_example(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit):
        cli.main(["simulate", "--help"])
    out = capsys.readouterr().out
    assert "lanecast simulate --out sim/ --minutes 5 --seed 1" in out
