"""The one registry of formats: which module reads or writes which format, with which options,
and how the streaming path cuts its inputs into pieces; format detection.

A reader module provides ``sniff(path) -> bool`` (a cheap look at the first bytes or the name) and
``read(paths, **options) -> pa.Table`` (a validated track table), and may provide ``read_parts``
(the same rows as parts built one at a time, :class:`PartsReaderModule`); a writer module provides
``write(table, out, fmt, **options) -> Path``. :class:`ReaderModule` and :class:`WriterModule` say
so, and mypy checks every registered module against them (the ``TYPE_CHECKING`` block). Modules
are imported only when first used, so that `lanecast --help` stays fast. An option a format does
not declare is an error naming it, never dropped.
"""

from __future__ import annotations

import enum
import importlib
import os
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol, cast

from lanecast.io_adapters.errors import FormatNotRecognisedError, UsageError

if TYPE_CHECKING:  # the registry is read by every command's parser: pyarrow and files only when used
    import pyarrow as pa


class ReaderModule(Protocol):
    def sniff(self, path: Path) -> bool: ...

    def read(self, paths: Sequence[Path], **options: Any) -> pa.Table: ...


class PartsReaderModule(ReaderModule, Protocol):
    """A reader that can also give what ``read`` gives as parts of whole tracks, built one at a
    time (``(table, continues the previous part's recording)``), so that a writer encodes one
    while the next is built."""

    def read_parts(self, paths: Sequence[Path], **options: Any) -> Iterator[tuple[pa.Table, bool]]: ...


class WriterModule(Protocol):
    def write(self, table: pa.Table, out: Path, fmt: str, **options: Any) -> Path: ...


class Pieces(enum.Enum):
    """How the streaming path (``formats.streaming.plan``) cuts a format's inputs into pieces."""

    PER_FILE = "one piece per input"
    PARQUET_ROWS = "whole recordings of each file, found from its row groups"
    HIGHD_RECORDINGS = "one piece per recording; a large tracks file spilled recording by recording"
    NGSIM_FILES = "one piece per file; a large CSV export spilled recording by recording"


def _check_options(kind: str, name: str, options: Mapping[str, Any], accepted: frozenset[str]) -> None:
    unknown = sorted(set(options) - accepted)
    if unknown:
        raise UsageError(
            unknown[0],
            f"not an option of the {name} {kind}",
            expected=f"one of {sorted(accepted)}" if accepted else "no options",
        )


@dataclass(frozen=True)
class Reader:
    """A registered reader: its format ``name``, the ``module`` that implements it (imported on
    first use), the ``options`` it takes and how its inputs are cut into ``pieces``."""

    name: str
    module: str
    options: frozenset[str] = frozenset()
    pieces: Pieces = Pieces.PER_FILE

    def load(self) -> ReaderModule:
        return cast(ReaderModule, importlib.import_module(self.module))

    def sniff(self, path: Path) -> bool:
        return self.load().sniff(path)

    def accepted(self, options: Mapping[str, Any]) -> dict[str, Any]:
        """The entries of ``options`` this reader takes (a run's options for several formats)."""
        return {k: v for k, v in options.items() if k in self.options}

    def read(self, paths: Sequence[Path], options: Mapping[str, Any] | None = None) -> pa.Table:
        options = dict(options or {})
        _check_options("reader", self.name, options, self.options)
        return self.load().read(list(paths), **options)

    def read_parts(
        self, paths: Sequence[Path], options: Mapping[str, Any] | None = None
    ) -> Iterator[tuple[pa.Table, bool]]:
        """What :meth:`read` gives, in parts (:class:`PartsReaderModule`) where the module can, else whole."""
        options = dict(options or {})
        _check_options("reader", self.name, options, self.options)
        module = self.load()
        if hasattr(module, "read_parts"):
            yield from cast(PartsReaderModule, module).read_parts(list(paths), **options)
        else:
            yield module.read(list(paths), **options), False


@dataclass(frozen=True)
class Writer:
    """A registered writer: its format ``name``, the ``module`` (imported on first use), its ``options``."""

    name: str
    module: str
    options: frozenset[str] = frozenset()

    def load(self) -> WriterModule:
        return cast(WriterModule, importlib.import_module(self.module))

    def write(self, table: pa.Table, out: Path, options: Mapping[str, Any] | None = None) -> Path:
        options = dict(options or {})
        _check_options("writer", self.name, options, self.options)
        return self.load().write(table, out, self.name, **options)


