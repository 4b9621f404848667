"""The seven neighbours of every row (docs/design.md §2), in slot order FL, F, FR, L, R, RL, RR.

Three ways, chosen per recording by :func:`neighbour_rows` (``method="auto"``):

- ``source``: the neighbour ids the source gives (highD: precedingId -> F, leftPrecedingId -> FL,
  leftAlongsideId -> L, leftFollowingId -> RL, right… likewise), used where the source gives all
  seven (each column has ids somewhere in the recording; NGSIM gives only preceding/following, so
  its neighbours are computed);
- ``lanes``: from lane ids and longitudinal positions with highD's definitions: F = the next vehicle
  ahead in the same lane; in the lane to the left (the lane on the +y side; lanes are ordered per
  recording by their mean lateral position, so any lane numbering works) and to the right:
  alongside = longitudinal overlap of the bodies (|dx| < (len_T + len_N) / 2, nearest if several),
  front / rear = the nearest ahead / behind that does not overlap. Used for recordings in a road
  frame where every row has a lane id (with ``method="lanes"`` also elsewhere, the longitudinal axis
  then being the recording's mean direction of travel);
- ``bands``: as ``lanes`` but with lateral bands one lane wide (3.75 m) in the target's own frame
  instead of lanes: |dy| < w/2 same lane, w/2 <= dy < 3w/2 left, -3w/2 < dy <= -w/2 right, among
  vehicles heading the same way (|heading difference| < 90°). Used for everything else: tables
  without lane ids, and logs or arterials (NGSIM Lankershim, Peachtree) in a fixed world frame,
  where vehicles drive both ways and turn.

Everything is vectorised over rows and frames (sorting and searchsorted; the band method compares
each vehicle with those of its frame within reach along the road, in chunks of pairs). Results are
row indices into the table (-1 = none) so that the window stage can gather with fancy indexing.

The columns, the row index and the slots are in :mod:`lanecast.pipeline.neighbour_columns`, the
band method in :mod:`lanecast.pipeline.neighbour_bands`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc

from lanecast.io_adapters.contracts.track_runs import run_bounds
from lanecast.io_adapters.errors import TrackTableError
from lanecast.pipeline.neighbour_bands import from_bands
from lanecast.pipeline.neighbour_columns import (
    _CANDIDATES,
    LANE_WIDTH,
    METHODS,
    NEIGHBOUR_RANGE_M,
    SLOTS,
    SOURCE_COLUMNS,
    Columns,
    RowIndex,
    columns,
    limit_range,
    road_coordinates,
)


def has_source_columns(table: pa.Table) -> bool:
    return all(name in table.column_names for name in SOURCE_COLUMNS.values())


def from_source(table: pa.Table, cols: Columns, index: RowIndex) -> np.ndarray:
    """Neighbour rows [n, 7] from the source's neighbour id columns (null, unknown id or self -> -1)."""
    out = np.full((cols.n, len(SLOTS)), -1, dtype=np.int64)
    for s, slot in enumerate(SLOTS):
        col = table.column(SOURCE_COLUMNS[slot])
        known = ~np.asarray(pc.is_null(col))
        ids = np.asarray(col.fill_null(-1).to_numpy()).astype(np.int64, copy=False)
        known &= ids != cols.track
        q = np.flatnonzero(known)
        out[q, s] = index.rows(cols.rec[q], ids[q], cols.frame[q])
    return out


def lane_ranks(rec: np.ndarray, lane: np.ndarray, lat: np.ndarray, n_rec: int) -> np.ndarray:
    """Rank of each row's lane within its recording, ordered by the lane's mean lateral position
    (rank + 1 = the next lane to the left, +y). int64 [n]."""
    lane_min = int(lane.min())
    width = int(lane.max()) - lane_min + 1
    key = rec * width + (lane - lane_min)
    groups, inv = np.unique(key, return_inverse=True)
    mean_lat = np.bincount(inv, lat) / np.bincount(inv)
    g_rec = groups // width
    order = np.lexsort((mean_lat, g_rec))
    pos = np.empty(groups.size, dtype=np.int64)
    pos[order] = np.arange(groups.size)
    first_of_rec = np.full(n_rec, groups.size, dtype=np.int64)
    np.minimum.at(first_of_rec, g_rec, pos)
    rank = pos - first_of_rec[g_rec]
    return rank[inv]


