"""`lanecast report` scores the forecasts stored in annotated logs; `lanecast demo` runs everything."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest
from conftest import no_output, refused

from lanecast.io_adapters.datasets.highd import reader as highd
from lanecast.io_adapters.formats import registry
from lanecast.workflows.cli import main


@pytest.fixture(scope="module")
def annotated(sim_recording_dir: Path, tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """The simulated recording as an MCAP drive log, annotated with the shipped model."""
    work = tmp_path_factory.mktemp("report")
    table = highd.read([sim_recording_dir])
    log = registry.write_any(table, work / "drive.mcap", "mcap")
    assert main(["annotate", str(log), "--out", str(work / "annotated")]) == 0
    return log, work / "annotated"


@pytest.mark.slow
def test_report_scores_logged_forecasts_like_batch_prediction(
    annotated: tuple[Path, Path], tmp_path: Path
) -> None:
    """The report's metrics equal those of batch prediction on the same windows, without the log."""
    from lanecast.models.metrics import summary
    from lanecast.models.predict import STCNNForecaster
    from lanecast.pipeline.make_windows import make_windows
    from lanecast.workflows.annotation import log_scores as report

    log, out_dir = annotated
    assert main(["report", str(out_dir), "--out", str(tmp_path / "r")]) == 0
    metrics = json.loads((tmp_path / "r" / "metrics.json").read_text())
    assert set(metrics) >= {"stcnn", "cv", "ca", "meta"}
    assert (tmp_path / "r" / "report.html").read_text().count("data:image/png;base64,") >= 2
    assert (tmp_path / "r" / "logs" / "drive" / "metrics.json").is_file()

    # Independent computation: windows at the forecast times, the shipped model, lanecast.models.metrics.
    from lanecast.io_adapters.logs.conventions import read_offset

    docs = report.prediction_documents(out_dir / "drive.mcap")
    tracks = registry.read_any([log])
    assert read_offset(tracks) > 0  # a simulated recording's log starts at its date, not in 1970
    t0 = np.unique([d["t0_ns"] for d in docs]) - read_offset(tracks)  # the log's clock → the table's
    windows = make_windows(tracks, split="none", t0_ns=t0, allow_empty=True)
    known = np.isfinite(np.asarray(windows.future)).all(axis=(1, 2))
    pred = STCNNForecaster.load(None).predict(
        np.asarray(windows.inputs)[known], np.asarray(windows.present)[known], top_k=3, batch_size=4096
    )
    vehicle = windows.index.column("track_id").to_numpy()[known]
    expected = summary(
        pred.offsets,
        np.asarray(windows.future)[known],
        np.asarray(windows.maneuver)[known],
        vehicle,
        candidates=pred.top_offsets,
        predicted_maneuver=pred.maneuver,
    )
    assert metrics["stcnn"]["n_windows"] == expected["n_windows"] == int(known.sum())
    np.testing.assert_allclose(metrics["stcnn"]["rmse"], expected["rmse"], rtol=1e-4, atol=1e-4)
    np.testing.assert_allclose(metrics["stcnn"]["min_ade"], expected["min_ade"], rtol=1e-4, atol=1e-4)
    assert metrics["stcnn"]["maneuver_accuracy"] == pytest.approx(expected["maneuver_accuracy"], abs=1e-9)
    assert metrics["stcnn"]["confusion"] == expected["confusion"]


def test_report_refuses_a_log_without_forecasts(annotated: tuple[Path, Path], tmp_path: Path) -> None:
    log, _ = annotated
    assert main(["report", str(log), "--out", str(tmp_path / "r")]) == 2
    assert not (tmp_path / "r" / "metrics.json").exists()


