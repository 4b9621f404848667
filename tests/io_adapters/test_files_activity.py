"""Life signs of long steps: a line when a step starts and while it runs, and bars that show on a terminal
that does not say its size."""

from __future__ import annotations

import os
import pty
import sys
import time

import pytest

from lanecast.io_adapters import files


def test_an_activity_says_what_it_does_when_it_starts_and_when_it_ends(
    capsys: pytest.CaptureFixture[str],
) -> None:
    with files.activity("export: tracing"):
        time.sleep(1.2)
    lines = capsys.readouterr().err.splitlines()
    assert lines[0] == "export: tracing (00:00)"
    assert lines[-1].startswith("export: tracing (00:0") and lines[-1] != lines[0]


def test_an_activity_that_fails_leaves_the_error_as_the_last_word(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(ValueError, match="bad"), files.activity("windows: cutting"):
        time.sleep(1.2)
        raise ValueError("bad")
    assert capsys.readouterr().err.splitlines() == ["windows: cutting (00:00)"]


def test_a_terminal_without_a_size_still_gets_a_visible_bar(monkeypatch: pytest.MonkeyPatch) -> None:
    leader, follower = pty.openpty()  # a fresh pty says 0 columns, 0 rows, as `script -qc` does
    try:
        with os.fdopen(follower, "w", closefd=False) as terminal:
            monkeypatch.setattr(sys, "stderr", terminal)
            assert terminal.isatty() and os.get_terminal_size(follower).columns == 0
            kwargs = files._bar_kwargs(10)
            assert kwargs["ncols"] == 80 and kwargs["nrows"] > 1
            with files.bar(desc="convert", total=10, unit="recording") as shown:
                shown.update(3)
            terminal.flush()
        written = os.read(leader, 4096).decode("utf-8", "replace")
        assert "convert:" in written and "0/10" in written  # drawn: before, a bar of no width
    finally:
        os.close(leader)
        os.close(follower)


def test_a_job_bar_keeps_the_bars_of_its_parts_quiet(capsys: pytest.CaptureFixture[str]) -> None:
    with files.job_progress(desc="convert", total=3, unit="piece") as job:
        for _ in range(3):
            for _ in files.progress(range(1), desc="highD", unit="recording"):
                pass
            job.update(1)
    err = capsys.readouterr().err
    assert "highD" not in err and "convert: 3/3 piece" in err
    for _ in files.progress(range(1), desc="highD", unit="recording"):  # alone again: shown
        pass
    assert "highD: 1/1 recording" in capsys.readouterr().err
