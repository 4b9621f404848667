"""The track table: lanecast's one common format (docs/design.md §1), defined here and nowhere else.

One row per object per frame, an Arrow table, Parquet (zstd) on disk; the schema and the metadata
document are in ``track_schema`` (and named here too, so that a reader imports one module). Here:
building a table, its checks, row order, merging tables, the Parquet form, and what a table
another tool wrote may differ in (row order, types holding the same values).
"""

from __future__ import annotations

import base64
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import pyarrow as pa

from lanecast.io_adapters.arrow_numpy import dictionary_codes, filled, take, valid_mask
from lanecast.io_adapters.contracts import recording_names
from lanecast.io_adapters.contracts.track_runs import lane_change_starts, run_bounds, run_starts
from lanecast.io_adapters.contracts.track_schema import (
    FIELDS_BY_NAME,
    FINITE_COLUMNS,
    MAX_POSITION_M,
    META_KEY,
    NEIGHBOUR_COLUMNS,
    RANGES,
    REQUIRED_COLUMNS,
    UNITS,
    RecordingMeta,
    TableMeta,
    read_meta,
    schema,
)
from lanecast.io_adapters.contracts.track_schema import FRAME_RATES as FRAME_RATES  # for the readers
from lanecast.io_adapters.contracts.track_schema import (
    parquet_options as parquet_options,  # for the writers
)
from lanecast.io_adapters.contracts.track_schema import (
    plausible_frame_rate as plausible_frame_rate,  # for the readers
)
from lanecast.io_adapters.cores import map_columns
from lanecast.io_adapters.errors import InputError, TrackTableError
from lanecast.io_adapters.files import atomic_path

if TYPE_CHECKING:
    import pyarrow.parquet as pq


def build_table(columns: Mapping[str, Any], meta: TableMeta) -> pa.Table:
    """Assemble a track table from column arrays (numpy, lists or Arrow), cast to the schema.

    Columns are put in schema order; the neighbour columns are kept only where given (all or some:
    the missing ones of a partial set are filled with nulls). Rows are sorted by
    (recording, track_id, frame). The result is not validated: call :func:`validate`.
    """
    missing = [name for name in REQUIRED_COLUMNS if name not in columns]
    if missing:
        raise TrackTableError(f"cannot build a track table without columns {missing}")
    has_neighbours = any(name in columns for name in NEIGHBOUR_COLUMNS)
    target = schema(has_neighbours)
    n_rows = len(columns["track_id"])
    arrays = []
    for f in target:
        if f.name not in columns:
            arrays.append(pa.nulls(n_rows, f.type))
            continue
        arrays.append(_to_arrow(columns[f.name], f))
    table = pa.Table.from_arrays(arrays, schema=target)
    table = table.replace_schema_metadata({META_KEY: meta.to_json().encode()})
    return sort_rows(table)


def _to_arrow(values: Any, f: pa.Field) -> pa.Array:
    if isinstance(values, pa.ChunkedArray):
        values = values.combine_chunks()
    if pa.types.is_dictionary(f.type):
        arr = values if isinstance(values, pa.Array) else pa.array(np.asarray(values).astype(str))
        if not pa.types.is_dictionary(arr.type):
            import pyarrow.compute as pc  # names given as strings: not on every start

            arr = pc.dictionary_encode(arr.cast(pa.string()))
        return _cast(arr, f.type)
    if isinstance(values, pa.Array):
        return _cast(values, f.type)
    array = np.asarray(values)
    if f.nullable and array.dtype.kind == "f":
        # Float carriers of nullable integer columns: NaN means null.
        mask = np.isnan(array)
        return pa.array(np.where(mask, 0, array).astype(f.type.to_pandas_dtype()), mask=mask, type=f.type)
    return pa.array(array, type=f.type)


def _cast(array: pa.Array, to: pa.DataType) -> pa.Array:
    """``array`` as type ``to``; as it is where it has that type (``cast`` imports ``pyarrow.compute``)."""
    return array if array.type == to else array.cast(to)


def _in_order(rec: np.ndarray, track: np.ndarray, frame: np.ndarray) -> np.ndarray:
    """bool [n-1]: row i+1 comes after row i in (recording, track_id, frame) order (ties allowed)."""
    same_rec = rec[1:] == rec[:-1]
    same_track = same_rec & (track[1:] == track[:-1])
    return (
        (rec[1:] > rec[:-1])
        | (same_rec & (track[1:] > track[:-1]))
        | (same_track & (frame[1:] >= frame[:-1]))
    )


