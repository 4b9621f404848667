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
