"""Named traffic scenarios: each builds and runs in SUMO, and its traffic lies in its stated ranges;
lane changes move sideways smoothly; the traffic statistics of a table are computed correctly."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from conftest import TESTS

from lanecast.io_adapters.contracts.track_table import RecordingMeta, TableMeta, build_table
from lanecast.io_adapters.datasets.highd import reader as highd
from lanecast.io_adapters.errors import InputError
from lanecast.io_adapters.formats import registry
from lanecast.io_adapters.sim import recording, scenarios, to_highd
from lanecast.pipeline.traffic import speed_dips, traffic_statistics
from lanecast.workflows import cli


def test_smoothing_turns_a_lateral_ramp_into_an_s_curve() -> None:
    """SUMO's constant-speed sideways motion (3.75 m in 4 s at 10 Hz) smoothed by a 3 s triangle:
    same start and end, monotonic, peak lateral acceleration about 0.6 m/s² (raw: a 9 m/s² step);
    a constant track is unchanged; two tracks do not bleed into each other."""
    rate = 10.0
    t = np.arange(200) / rate
    ramp = np.clip((t - 8.0) / 4.0, 0.0, 1.0) * 3.75
    flat = np.full(200, -2.0)
    y = np.concatenate([ramp, flat])
    new_track = np.zeros(400, dtype=bool)
    new_track[[0, 200]] = True
    smooth = to_highd.smooth_lateral(y, new_track, 3.0, rate)
    np.testing.assert_allclose(smooth[200:], -2.0)
    s = smooth[:200]
    assert s[0] == pytest.approx(0.0) and s[-1] == pytest.approx(3.75)
    assert np.all(np.diff(s) >= -1e-12)
    acc = np.diff(s, 2) * rate**2
    raw_acc = np.diff(ramp, 2) * rate**2
    assert raw_acc.max() > 9.0
    assert 0.4 < np.abs(acc).max() < 0.8


def test_every_scenario_is_valid_and_unknown_names_are_refused() -> None:
    for name in scenarios.SCENARIOS:
        cfg = scenarios.scenario_config(name, minutes=1.0, seed=1)
        assert cfg.drivers == "mixed" and cfg.frame_rate == 10.0
    limits = [scenarios.scenario_config(n, minutes=1, seed=1).speed_limit_kmh for n in scenarios.SCENARIOS]
    lanes = [scenarios.scenario_config(n, minutes=1, seed=1).lanes_per_direction for n in scenarios.SCENARIOS]
    assert min(limits) == 60.0 and max(limits) == 130.0
    assert min(lanes) == 2 and max(lanes) == 5
    bottlenecks = {scenarios.scenario_config(n, minutes=1, seed=1).bottleneck for n in scenarios.SCENARIOS}
    assert {"on_ramp", "lane_drop", "slow_zone", "signal"} <= bottlenecks
    with pytest.raises(InputError, match="unknown scenario"):
        scenarios.scenario_config("rush_hour_on_mars", minutes=1.0, seed=1)


# (scenario, speed p50 range m/s, most lane changes per vehicle): stated ranges of each regime
EXPECTED = [("free_flow", (27.0, 38.0), 0.4), ("stop_and_go", (1.0, 9.0), 0.4)]


@pytest.mark.slow
@pytest.mark.parametrize(("name", "speed_range", "max_changes"), EXPECTED)
def test_scenario_traffic_in_its_stated_range(
    tmp_path: Path, name: str, speed_range: tuple[float, float], max_changes: float
) -> None:
    """Two minutes of each regime: median speeds in range, smooth lane changes (|lateral
    acceleration| p99 below 1.5 m/s², SUMO's raw lane changes reach 15 m/s²), some lane changes
    but fewer than ``max_changes`` per vehicle, the right number of lanes."""
    cfg = scenarios.scenario_config(name, minutes=2.0, seed=3)
    out = recording.simulate(tmp_path / name, minutes=2.0, seed=3, config=cfg, show_progress=False)
    stats = traffic_statistics(highd.read([out]))
    assert set(stats) == {"highd-01-upper", "highd-01-lower"}
    for st in stats.values():
        assert speed_range[0] <= st["speed_mps"]["p50"] <= speed_range[1], st
        assert st["lateral_acc_abs_mps2"]["p99"] < 1.5, st
        assert st["lanes"] == cfg.lanes_per_direction
    changes = sum(st["lane_changes"] for st in stats.values())
    vehicles = sum(st["vehicles"] for st in stats.values())
    assert 0 < changes <= max_changes * vehicles


@pytest.mark.slow
def test_cli_scenario(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    code = cli.main(
        ["simulate", "--out", str(tmp_path / "s"), "--minutes", "0.5", "--seed", "2", "--scenario", "signal"]
    )
    assert code == 0
    assert "of scenario signal" in capsys.readouterr().out
    meta = (tmp_path / "s" / "01_recordingMeta.csv").read_text().splitlines()
    row = dict(zip(meta[0].split(","), meta[1].split(","), strict=True))
    assert row["frameRate"] == "10" and float(row["speedLimit"]) == pytest.approx(60 / 3.6, abs=0.01)


def test_traffic_statistics_by_hand() -> None:
    """Two cars 100 m apart at 20 m/s in a road frame over 10 s (10 Hz), one changing lanes once."""
    n = 100
    t = np.arange(n)
    cols: dict[str, object] = {
        "track_id": np.repeat([1, 2], n),
        "frame": np.tile(t, 2),
        "time_ns": np.tile(t * 100_000_000, 2),
        "x": np.concatenate([2.0 * t, 100.0 + 2.0 * t]),
        "y": np.zeros(2 * n),
        "heading": np.zeros(2 * n),
        "vx": np.full(2 * n, 20.0),
        "vy": np.zeros(2 * n),
        "ax": np.zeros(2 * n),
        "ay": np.concatenate([np.zeros(n), np.where((t >= 40) & (t < 60), 0.5, 0.0)]),
        "length": np.full(2 * n, 4.5),
        "width": np.full(2 * n, 1.8),
        "lane_id": np.concatenate([np.full(n, 1), np.where(t < 50, 1, 2)]).astype(float),
        "recording": ["r"] * (2 * n),
        "object_class": ["car"] * (2 * n),
    }
    table = build_table(cols, TableMeta("test", {"r": RecordingMeta(10.0)}))
    st = traffic_statistics(table)["r"]
    assert st["vehicles"] == 2 and st["duration_s"] == pytest.approx(10.0)
    assert st["speed_mps"]["p50"] == pytest.approx(20.0)
    assert st["lane_changes"] == 1 and st["lane_changes_per_vehicle"] == pytest.approx(0.5)
    assert st["lane_changes_per_vehicle_km"] == pytest.approx(1 / 0.4, rel=1e-6)  # 2 × 200 m driven
    # 2 vehicles over the observed ~298 m (0.5-99.5 percentiles of x)
    assert st["density_veh_per_km"] == pytest.approx(2 / 0.2955, rel=0.02)
    assert st["lanes"] == 2
    assert st["lateral_acc_abs_mps2"]["p50"] == pytest.approx(0.0)
    assert st["lateral_acc_abs_mps2"]["p99"] == pytest.approx(0.5)


def test_lateral_acceleration_a_source_does_not_record_is_none(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """NGSIM records a scalar acceleration: every row's lateral component is 0. Its percentiles
    (0.00/0.00/0.00) would claim perfectly smooth lane changes; the statistics say None and
    ``lanecast info`` says the source has none, while a recording with lateral motion keeps them."""
    sample = TESTS / "data" / "ngsim" / "peachtree_sample.csv"
    table = registry.read_any([sample])
    stats = traffic_statistics(table)
    assert stats and all(st["lateral_acc_abs_mps2"] is None for st in stats.values())
    assert all(st["speed_mps"]["p95"] > 5.0 for st in stats.values())  # the rest is still there
    assert cli.main(["info", str(sample)]) == 0
    out = capsys.readouterr().out
    assert out.count("lat. acc. not in the source") == len(stats)
    assert "0.00/0.00/0.00 m/s²" not in out


def test_speed_dips_by_hand() -> None:
    """1 Hz speeds: a wave passing (12 → 6 → 12 m/s) is one dip; braking into a queue that then
    crawls (12 → 3 m/s, held) is none; a fast vehicle just before a slow one in the table does not
    make the slow one's start a dip; at 10 Hz the same speeds give the same count."""
    t = np.arange(60.0)
    wave = 12.0 - 6.0 * np.exp(-(((t - 30.0) / 4.0) ** 2))
    brake = np.where(t < 20, 12.0, np.maximum(12.0 - 1.5 * (t - 20.0), 3.0))
    track = np.repeat([1, 2, 3, 4], 60)
    speed = np.r_[wave, brake, np.full(60, 20.0), np.linspace(5.0, 9.0, 60)]
    assert speed_dips(track, speed, 1.0) == 1
    assert speed_dips(track[60:], speed[60:], 1.0) == 0
    assert speed_dips(np.repeat(track, 10), np.repeat(speed, 10), 10.0) == 1
    assert speed_dips(np.zeros(0, np.int64), np.zeros(0), 10.0) == 0


@pytest.mark.slow
def test_waves_scenario_has_stop_and_go_where_drivers_deciding_every_step_only_crawl(tmp_path: Path) -> None:
    """The ``waves`` scenario's 1 s reaction time is what makes its queue stop and go: the same
    road and demand with drivers deciding every step has far fewer speed dips per vehicle-minute."""
    dips = {}
    for reaction in (1.0, 0.0):
        cfg = scenarios.scenario_config("waves", minutes=3.0, seed=5, reaction_time_s=reaction)
        out = recording.simulate(
            tmp_path / f"r{reaction:g}", minutes=3.0, seed=5, config=cfg, show_progress=False
        )
        stats = traffic_statistics(highd.read([out]))
        dips[reaction] = np.mean([st["speed_dips_per_vehicle_min"] for st in stats.values()])
        assert all(1.0 < st["speed_mps"]["p50"] < 12.0 for st in stats.values()), stats
    assert dips[1.0] > 0.4 and dips[1.0] > 2 * dips[0.0], dips
