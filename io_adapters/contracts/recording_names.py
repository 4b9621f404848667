"""Recording names kept apart when inputs are combined: two simulations with ``simulate``'s default
recording id both hold ``highd-01-upper``, and windows, convert and info of both together qualify the
second by where it came from instead of refusing them; the same data given twice is still refused."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

import pyarrow as pa

from lanecast.io_adapters.contracts.track_schema import META_KEY, TableMeta, read_meta
from lanecast.io_adapters.errors import TrackTableError


def distinct_names(metas: Sequence[TableMeta], sources: Sequence[str]) -> list[dict[str, str]]:
    """Per input, the renames that keep its recording names apart from earlier inputs' (empty where
    none clash): two simulations both named ``highd-01-upper`` (``simulate``'s default recording id)
    become ``highd-01-upper`` and ``highd-01-upper@sim2``, qualified by the folder of the second's
    source files (else its input's name, else a number). A recording whose name and source files
    repeat is the same data given twice, which no rename makes right: TrackTableError."""
    seen: dict[str, tuple[str, tuple[str, ...]]] = {}
    taken: set[str] = set()
    renames: list[dict[str, str]] = []
    for meta, source in zip(metas, sources, strict=True):
        mine: dict[str, str] = {}
        for name, rec in meta.recordings.items():
            files = tuple(rec.source_files)
            if name in seen:
                first_source, first_files = seen[name]
                if files == first_files or source == first_source:
                    raise TrackTableError(
                        f"{source}: recording names [{name!r}] occur in more than one input (also in "
                        f"{first_source}) with the same source files: the same data given twice"
                    )
                mine[name] = _qualified(name, files, source, taken)
            else:
                seen[name] = (source, files)
            taken.add(mine.get(name, name))
        renames.append(mine)
    return renames


def _qualified(name: str, files: tuple[str, ...], source: str, taken: set[str]) -> str:
    hints = [Path(f).parent.name for f in files[:1]] + [Path(source).stem, Path(source).parent.name]
    for hint in hints:
        if hint and f"{name}@{hint}" not in taken:
            return f"{name}@{hint}"
    n = 2
    while f"{name}#{n}" in taken:
        n += 1
    return f"{name}#{n}"


def rename_meta(meta: TableMeta, renames: Mapping[str, str]) -> TableMeta:
    """``meta`` with its recordings renamed (``renames``: old → new)."""
    if not renames:
        return meta
    recordings = {renames.get(n, n): r for n, r in meta.recordings.items()}
    return TableMeta(meta.source_format, recordings, meta.source_files)


def rename_recordings(table: pa.Table, renames: Mapping[str, str]) -> pa.Table:
    """``table`` with recordings renamed in its column and metadata (``renames``: old → new)."""
    if not renames:
        return table
    import pyarrow.compute as pc  # only for a rename: not on every start

    column = pc.dictionary_encode(table.column("recording").cast(pa.string())).combine_chunks()
    names = column.dictionary.to_pylist()
    new_names = pa.array([renames.get(str(n), str(n)) for n in names], pa.string())
    column = pa.DictionaryArray.from_arrays(column.indices, new_names)
    table = table.set_column(table.schema.get_field_index("recording"), "recording", column)
    meta = rename_meta(read_meta(table), renames)
    return table.replace_schema_metadata({**(table.schema.metadata or {}), META_KEY: meta.to_json().encode()})
