"""A folder of drive logs is its logs: info describes each (with its topics), convert reads them all."""

from __future__ import annotations

from pathlib import Path

import pytest

from lanecast.workflows.cli import main

HIGHD = Path(__file__).resolve().parents[1] / "data" / "highd"


def test_info_on_a_folder_of_logs_describes_each_log(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    logs = tmp_path / "logs"
    assert main(["convert", str(HIGHD), "--out", str(logs / "sim.mcap")]) == 0
    assert main(["convert", str(HIGHD), "--to", "ros2", "--out", str(logs / "sim-bag")]) == 0
    capsys.readouterr()
    assert main(["info", str(logs)]) == 0
    captured = capsys.readouterr()
    assert "metadata.yaml" not in captured.err
    blocks = [line for line in captured.out.splitlines() if not line.startswith(" ")]
    assert blocks == [str(logs / "sim-bag"), str(logs / "sim.mcap")]
    assert f"topics of {logs / 'sim.mcap'} (2; messages" in captured.out
    assert main(["info", str(logs / "sim.mcap"), str(logs / "sim-bag")]) == 0  # two logs of one table
    capsys.readouterr()


def test_convert_reads_every_log_of_a_folder(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    logs = tmp_path / "logs"
    assert main(["convert", str(HIGHD), "--out", str(logs / "a.mcap")]) == 0
    assert main(["convert", str(HIGHD), "--out", str(logs / "nested" / "b.mcap")]) == 0
    capsys.readouterr()
    status = main(["convert", str(logs), "--out", str(tmp_path / "all.parquet")])
    # the two logs hold the same recordings from the same source files: the same data twice
    assert status == 2
    assert "the same data given twice" in capsys.readouterr().err
    assert main(["convert", str(logs / "nested"), "--out", str(tmp_path / "one.parquet")]) == 0
