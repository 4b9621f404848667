"""Pieces: bounded parts of a dataset's inputs, each read on its own (in any process or on any
machine), and the pieces of a Parquet track table, found from its row groups, never by loading it.

A :class:`Piece` is whole recordings of one input: a highD recording, a range of rows of a Parquet
track table, one log, one NGSIM location and period. Memory is set by the largest piece, not by
the dataset (docs/design.md, streaming). For windows, a recording of a Parquet track table larger
than a piece is cut into **chunks** of whole tracks (:func:`track_chunks`): each chunk's target
tracks, with every other vehicle of the recording during their lifetime as context, so that the
windows of the chunks, appended in order, are those of the whole recording.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from lanecast.io_adapters.contracts import track_table
from lanecast.io_adapters.datasets.ngsim import stream as ngsim_stream
from lanecast.io_adapters.datasets.parquet import pieces as chunks
from lanecast.io_adapters.datasets.parquet.pieces import Chunk
from lanecast.io_adapters.errors import InputError, TrackTableError
from lanecast.io_adapters.formats import registry

MAX_ROWS = 1_000_000  # input rows per piece where recordings are small enough to group (memory ~ rows)


@contextlib.contextmanager
def _readable(
    path: Path, what: str = "Parquet file", also: tuple[type[Exception], ...] = ()
) -> Iterator[None]:
    """Arrow's and the file system's errors reading ``path`` as an InputError naming it."""
    try:
        yield
    except (OSError, pa.ArrowException, *also) as exc:
        raise InputError(path, f"not a readable {what}: {exc}", expected="a lanecast track table") from exc


def _open(path: Path) -> pq.ParquetFile:
    return pq.ParquetFile(path, page_checksum_verification=True)


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
            return registry.reader(self.fmt).read([Path(p) for p in self.paths], dict(self.options))
        path = Path(self.paths[0])
        with _readable(path):
            pf = _open(path)
            table = pf.read_row_groups(list(self.row_groups))
        table = table.slice(self.offset, table.num_rows - self.offset if self.rows < 0 else self.rows)
        first = int(chunks.group_starts(pf)[self.row_groups[0]]) + self.offset
        # whole recordings: tracks written in another order are put in the contract's order
        return _with_meta(table, pf, path, first, sort=True)  # errors name rows of the file

    def read_parts(self) -> Iterator[tuple[pa.Table, bool]]:
        """:meth:`read` as parts of whole tracks, each with whether it continues the recording of
        the part before (the first: :attr:`continues`), where the reader builds them one at a time
        (``registry.PartsReaderModule``); else the whole piece."""
        if self.spilled or self.row_groups:
            yield self.read(), self.continues
            return
        parts = registry.reader(self.fmt).read_parts([Path(p) for p in self.paths], dict(self.options))
        for i, (table, continues) in enumerate(parts):
            yield table, continues if i else self.continues

    def read_with_context(self) -> pa.Table:
        """What windows need of the piece: :meth:`read`, or for a chunk its target tracks with
        the rows of every other track of the recording within the chunk's context times, one row
        group in memory at a time (sorted by track as in the file)."""
        if self.chunk is None:
            return self.read()
        path = Path(self.paths[0])
        with _readable(path):
            pf = _open(path)
            table = chunks.read_chunk(pf, self.chunk)
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
            starts = chunks.group_starts(pq.ParquetFile(piece.paths[0]))
            out.append(_row_range(Path(piece.paths[0]), starts, *chunk.rows))
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
        table = track_table.take_rows(table, order)
    track_table.validate(
        table, source=path, first_row=first_row, file_rows=None if order is None else order + first_row
    )
    return table


def recording_runs(path: Path) -> tuple[list[str], np.ndarray, np.ndarray]:
    """(names, first row, end row) of each recording of a Parquet track table, in file order,
    from its ``recording`` column only, one row group at a time."""
    pf = _open(path)
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
    one recording alone is larger (then cut as ``long`` says, see ``streaming.plan``), each
    reading only the row groups that hold its rows."""
    with _readable(path, "Parquet track table", (KeyError,)):
        pf = _open(path)
        if "recording" not in pf.schema_arrow.names:  # as validate names it, before it is looked up
            raise TrackTableError(f"{path}: missing column 'recording'")
        names, first, end = recording_runs(path)
    again = [k for k, name in enumerate(names) if name in names[:k]]
    if again and pf.metadata.num_rows <= max_rows:  # recordings interleaved: read whole, put in order
        return [Piece(registry.PARQUET, (str(path),))]
    if again:
        k = again[0]
        raise TrackTableError(
            f"{path}: row {int(first[k])}: recording {names[k]!r} starts again after rows of "
            f"{names[k - 1]!r}: rows are not sorted by (recording, track_id, frame)"
        )
    group_start = chunks.group_starts(pf)
    pieces: list[Piece] = []
    i = 0
    while i < len(names):
        j = i + 1
        while j < len(names) and end[j] - first[i] <= max_rows:
            j += 1
        lo, hi = int(first[i]), int(end[j - 1])
        if long != "whole" and hi - lo > max_rows:  # one recording (j == i + 1), larger than a piece
            pieces.extend(
                track_chunks(pf, path, names[i], (lo, hi), group_start, max_rows, long == "context")
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
        registry.PARQUET,
        (str(path),),
        row_groups=tuple(range(g0, g1)),
        offset=lo - int(group_start[g0]),
        rows=hi - lo,
        chunk=chunk,
        continues=continues,
    )


def track_chunks(
    pf: pq.ParquetFile,
    path: Path,
    recording: str,
    rows: tuple[int, int],
    group_start: np.ndarray,
    max_rows: int,
    context: bool,
) -> list[Piece]:
    """The pieces of the long recording ``recording`` (rows [first, end) of ``path``): whole
    tracks of about ``max_rows`` rows each, with their context (windows) or without (convert);
    every piece but the first ``continues`` the recording (:func:`chunks.plan_chunks`)."""
    return [
        _row_range(path, group_start, lo, hi, chunk if context else None, continues)
        for lo, hi, chunk, continues in chunks.plan_chunks(pf, recording, rows, group_start, max_rows)
    ]