def from_lanes(cols: Columns, rows: np.ndarray | None = None) -> np.ndarray:
    """Neighbour rows [n, 7] from lane ids and longitudinal positions (highD's definitions).

    ``rows``: the rows taking part (default: those with a lane id); others get -1 and are nobody's
    neighbour.
    """
    out = np.full((cols.n, len(SLOTS)), -1, dtype=np.int64)
    sel = np.flatnonzero(cols.lane_known) if rows is None else np.asarray(rows, dtype=np.int64)
    if sel.size == 0:
        return out
    lon_all, lat_all = road_coordinates(cols)
    rec = cols.rec[sel]
    frame = cols.frame[sel]
    lon = lon_all[sel]
    length = cols.length[sel]
    rank = lane_ranks(rec, cols.lane[sel], lat_all[sel], cols.names.size)
    # Sort by (recording, frame, lane rank, lon); an integer key names each (recording, frame, lane).
    f_rel = frame - frame.min()
    n_f = int(f_rel.max()) + 1
    n_r = int(rank.max()) + 3
    gkey = (rec * n_f + f_rel) * n_r + (rank + 1)
    order = np.lexsort((lon, gkey))
    g_sorted = gkey[order]
    lon_sorted = lon[order]
    pos = np.empty(sel.size, dtype=np.int64)
    pos[order] = np.arange(sel.size)
    # F: the next one ahead in the same lane.
    nxt = pos + 1
    has_f = nxt < sel.size
    has_f[has_f] = g_sorted[nxt[has_f]] == gkey[has_f]
    local = np.full((sel.size, len(SLOTS)), -1, dtype=np.int64)
    local[has_f, SLOTS.index("F")] = order[nxt[has_f]]
    search = _GroupedSearch(g_sorted, lon_sorted)
    for side, slots in ((+1, ("FL", "L", "RL")), (-1, ("FR", "R", "RR"))):
        qkey = gkey + side
        g_lo = np.searchsorted(g_sorted, qkey, side="left")
        g_hi = np.searchsorted(g_sorted, qkey, side="right")
        ins = search.insertion(qkey, lon, g_lo, g_hi)
        cand = ins[:, None] + _CANDIDATES[None, :]
        valid = (cand >= g_lo[:, None]) & (cand < g_hi[:, None])
        cand_rows = order[np.clip(cand, 0, sel.size - 1)]
        dx = lon[cand_rows] - lon[:, None]
        half = 0.5 * (length[:, None] + length[cand_rows])
        front, along, rear = _pick_front_along_rear(dx, half, valid)
        for slot, pick in zip(slots, (front, along, rear), strict=True):
            got = pick >= 0
            local[got, SLOTS.index(slot)] = cand_rows[got, pick[got]]
    out[sel] = np.where(local >= 0, sel[np.maximum(local, 0)], -1)
    return out


class _GroupedSearch:
    """Insertion points of (group, value) queries into data sorted by (group, value).

    Fast path: one float64 key group_index * span + value, exact enough (ulp <= 1 µm) when
    groups x span is below 4.5e9 m; otherwise an exact merge by lexsort.
    """

    def __init__(self, g_sorted: np.ndarray, v_sorted: np.ndarray) -> None:
        self.g_sorted = g_sorted
        self.v_sorted = v_sorted
        n = g_sorted.size
        new = np.ones(n, dtype=bool)
        new[1:] = g_sorted[1:] != g_sorted[:-1]
        self.gidx = np.cumsum(new) - 1
        self.v_min = float(v_sorted.min()) if n else 0.0
        self.span = (float(v_sorted.max()) - self.v_min + 1.0) if n else 1.0
        n_groups = int(self.gidx[-1]) + 1 if n else 0
        self.fast = n_groups * self.span < 4.5e9
        if self.fast:
            self.key = self.gidx * self.span + (v_sorted - self.v_min)

    def insertion(
        self, q_group: np.ndarray, q_value: np.ndarray, g_lo: np.ndarray, g_hi: np.ndarray
    ) -> np.ndarray:
        """Number of data entries before each query (ties before), int64 [q]; g_lo/g_hi: the
        bounds of each query's group in the data (equal where the group is absent)."""
        if not self.fast:
            return _grouped_insertion(self.g_sorted, self.v_sorted, q_group, q_value)
        exists = g_hi > g_lo
        g = self.gidx[np.minimum(g_lo, self.gidx.size - 1)]
        qkey = g * self.span + np.clip(q_value - self.v_min, 0.0, self.span)
        ins = np.searchsorted(self.key, qkey, side="right")
        return np.where(exists, np.clip(ins, g_lo, g_hi), g_lo)


def _grouped_insertion(
    g_sorted: np.ndarray, v_sorted: np.ndarray, q_group: np.ndarray, q_value: np.ndarray
) -> np.ndarray:
    """For each query, the number of data entries (sorted by (group, value)) that come before
    (q_group, q_value), ties counted before. Exact (merge by lexsort), int64 [q]."""
    n = g_sorted.size
    groups = np.concatenate([g_sorted, q_group])
    values = np.concatenate([v_sorted, q_value])
    kind = np.concatenate([np.zeros(n, np.int8), np.ones(q_group.size, np.int8)])
    merged = np.lexsort((kind, values, groups))
    is_data = merged < n
    before: np.ndarray = np.cumsum(is_data) - is_data
    out = np.empty(q_group.size, dtype=np.int64)
    out[merged[~is_data] - n] = before[~is_data]
    return out