def sort_rows(table: pa.Table) -> pa.Table:
    """Sort rows by (recording, track_id, frame), keeping the schema and its metadata.

    An already sorted table (every adapter that reads sorted sources) is returned as it is; one
    whose recordings are each sorted but interleaved (highD's two directions) is put in order by a
    stable sort of the recording codes alone; anything else gets a full sort.
    """
    if table.num_rows < 2:
        return table
    rec = recording_codes(table)[1]
    track, frame = table.column("track_id").to_numpy(), table.column("frame").to_numpy()
    if _in_order(rec, track, frame).all():
        return table
    # a recording's code fits 16 bits in any real table: numpy sorts those by radix, 4x faster
    order = np.argsort(rec.astype(np.int16) if rec.max() < 1 << 15 else rec, kind="stable")
    if not _in_order(rec[order], track[order], frame[order]).all():
        order = np.lexsort((frame, track, rec))
    return take_rows(table, order)


def take_rows(table: pa.Table, order: np.ndarray) -> pa.Table:
    """``table.take(order)``, the columns gathered on the free cores (:func:`arrow_numpy.take`)."""
    columns = map_columns(
        lambda column: take(column, order), table.columns, None if len(order) >= 100_000 else 1
    )
    return pa.Table.from_arrays(columns, schema=table.schema)


def validate(
    table: pa.Table, source: str | Path | None = None, first_row: int = 0, file_rows: np.ndarray | None = None
) -> None:
    """Check a table against the contract; raise TrackTableError naming the first violation.

    Checks: columns and types, units in the field metadata, recording metadata with a frame rate,
    no NaN/inf/null in required columns, positions within ±1e9 m, sizes and times >= 0, unique
    (recording, track_id, frame), rows sorted by (recording, track_id, frame), and time strictly
    increasing along every track. ``first_row``: the row of ``source`` that is the table's row 0 (a
    piece of a file), for the rows errors name; ``file_rows``: instead, the row of ``source`` of each
    of the table's rows (a file's rows put in order by :func:`file_order`).
    """
    where = f"{source}: " if source is not None else ""

    def at(row: int) -> int:
        return int(file_rows[row]) if file_rows is not None else row + first_row

    present = set(table.column_names)
    if len(present) != table.num_columns:  # Arrow allows it; every lookup by name would fail
        twice = next(n for i, n in enumerate(table.column_names) if n in table.column_names[:i])
        raise TrackTableError(f"{where}column {twice!r} appears twice, expected each column once")
    for name in REQUIRED_COLUMNS:
        if name not in present:
            raise TrackTableError(f"{where}missing column {name!r}")
    for name in table.column_names:
        expected = FIELDS_BY_NAME.get(name)
        if expected is None:
            raise TrackTableError(f"{where}unexpected column {name!r}; allowed: {sorted(FIELDS_BY_NAME)}")
        got = table.schema.field(name)
        if got.type != expected.type:
            raise TrackTableError(f"{where}column {name!r} has type {got.type}, expected {expected.type}")
        if name in UNITS and (got.metadata or {}).get(b"unit", b"").decode(errors="replace") != UNITS[name]:
            raise TrackTableError(f"{where}column {name!r} does not state its unit {UNITS[name]!r}")
    meta = read_meta(table, source)
    rec_codes = None
    if table.column("recording").null_count:  # a null one is reported with its row below
        import pyarrow.compute as pc  # a broken table: not on every start

        recordings = set(pc.unique(table.column("recording").drop_null().cast(pa.string())).to_pylist())
    else:
        rec_names, rec_codes = recording_codes(table)
        recordings = set(rec_names.tolist())
    unknown = recordings - set(meta.recordings)
    if unknown:
        raise TrackTableError(f"{where}recordings {sorted(unknown)} have no entry in the table metadata")
    for name, rec in meta.recordings.items():
        if not (np.isfinite(rec.frame_rate) and rec.frame_rate > 0):
            raise TrackTableError(f"{where}recording {name!r} has frame rate {rec.frame_rate}, expected > 0")
    if table.num_rows == 0:
        return
    for name in REQUIRED_COLUMNS:
        column = table.column(name)
        if name != "lane_id" and column.null_count:
            row = int(np.flatnonzero(~valid_mask(column))[0])
            raise TrackTableError(f"{where}row {at(row)}: column {name!r} is null")
    for name in FINITE_COLUMNS:
        values = table.column(name).to_numpy()
        bad = ~np.isfinite(values)
        if name in ("x", "y"):  # before the columns derived from them (a log's velocities)
            bad |= np.abs(values) > MAX_POSITION_M
        if bad.any():
            row = int(np.flatnonzero(bad)[0])
            expected = (
                f"a finite position within ±{MAX_POSITION_M:g} m" if name in ("x", "y") else "a finite number"
            )
            raise TrackTableError(
                f"{where}row {at(row)}: column {name!r} is {values[row]}, expected {expected}"
            )
    for name, limit, expected in RANGES:
        values = table.column(name).to_numpy()
        bad = np.abs(values) > limit if limit > 0 else values < limit
        if bad.any():
            row = int(np.flatnonzero(bad)[0])
            raise TrackTableError(
                f"{where}row {at(row)}: column {name!r} is {values[row]}, expected {expected}"
            )
    assert rec_codes is not None  # a null recording was refused above
    track = table.column("track_id").to_numpy()
    frame = table.column("frame").to_numpy()
    time = table.column("time_ns").to_numpy()
    same_track = (rec_codes[1:] == rec_codes[:-1]) & (track[1:] == track[:-1])
    order_ok = _in_order(rec_codes, track, frame)
    if not order_ok.all():
        row = int(np.flatnonzero(~order_ok)[0]) + 1
        raise TrackTableError(f"{where}row {at(row)}: rows are not sorted by (recording, track_id, frame)")
    duplicate = same_track & (frame[1:] == frame[:-1])
    if duplicate.any():
        row = int(np.flatnonzero(duplicate)[0]) + 1
        raise TrackTableError(
            f"{where}row {at(row)}: duplicate (recording, track_id, frame) = "
            f"({table.column('recording')[row]}, {track[row]}, {frame[row]})"
        )
    backwards = same_track & (time[1:] <= time[:-1])
    if backwards.any():
        row = int(np.flatnonzero(backwards)[0]) + 1
        raise TrackTableError(
            f"{where}row {at(row)}: time_ns does not increase along track {track[row]} "
            f"({time[row - 1]} then {time[row]})"
        )
    _check_rate(table, meta, rec_codes, track, frame, time, where, at)


