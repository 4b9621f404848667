"""A dataset's pieces -> a windows dataset on disk: :func:`write_windows`, what `lanecast windows`
runs. One piece (whole recordings, or a chunk of a long one with its context) in memory at a time,
optionally on worker processes or Ray; each piece's windows cut by the stages of
:mod:`lanecast.pipeline.make_windows` and appended to the dataset's files, the index and manifest of
all pieces written last. Equal to :func:`~lanecast.pipeline.make_windows.make_windows` of the whole
table (but for the manifest's timings).
"""

from __future__ import annotations

import functools
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import numpy as np
import pyarrow as pa

from lanecast.io_adapters.contracts import recording_names, track_table
from lanecast.io_adapters.contracts.windows import (
    HISTORY,
    Windows,
)
from lanecast.io_adapters.datasets.parquet.pieces import Chunk
from lanecast.io_adapters.errors import InputError
from lanecast.io_adapters.formats.pieces import Piece, uncut
from lanecast.io_adapters.windows_store.dataset import DatasetWriter, load_windows, save_shard
from lanecast.pipeline import neighbour_columns as nb_cols
from lanecast.pipeline import window_tensors as wt
from lanecast.pipeline.make_windows import (
    build_manifest,
    concat_arrays,
    prepare_group,
    splits_of_windows,
    window_index,
    window_parameters,
)
from lanecast.pipeline.resample import RATE_HZ
from lanecast.pipeline.splits import (
    SPLIT_METHODS,
)


@dataclass(frozen=True)
class WindowOptions:
    """How windows are cut (the options of :func:`make_windows` that a streamed dataset supports)."""

    stride: int = 10
    require_future: bool = True
    split: str = "pip"
    seed: int = 0
    neighbours: str = "auto"
    lane_width: float = nb_cols.LANE_WIDTH
    neighbour_range: float = nb_cols.NEIGHBOUR_RANGE_M

    def check(self) -> None:
        if self.stride < 1:
            raise InputError(None, f"stride {self.stride}", expected="a stride of at least 1 frame")
        if not self.neighbour_range > 0:
            raise InputError(
                None, f"neighbour range {self.neighbour_range}", expected="a positive range in metres"
            )
        if self.split not in SPLIT_METHODS:
            raise InputError(None, f"unknown split method {self.split!r}", expected=f"one of {SPLIT_METHODS}")


@dataclass
class PieceWindows:
    """The windows of one piece of a dataset (whole recordings), in dataset order.

    ``arrays``: inputs/present/future/maneuver in memory, or None when a worker wrote them to
    ``shard`` (then only the small per-window columns travel back to the driver).
    """

    meta_json: str  # the piece's TableMeta
    names: list[str]  # recordings with rows
    max_track: dict[str, int]  # largest track id of each recording (over input rows)
    rec_code: np.ndarray  # int64 [W] into names
    track: np.ndarray  # int64 [W]
    t0_ns: np.ndarray  # int64 [W]
    origin: np.ndarray  # float64 [W, 3]
    methods: dict[str, str]
    skipped: dict[str, str]
    timings: dict[str, float]
    arrays: dict[str, np.ndarray] | None = None
    shard: str | None = None
    chunk_of: str = ""  # the recording a chunk piece is part of (its metadata is given once)
    label: str = ""  # the piece's input, for errors (a dataset part, a file's row groups)


class Buffers(Protocol):
    """Where a piece's inputs and presence are gathered: ``take(n)`` gives [n, 4, 8, 30] float32
    and [n, 8, 30] bool arrays (a :class:`DatasetWriter`'s staging memory)."""

    def take(self, n: int) -> tuple[np.ndarray, np.ndarray]: ...


