"""Whole datasets piece by piece: the piece plan of any registered input format, and the track
table written as the pieces come (docs/design.md, streaming).

:func:`plan` cuts inputs as their reader's registration says (``registry.Pieces``): one piece
per log, whole recordings of a Parquet track table, a highD recording or NGSIM period per piece
(large files spilled recording by recording). :class:`TrackTableWriter` writes one Parquet file
(row groups per piece; the table metadata naming every recording is stored when the file is
complete) or a dataset directory of one Parquet file per piece (``part-00000.parquet``, …),
which every reader of track tables accepts in place of a file.
"""

from __future__ import annotations

import contextlib
import functools
import shutil
import tempfile
from collections.abc import Callable, Iterator, Mapping, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path
from types import TracebackType
from typing import Any

import pyarrow as pa
import pyarrow.parquet as pq

from lanecast.io_adapters.contracts import recording_names, track_table
from lanecast.io_adapters.contracts.track_schema import ROW_GROUP_ROWS
from lanecast.io_adapters.datasets.highd import reader as highd
from lanecast.io_adapters.datasets.highd import stream as highd_stream
from lanecast.io_adapters.datasets.ngsim import stream as ngsim_stream
from lanecast.io_adapters.datasets.parquet import tables as parquet_format
from lanecast.io_adapters.errors import InputError
from lanecast.io_adapters.files import atomic_path
from lanecast.io_adapters.formats import registry
from lanecast.io_adapters.formats.pieces import MAX_ROWS, Piece, parquet_pieces
from lanecast.io_adapters.formats.registry import Pieces
from lanecast.io_adapters.progress import job_progress

LONG = ("whole", "tracks", "context")  # what a recording larger than a piece becomes (plan)
PARTS = ("part-*.parquet",)  # the files of a dataset directory output (a new one replaces them)
STREAM_BYTES = 256 << 20  # NGSIM CSV exports from this size on are read incrementally
HIGHD_STREAM_BYTES = 256 << 20  # highD tracks files likewise (longer than ~30 dense minutes; a
# real highD recording, 15-20 minutes, is read whole: 10-20 % faster, 0.7 GB)


def plan(
    paths: Sequence[str | Path],
    fmt: str | None = None,
    max_rows: int = MAX_ROWS,
    *,
    spill_dir: Path | None = None,
    stream_bytes: int | None = None,
    options: Mapping[str, Any] | None = None,
    long: str = "whole",
) -> list[Piece]:
    """The pieces of ``paths`` (formats detected per path unless ``fmt``; ``options`` for the
    readers, each getting those it takes), in dataset order. ``long``: what a recording of a
    Parquet track table larger than ``max_rows`` becomes: ``whole`` one piece, ``tracks`` pieces of
    whole tracks (each but the first ``continues`` the recording: for convert), ``context`` chunks
    of whole tracks with the traffic around them (for windows: :meth:`Piece.read_with_context`).

    With ``spill_dir`` (storage every worker sees, removed by the caller), NGSIM CSV exports and
    highD tracks files of at least ``stream_bytes`` (default STREAM_BYTES, HIGHD_STREAM_BYTES for
    highD) are read incrementally into one spill per recording there (a highD spill is a Parquet
    track table, cut as ``long`` says).
    """
    if long not in LONG:
        raise ValueError(f"long={long!r}, expected one of {LONG}")
    highd_bytes = HIGHD_STREAM_BYTES if stream_bytes is None else stream_bytes
    stream_bytes = STREAM_BYTES if stream_bytes is None else stream_bytes
    options = registry.reader_options(options or {})
    pieces: list[Piece] = []
    for name, group in registry.group_by_format(paths, fmt).items():
        entry = registry.READERS[name]
        own = entry.accepted(options)
        opts = tuple(sorted(own.items()))
        if entry.pieces is Pieces.PARQUET_ROWS:
            for file in parquet_format.files(group):
                pieces.extend(parquet_pieces(file, max_rows, long=long))
        elif entry.pieces is Pieces.HIGHD_RECORDINGS:
            for rec in highd.recordings(group):
                tracks = rec.path("tracks")
                if spill_dir is None or not tracks.is_file() or tracks.stat().st_size < highd_bytes:
                    pieces.append(Piece(name, (str(tracks),), options=opts))
                    continue
                prefix = str(own.get("recording_prefix", "highd"))
                for spill in highd_stream.split_tracks(rec, Path(spill_dir), prefix):
                    pieces.extend(parquet_pieces(spill, max_rows, long=long))
        elif entry.pieces is Pieces.NGSIM_FILES:  # recordings are per file (location, file, period)
            for p in group:
                pieces.extend(_ngsim_pieces(name, p, spill_dir, stream_bytes, own))
        else:
            pieces.extend(Piece(name, (str(p),), options=opts) for p in group)
    return pieces


class SpillDirectory:
    """A temporary directory beside an output for the spills (or the workers' parts) of a run;
    removed on exit."""

    def __init__(self, out: Path, kind: str = "spill") -> None:
        out.parent.mkdir(parents=True, exist_ok=True)
        self.path = Path(tempfile.mkdtemp(prefix=f".{out.name}.{kind}-", dir=out.parent))

    def __enter__(self) -> SpillDirectory:
        return self

    def __exit__(self, *_: object) -> None:
        shutil.rmtree(self.path, ignore_errors=True)


