"""Realism of simulated training data: drivers' in-lane weave, and the measured copy of a recording
(tracker-like position errors, speeds and accelerations re-derived from them)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyarrow as pa
import pytest

from lanecast.io_adapters.datasets.highd import reader as highd
from lanecast.io_adapters.sim import recording, sumo_highway, to_highd
from lanecast.io_adapters.sim.tracking_errors import (
    NGSIM_MAX_ACC,
    add_tracking_errors,
    central_difference,
    forward_difference,
    held_while_standing,
    interpolate_between,
    write_measured_copy,
)


def test_in_lane_weave_has_its_std_is_smooth_and_deterministic() -> None:
    """Over 20 vehicles × 10 min the weave's std is the stated one, its lateral acceleration stays
    below a lane change's peak (0.6 m/s²) and within its bound, it depends on (vehicle, time) only,
    and on the seed."""
    rate = 10.0
    vehicle = np.repeat(np.arange(20), 6000)
    t = np.tile(np.arange(6000) / rate, 20)
    w = to_highd.lateral_wander(vehicle, t, 0.15, seed=3)
    assert w.std() == pytest.approx(0.15, rel=0.15)
    acc = np.diff(w.reshape(20, -1), 2, axis=1) * rate**2
    bound = 3 * 0.15 * np.sqrt(2 / 3) * (2 * np.pi / 6.0) ** 2
    assert np.abs(acc).max() < bound < 0.6
    assert np.percentile(np.abs(acc), 50) < 0.1
    shuffled = np.random.default_rng(0).permutation(vehicle.size)
    np.testing.assert_array_equal(
        to_highd.lateral_wander(vehicle[shuffled], t[shuffled], 0.15, 3), w[shuffled]
    )
    assert not np.allclose(to_highd.lateral_wander(vehicle, t, 0.15, seed=4), w)
    assert (
        sumo_highway.HighwayConfig(minutes=1, seed=1).lateral_wander_m == 0.0
    )  # plain simulate: exact centre


def _tracks(n: int = 2500, rate: float = 25.0) -> pa.Table:
    """Two highD tracks: one at a constant 30 m/s, one braking at 1 m/s² from 20 m/s."""
    t = np.arange(n) / rate
    x = np.concatenate([10 + 30 * t, 5 + 20 * t - 0.5 * t**2])
    vx = np.concatenate([np.full(n, 30.0), 20 - t])
    ax = np.concatenate([np.zeros(n), np.full(n, -1.0)])
    return pa.table(
        {
            "frame": np.tile(np.arange(1, n + 1), 2),
            "id": np.repeat([1, 2], n),
            "x": x,
            "y": np.full(2 * n, 12.0),
            "xVelocity": vx,
            "yVelocity": np.zeros(2 * n),
            "xAcceleration": ax,
            "yAcceleration": np.zeros(2 * n),
            "laneId": np.repeat([2, 3], n).astype(np.int64),
        }
    )


def test_measured_copy_errors_have_the_level_and_derivatives_follow_positions() -> None:
    tracks = _tracks()
    clean = add_tracking_errors(tracks, 25.0, 0.0, seed=1)
    # level 0: positions kept, derivatives re-derived exactly (a line and a parabola)
    np.testing.assert_allclose(clean.column("x").to_numpy(), np.round(tracks.column("x").to_numpy(), 2))
    inner = np.r_[10:2490, 2510:4990]
    np.testing.assert_allclose(
        clean.column("xVelocity").to_numpy()[inner], tracks.column("xVelocity").to_numpy()[inner], atol=0.01
    )
    np.testing.assert_allclose(
        clean.column("xAcceleration").to_numpy()[inner],
        tracks.column("xAcceleration").to_numpy()[inner],
        atol=0.01,
    )

    noisy = add_tracking_errors(tracks, 25.0, 0.3, seed=1)
    err_x = noisy.column("x").to_numpy() - tracks.column("x").to_numpy()
    err_y = noisy.column("y").to_numpy() - tracks.column("y").to_numpy()
    assert np.hypot(0.3, 0.3 / 4) * 0.7 < err_x.std() < np.hypot(0.3, 0.3 / 4) * 1.3
    assert 0.1 * 0.7 * np.sqrt(2) < err_y.std() < 0.1 * 1.3 * np.sqrt(2)
    # velocities are the central difference of the erroneous positions over ±0.2 s, per track
    x = noisy.column("x").to_numpy()
    first = np.repeat([0, 2500], 2500)
    last = np.repeat([2499, 4999], 2500)
    np.testing.assert_allclose(
        noisy.column("xVelocity").to_numpy(),
        np.round(central_difference(x, first, last, 5, 0.04), 2),
        atol=0.04,
    )
    # accelerations are much noisier than positions (as real datasets' are), lanes kept
    acc_err = (
        noisy.column("xAcceleration").to_numpy()[inner] - tracks.column("xAcceleration").to_numpy()[inner]
    )
    assert acc_err.std() > 1.0
    assert noisy.column("laneId").equals(tracks.column("laneId"))
    assert not np.allclose(add_tracking_errors(tracks, 25.0, 0.3, seed=2).column("x").to_numpy(), x)
    with pytest.raises(ValueError, match="level_m"):
        add_tracking_errors(tracks, 25.0, -0.1, seed=1)


def test_measured_copy_of_a_simulated_recording_reads_back(tmp_path: Path) -> None:
    """SUMO → highD files → measured copy as another recording id: the highD reader reads both, same
    vehicles and rows, positions moved by about the level, speeds still near the true ones."""
    sim = recording.simulate(tmp_path / "sim", minutes=0.5, seed=3, show_progress=False)
    out = write_measured_copy(sim, 1, tmp_path / "measured", 21, 0.2, seed=5)
    assert sorted(p.name for p in out.iterdir()) == [
        "21_recordingMeta.csv",
        "21_tracks.csv",
        "21_tracksMeta.csv",
    ]
    a, b = highd.read([sim]), highd.read([out])
    assert b.num_rows == a.num_rows
    assert set(b.column("recording").to_pylist()) == {
        r.replace("-01-", "-21-") for r in set(a.column("recording").to_pylist())
    }
    dx = b.column("x").to_numpy() - a.column("x").to_numpy()
    assert 0.1 < dx.std() < 0.35
    dv = b.column("vx").to_numpy() - a.column("vx").to_numpy()
    assert 0.1 < np.median(np.abs(dv)) < 2.0


def _stopping_track(rate: float = 25.0) -> pa.Table:
    """One highD track braking at 2 m/s² from 10 m/s to a stop at 5 s, then standing for 15 s."""
    t = np.arange(int(20 * rate)) / rate
    moving = t < 5.0
    x = np.where(moving, 10 * t - t**2, 25.0)
    vx = np.where(moving, 10 - 2 * t, 0.0)
    n = t.size
    return pa.table(
        {
            "frame": np.arange(1, n + 1),
            "id": np.ones(n, np.int64),
            "x": x,
            "y": np.full(n, 12.0),
            "xVelocity": vx,
            "yVelocity": np.zeros(n),
            "xAcceleration": np.where(moving, -2.0, 0.0),
            "yAcceleration": np.zeros(n),
            "laneId": np.full(n, 2, np.int64),
        }
    )


def test_standing_vehicles_are_held_still_unless_asked_to_jitter() -> None:
    """Once stopped, the measured box keeps the error it had when the vehicle stopped: positions
    constant, speed and acceleration exactly 0 (as NGSIM reports standing cars); moving rows keep
    their errors; ``hold_standing=False`` makes the standing box jitter like a moving one."""
    tracks = _stopping_track()
    standing_rows = np.r_[140:500]  # > 0.2 s (the difference span) after the stop at row 125
    held = add_tracking_errors(tracks, 25.0, 0.3, seed=1)
    x = held.column("x").to_numpy()
    assert np.unique(x[standing_rows]).size == 1
    assert np.abs(x[standing_rows][0] - 25.0) < 1.5  # the error it had when it stopped
    assert not np.any(held.column("xVelocity").to_numpy()[standing_rows])
    assert not np.any(held.column("xAcceleration").to_numpy()[standing_rows])
    assert np.unique(held.column("y").to_numpy()[standing_rows]).size == 1
    assert (x[:100] - tracks.column("x").to_numpy()[:100]).std() > 0.1  # moving: errors as before
    jitter = add_tracking_errors(tracks, 25.0, 0.3, seed=1, hold_standing=False)
    assert np.abs(jitter.column("xVelocity").to_numpy()[standing_rows]).mean() > 0.1
    np.testing.assert_array_equal(jitter.column("x").to_numpy()[:120], x[:120])


def test_held_while_standing_takes_the_last_moving_value_per_track() -> None:
    error = np.array([1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0])
    standing = np.array([True, False, True, True, False, True, True])
    first = np.array([0, 0, 0, 0, 4, 4, 4])  # two tracks: rows 0-3 and 4-6
    np.testing.assert_array_equal(
        held_while_standing(error, standing, first), [1.0, 2.0, 2.0, 2.0, 5.0, 5.0, 5.0]
    )
    first2 = np.array([0, 0, 0, 0, 4, 4, 4])
    standing2 = np.array([False, False, False, False, True, True, False])  # track 2 starts standing
    np.testing.assert_array_equal(
        held_while_standing(error, standing2, first2), [1.0, 2.0, 3.0, 4.0, 5.0, 5.0, 7.0]
    )


def test_a_standing_vehicle_does_not_weave(tmp_path: Path) -> None:
    """The weave advances with distance: in a signal queue, a vehicle standing for seconds keeps
    its lateral position (real cars do not drift sideways at a red light)."""
    from lanecast.io_adapters.sim.scenarios import scenario_config

    cfg = scenario_config("signal", minutes=2, seed=4)
    assert cfg.lateral_wander_m > 0
    sim = recording.simulate(tmp_path / "sim", minutes=2, seed=4, config=cfg, show_progress=False)
    t = highd.read([sim])
    standing = np.abs(t.column("vx").to_numpy()) < 0.01  # standing still along the road
    assert standing.mean() > 0.05  # the red phase makes queues
    track = t.column("track_id").to_numpy()
    starts = np.r_[True, (standing[1:] != standing[:-1]) | (track[1:] != track[:-1])]
    run = np.cumsum(starts)[standing]  # one id per stretch of standing rows of one track
    y = t.column("y").to_numpy()[standing]
    low, high = np.full(run.max() + 1, np.inf), np.full(run.max() + 1, -np.inf)
    np.minimum.at(low, run, y)
    np.maximum.at(high, run, y)
    spread = (high - low)[np.isfinite(low)]
    assert spread.max() < 0.011  # centimetre rounding of the files: no weave while standing


def test_interpolate_between_and_forward_difference_stay_within_each_track() -> None:
    values = np.array([0.0, 5.0, 5.0, 3.0, 10.0, 99.0, 12.0])
    measured = np.array([True, False, False, True, True, False, True])  # tracks: rows 0-3, 4-6
    np.testing.assert_allclose(interpolate_between(values, measured), [0, 1, 2, 3, 10, 11, 12])
    first, last = np.repeat([0, 4], [4, 3]), np.repeat([3, 6], [4, 3])
    v = np.array([0.0, 1.0, 2.0, 4.0, 10.0, 11.0, 13.0])
    # forward differences; a track's last row takes the backward one, never the next track's row
    np.testing.assert_allclose(forward_difference(v, first, last, 0.1), [10, 10, 20, 20, 10, 20, 20])


def test_an_interpolating_tracker_holds_speeds_and_saturates_accelerations() -> None:
    """NGSIM-like derivatives: speeds constant between measured frames (held for several frames),
    accelerations 0 there and clipped to +-11.2 ft/s^2 where the speed jumps; positions still near
    the truth and the speeds right on average."""
    tracks = _tracks()
    out = add_tracking_errors(tracks, 25.0, 0.1, seed=4, interpolating=True)
    vx = out.column("xVelocity").to_numpy()
    ax = out.column("xAcceleration").to_numpy()
    held = np.r_[False, (vx[1:] == vx[:-1])]
    assert 0.2 < held.mean() < 0.95  # held for frames, then jumping
    assert np.all(np.abs(ax) <= NGSIM_MAX_ACC + 1e-3)
    assert np.mean(np.abs(np.abs(ax) - NGSIM_MAX_ACC) < 1e-3) > 0.01  # saturates, as NGSIM's do
    assert np.mean(ax == 0) > 0.2
    err = out.column("x").to_numpy() - tracks.column("x").to_numpy()
    assert 0.05 < err.std() < 0.2
    np.testing.assert_allclose(vx[:2500].mean(), 30.0, atol=0.05)
    central = add_tracking_errors(tracks, 25.0, 0.1, seed=4)
    assert (
        np.mean(central.column("xVelocity").to_numpy()[1:] == central.column("xVelocity").to_numpy()[:-1])
        < 0.1
    )
