"""Progress: whole lines every few seconds and a last one at the end when stderr is not a terminal,
a bar on one that does not say its size, life signs of long steps, and job bars that keep their
parts' bars quiet."""

from __future__ import annotations

import os
import pty
import sys
import time

import pytest

from lanecast.io_adapters import progress


def test_piped_progress_writes_plain_lines_ending_with_the_final_count(
    capfd: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(progress, "LINE_INTERVAL_S", 0.0)
    assert list(progress.progress(range(3), desc="report", unit="log")) == [0, 1, 2]
    err = capfd.readouterr().err
    assert "\r" not in err and "█" not in err
    lines = err.splitlines()
    assert lines[0].startswith("report: 0/3 log (0%)")
    assert lines[-1].startswith("report: 3/3 log (100%)")


def test_piped_progress_is_rate_limited_and_a_postfix_forces_no_line(
    capfd: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(progress, "LINE_INTERVAL_S", 3600.0)
    shown = progress.bar(desc="annotate", total=100, unit="log")
    for i in range(100):
        shown.update(1)
        shown.set_postfix_str(f"{i} msgs")
    shown.write("annotate: FAILED x.mcap")
    shown.close()
    captured = capfd.readouterr()
    assert captured.out == "annotate: FAILED x.mcap\n"
    lines = captured.err.splitlines()
    assert len(lines) == 2 and lines[0] == "annotate: 0/100 log (0%) [00:00<?, ?log/s]"
    assert lines[-1].startswith("annotate: 100/100 log (100%)") and lines[-1].endswith("99 msgs]")


def test_an_activity_says_what_it_does_when_it_starts_and_when_it_ends(
    capsys: pytest.CaptureFixture[str],
) -> None:
    with progress.activity("export: tracing"):
        time.sleep(1.2)
    lines = capsys.readouterr().err.splitlines()
    assert lines[0] == "export: tracing (00:00)"
    assert lines[-1].startswith("export: tracing (00:0") and lines[-1] != lines[0]


def test_an_activity_that_fails_leaves_the_error_as_the_last_word(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(ValueError, match="bad"), progress.activity("windows: cutting"):
        time.sleep(1.2)
        raise ValueError("bad")
    assert capsys.readouterr().err.splitlines() == ["windows: cutting (00:00)"]


def test_a_terminal_without_a_size_still_gets_a_visible_bar(monkeypatch: pytest.MonkeyPatch) -> None:
    leader, follower = pty.openpty()  # a fresh pty says 0 columns, 0 rows, as `script -qc` does
    try:
        with os.fdopen(follower, "w", closefd=False) as terminal:
            monkeypatch.setattr(sys, "stderr", terminal)
            assert terminal.isatty() and os.get_terminal_size(follower).columns == 0
            with progress.bar(desc="convert", total=10, unit="recording") as shown:
                assert shown.terminal
                shown.update(3)
            terminal.flush()
        written = os.read(leader, 4096).decode("utf-8", "replace")
        assert "convert:" in written and "0/10" in written  # drawn: before, a bar of no width
        drawn = written.split("\r")[1].removesuffix("\x1b[K")
        assert len(drawn) == progress.DEFAULT_COLUMNS - 1 and "|" in drawn
    finally:
        os.close(leader)
        os.close(follower)


def test_a_job_bar_keeps_the_bars_of_its_parts_quiet(capsys: pytest.CaptureFixture[str]) -> None:
    with progress.job_progress(desc="convert", total=3, unit="piece") as job:
        for _ in range(3):
            for _ in progress.progress(range(1), desc="highD", unit="recording"):
                pass
            job.update(1)
    err = capsys.readouterr().err
    assert "highD" not in err and "convert: 3/3 piece" in err
    for _ in progress.progress(range(1), desc="highD", unit="recording"):  # alone again: shown
        pass
    assert "highD: 1/1 recording" in capsys.readouterr().err
