"""The track table's own on-disk form: one Parquet file (zstd)."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import pyarrow as pa

from lanecast.io_adapters.contracts import track_table

FORMAT = "parquet"
_MAGIC = b"PAR1"


def sniff(path: Path) -> bool:
    if not path.is_file():
        return False
    with path.open("rb") as fh:
        return fh.read(4) == _MAGIC


def read(paths: Sequence[Path], **_: Any) -> pa.Table:
    tables = [track_table.read_parquet(p) for p in paths]
    return tables[0] if len(tables) == 1 else track_table.concat(tables, [str(p) for p in paths])


def write(table: pa.Table, out: Path, fmt: str = FORMAT, **_: Any) -> Path:
    return track_table.write_parquet(table, out)
