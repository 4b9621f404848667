"""Which adapter reads or writes which format, and format detection.

Every reader module exposes ``FORMAT`` (its name), ``sniff(path) -> bool`` (cheap look at the
first bytes or the file name) and ``read(paths, **options) -> pa.Table`` returning a validated track
table. Every writer module exposes ``write(table, out, fmt, **options) -> Path``. Modules are
imported only when used, so that `lanecast --help` stays fast.
"""

from __future__ import annotations

import importlib
from collections.abc import Sequence
from pathlib import Path
from types import ModuleType
from typing import Any

import pyarrow as pa

from lanecast.io_adapters.contracts import track_table
from lanecast.io_adapters.datasets.csv_errors import not_text
from lanecast.io_adapters.errors import FormatNotRecognisedError
from lanecast.io_adapters.files import check_input, first_of

READERS: dict[str, str] = {
    "parquet": "lanecast.io_adapters.datasets.parquet.tables",
    "highd": "lanecast.io_adapters.datasets.highd.reader",
    "ngsim": "lanecast.io_adapters.datasets.ngsim.reader",
    "mcap": "lanecast.io_adapters.logs.mcap.reader",
    "rosbag": "lanecast.io_adapters.logs.rosbag.reader",
}
WRITERS: dict[str, str] = {
    "parquet": "lanecast.io_adapters.datasets.parquet.tables",
    "mcap": "lanecast.io_adapters.logs.mcap.writer",
    "ros2": "lanecast.io_adapters.logs.rosbag.writer",
    "ros1": "lanecast.io_adapters.logs.rosbag.writer",
}


# Options that only some readers take (the others never see them): NGSIM's ``location``.
READER_ONLY_OPTIONS: dict[str, tuple[str, ...]] = {"location": ("ngsim",)}


def options_for(fmt: str, options: dict[str, Any]) -> dict[str, Any]:
    """``options`` without those meant for other readers (see ``READER_ONLY_OPTIONS``)."""
    return {k: v for k, v in options.items() if fmt in READER_ONLY_OPTIONS.get(k, (fmt,))}


def reader(fmt: str) -> ModuleType:
    if fmt not in READERS:
        raise FormatNotRecognisedError(
            None, f"unknown input format {fmt!r}", expected=f"one of {sorted(READERS)}"
        )
    return importlib.import_module(READERS[fmt])


def writer(fmt: str) -> ModuleType:
    if fmt not in WRITERS:
        raise FormatNotRecognisedError(
            None, f"unknown output format {fmt!r}", expected=f"one of {sorted(WRITERS)}"
        )
    return importlib.import_module(WRITERS[fmt])


#: What a file named with these suffixes starts with (a file that does not is named with its first bytes).
SUFFIX_MAGIC = {
    ".mcap": ("an MCAP file", b"\x89MCAP0\r\n"),
    ".bag": ("a ROS 1 bag", b"#ROSBAG V2.0\n"),
    ".parquet": ("a Parquet file", b"PAR1"),
    ".db3": ("a ROS 2 bag's SQLite storage", b"SQLite format 3\x00"),
}


def detect(path: str | Path) -> str:
    """The name of the format of ``path`` (a file, or a directory such as a ROS 2 bag)."""
    path = check_input(path)
    for fmt in READERS:
        if reader(fmt).sniff(path):
            return fmt
    expected = "a highD or NGSIM CSV, an NGSIM .txt, Parquet, MCAP or a ROS bag"
    if path.is_file():  # say what it is where that is plain from its first bytes
        with path.open("rb") as fh:
            head = fh.read(4096)
        if not head.strip():
            raise FormatNotRecognisedError(path, "empty file", offset=0, expected=expected)
        kind = not_text(head)
        if kind is not None:
            raise FormatNotRecognisedError(
                path, f"format not recognised: the file is {kind}", offset=0, expected=expected
            )
        magic = SUFFIX_MAGIC.get(path.suffix.lower())
        if magic is not None and not head.startswith(magic[1]):
            raise FormatNotRecognisedError(
                path,
                f"format not recognised: the file is named {path.suffix} but starts with {head[:16]!r}",
                offset=0,
                expected=f"{magic[0]}, which starts with {magic[1]!r}",
            )
    if path.suffix in (".safetensors", ".onnx") or (path.is_dir() and any(path.glob("*.safetensors"))):
        raise FormatNotRecognisedError(
            path,
            "a model (the output of `lanecast train`), not a dataset or log",
            expected=f"{expected}; a model goes to --model or --init",
        )
    if path.is_dir() and not (path / "metadata.yaml").exists():
        storage = sorted(p.name for p in path.iterdir() if p.suffix in (".db3", ".mcap") and p.is_file())
        if storage:  # the files of a ROS 2 bag without the index that says what they hold
            raise FormatNotRecognisedError(
                path,
                f"the directory holds {first_of(storage)} but no metadata.yaml, which a ROS 2 bag needs",
                expected="a ROS 2 bag with its metadata.yaml (ros2 bag reindex writes one), or the log files",
            )
    if path.is_dir():  # a release folder (highD-dataset-v1.0/ holds data/): name the folder to pass
        inner = [p for p in sorted(path.iterdir())[:64] if p.is_dir() and not p.name.startswith(".")]
        readable = [p for p in inner if any(reader(fmt).sniff(p) for fmt in READERS)]
        if readable:
            raise FormatNotRecognisedError(
                path,
                f"format not recognised here, but its folder {readable[0].name}/ holds a dataset or log",
                expected=f"the folder itself: {readable[0]}",
            )
    raise FormatNotRecognisedError(path, "format not recognised", expected=expected)


def read_any(paths: Sequence[str | Path], fmt: str | None = None, **options: Any) -> pa.Table:
    """Read inputs of any supported format (detected per path unless ``fmt``) into one track table.

    Every path is checked by :func:`check_input` before any reader opens it (also with ``fmt``).
    """
    groups: dict[str, list[Path]] = {}
    for p in map(check_input, paths):
        groups.setdefault(fmt or detect(p), []).append(p)
    tables = [reader(name).read(group, **options_for(name, options)) for name, group in groups.items()]
    return tables[0] if len(tables) == 1 else track_table.concat(tables)


def write_any(table: pa.Table, out: str | Path, fmt: str, **options: Any) -> Path:
    """Write a track table in ``fmt`` (parquet, mcap, ros2, ros1)."""
    path: Path = writer(fmt).write(table, Path(out), fmt, **options)
    return path