@pytest.mark.slow
def test_demo_runs_the_whole_pipeline(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """With a relative --out, as the README's first command runs it."""
    monkeypatch.chdir(tmp_path)
    out = Path("demo")
    assert main(["demo", "--out", str(out), "--minutes", "2", "--density", "low"]) == 0
    printed = capsys.readouterr().out
    assert f"{out / 'annotated' / 'highway.mcap'}" in printed
    assert f"{out / 'report' / 'report.html'}" in printed
    metrics = json.loads((out / "report" / "metrics.json").read_text())
    assert metrics["meta"]["forecasts_scored"] > 100
    page = (out / "report" / "report.html").read_text()
    assert "href='logs/highway/report.html'" in page  # each log's page is linked
    assert (out / "report" / "logs" / "highway" / "report.html").is_file()
    assert "ST-CNN (maneuver-based)" in page and "constant velocity" in page and '{"' not in page
    assert set(metrics["stcnn"]["per_recording"]) == {"highway"}  # one row per log
    # Forecasts are in the annotated log, the original log is untouched and still readable.
    assert report_topics(out / "annotated" / "highway.mcap") >= {"/lanecast/forecast", "/lanecast/prediction"}
    assert registry.read_any([out / "logs" / "highway.mcap"]).num_rows > 0
    # What it prints is what it wrote: the paths exist from the cwd, the figures are metrics.json's.
    done = re.search(r"done\. Open (\S+) in Foxglove; the report is (\S+)$", printed, re.M)
    assert done is not None and Path(done[1]).is_file() and Path(done[2]).is_file()
    assert printed_rmse(printed) == [round(v, 2) for v in metrics["stcnn"]["rmse"]]
    scored = metrics["meta"]["forecasts_scored"]
    assert f"scored {scored:,} of {metrics['meta']['forecasts_in_logs']:,} forecasts in 1 log " in printed

    # A rerun (the same command again, or after an interruption) redoes the demo in its own folder.
    (out / "report" / "notes.txt").write_text("the user's")
    assert main(["demo", "--out", str(out), "--minutes", "2", "--density", "low"]) == 0
    again = capsys.readouterr().out
    assert printed_rmse(again) == printed_rmse(printed)
    assert (
        json.loads((out / "report" / "metrics.json").read_text())["stcnn"]["rmse"] == metrics["stcnn"]["rmse"]
    )
    assert (out / "report" / "notes.txt").read_text() == "the user's"


def printed_rmse(printed: str) -> list[float]:
    line = re.search(r"RMSE 1-5 s \(m\): forecasts ([\d. ]+) \|", printed)
    assert line is not None, printed
    return [float(v) for v in line[1].split()]


def report_topics(path: Path) -> set[str]:
    from mcap.reader import make_reader

    with path.open("rb") as fh:
        summary = make_reader(fh).get_summary()
    assert summary is not None
    return {c.topic for c in summary.channels.values()}


def test_report_on_a_truncated_log_names_the_damage(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """`report` read /lanecast/prediction with the mcap library before the tracks: a log cut in half
    was a RecordLengthLimitExceeded traceback (and, for one log, 'no log could be scored' hid the
    reason). Now the log's own error, with its offset, is the command's."""
    from conftest import json_log, straight_messages

    log = json_log(tmp_path / "cut.mcap", straight_messages(n=120))
    log.write_bytes(log.read_bytes()[: log.stat().st_size // 2])
    out = tmp_path / "rep"
    refused(["report", str(log), "--out", str(out)], capsys, f"{log}, offset ", "truncated")
    no_output(out)


def test_a_log_of_a_folder_that_cannot_be_scored_is_named_in_the_report_and_on_stderr(
    annotated: tuple[Path, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """It was named on stdout only ('skipped …'), and the report said nothing of it."""
    _, folder = annotated
    logs = tmp_path / "logs"
    logs.mkdir()
    good = next(folder.glob("*.mcap"))
    (logs / "a.mcap").write_bytes(good.read_bytes())
    cut = logs / "b.mcap"
    cut.write_bytes(good.read_bytes()[: good.stat().st_size // 2])
    out = tmp_path / "rep"
    assert main(["report", str(logs), "--out", str(out)]) == 1
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert err.startswith(f"lanecast report: error: not scored: {cut}: {cut}, offset ")
    meta = json.loads((out / "metrics.json").read_text())["meta"]
    assert meta["logs"] == 1 and [line.split(":")[0] for line in meta["logs_not_scored"]] == [str(cut)]
    assert str(cut) in (out / "report.md").read_text() and str(cut) in (out / "report.html").read_text()


@pytest.mark.parametrize("manifest", ["{not json\n", "", "[1, 2, 3]\n"])
def test_a_damaged_manifest_is_named_and_the_logs_beside_it_are_reported(
    annotated: tuple[Path, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str], manifest: str
) -> None:
    """'no drive logs found' was the answer, naming neither the manifest nor the log beside it."""
    _, folder = annotated
    copy = tmp_path / "annotated"
    copy.mkdir()
    for log in folder.glob("*.mcap"):
        (copy / log.name).write_bytes(log.read_bytes())
    (copy / "manifest.jsonl").write_text(manifest)
    assert main(["report", str(copy), "--out", str(tmp_path / "rep")]) == 0
    assert (
        f"{copy / 'manifest.jsonl'}: lists no annotated log; reading the logs in {copy}"
        in capsys.readouterr().err
    )
    assert json.loads((tmp_path / "rep" / "metrics.json").read_text())["meta"]["logs"] == 1
