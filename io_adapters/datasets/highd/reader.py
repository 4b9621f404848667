"""highD reader: ``NN_tracks.csv`` + ``NN_tracksMeta.csv`` + ``NN_recordingMeta.csv`` → track table.

The format's entry points (``FORMAT``, ``sniff``, ``read``); the work is done beside it, one
concern a module: sniff.py (which files make a recording), parse.py (text → typed columns),
meta.py (recordingMeta), checks.py and meta_checks.py (values and their consistency), convert.py
(road frame, track-table columns) and stream.py (a long file a block at a time).
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

import pyarrow as pa

from lanecast.io_adapters.contracts import recording_names, track_table
from lanecast.io_adapters.contracts.track_schema import ROW_GROUP_ROWS
from lanecast.io_adapters.datasets.highd.columns import NEIGHBOURS, TRACKS_COLUMNS, TRACKS_META_COLUMNS
from lanecast.io_adapters.datasets.highd.convert import (
    CheckedTracks,
    check_tracks,
    concat,
    direction_parts,
    recording_metas,
    track_columns,
)
from lanecast.io_adapters.datasets.highd.meta import Meta, read_recording_meta
from lanecast.io_adapters.datasets.highd.parse import read_csv
from lanecast.io_adapters.datasets.highd.sniff import Recording, check_present, recordings, sniff
from lanecast.io_adapters.progress import progress

__all__ = ["FORMAT", "NEIGHBOURS", "TRACKS_COLUMNS", "Recording", "read", "read_parts", "recordings", "sniff"]

FORMAT = "highd"


def read_companions(rec: Recording) -> tuple[Meta, pa.Table]:
    """The checked recordingMeta and the parsed tracksMeta of ``rec``, after checking that all three
    of its files are there (the tracks file is read by the caller, whole or in blocks)."""
    check_present(rec)
    meta = read_recording_meta(rec.path("recordingMeta"))
    return meta, read_csv(rec.path("tracksMeta"), TRACKS_META_COLUMNS, "tracksMeta")


def _checked(
    paths: Sequence[str | Path], recording_prefix: str
) -> Iterator[tuple[CheckedTracks, list[str], track_table.TableMeta]]:
    """Each recording of ``paths`` read and checked, with its recording names ``[upper, lower]``
    and metadata; two folders of one recording number (two simulations): the later one's names
    qualified (``contracts.recording_names``)."""
    recs = recordings([paths] if isinstance(paths, (str, Path)) else paths)
    read_metas: list[track_table.TableMeta] = []
    for rec in progress(recs, desc="highD", total=len(recs), unit="recording"):
        meta, meta_table = read_companions(rec)
        tracks = read_csv(rec.path("tracks"), TRACKS_COLUMNS, "tracks")
        checked = check_tracks(rec, meta, meta_table, tracks)
        del tracks  # the parsed text's columns: freed before the table is built (peak memory)
        names, metas = recording_metas(rec, recording_prefix, meta, checked.direction)
        read_metas.append(track_table.TableMeta(FORMAT, metas, [str(p) for p in rec.paths]))
        labels = [str(r.path("tracks")) for r in recs[: len(read_metas)]]
        renames = recording_names.distinct_names(read_metas, labels)[-1]
        if renames:
            read_metas[-1] = recording_names.rename_meta(read_metas[-1], renames)
            names = [renames.get(n, n) for n in names]
        yield checked, names, read_metas[-1]


def _source(paths: Sequence[str | Path]) -> str:
    return str(paths) if isinstance(paths, (str, Path)) else ", ".join(str(p) for p in paths)


def read(paths: Sequence[str | Path], *, recording_prefix: str = "highd", **_: Any) -> pa.Table:
    """Read highD recordings (any of their files, or directories of them) into one track table.

    Each recording ``NN`` gives ``{recording_prefix}-NN-upper`` and ``-lower`` (only those with
    vehicles). Other options (e.g. ``topic``, meant for logs) are ignored. The table is validated.
    """
    parts = []
    recording_meta: dict[str, track_table.RecordingMeta] = {}
    sources: list[str] = []
    for checked, names, meta in _checked(paths, recording_prefix):
        parts.append({"recording_names": names, "class_names": checked.class_names, **track_columns(checked)})
        recording_meta.update(meta.recordings)
        sources.extend(meta.source_files)
    table = track_table.build_table(concat(parts), track_table.TableMeta(FORMAT, recording_meta, sources))
    track_table.validate(table, source=_source(paths))
    return table


def read_parts(
    paths: Sequence[str | Path],
    *,
    recording_prefix: str = "highd",
    part_rows: int = ROW_GROUP_ROWS,
    **_: Any,
) -> Iterator[tuple[pa.Table, bool]]:
    """The rows :func:`read` gives, recording by recording, as validated tables of whole tracks of
    one track-table recording each (at most ``part_rows`` rows but for a longer track), each with
    whether it continues the recording of the part before: a writer encodes one while the next is
    built. Each highD recording is checked whole before its first part."""
    first_row = 0  # of the part, in the table read would give (the rows errors name)
    for checked, names, meta in _checked(paths, recording_prefix):
        for code, parts in direction_parts(checked, names, part_rows):
            only = track_table.restrict_meta(meta, [names[code]])
            for i, rows in enumerate(parts):
                # both names in the dictionary, as in read's table: the file holds the same dictionary
                part = {"recording_names": names, "class_names": checked.class_names}
                part.update(track_columns(checked, rows))
                table = track_table.build_table(concat([part]), only)
                track_table.validate(table, source=_source(paths), first_row=first_row)
                first_row += table.num_rows
                yield table, i > 0
