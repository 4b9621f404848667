"""The track table's own on-disk form: one Parquet file (zstd), or a dataset directory of Parquet
files (one per piece of a dataset written piece by piece, ``part-00000.parquet``, …) read as one."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import pyarrow as pa

from lanecast.io_adapters.contracts import track_table
from lanecast.io_adapters.contracts.windows import DATASET_FILES
from lanecast.io_adapters.errors import InputError
from lanecast.io_adapters.files import not_regular

FORMAT = "parquet"
_MAGIC = b"PAR1"


def _is_parquet(path: Path) -> bool:
    if not path.is_file():
        return False
    with path.open("rb") as fh:
        return fh.read(4) == _MAGIC


def dataset_files(directory: Path) -> list[Path]:
    """The Parquet files of a dataset directory, in name order (hidden and temporary ones skipped)."""
    return sorted(p for p in directory.glob("*.parquet") if not p.name.startswith((".", "_")) and p.is_file())


def check_parts(directory: Path) -> None:
    """InputError naming a part of the dataset ``directory`` that is no file to read (a FIFO, a
    device, a link to nothing): left out, its rows would be missing without a word; or naming
    the directory if it is a windows dataset, whose windows.parquet is no track table (before:
    "missing column 'frame'" or "no 'lanecast' schema metadata", about a file the user never named)."""
    if all((directory / name).is_file() for name in DATASET_FILES):
        raise InputError(
            directory,
            "a windows dataset (the output of `lanecast windows`), not a track table",
            expected="a track table, highD or NGSIM files, or a drive log; `lanecast train` and "
            "`lanecast evaluate` read windows datasets",
        )
    for p in sorted(directory.glob("*.parquet")):
        reason = None if p.name.startswith((".", "_")) else not_regular(p)
        if reason is not None:
            raise InputError(p, f"part of the dataset {directory.name!r}: {reason}", expected="Parquet files")


def sniff(path: Path) -> bool:
    """A Parquet file, or a dataset directory: one whose ``*.parquet`` files are Parquet, but for
    damaged ones (a part cut short, or another file under a part's name) that the reader names."""
    if path.is_dir():
        return any(_is_parquet(p) for p in dataset_files(path))
    return _is_parquet(path)


def files(paths: Sequence[Path]) -> list[Path]:
    """``paths`` with every dataset directory replaced by its Parquet files."""
    out: list[Path] = []
    for p in map(Path, paths):
        if p.is_dir():
            check_parts(p)
            found = dataset_files(p)
            if not found:
                raise InputError(
                    p, "no Parquet files in the directory", expected="a track table dataset directory"
                )
            out.extend(found)
        else:
            out.append(p)
    return out


def read(paths: Sequence[Path], **_: Any) -> pa.Table:
    found = files(paths)
    tables = [track_table.read_parquet(p) for p in found]
    return tables[0] if len(tables) == 1 else track_table.concat(tables, [str(p) for p in found])


def write(table: pa.Table, out: Path, fmt: str = FORMAT, **_: Any) -> Path:
    return track_table.write_parquet(table, out)
