"""Whole datasets piece by piece: bounded parts of the inputs, each read on its own (in any process
or on any machine), and the track table written as the pieces come.

A :class:`Piece` is whole recordings of one input: a highD recording, a range of rows of a Parquet
track table (found from its row groups, never by loading it), one log, one NGSIM location and
period. Memory is set by the largest piece, not by the dataset (docs/design.md, streaming).
For windows, a recording of a Parquet track table larger than a piece is cut into **chunks** of
whole tracks (:func:`track_chunks`): each chunk's target tracks, with every other vehicle of the
recording during their lifetime as context (neighbours), so that the windows of the chunks,
appended in order, are those of the whole recording.

Outputs: :class:`TrackTableWriter` writes one Parquet file (row groups per piece; the table
metadata naming every recording is stored when the file is complete) or a dataset directory of
one Parquet file per piece (``part-00000.parquet``, …), which every reader of track tables
accepts in place of a file.

Size: the piece plan, the per-piece readers and the two writers are one protocol (what a piece is
decides how it is read and where its rows go); split up, each file would restate the others.
"""

from __future__ import annotations

import contextlib
import functools
import shutil
import tempfile
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from types import TracebackType
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from lanecast.io_adapters.contracts import track_table
from lanecast.io_adapters.datasets.highd import reader as highd
from lanecast.io_adapters.datasets.highd import stream as highd_stream
from lanecast.io_adapters.datasets.ngsim import stream as ngsim_stream
from lanecast.io_adapters.datasets.parquet import pieces as chunks
from lanecast.io_adapters.datasets.parquet import tables as parquet_format
from lanecast.io_adapters.datasets.parquet.pieces import Chunk
from lanecast.io_adapters.errors import InputError, TrackTableError
from lanecast.io_adapters.files import atomic_path, check_input
from lanecast.io_adapters.formats import registry

LONG = ("whole", "tracks", "context")  # what a recording larger than a piece becomes (plan)
PARTS = ("part-*.parquet",)  # the files of a dataset directory output (a new one replaces them)
MAX_ROWS = 1_000_000  # input rows per piece where recordings are small enough to group (memory ~ rows)
ROW_GROUP_ROWS = 1 << 17  # rows per Parquet row group of written track tables (a chunk of a long
# recording reads the groups that hold its context: small groups, little decoded in vain)
STREAM_BYTES = 256 << 20  # NGSIM CSV exports from this size on are read incrementally
HIGHD_STREAM_BYTES = 256 << 20  # highD tracks files likewise (longer than ~30 dense minutes; a
# real highD recording, 15-20 minutes, is read whole: 10-20 % faster, 0.7 GB)


@dataclass(frozen=True)
class Piece:
    """Whole recordings of one input, read on their own.

    ``fmt``: reader name; ``paths``: what the reader is given; for Parquet, ``row_groups`` to read
    and the ``offset``/``rows`` of the piece within them (``rows`` -1: all); ``options``: reader
    options (picklable, e.g. ``location``).
    """

    fmt: str
    paths: tuple[str, ...]
    row_groups: tuple[int, ...] = ()
    offset: int = 0
    rows: int = -1
    options: tuple[tuple[str, Any], ...] = field(default_factory=tuple)
    spilled: str = ""  # NGSIM CSV export: a recording spilled by ngsim_stream (JSON)
    chunk: Chunk | None = None  # a chunk of whole tracks of one long recording (windows only)
    continues: bool = False  # whole tracks of the previous piece's recording (a long one cut)

    @property
    def label(self) -> str:
        if self.spilled:
            return f"{self.paths[0]} recording {ngsim_stream.SpilledRecording.from_json(self.spilled).name}"
        where = ""
        if self.row_groups:
            where = (
                f" rows {self.offset}+{self.rows} of row groups {self.row_groups[0]}…{self.row_groups[-1]}"
            )
            if self.chunk is not None:
                where += (
                    f" (tracks {self.chunk.targets[0]}…{self.chunk.targets[1]} of {self.chunk.recording})"
                )
        return ", ".join(self.paths) + where

    def read(self) -> pa.Table:
        """The piece as a validated track table whose metadata names only its recordings."""
        if self.spilled:
            return ngsim_stream.read_spilled(ngsim_stream.SpilledRecording.from_json(self.spilled))
        if not self.row_groups:
            return registry.reader(self.fmt).read([Path(p) for p in self.paths], **dict(self.options))
        path = Path(self.paths[0])
        try:
            pf = pq.ParquetFile(path, page_checksum_verification=True)
            table = pf.read_row_groups(list(self.row_groups))
        except (OSError, pa.ArrowException) as exc:
            raise InputError(
                path, f"not a readable Parquet file: {exc}", expected="a lanecast track table"
            ) from exc
        table = table.slice(self.offset, table.num_rows - self.offset if self.rows < 0 else self.rows)
        first = sum(pf.metadata.row_group(i).num_rows for i in range(self.row_groups[0])) + self.offset
        # whole recordings: tracks written in another order are put in the contract's order
        return _with_meta(table, pf, path, first, sort=True)  # errors name rows of the file

    def read_with_context(self) -> pa.Table:
        """What windows need of the piece: :meth:`read`, or for a chunk its target tracks with
        the rows of every other track of the recording within the chunk's context times, one row
        group in memory at a time (sorted by track as in the file)."""
        if self.chunk is None:
            return self.read()
        chunk, path = self.chunk, Path(self.paths[0])
        try:
            pf = pq.ParquetFile(path, page_checksum_verification=True)
            table = chunks.read_chunk(pf, chunk)
        except (OSError, pa.ArrowException) as exc:
            raise InputError(
                path, f"not a readable Parquet file: {exc}", expected="a lanecast track table"
            ) from exc
        return _with_meta(table, pf, path)


