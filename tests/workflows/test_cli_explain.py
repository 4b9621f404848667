"""`lanecast explain` on a windows dataset missing a file names the file."""

from __future__ import annotations

from pathlib import Path

import pytest
from conftest import no_output, refused, windows_copy


@pytest.mark.parametrize("missing", ["inputs.npy", "manifest.json"])
def test_explain_on_a_windows_dataset_missing_a_file_names_it(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], missing: str
) -> None:
    """Without inputs.npy or manifest.json a windows dataset was read as a Parquet track table
    (its windows.parquet): 'win/windows.parquet: missing column 'frame''."""
    directory = windows_copy(tmp_path, lambda d: (d / missing).unlink())
    out = tmp_path / "explain"
    refused(
        ["explain", str(directory), "--track", "1", "--time", "5", "--out", str(out)],
        capsys,
        f"error: {directory / missing}: missing file of a windows dataset",
    )
    no_output(out)


def test_explain_names_its_options_not_a_column(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A track or time with no window was 'column '--track/--time'', as if a CSV column were wrong."""
    from conftest import synthetic_windows

    from lanecast.io_adapters.windows_store.dataset import save_windows
    from lanecast.workflows.cli import main

    windows = save_windows(synthetic_windows(50), tmp_path / "w")
    assert (
        main(["explain", str(windows), "--track", "99999", "--time", "3", "--out", str(tmp_path / "e")]) == 2
    )
    err = capsys.readouterr().err
    assert "column" not in err and f"{windows}: --track 99999 --time 3: no window of track 99999" in err, err
