"""annotate names the model that made its forecasts, with the checksum of its weights and its training data."""

from __future__ import annotations

from pathlib import Path

import pytest

from lanecast.models.card import provenance
from lanecast.workflows.cli import main

HIGHD = Path(__file__).resolve().parents[1] / "data" / "highd"


def test_the_annotate_summary_names_the_model(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    log = tmp_path / "logs" / "sim.mcap"
    assert main(["convert", str(HIGHD), "--out", str(log)]) == 0
    capsys.readouterr()
    assert main(["annotate", str(log.parent), "--out", str(tmp_path / "annotated")]) == 0
    out = capsys.readouterr().out
    sha = provenance(None)["sha256"]
    assert (
        f"model: the shipped model (stcnn-sumo) (sha256 {sha[:12]}), trained on 8 simulated recordings" in out
    )


def test_the_annotate_summary_names_out_as_the_user_gave_it(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(tmp_path)
    assert main(["convert", str(HIGHD), "--out", "sim.mcap"]) == 0
    capsys.readouterr()
    assert main(["annotate", "sim.mcap", "--out", "annotated"]) == 0
    first = capsys.readouterr().out.splitlines()[0]
    assert first.endswith("-> annotated (manifest: annotated/manifest.jsonl)"), first


def test_an_annotated_log_and_its_report_name_the_model(
    tmp_path: Path, sim_recording_dir: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from mcap.reader import make_reader

    log = tmp_path / "logs" / "sim.mcap"
    assert main(["convert", str(sim_recording_dir), "--out", str(log)]) == 0
    assert main(["annotate", str(log), "--out", str(tmp_path / "annotated")]) == 0
    annotated = tmp_path / "annotated" / "sim.mcap"
    with annotated.open("rb") as fh:
        summary = make_reader(fh).get_summary()
    assert summary is not None
    forecast = next(c for c in summary.channels.values() if c.topic == "/lanecast/forecast")
    prov = provenance(None)
    assert forecast.metadata == {
        "model": prov["model"],
        "model_sha256": prov["sha256"],
        "model_trained_on": prov["trained_on"],
    }
    capsys.readouterr()
    assert main(["report", str(annotated), "--out", str(tmp_path / "report")]) == 0
    assert (
        f"forecasts by model: the shipped model (stcnn-sumo) (sha256 {prov['sha256'][:12]})"
        in capsys.readouterr().out
    )
    page = (tmp_path / "report" / "report.html").read_text()
    assert prov["sha256"] in page and prov["trained_on"] in page


def test_an_annotated_ros2_bag_names_the_model_in_its_metadata_and_info_shows_it(
    tmp_path: Path, sim_recording_dir: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from ruamel.yaml import YAML

    bag = tmp_path / "logs" / "sim-bag"
    assert main(["convert", str(sim_recording_dir), "--to", "ros2", "--out", str(bag)]) == 0
    assert main(["annotate", str(bag), "--out", str(tmp_path / "annotated")]) == 0
    annotated = tmp_path / "annotated" / "sim-bag"
    info = YAML(typ="safe").load((annotated / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    prov = provenance(None)
    assert {k: v for k, v in info["custom_data"].items() if k.startswith("lanecast.forecast.")} == {
        "lanecast.forecast.model": prov["model"],
        "lanecast.forecast.model_sha256": prov["sha256"],
        "lanecast.forecast.model_trained_on": prov["trained_on"],
    }
    capsys.readouterr()
    for log in (annotated, bag):
        assert main(["info", str(log)]) == 0
        out = capsys.readouterr().out
        named = f"forecasts by model: the shipped model (stcnn-sumo) (sha256 {prov['sha256'][:12]})" in out
        assert named == (log == annotated), out
    assert main(["report", str(annotated), "--out", str(tmp_path / "report")]) == 0
    assert f"forecasts by model: the shipped model (stcnn-sumo) (sha256 {prov['sha256'][:12]})" in (
        capsys.readouterr().out
    )


def test_info_on_an_annotated_mcap_names_the_model(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    log = tmp_path / "logs" / "sim.mcap"
    assert main(["convert", str(HIGHD), "--out", str(log)]) == 0
    assert main(["annotate", str(log), "--out", str(tmp_path / "annotated")]) == 0
    capsys.readouterr()
    assert main(["info", str(tmp_path / "annotated" / "sim.mcap")]) == 0
    sha = provenance(None)["sha256"]
    assert f"  forecasts by model: the shipped model (stcnn-sumo) (sha256 {sha[:12]}), trained on" in (
        capsys.readouterr().out
    )
