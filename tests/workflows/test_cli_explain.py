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
