"""Chunks of a long recording of a Parquet track table, for windows (docs/design.md, whole datasets).

A recording larger than a piece is cut into chunks of consecutive whole tracks; each chunk is read
with the rows of every other track of the recording alive during its tracks' lifetime as context
(the neighbours its windows see), so that the chunks' windows, appended in order, are those of
the whole recording. Only the chunk's own tracks (``targets``) get windows.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from lanecast.io_adapters.contracts import track_table
from lanecast.io_adapters.contracts.track_runs import run_groups

CONTEXT_MARGIN_NS = 2_000_000_000  # context beyond the targets' lifetime: the native samples around
# their first and last 10 Hz frames (resampling interpolates between neighbours' samples)


@dataclass(frozen=True)
class Chunk:
    """Whole tracks ``targets`` (first, last track id) of the long recording ``recording`` (rows
    ``rows`` [first, end) of its file) and the context windows need: the rows of every other of its
    tracks at times ``context_ns`` [first, last] (the targets' lifetime and a margin), found in
    row groups ``context_groups``; what ``auto`` needs to pick the recording's neighbour method over
    the whole recording, not over a chunk (``ids_given``, ``lanes_everywhere``, ``road_frame``)."""

    recording: str
    rows: tuple[int, int]
    targets: tuple[int, int]
    context_ns: tuple[int, int]
    context_groups: tuple[int, ...]
    ids_given: tuple[str, ...]  # neighbour id columns with an id somewhere in the recording
    lanes_everywhere: bool  # every row of the recording has a lane id
    road_frame: bool  # the recording is in a road frame


def plan_chunks(
    pf: pq.ParquetFile, recording: str, rows: tuple[int, int], group_start: np.ndarray, max_rows: int
) -> list[tuple[int, int, Chunk, bool]]:
    """Chunks of the long recording ``recording`` (rows [first, end) of the track table ``pf``,
    whose row groups start at ``group_start``): consecutive whole tracks of about ``max_rows``
    rows each (one track alone may be larger), each with the rows of every other track alive
    during its tracks' lifetime (± CONTEXT_MARGIN_NS) as context. Returns (first row, end row,
    chunk, continues: not the first chunk) per chunk.

    A time cut would lose what windows take from a track's past and future (the run a window's
    stride counts from, labels and the window frame's chord, seconds away); whole tracks keep
    them, and their windows come in the order of the whole recording. Memory: the targets and the
    traffic during their lifetime (highway vehicles stay minutes; a vehicle present for hours
    brings those hours). Reads ``track_id``, ``time_ns``, ``lane_id`` and the neighbour id
    columns of the recording, one row group at a time.
    """
    lo, hi = rows
    g0 = int(np.searchsorted(group_start, lo, side="right") - 1)
    g1 = int(np.searchsorted(group_start, hi, side="left"))
    given = [c for c in track_table.NEIGHBOUR_COLUMNS if c in pf.schema_arrow.names]
    frame = track_table.read_meta(track_table.file_schema(pf)).recordings[recording].coordinate_frame
    track_parts, time_parts = [], []
    ids_given: set[str] = set()
    lanes_everywhere = True
    for g in range(g0, g1):
        a, b = max(lo, int(group_start[g])), min(hi, int(group_start[g + 1]))
        part = pf.read_row_group(g, columns=["track_id", "time_ns", "lane_id", *given])
        part = part.slice(a - int(group_start[g]), b - a)
        track_parts.append(part.column("track_id").to_numpy())
        time_parts.append(part.column("time_ns").to_numpy())
        lanes_everywhere &= part.column("lane_id").null_count == 0
        ids_given.update(c for c in given if part.column(c).null_count < part.num_rows)
    track = np.concatenate(track_parts)
    time_ns = np.concatenate(time_parts)
    del track_parts, time_parts
    first = np.r_[0, np.flatnonzero(track[1:] != track[:-1]) + 1]  # each track's first row
    last = np.r_[first[1:], track.size] - 1
    t_first, t_last, ids = time_ns[first], time_ns[last], track[first]
    groups = run_groups(np.r_[first, track.size], max_rows)  # consecutive tracks, max_rows a group
    out = []
    for a, b in itertools.pairwise(groups.tolist()):
        t0 = int(t_first[a:b].min()) - CONTEXT_MARGIN_NS
        t1 = int(t_last[a:b].max()) + CONTEXT_MARGIN_NS
        alive = np.flatnonzero((t_last >= t0) & (t_first <= t1))
        chunk = Chunk(
            recording=recording,
            rows=(lo, hi),
            targets=(int(ids[a]), int(ids[b - 1])),
            context_ns=(t0, t1),
            context_groups=tuple(int(g) for g in _groups_of(alive, first, last, lo, group_start)),
            ids_given=tuple(sorted(ids_given)),
            lanes_everywhere=bool(lanes_everywhere),
            road_frame=frame == "road",
        )
        out.append((int(first[a]) + lo, int(last[b - 1]) + 1 + lo, chunk, a > 0))
    return out


def _groups_of(
    tracks: np.ndarray, first: np.ndarray, last: np.ndarray, offset: int, group_start: np.ndarray
) -> np.ndarray:
    """The row groups holding any row of ``tracks`` (indices into ``first``/``last``, rows
    relative to ``offset``), sorted: every group from each track's first to its last row."""
    g_first = np.searchsorted(group_start, first[tracks] + offset, side="right") - 1
    g_last = np.searchsorted(group_start, last[tracks] + offset, side="right") - 1
    spans = g_last - g_first + 1
    within = np.arange(spans.sum()) - np.repeat(np.cumsum(spans) - spans, spans)
    return np.unique(np.repeat(g_first, spans) + within)


def group_starts(pf: pq.ParquetFile) -> np.ndarray:
    """int64 [G + 1]: the first row of each row group of ``pf``, and its row count at the end."""
    rows = [pf.metadata.row_group(i).num_rows for i in range(pf.num_row_groups)]
    return np.r_[0, np.cumsum(rows)].astype(np.int64)


def read_chunk(pf: pq.ParquetFile, chunk: Chunk) -> pa.Table:
    """A chunk's target tracks with the rows of every other track of its recording within the
    chunk's context times, one row group in memory at a time, sorted by track as in the file
    (without the table metadata)."""
    starts = group_starts(pf)
    kept = []
    for g in chunk.context_groups:
        lo = max(chunk.rows[0] - int(starts[g]), 0)  # the recording's rows of the group
        hi = min(chunk.rows[1], int(starts[g + 1])) - int(starts[g])
        group = pf.read_row_group(g).slice(lo, hi - lo)
        track = group.column("track_id").to_numpy()
        keep = (track >= chunk.targets[0]) & (track <= chunk.targets[1])
        if not keep.all():  # most groups hold targets only: kept without a copy
            time_ns = group.column("time_ns").to_numpy()
            keep |= (time_ns >= chunk.context_ns[0]) & (time_ns <= chunk.context_ns[1])
        kept.append(group if keep.all() else group.filter(pa.array(keep)))
    return pa.concat_tables(kept).combine_chunks()