def piece_windows(
    table: pa.Table, options: WindowOptions, buffers: Buffers | None = None, chunk: Chunk | None = None
) -> PieceWindows:
    """Every window of one piece (a validated track table of whole recordings, or a ``chunk``'s
    target tracks and their context); inputs and presence go into ``buffers`` when given (valid
    until their next use)."""
    meta = track_table.read_meta(table)
    prep = prepare_group(
        table,
        meta,
        options.stride,
        options.require_future,
        None,
        options.neighbours if chunk is None else chunk_method(chunk, meta, options.neighbours),
        options.lane_width,
        options.neighbour_range,
        None if chunk is None else chunk.targets,
    )
    n = prep.t0_rows.size
    out = None if buffers is None else buffers.take(n)  # None: gather allocates them
    t = time.perf_counter()
    arrays = wt.gather(prep.cols, prep.neighbour_rows, prep.labels, prep.t0_rows, prep.fwd, out=out)
    prep.timings["windows_s"] += time.perf_counter() - t
    names, codes = track_table.recording_codes(table)
    max_track = np.full(names.size, np.iinfo(np.int64).min, dtype=np.int64)
    np.maximum.at(max_track, codes, table.column("track_id").to_numpy())
    cols = prep.cols
    return PieceWindows(
        meta_json=meta.to_json(),
        names=[str(v) for v in cols.names],
        max_track={str(k): int(v) for k, v in zip(names, max_track, strict=True)},
        rec_code=cols.rec[prep.t0_rows].astype(np.int64),
        track=cols.track[prep.t0_rows].astype(np.int64),
        t0_ns=cols.time_ns[prep.t0_rows].astype(np.int64),
        origin=arrays.origin,
        methods=prep.methods,
        skipped=prep.skipped,
        timings=prep.timings,
        chunk_of="" if chunk is None else chunk.recording,
        arrays={
            "inputs": arrays.inputs,
            "present": arrays.present,
            "future": arrays.future,
            "maneuver": arrays.maneuver,
        },
    )


def chunk_method(chunk: Chunk, meta: track_table.TableMeta, method: str) -> str:
    """The neighbour method of a chunk's recording: ``auto`` decided over the whole recording
    (docs/design.md §2: the source's ids where it gives all seven, else lanes in a road frame where
    every row has a lane id, else bands), as the unchunked recording decides it."""
    if method != "auto":
        return method
    if set(nb_cols.SOURCE_COLUMNS.values()) <= set(chunk.ids_given):
        return "source"
    road = meta.recordings[chunk.recording].coordinate_frame == "road"
    return "lanes" if chunk.lanes_everywhere and road else "bands"


def piece_shard(piece: Piece, options: WindowOptions, shard_root: str, number: int) -> PieceWindows:
    """A worker's task: read ``piece``, cut its windows, write their arrays as shard ``number``
    under ``shard_root`` (storage the driver names) and return the rest (small)."""
    result = piece_windows(piece.read_with_context(), options, chunk=piece.chunk)
    result.label = piece.label
    assert result.arrays is not None
    shard = save_shard(Path(shard_root) / f"{number:06d}", result.arrays)
    result.arrays, result.shard = None, str(shard)
    return result


#: runs a task over items, yielding results in item order (inline, a process pool, Ray: workflows)
OrderedMap = Callable[[Callable[[Any], PieceWindows], Sequence[Any]], Iterator[PieceWindows]]


def write_windows(
    pieces: Sequence[Piece],
    out: str | Path,
    options: WindowOptions | None = None,
    *,
    ordered_map: OrderedMap | None = None,
    allow_empty: bool = False,
    sources: dict[str, Any] | None = None,
    replace_any: bool = False,
) -> Windows:
    """Stream the windows of a dataset's pieces (whole recordings each) into the dataset directory
    ``out``, written atomically; return it memory-mapped. An existing ``out`` holding files other
    than a dataset's is refused unless ``replace_any`` (``--force``).

    Memory is set by the largest piece: each piece's windows are appended to the arrays on disk
    before the next is read. With ``ordered_map`` (e.g. worker processes or Ray tasks) each piece
    is a task that writes a shard beside the output, appended in piece order, so the dataset is
    the same as with one process. Equal to :func:`make_windows` of the whole table (but for the
    manifest's timings).
    """
    options = options or WindowOptions()
    options.check()
    if options.neighbours == "lanes":  # lanes off a road frame run along the recording's mean
        # direction of travel, which a chunk would take from its own rows: such recordings whole
        pieces = uncut(pieces, lambda chunk: not chunk.road_frame)
    parts: list[PieceWindows] = []
    with DatasetWriter(out, replace_any=replace_any) as writer:
        if ordered_map is None:
            for piece in pieces:  # gathered into the dataset files' staging memory: no copy
                part = piece_windows(piece.read_with_context(), options, writer, piece.chunk)
                part.label = piece.label
                assert part.arrays is not None
                writer.append(part.arrays)
                part.arrays = None
                parts.append(part)
        else:
            root = str(writer.shard_root)
            task = functools.partial(_numbered_shard, options=options, shard_root=root)
            for part in ordered_map(task, list(enumerate(pieces))):
                assert part.shard is not None
                writer.append_shard(Path(part.shard))
                parts.append(part)
        writer.finish(*_index_and_manifest(parts, options, allow_empty, sources))
    return load_windows(out)


def _numbered_shard(item: tuple[int, Piece], options: WindowOptions, shard_root: str) -> PieceWindows:
    number, piece = item
    return piece_shard(piece, options, shard_root, number)