def uncut(pieces: Sequence[Piece], keep_whole: Callable[[Chunk], bool]) -> list[Piece]:
    """``pieces`` with the chunks of every recording for which ``keep_whole`` holds put back
    together as one piece of the whole recording (what a chunk cannot reproduce exactly)."""
    out: list[Piece] = []
    for piece in pieces:
        chunk = piece.chunk
        if chunk is None or not keep_whole(chunk):
            out.append(piece)
        elif not piece.continues:
            pf = pq.ParquetFile(piece.paths[0])
            starts = np.r_[
                0, np.cumsum([pf.metadata.row_group(i).num_rows for i in range(pf.num_row_groups)])
            ]
            out.append(_row_range(Path(piece.paths[0]), starts.astype(np.int64), *chunk.rows))
    return out


def _with_meta(
    table: pa.Table, pf: pq.ParquetFile, path: Path, first_row: int = 0, *, sort: bool = False
) -> pa.Table:
    """``table`` (rows of ``pf`` from ``first_row`` on) validated, with its recordings' metadata only;
    with ``sort`` (a piece of whole recordings) its rows put in (recording, track_id, frame) order."""
    meta = track_table.read_meta(track_table.file_schema(pf), source=path)
    names = track_table.recording_codes(table)[0]
    meta = track_table.restrict_meta(meta, names.tolist())
    table = track_table.widen_types(
        table.replace_schema_metadata({track_table.META_KEY: meta.to_json().encode()})
    )
    order = track_table.file_order(table) if sort else None
    if order is not None:
        table = table.take(pa.array(order))
    track_table.validate(
        table, source=path, first_row=first_row, file_rows=None if order is None else order + first_row
    )
    return table


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
    readers, e.g. ``location``), in dataset order. ``long``: what a recording of a Parquet track
    table larger than ``max_rows`` becomes: ``whole`` one piece, ``tracks`` pieces of whole tracks
    (each but the first ``continues`` the recording: for convert), ``context`` chunks of whole
    tracks with the traffic around them (for windows: :meth:`Piece.read_with_context`).

    With ``spill_dir`` (storage every worker sees, removed by the caller), NGSIM CSV exports and
    highD tracks files of at least ``stream_bytes`` (default STREAM_BYTES, HIGHD_STREAM_BYTES for
    highD) are read incrementally into one spill per recording there (a highD spill is a Parquet
    track table, cut as ``long`` says).
    """
    if long not in LONG:
        raise ValueError(f"long={long!r}, expected one of {LONG}")
    highd_bytes = HIGHD_STREAM_BYTES if stream_bytes is None else stream_bytes
    stream_bytes = STREAM_BYTES if stream_bytes is None else stream_bytes
    options = dict(options or {})
    opts = {fmt: tuple(sorted(registry.options_for(fmt, options).items())) for fmt in registry.READERS}
    groups: dict[str, list[Path]] = {}
    for p in map(check_input, paths):  # before anything opens it (a FIFO would block)
        groups.setdefault(fmt or registry.detect(p), []).append(p)
    pieces: list[Piece] = []
    for name, group in groups.items():
        if name == parquet_format.FORMAT:
            for file in parquet_format.files(group):
                pieces.extend(parquet_pieces(file, max_rows, long=long))
        elif name == highd.FORMAT:
            for rec in highd.recordings(group):
                tracks = rec.path("tracks")
                if spill_dir is None or not tracks.is_file() or tracks.stat().st_size < highd_bytes:
                    pieces.append(Piece(name, (str(tracks),), options=opts[name]))
                    continue
                prefix = str(options.get("recording_prefix", "highd"))
                for spill in highd_stream.split_tracks(rec, Path(spill_dir), prefix):
                    pieces.extend(parquet_pieces(spill, max_rows, long=long))
        elif name == "ngsim":  # recordings are per file (location, file, period)
            for p in group:
                pieces.extend(_ngsim_pieces(p, spill_dir, stream_bytes, options))
        elif name in ("mcap", "rosbag"):
            pieces.extend(Piece(name, (str(p),), options=opts[name]) for p in group)
        else:
            pieces.append(Piece(name, tuple(map(str, group)), options=opts[name]))
    return pieces


class SpillDirectory:
    """A temporary directory beside an output for the spills of a run; removed on exit."""

    def __init__(self, out: Path) -> None:
        out.parent.mkdir(parents=True, exist_ok=True)
        self.path = Path(tempfile.mkdtemp(prefix=f".{out.name}.spill-", dir=out.parent))

    def __enter__(self) -> SpillDirectory:
        return self

    def __exit__(self, *_: object) -> None:
        shutil.rmtree(self.path, ignore_errors=True)


def spill_directory(out: str | Path) -> SpillDirectory:
    return SpillDirectory(Path(out))


def _ngsim_pieces(
    path: Path, spill_dir: Path | None, stream_bytes: int, options: dict[str, Any]
) -> list[Piece]:
    whole = [Piece("ngsim", (str(path),), options=tuple(sorted(options.items())))]
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
    return [Piece("ngsim", (str(path),), spilled=rec.to_json()) for rec in spilled]


def recording_runs(path: Path) -> tuple[list[str], np.ndarray, np.ndarray]:
    """(names, first row, end row) of each recording of a Parquet track table, in file order,
    from its ``recording`` column only, one row group at a time."""
    pf = pq.ParquetFile(path, page_checksum_verification=True)
    names: list[str] = []
    starts: list[int] = []
    offset = 0
    for i in range(pf.num_row_groups):
        col = pf.read_row_group(i, columns=["recording"]).column("recording")
        for chunk in col.chunks:
            chunk = chunk if pa.types.is_dictionary(chunk.type) else chunk.dictionary_encode()
            if chunk.null_count:  # a null recording has no code: name its row, as validate does
                row = offset + int(np.flatnonzero(chunk.is_null().to_numpy(zero_copy_only=False))[0])
                raise TrackTableError(f"{path}: row {row}: column 'recording' is null")
            codes = chunk.indices.to_numpy(zero_copy_only=False)
            if codes.size == 0:
                continue
            dictionary = chunk.dictionary.to_pylist()
            change = np.r_[0, np.flatnonzero(codes[1:] != codes[:-1]) + 1]
            for row, code in zip(change.tolist(), codes[change].tolist(), strict=True):
                name = str(dictionary[code])
                if not names or names[-1] != name:
                    names.append(name)
                    starts.append(offset + row)
            offset += codes.size
    first = np.asarray(starts, dtype=np.int64)
    return names, first, np.r_[first[1:], offset].astype(np.int64)


def parquet_pieces(path: Path, max_rows: int = MAX_ROWS, *, long: str = "whole") -> list[Piece]:
    """Pieces of whole recordings of one Parquet track table, each at most ``max_rows`` rows unless
    one recording alone is larger (then cut as ``long`` says, see :func:`plan`), each reading only
    the row groups that hold its rows."""
    try:
        pf = pq.ParquetFile(path, page_checksum_verification=True)
        names, first, end = recording_runs(path)
    except (OSError, pa.ArrowException, KeyError) as exc:
        raise InputError(
            path, f"not a readable Parquet track table: {exc}", expected="a lanecast track table"
        ) from exc
    again = [k for k, name in enumerate(names) if name in names[:k]]
    if again and pf.metadata.num_rows <= max_rows:  # recordings interleaved: read whole, put in order
        return [Piece(parquet_format.FORMAT, (str(path),))]
    if again:
        k = again[0]
        raise TrackTableError(
            f"{path}: row {int(first[k])}: recording {names[k]!r} starts again after rows of "
            f"{names[k - 1]!r}: rows are not sorted by (recording, track_id, frame)"
        )
    group_rows = [pf.metadata.row_group(i).num_rows for i in range(pf.num_row_groups)]
    group_start = np.r_[0, np.cumsum(group_rows)].astype(np.int64)
    pieces: list[Piece] = []
    i = 0
    while i < len(names):
        j = i + 1
        while j < len(names) and end[j] - first[i] <= max_rows:
            j += 1
        lo, hi = int(first[i]), int(end[j - 1])
        if long != "whole" and hi - lo > max_rows:  # one recording (j == i + 1), larger than a piece
            pieces.extend(
                track_chunks(path, pf, names[i], (lo, hi), group_start, max_rows, context=long == "context")
            )
        else:
            pieces.append(_row_range(path, group_start, lo, hi))
        i = j
    return pieces


def _row_range(
    path: Path, group_start: np.ndarray, lo: int, hi: int, chunk: Chunk | None = None, continues: bool = False
) -> Piece:
    """The piece of rows [lo, hi) of a Parquet file whose row groups start at ``group_start``."""
    g0 = int(np.searchsorted(group_start, lo, side="right") - 1)
    g1 = int(np.searchsorted(group_start, hi, side="left"))
    return Piece(
        parquet_format.FORMAT,
        (str(path),),
        row_groups=tuple(range(g0, g1)),
        offset=lo - int(group_start[g0]),
        rows=hi - lo,
        chunk=chunk,
        continues=continues,
    )


def track_chunks(
    path: Path,
    pf: pq.ParquetFile,
    recording: str,
    rows: tuple[int, int],
    group_start: np.ndarray,
    max_rows: int = MAX_ROWS,
    *,
    context: bool = True,
) -> list[Piece]:
    """The pieces of the long recording ``recording`` (rows [first, end) of ``path``): whole
    tracks of about ``max_rows`` rows each, with their context (windows) or without (convert);
    every piece but the first ``continues`` the recording (:func:`chunks.plan_chunks`)."""
    return [
        _row_range(path, group_start, lo, hi, chunk if context else None, continues)
        for lo, hi, chunk, continues in chunks.plan_chunks(pf, recording, rows, group_start, max_rows)
    ]


def iter_tables(pieces: Sequence[Piece]) -> Iterator[pa.Table]:
    """Read the pieces one after the other (one in memory at a time)."""
    for piece in pieces:
        yield piece.read()


class TrackTableWriter:
    """Writes a track table piece by piece, atomically: one Parquet file, or (``directory``) a
    dataset directory of one Parquet file per piece (the pieces of a long recording cut in whole
    tracks share one). Recording names must be unique across pieces, but for a piece that
    ``continues`` the previous one's recording."""

    def __init__(self, out: str | Path, *, directory: bool) -> None:
        self.out, self.directory = Path(out), directory
        self.rows = self.tracks = 0
        self._metas: list[track_table.TableMeta] = []
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
        if not continues:
            self._account(track_table.read_meta(table), source)
        self.rows += table.num_rows
        self.tracks += len(track_table.track_boundaries(table)) - 1
        if self.directory:
            if not continues:
                self._close_part()
                self._writer = pq.ParquetWriter(
                    self.part_path(self._parts), table.schema, compression="zstd", write_page_checksum=True
                )
                self._parts += 1
            assert self._writer is not None
            self._writer.write_table(table.cast(self._writer.schema), row_group_size=ROW_GROUP_ROWS)
            return
        if self._writer is None:
            self._writer = pq.ParquetWriter(
                self._tmp, table.schema.remove_metadata(), compression="zstd", write_page_checksum=True
            )
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
            self._account(track_table.read_meta(table), source)
            self.rows += table.num_rows
            self.tracks += len(track_table.track_boundaries(table)) - 1
            path.replace(self.part_path(self._parts))
            self._parts += 1
        else:
            self.write(table, source, continues=continues)
            path.unlink()

    def _close_part(self) -> None:
        if self.directory and self._writer is not None:
            self._writer.close()
            self._writer = None

    def _account(self, meta: track_table.TableMeta, source: str) -> None:
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
    pq.write_table(
        piece.read(), path, compression="zstd", row_group_size=ROW_GROUP_ROWS, write_page_checksum=True
    )
    return str(path)