RATE_TOLERANCE = 1.25  # a track's frames per second of time_ns over its recording's frame_rate, either way
MIN_RATE_FRAMES = 10  # tracks spanning fewer frames say little about the rate (a log's jitter)


def _check_rate(
    table: pa.Table,
    meta: TableMeta,
    rec_codes: np.ndarray,
    track: np.ndarray,
    frame: np.ndarray,
    time: np.ndarray,
    where: str,
    at: Any,
) -> None:
    """Refuse a track whose time_ns advances at another rate than its recording's frame_rate says
    (frame_rate 50 over times of frame / 25, time_ns in microseconds): every window and forecast
    horizon would be cut at the wrong times. Arrays [n] of the sorted, validated table."""
    bounds = run_bounds(rec_codes, track)
    first, last = bounds[:-1], bounds[1:] - 1
    frames = frame[last] - frame[first]
    judged = np.flatnonzero(frames >= MIN_RATE_FRAMES)
    if not judged.size:
        return
    names = recording_codes(table)[0]
    rate_of = np.array([meta.recordings[str(n)].frame_rate for n in names.tolist()])
    rate = rate_of[rec_codes[first[judged]]]
    implied = frames[judged] / ((time[last[judged]] - time[first[judged]]) / 1e9)
    off = np.flatnonzero((implied > rate * RATE_TOLERANCE) | (implied < rate / RATE_TOLERANCE))
    if not off.size:
        return
    k, row = int(off[0]), int(first[judged[off[0]]])
    raise TrackTableError(
        f"{where}row {at(row)}: track {track[row]} of recording {str(names[rec_codes[row]])!r} advances "
        f"{frames[judged[k]]} frames in {(time[last[judged[k]]] - time[row]) / 1e9:.6g} s of time_ns "
        f"({implied[k]:.4g} Hz), but the recording's frame_rate is {rate[k]:g} Hz, expected time_ns = "
        "frame / frame_rate in ns"
    )


def _is_text(type_: pa.DataType) -> bool:
    return pa.types.is_string(type_) or pa.types.is_large_string(type_)


def _same_values_in(got: pa.DataType, want: pa.DataType) -> bool:
    """A column of type ``got`` can be cast to ``want`` without changing a value (integers are
    range-checked by the safe cast): ids and frames of a narrower or unsigned integer type, names
    as plain or large strings or a dictionary with other indices, positions as float32."""
    if pa.types.is_integer(want):
        return pa.types.is_integer(got)
    if pa.types.is_dictionary(want):
        return _is_text(got) or (pa.types.is_dictionary(got) and _is_text(got.value_type))
    if pa.types.is_float64(want):
        return pa.types.is_float32(got) or pa.types.is_float16(got)
    return False


