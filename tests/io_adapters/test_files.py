"""Progress when stderr is not a terminal: whole lines, every few seconds, and a last one at the end."""

from __future__ import annotations

import pytest

from lanecast.io_adapters import files


def test_piped_progress_writes_plain_lines_ending_with_the_final_count(
    capfd: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(files, "LINE_INTERVAL_S", 0.0)
    assert list(files.progress(range(3), desc="report", unit="log")) == [0, 1, 2]
    err = capfd.readouterr().err
    assert "\r" not in err and "█" not in err
    lines = err.splitlines()
    assert lines[0].startswith("report: 0/3 log (0%)")
    assert lines[-1].startswith("report: 3/3 log (100%)")


def test_piped_progress_is_rate_limited_and_a_postfix_forces_no_line(
    capfd: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(files, "LINE_INTERVAL_S", 3600.0)
    shown = files.bar(desc="annotate", total=100, unit="log")
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
