"""`lanecast report --predictions`: a recorded predictor with known errors scored against the log's
future; figures equal to those computed by hand from the log's construction, unmatched objects
counted exactly."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow.compute as pc
import pytest
from predictor_drive_log import (
    CARS,
    CONFIDENCES,
    OFFSETS,
    PREDICTIONS_TOPIC,
    prediction_stamps,
    write_bag,
    write_mcap,
)

from lanecast.io_adapters.errors import InputError
from lanecast.io_adapters.formats import registry
from lanecast.workflows.annotation.predictor_report import predictor_metrics, report_predictors
from lanecast.workflows.annotation.predictor_scores import add_lanecast, score_predictor
from lanecast.workflows.annotation.recorded_predictions import read_predictions
from lanecast.workflows.cli import main

H = np.arange(1.0, 6.0)


def hand_errors() -> tuple[np.ndarray, np.ndarray]:
    """(errors of each path [N, 3, 5] in m, the scored rows' car ids [N]): cars 1–3 at t0 = 4…7 s.

    Each path is constant velocity from the true state shifted by its offset, so its error is the
    offset minus what constant velocity misses: ½·a·h² along x for the accelerating car."""
    rows = [(car, t0) for t0 in (4.0, 5.0, 6.0, 7.0) for car in (1, 2, 3)]
    err = np.array(
        [
            [np.hypot(dx - 0.5 * CARS[car][4] * H**2, dy * np.ones_like(H)) for dx, dy in OFFSETS]
            for car, _ in rows
        ]
    )
    return err, np.array([car for car, _ in rows])


def report(tmp_path: Path, log: Path, *options: str) -> dict[str, Any]:
    out = tmp_path / "report"
    assert main(["report", str(log), "--out", str(out), *options]) == 0
    assert (out / "report.html").is_file() and (out / "report.md").is_file()
    result: dict[str, Any] = json.loads((out / "metrics.json").read_text())
    return result


@pytest.fixture(scope="module")
def mcap_report(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    tmp = tmp_path_factory.mktemp("mcap")
    return report(tmp, write_mcap(tmp / "drive.mcap"), "--predictions")


def test_the_figures_equal_those_computed_by_hand(mcap_report: dict[str, Any]) -> None:
    entry = mcap_report[PREDICTIONS_TOPIC]
    m = entry["metrics"]["recorded"]
    err, car = hand_errors()
    best = err[:, 0]  # the most confident path (0.6)
    assert entry["scored"] == m["n"] == 12
    np.testing.assert_allclose(m["rmse"], np.sqrt((best**2).mean(axis=0)), rtol=1e-9)
    assert m["ade"] == pytest.approx(best.mean())
    assert m["fde"] == pytest.approx(best[:, -1].mean())
    assert m["min_ade"] == pytest.approx(err.mean(axis=2).min(axis=1).mean())
    assert m["min_fde"] == pytest.approx(err[:, :, -1].min(axis=1).mean())
    assert m["k"] == 3
    assert m["miss_rate"] == pytest.approx((best[:, -1] > 2.0).mean())
    p = np.array(CONFIDENCES) / sum(CONFIDENCES)
    closest = err.mean(axis=2).argmin(axis=1)
    assert m["brier"] == pytest.approx(np.mean([((p - np.eye(3)[c]) ** 2).sum() for c in closest]))
    assert m["nll"] == pytest.approx(np.mean(-np.log(p[closest])))
    assert m["per_class"] == {"car": {"n": 12, "rmse": pytest.approx(m["rmse"])}}
    low, high = m["rmse_ci"]["low"], m["rmse_ci"]["high"]
    assert all(lo <= r <= hi for lo, r, hi in zip(low, m["rmse"], high, strict=True))
    assert car.tolist().count(3) == 4


def test_unmatched_predictions_are_counted_exactly(mcap_report: dict[str, Any]) -> None:
    entry = mcap_report[PREDICTIONS_TOPIC]
    n_stamps = len(prediction_stamps())  # 9, at 4…12 s
    # the ghost at every stamp; cars 1–3 at 8…12 s (their 5 s pass the log's end at 12.9 s); car 4
    # (gone at 7 s) at 4…7 s
    assert entry["unmatched"] == {
        "no tracked object with its id (an id switch, or never tracked)": n_stamps,
        "horizon past the end of the log": 3 * 5,
        "object gone before the last horizon (it left, or its id switched)": 4,
    }
    assert entry["objects_predicted"] == n_stamps + 3 * n_stamps + 4
    assert entry["refused_paths"] == {}
    assert entry["stamp_offset_ms"] == {"drive": {"median": 0.0, "min": 0.0, "max": 0.0}}


def test_lanecast_is_scored_on_the_same_predictions_and_the_answer_leads(mcap_report: dict[str, Any]) -> None:
    entry = mcap_report[PREDICTIONS_TOPIC]
    metrics = entry["metrics"]
    assert set(metrics) == {"recorded", "stcnn", "cv"}
    assert {m["n"] for m in metrics.values()} == {12}
    r5, cv5 = metrics["recorded"]["rmse"][-1], metrics["cv"]["rmse"][-1]
    assert entry["headline"].startswith(
        f"{PREDICTIONS_TOPIC}: RMSE@5 s {r5:.2f} m, {r5 / cv5:.2f}× constant velocity ({cv5:.2f} m)"
    )
    assert "on 12 predictions of 3 objects (40 predicted: 28 without a future in the log" in entry["headline"]
    # constant velocity errs only on the accelerating car: less than the recorded offset of 1.1 m at 1 s
    assert metrics["cv"]["rmse"][0] < metrics["recorded"]["rmse"][0]
    assert metrics["cv"]["k"] == 1 and metrics["stcnn"]["k"] == 3


def test_a_ros2_bag_gives_the_same_report(tmp_path: Path, mcap_report: dict[str, Any]) -> None:
    bag = report(tmp_path, write_bag(tmp_path / "drive"), "--predictions", PREDICTIONS_TOPIC)
    for key in ("scored", "unmatched", "objects_predicted"):
        assert bag[PREDICTIONS_TOPIC][key] == mcap_report[PREDICTIONS_TOPIC][key]
    np.testing.assert_allclose(
        bag[PREDICTIONS_TOPIC]["metrics"]["recorded"]["rmse"],
        mcap_report[PREDICTIONS_TOPIC]["metrics"]["recorded"]["rmse"],
    )


def test_predictions_stamped_after_their_tracked_objects_are_aligned_and_the_offset_named(
    tmp_path: Path,
) -> None:
    shifted = report(
        tmp_path, write_mcap(tmp_path / "drive.mcap", stamp_shift_ns=50_000_000), "--predictions"
    )
    entry = shifted[PREDICTIONS_TOPIC]
    assert entry["stamp_offset_ms"]["drive"]["median"] == pytest.approx(50.0)
    assert entry["scored"] == 12
    # scored at its stamp: a path made at t but stamped t + 50 ms is 50 ms behind the car at every
    # horizon h (the truth at t + 50 ms + h, linear between the 10 Hz samples: a few mm off a parabola)
    lag = 0.05
    err = []
    for t in (4.0, 5.0, 6.0, 7.0):
        for car in (1, 2, 3):
            _, _, vx, vy, ax = CARS[car]
            v_t = vx + ax * t
            dx, dy = OFFSETS[0]
            ex = dx - v_t * lag - 0.5 * ax * (H + lag) ** 2
            err.append(np.hypot(ex, dy - vy * lag))
    np.testing.assert_allclose(
        entry["metrics"]["recorded"]["rmse"], np.sqrt((np.array(err) ** 2).mean(0)), atol=3e-3
    )
    assert entry["unmatched"] == {
        "no tracked object with its id (an id switch, or never tracked)": 9,
        "not tracked at its stamp": 1,  # car 4 stamped 7.05 s, tracked until 7 s
        "horizon past the end of the log": 15,
        "object gone before the last horizon (it left, or its id switched)": 3,
    }


def test_predictions_lanecast_cannot_forecast_are_counted_and_kept_for_the_recorded_predictor(
    tmp_path: Path,
) -> None:
    """Tracks from 2 s on: at 4 s no car has lanecast's 3 s of history; the recorded predictor is
    still scored there (its every-matched row), and the side by side leaves those 3 out."""
    log = write_mcap(tmp_path / "drive.mcap")
    tracks = registry.read_any([log])
    tracks = tracks.filter(pc.greater_equal(tracks["time_ns"], 2_000_000_000))
    (pred,) = read_predictions(log)
    scored = score_predictor(pred, tracks)
    assert add_lanecast(scored, tracks, []) == 3
    entry = predictor_metrics([scored], boots=0)
    assert entry["scored"] == 9
    assert entry["metrics"]["recorded"]["n"] == entry["metrics"]["cv"]["n"] == 9
    every = entry["metrics"]["recorded_all_matched"]
    err, _ = hand_errors()
    assert every["n"] == 12
    np.testing.assert_allclose(every["rmse"], np.sqrt((err[:, 0] ** 2).mean(axis=0)), rtol=1e-9)


def test_a_predictor_with_nothing_to_score_is_reported_as_such(tmp_path: Path) -> None:
    """Tracks that end at 3 s: every prediction (from 4 s on) is counted, none is scored."""
    log = write_mcap(tmp_path / "drive.mcap")
    tracks = registry.read_any([log])
    tracks = tracks.filter(pc.less(tracks["time_ns"], 3_000_000_000))
    (pred,) = read_predictions(log)
    scored = score_predictor(pred, tracks)
    assert add_lanecast(scored, tracks, []) == 0
    entry = predictor_metrics([scored], boots=10)
    assert entry["scored"] == 0
    assert entry["unmatched"] == {
        "no tracked object with its id (an id switch, or never tracked)": 9,
        "not tracked at its stamp": 31,
    }
    assert entry["metrics"]["recorded"]["rmse"] == [None] * 5
    json.dumps(entry, allow_nan=False)


def test_a_folder_of_logs_is_reported_per_log_and_pooled(tmp_path: Path, mcap_report: dict[str, Any]) -> None:
    logs = tmp_path / "logs"
    (logs / "day1").mkdir(parents=True)
    (logs / "day2").mkdir()
    write_mcap(logs / "day1" / "drive.mcap")
    write_bag(logs / "day2" / "drive")
    pooled = report(tmp_path, logs, "--predictions")[PREDICTIONS_TOPIC]
    one = mcap_report[PREDICTIONS_TOPIC]
    assert pooled["scored"] == 2 * one["scored"]
    assert pooled["unmatched"] == {reason: 2 * n for reason, n in one["unmatched"].items()}
    np.testing.assert_allclose(pooled["metrics"]["recorded"]["rmse"], one["metrics"]["recorded"]["rmse"])
    for name in ("day1/drive", "day2/drive"):
        page = json.loads((tmp_path / "report" / "logs" / name / "metrics.json").read_text())
        assert page[PREDICTIONS_TOPIC]["scored"] == one["scored"]
        assert pooled["stamp_offset_ms"][name] == {"median": 0.0, "min": 0.0, "max": 0.0}


def test_a_folder_without_logs_is_named(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="no drive logs found"):
        report_predictors([tmp_path], tmp_path / "report", predictions=[])


def test_lanecasts_own_forecasts_of_both_directions_are_all_matched(
    tmp_path: Path, sim_recording_dir: Path
) -> None:
    """A log of both highD directions (two recordings, two topics) annotated by lanecast: every
    forecast object is matched to the recording its track is in, none counted as unknown, and the
    scores equal those of `report` on the same log."""
    log = tmp_path / "logs" / "sim.mcap"
    assert main(["convert", str(sim_recording_dir), "--out", str(log)]) == 0
    assert main(["annotate", str(log), "--out", str(tmp_path / "annotated")]) == 0
    annotated = tmp_path / "annotated" / "sim.mcap"
    from lanecast.io_adapters.logs import conventions

    tracks = registry.read_any([annotated])
    tracks = conventions.shifted(tracks, conventions.read_offset(tracks))  # on the log's clock
    assert len(set(tracks.column("recording").to_pylist())) == 2
    (pred,) = read_predictions(annotated, ["/lanecast/prediction"], checked=True)
    scored = score_predictor(pred, tracks)
    assert "no tracked object with its id (an id switch, or never tracked)" not in scored.unmatched
    assert set(scored.row_recording) == set(tracks.column("recording").to_pylist())  # both directions
    assert scored.track_id.size + sum(scored.unmatched.values()) == len(pred)
    no_window = add_lanecast(scored, tracks, [])
    assert no_window == 0
    np.testing.assert_allclose(scored.lanecast["cv"]["true"], scored.true)  # same rows, same truth


def test_a_log_of_a_folder_that_cannot_be_scored_is_named_in_the_report_and_on_stderr(
    tmp_path: Path, mcap_report: dict[str, Any], capsys: pytest.CaptureFixture[str]
) -> None:
    """It was named on stdout only ('skipped …'), and the report said nothing of it."""
    logs = tmp_path / "logs"
    logs.mkdir()
    write_mcap(logs / "a.mcap")
    cut = write_mcap(logs / "b.mcap")
    cut.write_bytes(cut.read_bytes()[: cut.stat().st_size // 2])
    out = tmp_path / "report"
    assert main(["report", str(logs), "--out", str(out), "--predictions"]) == 1
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert err.startswith(f"lanecast report: error: not scored: {cut}: {cut}, offset ")
    page = json.loads((out / "metrics.json").read_text())
    assert [line.split(":")[0] for line in page["logs_not_scored"]] == [str(cut)]
    assert page[PREDICTIONS_TOPIC]["scored"] == mcap_report[PREDICTIONS_TOPIC]["scored"]  # a.mcap's alone
    assert (
        "## logs not scored" in (out / "report.md").read_text()
        and str(cut) in (out / "report.html").read_text()
    )