def _rename_piece(part: PieceWindows, renames: dict[str, str]) -> None:
    """A piece's recordings renamed wherever the piece names them (``renames``: old → new)."""
    if not renames:
        return
    part.names = [renames.get(n, n) for n in part.names]
    for field in ("max_track", "methods", "skipped"):
        setattr(part, field, {renames.get(k, k): v for k, v in getattr(part, field).items()})


def _index_and_manifest(
    parts: list[PieceWindows], options: WindowOptions, allow_empty: bool, sources: dict[str, Any] | None
) -> tuple[pa.Table, Callable[[Windows], dict[str, Any]]]:
    """The index of all windows (splits need every piece) and the manifest builder."""
    # a recording cut in chunks gives its metadata once (another repeat is an input given twice)
    first_chunks = {p.chunk_of: id(p) for p in reversed(parts) if p.chunk_of}
    given = [p for p in parts if not p.chunk_of or first_chunks[p.chunk_of] == id(p)]
    labels = [p.label or "an input" for p in given]
    metas = [track_table.TableMeta.from_json(p.meta_json) for p in given]
    renames = recording_names.distinct_names(metas, labels)  # two inputs' highd-01-upper kept apart
    if any(renames):
        of_chunk = {p.chunk_of: r for p, r in zip(given, renames, strict=True) if p.chunk_of}
        of_piece = {id(p): r for p, r in zip(given, renames, strict=True)}
        for p in parts:
            _rename_piece(p, of_chunk.get(p.chunk_of, {}) if p.chunk_of else of_piece.get(id(p), {}))
        metas = [recording_names.rename_meta(m, r) for m, r in zip(metas, renames, strict=True)]
    meta = track_table.merge_meta(metas, labels)
    max_track: dict[str, int] = {}
    for p in parts:  # chunks of one recording each saw part of its tracks
        for name, largest in p.max_track.items():
            max_track[name] = max(largest, max_track.get(name, largest))
    names = np.array(sorted(max_track), dtype=str)
    rec_codes = (
        np.concatenate([np.searchsorted(names, np.array(p.names, dtype=str))[p.rec_code] for p in parts])
        if parts
        else np.zeros(0, dtype=np.int64)
    ).astype(np.int64)
    track_ids = np.concatenate([p.track for p in parts]) if parts else np.zeros(0, dtype=np.int64)
    t0_times = np.concatenate([p.t0_ns for p in parts]) if parts else np.zeros(0, dtype=np.int64)
    origin = concat_arrays([p.origin for p in parts], (0, 3), np.float64)
    max_of_rec = np.array([max_track[str(n)] for n in names], dtype=np.int64)
    win_split = splits_of_windows(meta, names, max_of_rec, rec_codes, track_ids, options.split, options.seed)
    index = window_index(names[rec_codes], track_ids, t0_times, win_split, origin)
    with_windows = {p.names[c] for p in parts for c in np.unique(p.rec_code).tolist()}
    skipped = {k: v for p in parts for k, v in p.skipped.items() if k not in with_windows}
    methods = {k: v for p in parts for k, v in p.methods.items()}
    for name in meta.recordings:
        if name not in methods:
            skipped.setdefault(name, "no rows at 10 Hz (no sample on a multiple of 0.1 s within any track)")
    timings = {"resample_s": 0.0, "neighbours_s": 0.0, "windows_s": 0.0}
    for p in parts:
        for k, v in p.timings.items():
            timings[k] += v
    if index.num_rows == 0 and not allow_empty:
        reasons = "; ".join(f"{name}: {why}" for name, why in skipped.items()) or "no tracks"
        inputs = (sources or {}).get("inputs") or meta.source_files  # what was given, not its sources
        raise InputError(
            ", ".join(map(str, inputs)) or None,
            f"no windows: {reasons}",
            expected=f"tracks with {HISTORY / RATE_HZ:g} s of gap-free history"
            + (f" and {wt.FUTURE / RATE_HZ:g} s of future" if options.require_future else ""),
        )

    def manifest(windows: Windows) -> dict[str, Any]:
        doc = build_manifest(
            windows,
            meta,
            parameters=window_parameters(
                stride=options.stride,
                require_future=options.require_future,
                split=options.split,
                seed=options.seed,
                t0_ns_given=False,
                neighbours=options.neighbours,
                lane_width=options.lane_width,
                neighbour_range=options.neighbour_range,
            ),
            neighbour_methods=methods,
            skipped=skipped,
            timings=timings,
        )
        doc["sources"].update(sources or {})
        return doc

    return index, manifest
