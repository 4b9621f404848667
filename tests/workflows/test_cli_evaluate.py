"""`lanecast evaluate`: its report appears whole or not at all."""

from __future__ import annotations

from pathlib import Path

import pytest
from conftest import refused, windows_copy

from lanecast.workflows.cli import main


def test_a_report_appears_whole_or_not_at_all(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """evaluate wrote metrics.json straight into --out, then the report: interrupted (Ctrl-C) or
    failing in between, --out kept a metrics.json without its report. Here report.html cannot be
    written (a directory of that name is in the way): nothing of the run may appear."""
    directory = windows_copy(tmp_path, lambda d: None)
    out = tmp_path / "report"
    (out / "report.html").mkdir(parents=True)
    refused(
        ["evaluate", str(directory), "--out", str(out), "--split", "all"],
        capsys,
        "report.html",
        "is a directory",
    )
    assert [p.name for p in out.iterdir()] == ["report.html"]
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]
    (out / "report.html").rmdir()
    (out / "mine.txt").write_text("kept\n")
    assert main(["evaluate", str(directory), "--out", str(out), "--split", "all"]) == 0
    assert {"metrics.json", "report.html", "mine.txt"} <= {p.name for p in out.iterdir()}
