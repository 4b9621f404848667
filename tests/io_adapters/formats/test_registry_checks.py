"""Format detection on inputs that are no known format: what the file is instead (compressed,
another log kind by its first bytes), and two inputs with one recording name."""

from __future__ import annotations

import gzip
from pathlib import Path

import pytest
from conftest import US101, assert_one_line_error, cli, no_output, refused

from lanecast.io_adapters.contracts import track_table
from lanecast.io_adapters.errors import LanecastError
from lanecast.io_adapters.formats import registry


@pytest.mark.parametrize(
    ("content", "message"),
    [
        (b"", "offset 0: empty file"),
        (
            "Vehicle_ID,Frame_ID\n".encode("utf-16"),
            "offset 0: format not recognised: the file is UTF-16 text",
        ),
        (
            gzip.compress(b"Vehicle_ID,Frame_ID\n"),
            "offset 0: format not recognised: the file is gzip-compressed",
        ),
    ],
)
def test_unrecognised_file_says_what_it_is(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], content: bytes, message: str
) -> None:
    path = tmp_path / "trajectories.csv"
    path.write_bytes(content)
    out = tmp_path / "out.parquet"
    for command in (["convert", str(path), "--out", str(out)], ["info", str(path)]):
        refused(command, capsys, f"{path}, {message}")
    no_output(out)


def test_two_inputs_with_one_recording_name_are_named(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    a = track_table.write_parquet(registry.read_any([US101]), tmp_path / "a.parquet")
    b = tmp_path / "b.parquet"
    b.write_bytes(a.read_bytes())
    status, err = cli(["convert", str(a), str(b), "--out", str(tmp_path / "c.parquet")], capsys)
    assert_one_line_error(status, err.splitlines()[-1], "convert", str(b))
    assert str(a) in err


@pytest.mark.parametrize(
    ("name", "content", "expected"),
    [
        ("log.mcap", b"garbage, not a log", r"an MCAP file, which starts with b'\\x89MCAP0"),
        ("log.bag", b"#ROSX V2.0\n" + bytes(40), r"a ROS 1 bag, which starts with b'#ROSBAG V2\.0"),
        (
            "bag_0.db3",
            b"not sqlite at all" + bytes(40),
            r"SQLite storage, which starts with b'SQLite format 3",
        ),
    ],
)
def test_a_log_named_by_its_suffix_that_is_not_one_names_its_first_bytes(
    tmp_path: Path, name: str, content: bytes, expected: str
) -> None:
    """A file named .mcap, .bag or .db3 whose content is not was only 'format not recognised'."""
    path = tmp_path / name
    path.write_bytes(content)
    with pytest.raises(LanecastError, match=expected) as err:
        registry.read_any([path])
    assert f"{path}, offset 0: format not recognised: the file is named {path.suffix} but starts with" in str(
        err.value
    )
