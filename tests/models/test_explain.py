"""`lanecast explain` on the hand-built seven-neighbour scene: a removal zeroes exactly its slot, the
full-scene forecast is batch prediction's, every what-if is forecast and ranked, bad requests are refused."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from conftest import SEVEN, straight, table_of

from lanecast.io_adapters.contracts.track_table import write_parquet
from lanecast.io_adapters.contracts.windows import ROWS, TARGET_ROW
from lanecast.io_adapters.errors import InputError
from lanecast.models.explain import NEIGHBOURS, parse_removals, present_neighbours, remove_rows, what_if
from lanecast.models.predict import STCNNForecaster
from lanecast.pipeline.make_windows import make_windows
from lanecast.workflows.cli import main


@pytest.fixture(scope="module")
def scene_table() -> object:
    """T (track 1) in the middle lane with a vehicle in each of the seven slots; F slower than T."""
    frames = np.arange(80)
    return table_of(straight(SEVEN, frames, vx={2: 24.0}))


@pytest.fixture(scope="module")
def forecaster() -> STCNNForecaster:
    return STCNNForecaster.load(None)


def target_window(table: object) -> tuple[np.ndarray, np.ndarray, int, object]:
    w = make_windows(table, require_future=False, split="none")  # type: ignore[arg-type]
    i = int(np.flatnonzero(w.index.column("track_id").to_numpy() == 1)[0])
    return np.asarray(w.inputs[i]), np.asarray(w.present[i]), i, w


def test_removing_a_neighbour_zeroes_exactly_its_slot(scene_table: object) -> None:
    inputs, present, _, _ = target_window(scene_table)
    assert present_neighbours(present) == list(NEIGHBOURS)  # all seven slots occupied
    for name in NEIGHBOURS:
        row = ROWS.index(name)
        cut_inputs, cut_present = remove_rows(inputs, present, [row])
        assert not cut_inputs[:, row].any() and not cut_present[row].any()
        others = [r for r in range(8) if r != row]
        np.testing.assert_array_equal(cut_inputs[:, others], inputs[:, others])
        np.testing.assert_array_equal(cut_present[others], present[others])
    assert present[ROWS.index("F")].all() and inputs[:, ROWS.index("F")].any()  # the input was not touched


def test_full_scene_equals_batch_prediction(scene_table: object, forecaster: STCNNForecaster) -> None:
    inputs, present, i, w = target_window(scene_table)
    batch = forecaster.predict(w.inputs, w.present)  # type: ignore[attr-defined]
    result = what_if(forecaster, inputs, present, [("F",), ("RL",), ("FL", "F")])
    p = result.predictions
    assert result.names == ["full scene", "without F", "without RL", "without FL + F"]
    np.testing.assert_allclose(p.offsets[0], batch.offsets[i], atol=1e-5)
    np.testing.assert_allclose(p.probs[0], batch.probs[i], atol=1e-6)  # type: ignore[index]
    # each what-if is the batch prediction of the window with those rows removed
    alone = forecaster.predict(
        *[a[None] for a in remove_rows(inputs, present, [ROWS.index("FL"), ROWS.index("F")])]
    )
    np.testing.assert_allclose(p.offsets[3], alone.offsets[0], atol=1e-5)
    assert not result.inputs[3][:, [ROWS.index("FL"), ROWS.index("F")]].any()
    effects = result.effects()
    shift = np.hypot(*(p.offsets[1] - p.offsets[0]).T)
    assert effects[0]["shift_m"] == pytest.approx(shift.tolist(), abs=1e-4)
    assert effects[0]["max_probability_change"] == pytest.approx(
        float(np.abs(p.probs[1] - p.probs[0]).max()), abs=1e-4
    )  # type: ignore[index]
    ranked = [effects[s - 1]["mean_shift_m"] for s in result.rank()]
    assert ranked == sorted(ranked, reverse=True)


def test_parse_removals_refuses_what_is_not_there(scene_table: object) -> None:
    inputs, present, _, _ = target_window(scene_table)
    assert parse_removals("f, rl,FL+F", present) == [("F",), ("RL",), ("FL", "F")]
    with pytest.raises(InputError, match="no neighbour slot 'T'"):
        parse_removals("T", present)
    _, no_f = remove_rows(inputs, present, [ROWS.index("F")])
    with pytest.raises(InputError, match="slot F is empty"):
        parse_removals("F", no_f)
    assert TARGET_ROW == ROWS.index("T")


def test_cli_all_ranks_every_neighbour(
    scene_table: object, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    table_path = write_parquet(scene_table, tmp_path / "scene.parquet")  # type: ignore[arg-type]
    out = tmp_path / "explain"
    assert (
        main(["explain", str(table_path), "--track", "1", "--time", "2.9", "--all", "--out", str(out)]) == 0
    )
    doc = json.loads((out / "explain.json").read_text())
    assert doc["window"]["track_id"] == 1 and doc["window"]["t0_s"] == pytest.approx(2.9)
    assert [s["name"] for s in doc["scenarios"]] == ["full scene", *(f"without {n}" for n in NEIGHBOURS)]
    assert sorted(doc["ranking"]) == sorted(f"without {n}" for n in NEIGHBOURS)
    shifts = {e["scenario"]: e["mean_shift_m"] for e in doc["effects"]}
    assert [shifts[name] for name in doc["ranking"]] == sorted(shifts.values(), reverse=True)
    page = (out / "explain.html").read_text()
    assert "without RR" in page and "most influential first" in page
    assert len(list(out.glob("scene_*.png"))) == 8
    assert "most influential first" in capsys.readouterr().out
    # the same window from the windows dataset gives the same full-scene forecast
    argv = ["explain", str(table_path), "--track", "1", "--time", "2.9", "--out", str(tmp_path / "x")]
    assert main([*argv, "--remove", "F+RL"]) == 0
    again = json.loads((tmp_path / "x" / "explain.json").read_text())
    assert again["scenarios"][0] == doc["scenarios"][0] and again["scenarios"][1]["removed"] == ["F", "RL"]
    assert main([*argv, "--remove", "X"]) == 2
    assert main([*argv[:4], "--time", "0.5", "--out", str(tmp_path / "y")]) == 2  # no 3 s of history yet


def test_annotate_explain_writes_each_what_if(tmp_path: Path, forecaster: STCNNForecaster) -> None:
    """/lanecast/explain holds, per target and forecast time, one line per neighbour removed, equal to
    the forecast of that window with the neighbour's slot zeroed."""
    from mcap.reader import make_reader

    from lanecast.io_adapters.contracts.window_frame import to_source_frame
    from lanecast.io_adapters.formats import registry
    from lanecast.io_adapters.logs import forecast_messages as fm
    from lanecast.workflows.annotation.annotate_log import AnnotateOptions, annotate_log, forecast_times
    from lanecast.workflows.annotation.track_forecasts import windows_to_forecast

    frames = np.arange(100)
    table = table_of(straight({1: (2, 0.0), 2: (3, 20.0), 3: (2, 40.0)}, frames), rotate=0.3)
    log = registry.write_any(table, tmp_path / "drive.mcap", "mcap")
    out = tmp_path / "annotated.mcap"
    counts = annotate_log(log, out, AnnotateOptions(every_s=1.0, encoding="json", explain=True))
    with open(out, "rb") as f:
        messages = [(c.topic, m) for _, c, m in make_reader(f).iter_messages()]
    topics = [t for t, _ in messages]
    assert fm.EXPLAIN_TOPIC in topics
    explain = [json.loads(m.data) for t, m in messages if t == fm.EXPLAIN_TOPIC]
    times = [m.log_time for t, m in messages if t in (fm.FORECAST_TOPIC, fm.EXPLAIN_TOPIC)]
    assert times == sorted(times)  # merged in log-time order
    tracks = registry.read_any([log])
    windows = windows_to_forecast(tracks, forecaster, t0_ns=forecast_times(tracks, 1.0))
    entities = {(int(e["timestamp"]["sec"]), e["id"]): e for doc in explain for e in doc["entities"]}
    occupied = sum(len(present_neighbours(windows.present[i])) for i in range(len(windows)))
    assert len(entities) == occupied == counts["what_if_forecasts"] > 0
    checked = 0
    for i in range(len(windows)):
        row = windows.index.slice(i, 1).to_pylist()[0]
        names = present_neighbours(windows.present[i])
        result = what_if(forecaster, windows.inputs[i], windows.present[i], [(n,) for n in names], top_k=1)
        origin = (np.array([row["origin_x"]]), np.array([row["origin_y"]]), np.array([row["origin_heading"]]))
        for s, name in enumerate(names, start=1):
            e = entities[(row["t0_ns"] // 1_000_000_000, f"{row['track_id']} without {name}")]
            meta = {kv["key"]: kv["value"] for kv in e["metadata"]}
            assert meta["removed"] == name and meta["target_track_id"] == str(row["track_id"])
            expected = to_source_frame(result.predictions.offsets[s][None], *origin)[0]
            got = np.array([[p["x"], p["y"]] for p in e["lines"][0]["points"]])[-5:]
            np.testing.assert_allclose(got, expected, atol=1e-4)
            checked += 1
    assert checked == occupied


def test_a_time_between_strided_windows_takes_the_nearest(
    scene_table: object, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A windows dataset cut every 1 s has no window at 3.3 s: explain takes the one at 2.9 s and says
    so; a time outside the track's windows is still refused."""
    from lanecast.io_adapters.windows_store.dataset import save_windows

    frames = np.arange(120)
    windows = make_windows(
        table_of(straight(SEVEN, frames, vx={2: 24.0})), require_future=False, split="none", stride=10
    )  # type: ignore[arg-type]
    t0 = (
        np.sort(windows.index.column("t0_ns").to_numpy()[windows.index.column("track_id").to_numpy() == 1])
        / 1e9
    )
    assert np.allclose(np.diff(t0), 1.0) and 3.3 > t0[0]
    directory = save_windows(windows, tmp_path / "windows")
    out = tmp_path / "explain"
    argv = ["explain", str(directory), "--track", "1", "--out", str(out)]
    assert main([*argv, "--time", f"{t0[0] + 0.4:.1f}"]) == 0
    assert json.loads((out / "explain.json").read_text())["window"]["t0_s"] == pytest.approx(t0[0])
    assert f"the nearest to {t0[0] + 0.4:.1f} s is at {t0[0]:.1f} s" in capsys.readouterr().err
    assert main([*argv, "--time", f"{t0[0] + 0.6:.1f}"]) == 0
    assert json.loads((out / "explain.json").read_text())["window"]["t0_s"] == pytest.approx(t0[1])
    assert main([*argv, "--time", f"{t0[-1] + 2:.1f}"]) == 2