PARQUET = "parquet"  # the track table's own format, which every piece of a dataset may be read as
_LOGS = "lanecast.io_adapters.logs"
_DATASETS = "lanecast.io_adapters.datasets"
_LOG_OPTIONS = frozenset({"topic", "fixed_frames"})
#: rosbag2 storage plugins the ROS 2 writer writes (the first is the default)
ROS2_STORAGES = ("mcap", "sqlite3")

READERS: dict[str, Reader] = {
    r.name: r
    for r in (
        Reader(PARQUET, f"{_DATASETS}.parquet.tables", pieces=Pieces.PARQUET_ROWS),
        Reader(
            "highd", f"{_DATASETS}.highd.reader", frozenset({"recording_prefix"}), Pieces.HIGHD_RECORDINGS
        ),
        Reader(
            "ngsim", f"{_DATASETS}.ngsim.reader", frozenset({"location", "split_periods"}), Pieces.NGSIM_FILES
        ),
        Reader("mcap", f"{_LOGS}.mcap.reader", _LOG_OPTIONS | {"salvage", "crcs_checked_later"}),
        Reader("rosbag", f"{_LOGS}.rosbag.reader", _LOG_OPTIONS),
    )
}
WRITERS: dict[str, Writer] = {
    w.name: w
    for w in (
        Writer(PARQUET, f"{_DATASETS}.parquet.tables"),
        Writer("mcap", f"{_LOGS}.mcap.writer", frozenset({"encoding", "chunk_size"})),
        Writer("ros2", f"{_LOGS}.rosbag.writer", frozenset({"storage"})),
        Writer("ros1", f"{_LOGS}.rosbag.writer"),
    )
}
#: Every option some reader takes: a run's options are checked against it, then each reader gets its own.
READER_OPTIONS = frozenset().union(*(r.options for r in READERS.values()))

if TYPE_CHECKING:  # mypy checks each registered module against its protocol; nothing is imported at run time
    from lanecast.io_adapters.datasets.highd import reader as _highd
    from lanecast.io_adapters.datasets.ngsim import reader as _ngsim
    from lanecast.io_adapters.datasets.parquet import tables as _parquet
    from lanecast.io_adapters.logs.mcap import reader as _mcap
    from lanecast.io_adapters.logs.mcap import writer as _mcap_writer
    from lanecast.io_adapters.logs.rosbag import reader as _rosbag
    from lanecast.io_adapters.logs.rosbag import writer as _rosbag_writer

    _READER_MODULES: tuple[ReaderModule, ...] = (_parquet, _highd, _ngsim, _mcap, _rosbag)
    _PARTS_MODULES: tuple[PartsReaderModule, ...] = (_highd,)
    _WRITER_MODULES: tuple[WriterModule, ...] = (_parquet, _mcap_writer, _rosbag_writer)


def reader(fmt: str) -> Reader:
    if fmt not in READERS:
        raise FormatNotRecognisedError(
            None, f"unknown input format {fmt!r}", expected=f"one of {sorted(READERS)}"
        )
    return READERS[fmt]


def writer(fmt: str) -> Writer:
    if fmt not in WRITERS:
        raise FormatNotRecognisedError(
            None, f"unknown output format {fmt!r}", expected=f"one of {sorted(WRITERS)}"
        )
    return WRITERS[fmt]


def reader_options(options: Mapping[str, Any]) -> dict[str, Any]:
    """``options`` checked against every reader's (an option no reader takes is an error naming it)."""
    _check_options("readers", "registered", options, READER_OPTIONS)
    return dict(options)


#: What a file named with these suffixes starts with (a file that does not is named with its first bytes).
SUFFIX_MAGIC = {
    ".mcap": ("an MCAP file", b"\x89MCAP0\r\n"),
    ".bag": ("a ROS 1 bag", b"#ROSBAG V2.0\n"),
    ".parquet": ("a Parquet file", b"PAR1"),
    ".db3": ("a ROS 2 bag's SQLite storage", b"SQLite format 3\x00"),
}