def widen_types(table: pa.Table) -> pa.Table:
    """A table read from a file (written by another tool) with contract columns in types that hold
    the same values cast to the contract's types, field metadata (units) kept; any other type, or
    an integer out of range, is left for :func:`validate` to name."""
    for i, f in enumerate(table.schema):
        want = FIELDS_BY_NAME.get(f.name)
        if want is None or f.type == want.type or not _same_values_in(f.type, want.type):
            continue
        try:
            column = table.column(i).cast(want.type)  # safe: an integer out of range raises
        except pa.ArrowException:  # a value out of range, or a cast Arrow lacks: validate names it
            continue
        table = table.set_column(i, f.with_type(want.type), column)
    return table


def file_order(table: pa.Table) -> np.ndarray | None:
    """The row order (int64 [n]) that sorts a table read from a file by (recording, track_id,
    frame), stably (a repeated row stays after its first copy); None if it is in order already or
    its key columns cannot be put in order (missing, of another type, null: :func:`validate` names
    them). A track table written by another tool in another row order holds the same data."""
    names = ("recording", "track_id", "frame")
    if table.num_rows < 2 or any(n not in table.column_names for n in names):
        return None
    if any(table.schema.field(n).type != FIELDS_BY_NAME[n].type or table.column(n).null_count for n in names):
        return None
    rec = recording_codes(table)[1]
    track, frame = table.column("track_id").to_numpy(), table.column("frame").to_numpy()
    if _in_order(rec, track, frame).all():
        return None
    return np.lexsort((np.arange(table.num_rows), frame, track, rec))


def recording_codes(table: pa.Table) -> tuple[np.ndarray, np.ndarray]:
    """(sorted names str [R] of the recordings that have rows, code of each row int64 [n]) via the
    dictionary encoding (:func:`arrow_numpy.dictionary_codes`). The column has no nulls (validate
    refuses them)."""
    col = table.column("recording")
    if not pa.types.is_dictionary(col.type):
        import pyarrow.compute as pc  # a table built by hand: not on every start

        col = pc.dictionary_encode(col)
    return dictionary_codes(col)


def track_boundaries(table: pa.Table) -> np.ndarray:
    """Row indices where a new (recording, track_id) starts, plus the row count at the end.

    Assumes rows sorted by (recording, track_id, frame); ``starts[i]:starts[i+1]`` is track i.
    """
    if table.num_rows == 0:
        return np.zeros(1, dtype=np.int64)
    return run_bounds(recording_codes(table)[1], table.column("track_id").to_numpy())


def merge_meta(metas: Iterable[TableMeta], sources: Sequence[str] | None = None) -> TableMeta:
    """The metadata of several track tables (or pieces of one dataset) as one document.

    Recording names must be unique across them (``sources``, one per document, name the inputs in
    the error); formats are joined with ``+``, source files listed once.
    """
    metas = list(metas)
    recordings: dict[str, RecordingMeta] = {}
    origin: dict[str, str] = {}
    for i, m in enumerate(metas):
        clash = sorted(set(recordings) & set(m.recordings))
        here = sources[i] if sources is not None else ", ".join(m.source_files) or "an input"
        if clash:
            raise TrackTableError(
                f"{here}: recording names {clash} occur in more than one input (also in {origin[clash[0]]}); "
                "expected inputs with distinct recording names"
            )
        recordings.update(m.recordings)
        origin.update(dict.fromkeys(m.recordings, here))
    formats = sorted({m.source_format for m in metas})
    files = list(dict.fromkeys(f for m in metas for f in m.source_files))
    return TableMeta("+".join(formats), recordings, files)


def restrict_meta(meta: TableMeta, names: Iterable[str]) -> TableMeta:
    """``meta`` with only the recordings ``names`` (a piece of a dataset describes only its own)."""
    keep = set(names)
    recordings = {n: r for n, r in meta.recordings.items() if n in keep}
    files = list(dict.fromkeys(f for r in recordings.values() for f in r.source_files)) or meta.source_files
    return TableMeta(meta.source_format, recordings, files)