def _pick_front_along_rear(
    dx: np.ndarray, half: np.ndarray, valid: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Column of the nearest non-overlapping vehicle ahead, the nearest overlapping one and the
    nearest non-overlapping one behind, among candidates dx [q, c] (-1 where none)."""
    inf = np.inf
    overlap = valid & (np.abs(dx) < half)
    ahead = valid & (dx >= half)
    behind = valid & (dx <= -half)
    picks = []
    for mask, score in ((ahead, dx), (overlap, np.abs(dx)), (behind, -dx)):
        s = np.where(mask, score, inf)
        col = np.argmin(s, axis=1)
        picks.append(np.where(mask.any(axis=1), col, -1))
    return picks[0], picks[1], picks[2]


@dataclass
class Neighbours:
    """Neighbour rows [n, 7] (slot order SLOTS, -1 none) and the method used per recording."""

    rows: np.ndarray
    methods: dict[str, str]


def recording_methods(table: pa.Table, cols: Columns, method: str = "auto") -> dict[str, str]:
    """The neighbour method of each recording: the requested one, or for ``auto`` source where the
    source gives all seven neighbour columns, else lanes for road frames where every row has a lane
    id, else bands."""
    if method not in METHODS:
        raise TrackTableError(f"unknown neighbour method {method!r}, expected one of {METHODS}")
    n_rec = cols.names.size
    if method != "auto":
        if method == "source" and not has_source_columns(table):
            raise TrackTableError(
                "neighbour method 'source' needs the neighbour id columns, which the table lacks"
            )
        return {str(name): method for name in cols.names}
    src_all = np.zeros(n_rec, dtype=bool)
    bounds = run_bounds(cols.rec)  # rows are sorted by recording: one run each
    starts = bounds[:-1]
    runs = list(zip(cols.rec[starts].tolist(), starts.tolist(), np.diff(bounds).tolist(), strict=True))
    if has_source_columns(table):
        src_all[:] = True
        for name in SOURCE_COLUMNS.values():  # the column gives ids where not all rows are null
            column = table.column(name)
            for r, lo, size in runs:
                src_all[r] &= column.slice(lo, size).null_count < size
    lanes_all = np.zeros(n_rec, dtype=bool)
    for r, lo, size in runs:
        lanes_all[r] = cols.lane_known[lo : lo + size].all() and cols.road_frame[r]
    return {
        str(name): "source" if src_all[r] else ("lanes" if lanes_all[r] else "bands")
        for r, name in enumerate(cols.names)
    }


def neighbour_rows(
    table: pa.Table,
    cols: Columns | None = None,
    index: RowIndex | None = None,
    *,
    method: str = "auto",
    lane_width: float = LANE_WIDTH,
    max_range_m: float = NEIGHBOUR_RANGE_M,
) -> Neighbours:
    """The neighbours of every row of ``table`` (see the module docstring for the methods), none
    farther than ``max_range_m`` ahead or behind (:func:`limit_range`)."""
    cols = columns(table) if cols is None else cols
    methods = recording_methods(table, cols, method)
    rows: np.ndarray | None = None
    code_of = {str(name): r for r, name in enumerate(cols.names)}
    for m in ("source", "lanes", "bands"):
        codes = [code_of[name] for name, used in methods.items() if used == m]
        if not codes:
            continue
        part = np.flatnonzero(np.isin(cols.rec, codes))
        if m == "source":
            index = RowIndex(cols) if index is None else index
            got = from_source(table, cols, index)
        elif m == "lanes":
            got = from_lanes(cols, part[cols.lane_known[part]])
        else:
            got = from_bands(cols, part, lane_width, max_range_m)
        if part.size == cols.n:  # one method for every row: its result as it is
            rows = got
            break
        if rows is None:
            rows = np.full((cols.n, len(SLOTS)), -1, dtype=np.int64)
        rows[part] = got[part]
    if rows is None:
        rows = np.full((cols.n, len(SLOTS)), -1, dtype=np.int64)
    return Neighbours(limit_range(cols, rows, max_range_m), methods)


def neighbour_ids(
    table: pa.Table,
    *,
    method: str = "auto",
    lane_width: float = LANE_WIDTH,
    max_range_m: float = NEIGHBOUR_RANGE_M,
) -> np.ndarray:
    """Neighbour track ids [n, 7] of every row (slot order SLOTS, -1 none)."""
    cols = columns(table)
    rows = neighbour_rows(table, cols, method=method, lane_width=lane_width, max_range_m=max_range_m).rows
    return np.where(rows >= 0, cols.track[np.maximum(rows, 0)], -1)
