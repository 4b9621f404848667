"""highD reader: ``NN_tracks.csv`` + ``NN_tracksMeta.csv`` + ``NN_recordingMeta.csv`` → track table.

The format's entry points (``FORMAT``, ``sniff``, ``read``); the work is done beside it, one
concern a module: sniff.py (which files make a recording), parse.py (text → typed columns),
meta.py (recordingMeta), checks.py and meta_checks.py (values and their consistency), convert.py
(road frame, track-table columns) and stream.py (a long file a block at a time).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import pyarrow as pa

from lanecast.io_adapters.contracts import recording_names, track_table
from lanecast.io_adapters.datasets.highd.columns import NEIGHBOURS, TRACKS_COLUMNS, TRACKS_META_COLUMNS
from lanecast.io_adapters.datasets.highd.convert import concat, convert_tracks
from lanecast.io_adapters.datasets.highd.meta import Meta, read_recording_meta
from lanecast.io_adapters.datasets.highd.parse import read_csv
from lanecast.io_adapters.datasets.highd.sniff import Recording, check_present, recordings, sniff
from lanecast.io_adapters.progress import progress

__all__ = ["FORMAT", "NEIGHBOURS", "TRACKS_COLUMNS", "Recording", "read", "recordings", "sniff"]

FORMAT = "highd"


def read_companions(rec: Recording) -> tuple[Meta, pa.Table]:
    """The checked recordingMeta and the parsed tracksMeta of ``rec``, after checking that all three
    of its files are there (the tracks file is read by the caller, whole or in blocks)."""
    check_present(rec)
    meta = read_recording_meta(rec.path("recordingMeta"))
    return meta, read_csv(rec.path("tracksMeta"), TRACKS_META_COLUMNS, "tracksMeta")


def read(paths: Sequence[str | Path], *, recording_prefix: str = "highd", **_: Any) -> pa.Table:
    """Read highD recordings (any of their files, or directories of them) into one track table.

    Each recording ``NN`` gives ``{recording_prefix}-NN-upper`` and ``-lower`` (only those with
    vehicles). Other options (e.g. ``topic``, meant for logs) are ignored. The table is validated.
    """
    if isinstance(paths, (str, Path)):
        paths = [paths]
    recs = recordings(paths)
    parts = []
    recording_meta: dict[str, track_table.RecordingMeta] = {}
    read_metas: list[track_table.TableMeta] = []
    for rec in progress(recs, desc="highD", total=len(recs), unit="recording"):
        meta, meta_table = read_companions(rec)
        tracks = read_csv(rec.path("tracks"), TRACKS_COLUMNS, "tracks")
        columns, metas = convert_tracks(rec, recording_prefix, meta, meta_table, tracks)
        del tracks  # the parsed text's columns: freed before the table is built (peak memory)
        # two folders of one recording number (two simulations): the later one's names qualified
        read_metas.append(track_table.TableMeta(FORMAT, metas, []))
        labels = [str(r.path("tracks")) for r in recs[: len(read_metas)]]
        renames = recording_names.distinct_names(read_metas, labels)[-1]
        if renames:
            read_metas[-1] = recording_names.rename_meta(read_metas[-1], renames)
            metas = read_metas[-1].recordings
            columns["recording_names"] = [renames.get(n, n) for n in columns["recording_names"]]
        recording_meta.update(metas)
        parts.append(columns)
    table = track_table.build_table(
        concat(parts),
        track_table.TableMeta(FORMAT, recording_meta, [f for rec in recs for f in map(str, rec.paths)]),
    )
    track_table.validate(table, source=", ".join(str(p) for p in paths))
    return table
