"""A new user's first run: --help on any terminal, reports in any locale, no warnings about HOME,
the demo's --out."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import synthetic_windows

from lanecast.io_adapters.contracts.windows import save_windows
from lanecast.workflows import cli, demo

REPO = Path(__file__).resolve().parents[1]


def lanecast(*args: str, env: dict[str, str], cwd: Path) -> subprocess.CompletedProcess[str]:
    """`python -m lanecast ARGS` in a new process with ``env`` on top of this one's; output as bytes
    decoded as UTF-8 (what a UTF-8 terminal would show)."""
    done = subprocess.run(
        [sys.executable, "-m", "lanecast", *args],
        env={**os.environ, "PYTHONPATH": str(REPO), **env},
        cwd=cwd,
        capture_output=True,
        timeout=300,
    )
    return subprocess.CompletedProcess(
        done.args, done.returncode, done.stdout.decode("utf-8"), done.stderr.decode("utf-8")
    )


@pytest.mark.parametrize("encoding", ["ascii", "latin-1"])
def test_help_on_a_terminal_that_is_not_utf8(encoding: str, tmp_path: Path) -> None:
    """`lanecast demo --help` printed a traceback at its first arrow; now arrows are spelled."""
    done = lanecast("demo", "--help", env={"PYTHONIOENCODING": encoding}, cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    assert "SUMO traffic -> track table -> MCAP drive log" in done.stdout
    assert done.stderr == ""


def test_unencodable_characters_are_spelled_and_file_name_bytes_kept() -> None:
    """The error handler cli registers for stdout and stderr: ASCII spellings, "?", a name's own bytes."""
    assert cli.ASCII_SPELLING["→"] == "->"
    text = "a → b … 3 × 4 ≥ 2 ✓ \udce9t\udce9.mcap"
    assert text.encode("ascii", errors="lanecast-ascii") == b"a -> b ... 3 x 4 >= 2 ? \xe9t\xe9.mcap"


@pytest.mark.slow
def test_reports_are_utf8_in_an_ascii_locale(tmp_path: Path) -> None:
    """In a C locale without UTF-8 mode, writing report.md (an en dash, ±) raised UnicodeEncodeError."""
    save_windows(synthetic_windows(300, seed=2), tmp_path / "windows")
    env = {"PYTHONUTF8": "0", "LC_ALL": "C", "LANG": "C"}
    done = lanecast("evaluate", "windows", "--out", "report", env=env, cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    assert "–" in (tmp_path / "report" / "report.md").read_text(encoding="utf-8")
    assert "<meta charset='utf-8'>" in (tmp_path / "report" / "report.html").read_text(encoding="utf-8")


def test_matplotlib_without_a_writable_home_says_nothing(tmp_path: Path) -> None:
    """HOME unset or read-only: matplotlib's two lines about a temporary config directory are not shown."""
    (tmp_path / "home").write_text("a file, not a directory: no config directory can be made in it")
    env = {k: v for k, v in os.environ.items() if not k.startswith(("MPL", "XDG_"))}
    done = subprocess.run(
        [sys.executable, "-c", "from lanecast.models.report_plots import pyplot; pyplot().figure()"],
        env={**env, "HOME": str(tmp_path / "home"), "PYTHONPATH": str(REPO)},
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 0, done.stderr
    assert done.stderr == ""


# ------------------------------------------------------------------------------------ demo --out


def test_demo_refuses_an_out_holding_what_it_did_not_write(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """`lanecast demo --out .` beside one's own tracks.parquet overwrote it; now it is refused before
    anything is simulated."""
    mine = tmp_path / "tracks.parquet"
    mine.write_bytes(b"my own table")
    assert cli.main(["demo", "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert f"{mine}: exists and was not written by `lanecast demo`" in err
    assert mine.read_bytes() == b"my own table"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["tracks.parquet"]


def test_demo_claims_a_new_empty_or_previous_demo_directory(tmp_path: Path) -> None:
    demo.claim(tmp_path / "new" / "demo")  # created, parents too
    assert (tmp_path / "new" / "demo" / demo.MARK).is_file()
    (tmp_path / "empty").mkdir()
    demo.claim(tmp_path / "empty")
    (tmp_path / "empty" / "tracks.parquet").write_bytes(b"the demo's own")
    demo.claim(tmp_path / "empty")  # a rerun: its mark says the outputs are the demo's
    (tmp_path / "other").mkdir()
    (tmp_path / "other" / "notes.txt").write_text("unrelated")
    demo.claim(tmp_path / "other")  # nothing the demo writes is there: it writes beside it


def test_demo_refuses_a_file_as_out(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    (tmp_path / "f").write_text("x")
    assert cli.main(["demo", "--out", str(tmp_path / "f")]) == 2
    assert "exists and is not a directory" in capsys.readouterr().err