def concat(tables: Iterable[pa.Table], sources: Sequence[str] | None = None) -> pa.Table:
    """Concatenate track tables from several sources into one, merging their metadata.

    Recording names must be unique across the inputs; ``sources`` (one per table, e.g. the files
    read) name them in the error otherwise (default: each table's own source files).
    """
    tables = list(tables)
    if not tables:
        raise TrackTableError("nothing to concatenate")
    labels = (
        list(sources)
        if sources is not None
        else [", ".join(read_meta(t).source_files) or f"input {i + 1}" for i, t in enumerate(tables)]
    )
    renames = recording_names.distinct_names([read_meta(t) for t in tables], labels)
    tables = [recording_names.rename_recordings(t, r) for t, r in zip(tables, renames, strict=True)]
    meta = merge_meta([read_meta(t) for t in tables], sources)
    with_neighbours = any(NEIGHBOUR_COLUMNS[0] in t.column_names for t in tables)
    target = schema(with_neighbours)
    aligned = []
    for t in tables:
        cols = {name: t.column(name) for name in t.column_names}
        arrays = [
            cols[f.name].combine_chunks().cast(f.type) if f.name in cols else pa.nulls(t.num_rows, f.type)
            for f in target
        ]
        aligned.append(pa.Table.from_arrays(arrays, schema=target))
    merged = pa.concat_tables(aligned, promote_options="permissive").unify_dictionaries()
    merged = merged.replace_schema_metadata({META_KEY: meta.to_json().encode()})
    return sort_rows(merged)


def write_parquet(table: pa.Table, path: str | Path) -> Path:
    """Write a validated track table as Parquet, atomically."""
    import pyarrow.parquet as pq

    validate(table)
    path = Path(path)
    with atomic_path(path) as tmp:
        pq.write_table(table, tmp, **parquet_options(table.schema))
    return path


def read_parquet(path: str | Path) -> pa.Table:
    """Read a track table written by :func:`write_parquet` and validate it.

    Page checksums are verified where the file has them (every file :func:`write_parquet` writes);
    what they do not cover (the footer) is checked by :func:`validate`.
    """
    import pyarrow.parquet as pq

    try:
        pf = pq.ParquetFile(path, page_checksum_verification=True)
        table = pf.read().replace_schema_metadata(file_schema(pf).metadata)
        # Arrow's own structural check (dictionary indices in range, offsets, …): page checksums
        # do not cover page headers, whose counts a damaged file may get wrong.
        table.validate(full=True)
        _ = [f.name for f in table.schema]  # names decode lazily: a non-UTF-8 name fails here
    except (OSError, pa.ArrowException, UnicodeDecodeError) as exc:
        raise InputError(
            path, f"not a readable Parquet file: {exc}", expected="a lanecast track table"
        ) from exc
    table = widen_types(table)  # another tool's types and row order: the same values, the contract's form
    order = file_order(table)
    if order is not None:
        table = take_rows(table, order)
    validate(table, source=path, file_rows=order)
    return table


def arrow_schema_entry(schema_: pa.Schema, meta: bytes) -> dict[bytes, bytes]:
    """The Parquet key-value entry in which Arrow readers find a file's Arrow schema
    (``ARROW:schema``: the IPC-serialised schema, base64), for ``schema_`` with the ``lanecast``
    metadata ``meta``. A file written piece by piece knows its metadata only when complete; adding
    this entry then (it replaces the one written at the start) lets pyarrow, pandas and other Arrow
    readers see the metadata in the schema, so a table read, filtered and written back with pyarrow
    stays a lanecast track table."""
    serialised = schema_.with_metadata({**(schema_.metadata or {}), META_KEY: meta}).serialize()
    return {b"ARROW:schema": base64.b64encode(serialised.to_pybytes())}


def file_schema(pf: pq.ParquetFile) -> pa.Schema:
    """The Arrow schema of a Parquet track table with its ``lanecast`` metadata, which a file
    written piece by piece stores in the file's key-value metadata when it is complete."""
    schema_ = pf.schema_arrow
    stored = (pf.metadata.metadata or {}).get(META_KEY)
    if stored is None:
        return schema_
    return schema_.with_metadata({**(schema_.metadata or {}), META_KEY: stored})


def lane_change_rows(table: pa.Table) -> np.ndarray:
    """Rows whose ``lane_id`` differs from the previous row of the same track (both known).

    This is where a lane change happens (docs/design.md §1, §2); the row returned is
    the first frame in the new lane.
    """
    if table.num_rows < 2:
        return np.zeros(0, dtype=np.int64)
    lane = table.column("lane_id")
    new_track = run_starts(recording_codes(table)[1], table.column("track_id").to_numpy())
    return np.flatnonzero(lane_change_starts(new_track, filled(lane, 0), valid_mask(lane)))