def spill_directory(out: str | Path) -> SpillDirectory:
    return SpillDirectory(Path(out))


def _ngsim_pieces(
    name: str, path: Path, spill_dir: Path | None, stream_bytes: int, options: dict[str, Any]
) -> list[Piece]:
    whole = [Piece(name, (str(path),), options=tuple(sorted(options.items())))]
    if spill_dir is None or not path.is_file() or path.stat().st_size < stream_bytes:
        return whole
    if not ngsim_stream.streamable(path):
        return whole
    spilled = ngsim_stream.split_csv(
        path,
        Path(spill_dir),
        location=options.get("location"),
        split_periods=bool(options.get("split_periods", True)),
    )
    if spilled is None:
        return whole
    return [Piece(name, (str(path),), spilled=rec.to_json()) for rec in spilled]


class TrackTableWriter:
    """Writes a track table piece by piece, atomically: one Parquet file, or (``directory``) a
    dataset directory of one Parquet file per piece (the pieces of a long recording cut in whole
    tracks share one). Recording names must be unique across pieces, but for a piece that
    ``continues`` the previous one's recording."""

    def __init__(self, out: str | Path, *, directory: bool) -> None:
        self.out, self.directory = Path(out), directory
        self.rows = self.tracks = 0
        self._metas: list[track_table.TableMeta] = []
        self._renames: dict[str, str] = {}  # of the last new recording: its pieces that follow keep it
        self._sources: list[str] = []
        self._stack = contextlib.ExitStack()
        self._tmp: Path | None = None
        self._writer: pq.ParquetWriter | None = None  # the file, or the open part of a directory
        self._parts = 0

    def __enter__(self) -> TrackTableWriter:
        self._tmp = self._stack.enter_context(atomic_path(self.out, directory=self.directory, replaces=PARTS))
        return self

    def __exit__(
        self, kind: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        try:
            if kind is None:
                self._finish()
            elif self._writer is not None:
                self._writer.close()
        except BaseException as error:  # e.g. no rows: the temporary output is removed, never renamed
            self._stack.__exit__(type(error), error, error.__traceback__)
            raise
        self._stack.__exit__(kind, exc, tb)

    def part_root(self) -> Path:
        """The temporary directory output, where workers write their ``part-NNNNN.parquet``."""
        assert self._tmp is not None and self.directory
        return self._tmp

    def part_path(self, index: int) -> Path:
        """Where part ``index`` of a directory output goes."""
        return self.part_root() / f"part-{index:05d}.parquet"

    def write(self, table: pa.Table, source: str = "", *, continues: bool = False) -> None:
        """Append one validated piece (its metadata names its recordings; ``source`` names the
        input in errors); ``continues``: more whole tracks of the previous piece's recording."""
        assert self._tmp is not None, "use TrackTableWriter as a context manager"
        table = self._distinct(table, source, continues)
        self._account(table, source, continues)
        if self.directory:
            if not continues:
                self._close_part()
                self._writer = pq.ParquetWriter(
                    self.part_path(self._parts), table.schema, **track_table.parquet_options(table.schema)
                )
                self._parts += 1
            assert self._writer is not None
            self._writer.write_table(table.cast(self._writer.schema), row_group_size=ROW_GROUP_ROWS)
            return
        if self._writer is None:
            schema = table.schema.remove_metadata()
            self._writer = pq.ParquetWriter(self._tmp, schema, **track_table.parquet_options(schema))
        self._writer.write_table(self._aligned(table), row_group_size=ROW_GROUP_ROWS)

    def add_part(
        self, path: Path, source: str = "", *, continues: bool = False, continued: bool = False
    ) -> None:
        """Take a part file a worker wrote: moved into a directory output as its next part, or
        appended (file output, or a piece of a long recording: it ``continues`` the previous
        piece's recording or is ``continued`` by the next); the worker's file is removed."""
        table = track_table.read_parquet(path)
        if self.directory and not (continues or continued):
            self._close_part()
            table = self._distinct(table, source, False)
            self._account(table, source)
            if self._renames:  # the part's recordings renamed: written anew, not moved
                track_table.write_parquet(table, self.part_path(self._parts))
                path.unlink()
            else:
                path.replace(self.part_path(self._parts))
            self._parts += 1
        else:
            self.write(table, source, continues=continues)
            path.unlink()

    def _distinct(self, table: pa.Table, source: str, continues: bool) -> pa.Table:
        """``table`` with its recordings renamed where an earlier input holds the same names
        (``contracts.recording_names``); the pieces that continue a recording keep its rename."""
        if not continues:
            meta = track_table.read_meta(table)
            labels = [*self._sources, source or ", ".join(meta.source_files)]
            self._renames = recording_names.distinct_names([*self._metas, meta], labels)[-1]
        return recording_names.rename_recordings(table, self._renames)

    def _close_part(self) -> None:
        if self.directory and self._writer is not None:
            self._writer.close()
            self._writer = None

    def _account(self, table: pa.Table, source: str, continues: bool = False) -> None:
        """Count the rows and tracks of a piece; a new recording's metadata is merged (raises on
        a recording given twice)."""
        self.rows += table.num_rows
        self.tracks += len(track_table.track_boundaries(table)) - 1
        if continues:
            return
        meta = track_table.read_meta(table)
        self._metas.append(meta)
        self._sources.append(source or ", ".join(meta.source_files))
        track_table.merge_meta(self._metas, self._sources)  # raises on a recording given twice

    def _aligned(self, table: pa.Table) -> pa.Table:
        """``table`` in the file's schema: optional neighbour columns it lacks become nulls."""
        assert self._writer is not None
        target = self._writer.schema
        extra = set(table.column_names) - set(target.names)
        if extra:
            raise InputError(
                self.out,
                f"inputs differ in their neighbour columns ({sorted(extra)} not in the first input)",
                expected="inputs of one kind per Parquet file, or a dataset directory (--out DIR)",
            )
        arrays = [
            table.column(f.name) if f.name in table.column_names else pa.nulls(table.num_rows, f.type)
            for f in target
        ]
        return pa.Table.from_arrays(arrays, schema=target)

    def _finish(self) -> None:
        if not self._metas:
            raise InputError(self.out, "no rows to write", expected="at least one recording")
        if self.directory:
            self._close_part()
            return
        assert self._writer is not None
        meta = track_table.merge_meta(self._metas, self._sources).to_json().encode()
        self._writer.add_key_value_metadata(
            {track_table.META_KEY: meta, **track_table.arrow_schema_entry(self._writer.schema, meta)}
        )
        self._writer.close()


#: runs a task over items, yielding results in item order (inline, processes, Ray: workflows/engines)
OrderedMap = Callable[[Callable[[Any], str], Sequence[Any]], Iterator[str]]


def write_part(item: tuple[int, Piece], root: str) -> str:
    """A worker's task: read piece ``item[1]`` and write it as ``root/part-NNNNN.parquet``."""
    number, piece = item
    path = Path(root) / f"part-{number:05d}.parquet"
    table = piece.read()
    pq.write_table(table, path, row_group_size=ROW_GROUP_ROWS, **track_table.parquet_options(table.schema))
    return str(path)


def _parts(piece: Piece, *, whole: bool) -> Iterator[tuple[pa.Table, bool]]:
    """``piece`` whole, or as the parts its reader builds (:meth:`Piece.read_parts`)."""
    if whole:
        yield piece.read(), piece.continues
    else:
        yield from piece.read_parts()


def _write_while_reading(
    writer: TrackTableWriter, pieces: Sequence[Piece], done: Callable[[int], None]
) -> None:
    """Write each part on a thread while the next one is read: Parquet's encoder runs on one core
    and releases the GIL, so both cores stay busy (two parts in memory at a time). A part is a
    piece, or into a file a part of whole tracks of it where its reader builds those one at a time
    (:meth:`Piece.read_parts`: a highD recording); a directory output keeps a file per piece. The
    parts are written in order; the first error, of a read or a write, is raised once the write
    before it has ended. ``done(n)``: n more pieces written."""
    with ThreadPoolExecutor(1, thread_name_prefix="convert: writing") as pool:
        pending: Future[None] | None = None
        ended = 0  # pieces whose last part is the pending write

        def written() -> None:  # the write before, ended (its error raised here)
            nonlocal ended
            if pending is not None:
                pending.result()
            if ended:
                done(ended)
                ended = 0

        for piece in pieces:
            parts = _parts(piece, whole=writer.directory)
            while True:
                try:
                    part = next(parts, None)
                except BaseException:
                    written()  # an error of the earlier part's write comes first
                    raise
                if part is None:
                    break
                written()
                pending = pool.submit(writer.write, part[0], piece.paths[0], continues=part[1])
                del part
            ended += 1
        written()


def convert(
    pieces: Sequence[Piece], out: str | Path, *, directory: bool, ordered_map: OrderedMap | None = None
) -> tuple[int, int]:
    """Write the pieces as one track table (a Parquet file, or a dataset ``directory``), a piece
    read while the one before it is written (two in memory at a time); with ``ordered_map``
    pieces are read by workers that write parts, which the driver appends in order (the same
    output as one process). Returns (rows, tracks)."""
    with TrackTableWriter(out, directory=directory) as writer:
        if ordered_map is None:
            with job_progress(desc="convert", total=len(pieces), unit="piece") as shown:
                _write_while_reading(writer, pieces, shown.update)
        else:
            with SpillDirectory(Path(out), "parts") as parts:
                task = functools.partial(write_part, root=str(parts.path))
                results = ordered_map(task, list(enumerate(pieces)))
                for i, (piece, path) in enumerate(zip(pieces, results, strict=False)):
                    continued = i + 1 < len(pieces) and pieces[i + 1].continues
                    writer.add_part(
                        Path(path), piece.paths[0], continues=piece.continues, continued=continued
                    )
    return writer.rows, writer.tracks
