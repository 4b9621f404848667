"""A long highD recording read incrementally: blocks of whole tracks, one Parquet spill per direction.

A highD ``tracks.csv`` of two hours of dense traffic is ~10 M rows; read at once it needs ~4 GB.
Here pyarrow's streaming CSV reader parses it a block at a time (the same columns and types as
highd.read), the rows of the last track of a block held back for the next, and each block of
whole tracks is converted exactly as highd.read converts the file (convert.convert_tracks: the
same checks, road frame, heading, neighbours) and its rows appended to one Parquet track table
per recording (``highd-NN-lower``, ``-upper``) beside the output. Those spills are then cut into
pieces of whole tracks like any long recording of a track table (io_adapters/formats/streaming.py).

Tracks must come sorted by id (highD's files do); a file that is not, or a block that does not
parse or check cleanly, goes through reader.read's whole-file path, which sorts or names the line
and column of the problem (not bounded in memory, like NGSIM's stream).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.csv as pacsv
import pyarrow.parquet as pq

from lanecast.io_adapters.contracts import track_table
from lanecast.io_adapters.datasets.highd import reader
from lanecast.io_adapters.datasets.highd.columns import TRACKS_COLUMNS
from lanecast.io_adapters.datasets.highd.convert import concat, convert_tracks
from lanecast.io_adapters.datasets.highd.parse import check_cells, checked_header, convert_options
from lanecast.io_adapters.datasets.highd.sniff import Recording
from lanecast.io_adapters.errors import InputError

# bytes of CSV per block; the peak of a 2-hour file grows with it (measured: 8 MB 0.6 GB, 16 MB 0.95 GB,
# 32 MB 1.6 GB), the time hardly changes
BLOCK_BYTES = 8 << 20


class _NotStreamable(Exception):
    """The file must be read whole (unsorted tracks, or a block with a problem to name)."""


def split_tracks(
    rec: Recording, spill_dir: Path, name_prefix: str = "highd", block_bytes: int | None = None
) -> list[Path]:
    """Spill recording ``rec`` block by block (``block_bytes`` of CSV, default BLOCK_BYTES) into
    ``spill_dir``: one Parquet track table per direction, in the order reader.read puts them
    (sorted by name). Raises reader.read's own InputError where the file has a problem."""
    try:
        return _split(rec, spill_dir, name_prefix, block_bytes or BLOCK_BYTES)
    except (_NotStreamable, InputError, pa.ArrowInvalid):
        # names the line, or sorts; a block's error where the whole file reads cleanly came from a
        # track cut by unsorted rows (a row of it further on), which the whole read puts in order
        whole = reader.read([rec.path("tracks")], recording_prefix=name_prefix)
        paths = []
        for name, part in _by_recording(whole):
            paths.append(spill_dir / f"{name}.parquet")
            pq.write_table(part, paths[-1], **track_table.parquet_options(part.schema))
        return paths


def _by_recording(table: pa.Table) -> list[tuple[str, pa.Table]]:
    """The rows of each recording of ``table``, with the metadata of that recording alone."""
    rec_names, codes = track_table.recording_codes(table)
    meta = track_table.read_meta(table)
    out = []
    for code, name in enumerate(rec_names.tolist()):
        part_meta = track_table.restrict_meta(meta, [name]).to_json().encode()
        part = track_table.take_rows(table, np.flatnonzero(codes == code))
        out.append((name, part.replace_schema_metadata({track_table.META_KEY: part_meta})))
    return out


def _split(rec: Recording, spill_dir: Path, name_prefix: str, block_bytes: int) -> list[Path]:
    meta, meta_table = reader.read_companions(rec)
    path = rec.path("tracks")
    names = checked_header(path, TRACKS_COLUMNS, "tracks")
    blocks = pacsv.open_csv(
        path,
        read_options=pacsv.ReadOptions(column_names=names, skip_rows=1, block_size=block_bytes),
        convert_options=convert_options(TRACKS_COLUMNS),
    )
    files = [str(p) for p in rec.paths]
    writers: dict[str, pq.ParquetWriter] = {}
    seen: list[np.ndarray] = []
    last_id = np.iinfo(np.int64).min
    held: pa.Table | None = None

    def convert(block: pa.Table) -> None:
        nonlocal last_id
        ids = block.column("id").to_numpy()
        if ids[0] <= last_id or (ids.size > 1 and (ids[1:] < ids[:-1]).any()):
            raise _NotStreamable("tracks not sorted by id")
        last_id = int(ids[-1])
        seen.append(np.unique(ids))
        check_cells(path, block, names, TRACKS_COLUMNS)
        columns, recs = convert_tracks(rec, name_prefix, meta, meta_table, block, all_tracks=False)
        table = track_table.build_table(concat([columns]), track_table.TableMeta(reader.FORMAT, recs, files))
        for name, part in _by_recording(table):
            if name not in writers:
                writers[name] = pq.ParquetWriter(
                    spill_dir / f"{name}.parquet", part.schema, **track_table.parquet_options(part.schema)
                )
            writers[name].write_table(part.replace_schema_metadata(writers[name].schema.metadata))

    try:
        for batch in blocks:
            if batch.num_rows == 0:
                continue
            table = pa.Table.from_batches([batch])
            table = table if held is None else pa.concat_tables([held, table])
            ids = table.column("id").to_numpy()
            last_start = int(np.flatnonzero(np.r_[True, ids[1:] != ids[:-1]])[-1])
            held = table.slice(last_start)  # the last track may go on in the next block
            if last_start:
                convert(table.slice(0, last_start).combine_chunks())
        if held is None:
            raise _NotStreamable("no rows")
        convert(held.combine_chunks())
    finally:
        for w in writers.values():
            w.close()
    meta_ids = meta_table.column("id").to_numpy()
    if np.setdiff1d(meta_ids, np.concatenate(seen)).size:
        raise _NotStreamable("a tracksMeta id without rows")  # reader.read names it
    return [spill_dir / f"{name}.parquet" for name in sorted(writers)]
