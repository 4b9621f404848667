"""ablate --quick says in every output that it compares nothing, and names no winner."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from conftest import synthetic_windows

from lanecast.io_adapters.windows_store.dataset import save_windows
from lanecast.workflows.cli import main


@pytest.mark.slow
def test_a_quick_ablation_warns_in_every_output_and_bolds_no_winner(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    windows = save_windows(synthetic_windows(300, seed=2), tmp_path / "windows")
    out = tmp_path / "ablation"
    argv = ["ablate", str(windows), "--out", str(out), "--variants", "no_dilation,full", "--seeds", "1"]
    assert main([*argv, "--quick", "--epochs", "1"]) == 0
    printed = capsys.readouterr().out
    assert "report.md, ablation.png and" in printed and "report.html" in printed
    doc = json.loads((out / "ablation.json").read_text())
    assert "do not compare the variants" in doc["quick_warning"]
    page = (out / "report.html").read_text()
    assert "Quick run:" in page and "do not compare the variants" in page
    assert "<b>" not in page.split("Quick run:")[1]  # no bold winner in any table
    assert "**Quick run:" in (out / "report.md").read_text()
    headline = doc["headline"]
    assert (
        headline["winner"] in ("no_dilation", "full") and headline["n_windows"] == doc["scored_on"]["windows"]
    )
    (comparison,) = headline["comparisons"]
    assert comparison["against"] == ({"no_dilation", "full"} - {headline["winner"]}).pop()
    assert (
        comparison["difference_m"] <= 0
        and comparison["low"] <= comparison["difference_m"] <= comparison["high"]
    )
    assert comparison["significant"] == (comparison["high"] < 0)
    assert headline["text"] in page and "A quick run: these figures do not compare the variants." in page
    assert headline["text"] in printed

    from lanecast.models.reports.ablation import write_ablation_report

    doc.pop("quick_warning")  # the same figures from a full run: the answer leads, in bold
    page = write_ablation_report(tmp_path / "full", doc).read_text()
    assert f"<p><b>{headline['text']}</b></p>" in page
    assert f"**{headline['text']}**" in (tmp_path / "full" / "report.md").read_text()
