"""Every command replaces only what lanecast wrote: a user's own Parquet, MCAP or report is refused, named,
and left as it was, unless --force; lanecast's own earlier outputs are replaced as a rerun expects."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from conftest import make_track_table, synthetic_windows
from mcap.writer import Writer

from lanecast.io_adapters.ownership import lanecast_wrote
from lanecast.io_adapters.windows_store.dataset import save_windows
from lanecast.workflows.cli import main

HIGHD = Path(__file__).resolve().parents[1] / "data" / "highd"


def _last_error(capsys: pytest.CaptureFixture[str]) -> str:
    err = capsys.readouterr().err.strip()
    assert "Traceback" not in err
    return err.splitlines()[-1] if err else ""


def _user_mcap(path: Path) -> bytes:
    with path.open("wb") as fh:
        writer = Writer(fh)
        writer.start(profile="", library="my-recorder")
        schema = writer.register_schema("std_msgs/String", "ros2msg", b"string data")
        channel = writer.register_channel("/chatter", "cdr", schema)
        writer.add_message(channel, log_time=1, publish_time=1, data=b"\x00\x01\x00\x00\x02\x00\x00\x00a\x00")
        writer.finish()
    return path.read_bytes()


def test_convert_refuses_a_users_parquet_and_mcap_and_replaces_them_with_force(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    user_table = tmp_path / "user.parquet"
    pq.write_table(pa.table({"a": [1, 2, 3]}), user_table)
    user_log = tmp_path / "userlog.mcap"
    log_bytes = _user_mcap(user_log)
    for out in (user_table, user_log):
        before = out.read_bytes()
        assert main(["convert", str(HIGHD), "--out", str(out)]) == 2
        line = _last_error(capsys)
        assert str(out) in line and "not an output of lanecast's, so it is not replaced" in line, line
        assert "--force" in line
        assert out.read_bytes() == before
    assert log_bytes == user_log.read_bytes()
    assert main(["convert", str(HIGHD), "--out", str(user_table), "--force"]) == 0
    assert lanecast_wrote(user_table)
    assert main(["convert", str(HIGHD), "--out", str(user_table)]) == 0  # its own output: replaced
    capsys.readouterr()


def test_convert_replaces_its_own_mcap_but_not_a_users_ros2_bag(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    log = tmp_path / "sim.mcap"
    for _ in range(2):
        assert main(["convert", str(HIGHD), "--out", str(log)]) == 0
    assert lanecast_wrote(log)
    bag = tmp_path / "bag"
    bag.mkdir()
    (bag / "metadata.yaml").write_text("rosbag2_bagfile_information:\n  version: 5\n")
    (bag / "bag_0.mcap").write_bytes(b"\x89MCAP0\r\n")
    assert main(["convert", str(HIGHD), "--to", "ros2", "--out", str(bag)]) == 2
    assert "not an output of lanecast's" in _last_error(capsys)
    assert (bag / "bag_0.mcap").read_bytes() == b"\x89MCAP0\r\n"
    assert main(["convert", str(HIGHD), "--to", "ros2", "--out", str(tmp_path / "own")]) == 0
    assert lanecast_wrote(tmp_path / "own")


def test_evaluate_and_report_refuse_a_users_report_before_any_work(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    windows = save_windows(synthetic_windows(200, seed=1), tmp_path / "windows")
    out = tmp_path / "myreport"
    out.mkdir()
    mine = out / "report.html"
    mine.write_text("<html><body>my own notes</body></html>")
    for command in (["evaluate", str(windows)], ["report", str(tmp_path / "nothing-here")]):
        assert main([*command, "--out", str(out)]) == 2
        line = _last_error(capsys)
        assert str(mine) in line and "not replaced" in line, line
        assert mine.read_text() == "<html><body>my own notes</body></html>"
    assert main(["evaluate", str(windows), "--out", str(out), "--split", "all", "--force"]) == 0
    assert lanecast_wrote(mine) and lanecast_wrote(out / "report.md") and lanecast_wrote(out / "metrics.json")
    assert main(["evaluate", str(windows), "--out", str(out), "--split", "all"]) == 0  # its own: replaced
    capsys.readouterr()


def _windowable_table(tmp_path: Path) -> Path:
    """Two cars driving 6 s side by side: windows to cut."""
    frames = np.arange(60)
    columns = {
        "track_id": np.repeat([1, 2], 60),
        "frame": np.tile(frames, 2),
        "x": np.tile(frames * 2.5, 2),
        "y": np.repeat([1.75, 5.25], 60),
        "vx": np.full(120, 25.0),
        "lane_id": np.repeat([1, 2], 60),
    }
    path = tmp_path / "table.parquet"
    pq.write_table(make_track_table(columns), path)
    return path


def test_windows_refuses_a_folder_of_a_users_files_and_replaces_it_with_force(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    table = str(_windowable_table(tmp_path))
    out = tmp_path / "mine"
    out.mkdir()
    (out / "notes.txt").write_text("keep me")
    assert main(["windows", table, "--out", str(out), "--no-future"]) == 2
    line = _last_error(capsys)
    assert str(out) in line and "'notes.txt'" in line, line
    assert (out / "notes.txt").read_text() == "keep me"
    assert main(["windows", table, "--out", str(out), "--no-future", "--force"]) == 0
    assert not (out / "notes.txt").exists() and (out / "manifest.json").is_file()
    assert main(["windows", table, "--out", str(out), "--no-future"]) == 0  # its own: replaced
    capsys.readouterr()


def test_windows_force_never_deletes_a_tree_or_the_working_directory(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    out = tmp_path / "project"
    (out / "src").mkdir(parents=True)
    assert main(["windows", str(HIGHD), "--out", str(out), "--no-future", "--force"]) == 2
    assert "holds the folder 'src'" in _last_error(capsys)
    assert (out / "src").is_dir()
    (out / "src").rmdir()
    (out / "a.txt").write_text("a")
    monkeypatch.chdir(out)
    assert main(["windows", str(HIGHD), "--out", ".", "--no-future", "--force"]) == 2
    assert "working directory" in _last_error(capsys)
    assert (out / "a.txt").read_text() == "a"


def test_simulate_refuses_an_existing_recording_and_replaces_it_with_force(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "sim"
    out.mkdir()
    tracks = out / "01_tracks.csv"
    tracks.write_text("mine\n")
    args = ["simulate", "--out", str(out), "--minutes", "0.5", "--seed", "1", "--density", "low"]
    assert main(args) == 2
    line = _last_error(capsys)
    assert str(tracks) in line and "never overwrites" in line, line
    assert tracks.read_text() == "mine\n"
    assert main([*args, "--force"]) == 0
    assert tracks.read_text().startswith("frame,")
    assert {p.name for p in out.iterdir()} == {"01_tracks.csv", "01_tracksMeta.csv", "01_recordingMeta.csv"}
    capsys.readouterr()