def detect(path: str | Path) -> str:
    """The name of the format of ``path`` (a file, or a directory such as a ROS 2 bag)."""
    from lanecast.io_adapters.datasets.csv_errors import not_text
    from lanecast.io_adapters.files import check_input, first_of

    path = check_input(path)
    for fmt, entry in READERS.items():
        if entry.sniff(path):
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
        if path.suffix.lower() == ".txt":  # an NGSIM .txt but for its layout: say where and how
            from lanecast.io_adapters.datasets.ngsim.sniff import txt_near_miss

            miss = txt_near_miss(head)
            if miss is not None:
                raise FormatNotRecognisedError(
                    path,
                    f"format not recognised: {miss[1]}",
                    line=miss[0],
                    expected="an NGSIM .txt: 18 whitespace-separated numbers a line, no header",
                )
    if path.suffix in (".safetensors", ".onnx") or (path.is_dir() and any(path.glob("*.safetensors"))):
        raise FormatNotRecognisedError(
            path,
            "a model (the output of `lanecast train`), not a dataset or log",
            expected=f"{expected}; a model goes to --model or --init",
        )
    if path.is_dir() and not (path / "metadata.yaml").exists():
        storage = sorted(p.name for p in path.iterdir() if p.suffix == ".db3" and p.is_file())
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


LOG_SUFFIXES = (".mcap", ".bag")


def logs_in(folder: Path) -> list[Path]:
    """The drive logs in a folder that is no dataset or log itself (``logs/``, an annotate
    ``--out``): :func:`walk_logs`; empty for a folder any reader takes as a whole (a highD folder,
    a ROS 2 bag)."""
    if not folder.is_dir() or (folder / "metadata.yaml").exists() or _read_whole(folder):
        return []
    return list(walk_logs(folder))


def walk_logs(folder: Path, exclude: str | None = None) -> Iterator[Path]:
    """The drive logs below ``folder``, searched recursively in name order: MCAP files, ROS 1 bags
    and ROS 2 bag directories (not descended into). Hidden entries, ``exclude`` (a real path: an
    annotate OUT_DIR inside the inputs) and folders a reader takes whole (a highD recording's
    folder) are skipped. The one walk of ``info``, ``convert``, ``windows`` and ``annotate``."""
    for entry in sorted(folder.iterdir()):
        if entry.name.startswith(".") or (exclude is not None and os.path.realpath(entry) == exclude):
            continue
        if entry.is_dir():
            if (entry / "metadata.yaml").is_file():
                yield entry
            elif not _read_whole(entry):
                yield from walk_logs(entry, exclude)
        elif entry.suffix.lower() in LOG_SUFFIXES and entry.is_file():
            yield entry


def _read_whole(folder: Path) -> bool:
    """A reader takes ``folder`` as one input (a highD folder, a partitioned Parquet table)."""
    return any(e.sniff(folder) for e in READERS.values())


def expand(paths: Sequence[str | Path]) -> list[Path]:
    """``paths`` with each folder of drive logs replaced by the logs in it (:func:`logs_in`)."""
    from lanecast.io_adapters.files import check_input

    out: list[Path] = []
    for p in map(check_input, paths):
        out += logs_in(p) or [p]
    return out


def group_by_format(paths: Sequence[str | Path], fmt: str | None = None) -> dict[str, list[Path]]:
    """``paths`` by format (detected per path unless ``fmt``; a folder of drive logs is its logs),
    each checked by :func:`check_input` before any reader opens it (a FIFO would block)."""
    from lanecast.io_adapters.files import check_input

    groups: dict[str, list[Path]] = {}
    for p in expand(paths) if fmt is None else map(check_input, paths):
        groups.setdefault(reader(fmt).name if fmt else detect(p), []).append(p)
    return groups


def read_any(paths: Sequence[str | Path], fmt: str | None = None, **options: Any) -> pa.Table:
    """Read inputs of any supported format into one track table; each reader gets the options it
    takes (``location`` goes to NGSIM only), an option no reader takes is an error."""
    from lanecast.io_adapters.contracts import track_table

    options = reader_options(options)
    groups = group_by_format(paths, fmt)
    tables = [READERS[name].read(group, READERS[name].accepted(options)) for name, group in groups.items()]
    return tables[0] if len(tables) == 1 else track_table.concat(tables)


def write_any(table: pa.Table, out: str | Path, fmt: str, **options: Any) -> Path:
    """Write a track table in ``fmt`` (parquet, mcap, ros2, ros1) with that writer's options."""
    return writer(fmt).write(table, Path(out), options)
