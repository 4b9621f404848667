"""The format registry: one entry per reader and writer, options checked, modules loaded lazily."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pyarrow as pa
import pytest

from lanecast.io_adapters.errors import FormatNotRecognisedError, UsageError
from lanecast.io_adapters.formats import registry, streaming
from lanecast.io_adapters.formats.registry import Pieces

HIGHD = Path(__file__).parents[2] / "data" / "highd"


def test_every_registered_module_provides_its_protocol() -> None:
    for entry in registry.READERS.values():
        module = entry.load()
        assert callable(module.sniff) and callable(module.read), entry.name
        assert entry.options <= registry.READER_OPTIONS
    for writer in registry.WRITERS.values():
        assert callable(writer.load().write), writer.name
    assert registry.READERS["highd"].pieces is Pieces.HIGHD_RECORDINGS
    assert registry.READERS["mcap"].pieces is Pieces.PER_FILE


def test_importing_the_registry_imports_no_reader() -> None:
    code = (
        "import sys; from lanecast.io_adapters.formats import registry; "
        "print(sorted(m for m in sys.modules if m.startswith(('rosbags', 'mcap', 'lanecast.io_adapters.logs')) "
        "or m.endswith(('highd.reader', 'ngsim.reader'))))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"


def test_an_option_no_reader_takes_is_an_error_naming_it() -> None:
    with pytest.raises(UsageError, match=r"^colour: not an option of the registered readers"):
        registry.read_any([HIGHD], colour="red")
    with pytest.raises(UsageError, match=r"^colour: "):
        streaming.plan([HIGHD], options={"colour": "red"})


def test_a_reader_called_with_an_option_it_does_not_take_names_it() -> None:
    with pytest.raises(
        UsageError,
        match=r"^topic: not an option of the highd reader \(expected one of \['recording_prefix'\]\)",
    ):
        registry.READERS["highd"].read([HIGHD], {"topic": "/objects"})


def test_options_of_other_readers_go_only_to_them() -> None:
    plain = registry.read_any([HIGHD])
    table = registry.read_any([HIGHD], location="us-101", topic="/objects", recording_prefix="x")
    assert table.num_rows == plain.num_rows
    names = set(table.column("recording").cast(pa.string()).to_pylist())
    assert names and all(name.startswith("x-01-") for name in names)
    pieces = streaming.plan([HIGHD], options={"location": "us-101", "recording_prefix": "x"})
    assert [p.options for p in pieces] == [(("recording_prefix", "x"),)]


def test_a_writer_option_is_checked(tmp_path: Path) -> None:
    table = registry.read_any([HIGHD])
    with pytest.raises(UsageError, match=r"^storage: not an option of the mcap writer"):
        registry.write_any(table, tmp_path / "a.mcap", "mcap", storage="sqlite3")
    assert not (tmp_path / "a.mcap").exists()
    with pytest.raises(FormatNotRecognisedError, match="unknown output format 'csv'"):
        registry.write_any(table, tmp_path / "a.csv", "csv")


def test_one_walk_finds_the_logs_of_a_folder_tree(tmp_path: Path) -> None:
    """MCAP files, ROS 1 bags and ROS 2 bag directories in name order; not inside a bag, a highD
    folder, a hidden folder or the excluded output; a folder a reader takes whole has no logs."""
    import shutil

    from conftest import TESTS

    root = tmp_path / "logs"
    for name in ("b/2.mcap", "a/1.bag", "a/z.mcap", ".hidden/3.mcap", "out/4.mcap", "notes.txt"):
        (root / name).parent.mkdir(parents=True, exist_ok=True)
        (root / name).write_bytes(b"x")
    bag = root / "c" / "bag"
    bag.mkdir(parents=True)
    (bag / "metadata.yaml").write_text("rosbag2_bagfile_information: {}\n")
    (bag / "inner.mcap").write_bytes(b"x")
    highd = root / "d" / "highd"
    shutil.copytree(TESTS / "data" / "highd", highd)
    (highd / "5.mcap").write_bytes(b"x")
    found = [p.relative_to(root).as_posix() for p in registry.walk_logs(root, os.path.realpath(root / "out"))]
    assert found == ["a/1.bag", "a/z.mcap", "b/2.mcap", "c/bag"]
    assert [p.relative_to(root).as_posix() for p in registry.logs_in(root)][-1] == "out/4.mcap"
    assert registry.logs_in(highd) == [] and registry.logs_in(bag) == []
