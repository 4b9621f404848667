"""Inputs with the same recording names combine: the later input's names are qualified by where it came
from, in windows, convert and info alike; the same data given twice is still refused."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from lanecast.io_adapters.contracts.recording_names import distinct_names
from lanecast.io_adapters.contracts.track_schema import RecordingMeta, TableMeta
from lanecast.io_adapters.errors import TrackTableError
from lanecast.workflows.cli import main


def _meta(name: str, files: list[str]) -> TableMeta:
    return TableMeta("highd", {name: RecordingMeta(25.0, source_files=files)}, files)


def test_distinct_names_qualifies_by_folder_and_refuses_the_same_files() -> None:
    a, b = _meta("r-01", ["sim1/01_tracks.csv"]), _meta("r-01", ["sim2/01_tracks.csv"])
    assert distinct_names([a, b], ["sim1", "sim2"]) == [{}, {"r-01": "r-01@sim2"}]
    c = _meta("r-01", ["other/sim2/01_tracks.csv"])  # its folder's name is taken: the input's name
    assert distinct_names([a, b, c], ["sim1", "sim2", "x.parquet"]) == [
        {},
        {"r-01": "r-01@sim2"},
        {"r-01": "r-01@x"},
    ]
    with pytest.raises(TrackTableError, match="the same data given twice"):
        distinct_names([a, _meta("r-01", ["sim1/01_tracks.csv"])], ["sim1", "copy.parquet"])


@pytest.fixture
def two_simulations(tmp_path: Path, sim_recording_dir: Path) -> tuple[Path, Path]:
    """Two folders of one simulated recording number (simulate's default --recording-id 1)."""
    for sub in ("sim1", "sim2"):
        shutil.copytree(sim_recording_dir, tmp_path / sub)
    return tmp_path / "sim1", tmp_path / "sim2"


def test_two_recordings_of_one_number_window_convert_and_summarise_together(
    two_simulations: tuple[Path, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    sim1, sim2 = two_simulations
    assert main(["convert", str(sim1), "--out", str(tmp_path / "a.parquet")]) == 0
    assert main(["convert", str(sim2), "--out", str(tmp_path / "b.parquet")]) == 0
    assert main(["convert", str(sim1), str(sim2), "--out", str(tmp_path / "both.parquet")]) == 0
    capsys.readouterr()
    assert main(["info", str(tmp_path / "a.parquet"), str(tmp_path / "b.parquet")]) == 0
    out = capsys.readouterr().out  # info describes each input on its own
    blocks = [line for line in out.splitlines() if not line.startswith(" ")]
    assert blocks == [str(tmp_path / "a.parquet"), str(tmp_path / "b.parquet")] and "@" not in out
    assert main(["info", str(tmp_path / "both.parquet")]) == 0
    assert "highd-01-lower@sim2 " in capsys.readouterr().out
    for inputs, out_dir in (([sim1, sim2], "w1"), ([tmp_path / "a.parquet", tmp_path / "b.parquet"], "w2")):
        status = main(["windows", *map(str, inputs), "--out", str(tmp_path / out_dir)])
        err = capsys.readouterr().err
        assert status == 0, err
        recordings = json.loads((tmp_path / out_dir / "manifest.json").read_text())["sources"]["recordings"]
        assert "highd-01-lower" in recordings and any(n.startswith("highd-01-lower@") for n in recordings)