def convert(
    pieces: Sequence[Piece], out: str | Path, *, directory: bool, ordered_map: OrderedMap | None = None
) -> tuple[int, int]:
    """Write the pieces as one track table (a Parquet file, or a dataset ``directory``), one piece
    in memory at a time; with ``ordered_map`` pieces are read by workers that write parts, which
    the driver appends in order (the same output as one process). Returns (rows, tracks)."""
    with TrackTableWriter(out, directory=directory) as writer:
        if ordered_map is None:
            for piece in pieces:
                writer.write(piece.read(), piece.paths[0], continues=piece.continues)
        else:
            with _parts_dir(Path(out)) as root:
                task = functools.partial(write_part, root=str(root))
                results = ordered_map(task, list(enumerate(pieces)))
                for i, (piece, path) in enumerate(zip(pieces, results, strict=False)):
                    continued = i + 1 < len(pieces) and pieces[i + 1].continues
                    writer.add_part(
                        Path(path), piece.paths[0], continues=piece.continues, continued=continued
                    )
    return writer.rows, writer.tracks


@contextlib.contextmanager
def _parts_dir(out: Path) -> Iterator[Path]:
    """A temporary directory beside ``out`` for workers' parts, removed at the end."""
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.parts-", dir=out.parent))
    try:
        yield tmp
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
