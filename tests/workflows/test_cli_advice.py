"""Errors that say what to do: a dataset release folder, a dataset given where windows go, a mistyped command."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from lanecast.workflows.cli import main

HIGHD = Path(__file__).resolve().parents[1] / "data" / "highd"


def _error(capsys: pytest.CaptureFixture[str]) -> str:
    err = capsys.readouterr().err.strip()
    assert "Traceback" not in err
    return err.splitlines()[-1]


def test_a_release_folder_names_the_folder_that_holds_the_recordings(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    release = tmp_path / "highD-dataset-v1.0"
    shutil.copytree(HIGHD, release / "data")
    (release / "Format.pdf").write_bytes(b"%PDF-1.4\n")
    for command in (["convert", str(release), "--out", str(tmp_path / "x.parquet")], ["info", str(release)]):
        assert main(command) == 2
        line = _error(capsys)
        assert f"{release}: format not recognised here, but its folder data/ holds" in line, line
        assert f"expected the folder itself: {release / 'data'}" in line, line
    assert not (tmp_path / "x.parquet").exists()


@pytest.mark.parametrize("command", ["train", "evaluate"])
def test_a_dataset_given_where_windows_go_says_to_run_windows_first(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], command: str
) -> None:
    assert main([command, str(HIGHD), "--out", str(tmp_path / "out")]) == 2
    line = _error(capsys)
    assert f"{HIGHD}: not a windows dataset" in line, line
    assert f"run `lanecast windows {HIGHD} --out windows/highd` first" in line, line
    assert not (tmp_path / "out").exists()


def test_a_mistyped_command_gets_a_did_you_mean(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exit_:
        main(["trian", "windows/sim", "--out", "runs/model"])
    assert exit_.value.code == 2
    assert "unknown command 'trian'; did you mean 'train'?" in _error(capsys)
    with pytest.raises(SystemExit):
        main(["frobnicate"])
    line = _error(capsys)
    assert "unknown command 'frobnicate' (commands: demo, simulate, convert" in line and "did you" not in line
