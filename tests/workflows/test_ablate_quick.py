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
