"""`lanecast windows` on tracks that give no windows names the input."""

from __future__ import annotations

from pathlib import Path

import pytest
from conftest import highd_copy, no_output, refused, set_cell, track_table_copy


def test_windows_of_tracks_without_a_10hz_sample(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """At 1 kHz every track of the fixture lasts milliseconds: no sample at 10 Hz, so no windows
    (resampling gave an empty table, which crashed the lane-change labels)."""
    rec = highd_copy(tmp_path, "recordingMeta", set_cell("frameRate", "1000"))
    out = tmp_path / "win"
    refused(["windows", str(rec), "--out", str(out)], capsys, "no windows", "no rows at 10 Hz")
    no_output(out)


def test_no_windows_names_the_table_given(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A converted table without windows blamed the highD CSVs it was once converted from (its
    metadata's source files), which may not even exist here; an empty one said '<input>'."""
    for name, edit in (("short", None), ("empty", lambda t: t.slice(0, 0))):
        (tmp_path / name).mkdir()
        path = track_table_copy(tmp_path / name, edit)
        out = tmp_path / name / "win"
        line = refused(["windows", str(path), "--out", str(out)], capsys, f"error: {path}: no windows")
        assert "01_tracks.csv" not in line
        no_output(out)
