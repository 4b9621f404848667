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

Size: the three selection methods share the columns, the row index and the slot rules; about
600 lines.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc

from lanecast.io_adapters.contracts import track_table
from lanecast.io_adapters.contracts.track_runs import run_bounds, run_starts
from lanecast.io_adapters.contracts.windows import ROWS
from lanecast.io_adapters.errors import TrackTableError

#: The seven neighbour slots: the window's vehicle rows without the target.
SLOTS: tuple[str, ...] = tuple(row for row in ROWS if row != "T")
SOURCE_COLUMNS: dict[str, str] = {
    "FL": "left_preceding_id",
    "F": "preceding_id",
    "FR": "right_preceding_id",
    "L": "left_alongside_id",
    "R": "right_alongside_id",
    "RL": "left_following_id",
    "RR": "right_following_id",
}
LANE_WIDTH = 3.75
# Longitudinal range of a neighbour (m). 100 m: at 130 km/h (36 m/s) a vehicle 100 m away is 2.8 s
# away, beyond the time gaps at which drivers interact (car-following gaps are ~1-2 s), and it
# stays well inside highD's ~420 m field of view from anywhere in its central part, so that a
# neighbour slot means the same in highD, simulations and logs (whose trackers may see 3 km).
NEIGHBOUR_RANGE_M = 100.0
METHODS = ("auto", "source", "lanes", "bands")
_CANDIDATES = np.arange(-4, 4)  # positions around the insertion point searched in an adjacent lane
_MAX_PAIRS = 4_000_000  # (target, candidate) pairs per chunk in the band method


@dataclass
class Columns:
    """The numpy columns the stages work on (float64 physics, int64 ids), rows as in the table."""

    names: np.ndarray  # str [R]: recording names, sorted
    rec: np.ndarray  # int64 [n]: recording code (index into names)
    track: np.ndarray  # int64 [n]
    frame: np.ndarray  # int64 [n]
    time_ns: np.ndarray  # int64 [n]
    x: np.ndarray
    y: np.ndarray
    heading: np.ndarray
    vx: np.ndarray
    vy: np.ndarray
    ax: np.ndarray
    ay: np.ndarray
    length: np.ndarray
    width: np.ndarray
    lane: np.ndarray  # int64 [n], 0 where unknown
    lane_known: np.ndarray  # bool [n]
    road_frame: np.ndarray  # bool [R]: recording is in a road frame (x along travel)

    @property
    def n(self) -> int:
        return int(self.track.size)


def columns(
    table: pa.Table,
    *,
    meta: track_table.TableMeta | None = None,
    physics: Mapping[str, np.ndarray] | None = None,
) -> Columns:
    """Pull the stage columns out of a (sorted, validated) track table (``meta``: its metadata when
    the caller has parsed it already; ``physics``: float64 columns [n] already at hand, e.g. as
    resampling computed them, taken instead of the table's own)."""
    meta = meta or track_table.read_meta(table)
    names, rec = track_table.recording_codes(table)
    lane_col = table.column("lane_id")

    def f64(name: str) -> np.ndarray:
        if physics is not None and name in physics:
            return np.asarray(physics[name], dtype=np.float64)
        return table.column(name).to_numpy().astype(np.float64)

    return Columns(
        names=names.astype(str),
        rec=rec.astype(np.int64),
        track=table.column("track_id").to_numpy(),
        frame=table.column("frame").to_numpy(),
        time_ns=table.column("time_ns").to_numpy(),
        x=f64("x"),
        y=f64("y"),
        heading=f64("heading"),
        vx=f64("vx"),
        vy=f64("vy"),
        ax=f64("ax"),
        ay=f64("ay"),
        length=f64("length"),
        width=f64("width"),
        lane=np.asarray(lane_col.fill_null(0).to_numpy()).astype(np.int64),
        lane_known=~np.asarray(pc.is_null(lane_col)),
        road_frame=np.array(
            [meta.recordings[str(name)].coordinate_frame == "road" for name in names], dtype=bool
        ),
    )


class RowIndex:
    """Exact (recording, track_id, frame) -> row look-ups (rows sorted by that key).

    Track ids map to tracks through a dense table when the ids are small integers (as in every
    dataset), else through searchsorted; within a track, frame f is row start + (f - first frame)
    unless the track has a gap, where a searchsorted on (track, frame) decides.
    """

    _DENSE_LIMIT = 50_000_000  # entries of the dense (recording, id) -> track table

    def __init__(self, cols: Columns) -> None:
        n = cols.n
        self.frame = cols.frame
        new_track = run_starts(cols.rec, cols.track)
        self.track_start = np.flatnonzero(new_track)
        self.track_of_row = np.cumsum(new_track) - 1
        self.track_end = np.append(self.track_start[1:], n)  # exclusive
        self.first_frame = cols.frame[self.track_start] if n else np.zeros(0, dtype=np.int64)
        self.last_frame = cols.frame[self.track_end - 1] if n else np.zeros(0, dtype=np.int64)
        self.uniq_ids = np.unique(cols.track[self.track_start])  # every id starts a track
        self.n_ids = max(self.uniq_ids.size, 1)
        rank = np.searchsorted(self.uniq_ids, cols.track[self.track_start])
        self.track_key = cols.rec[self.track_start] * self.n_ids + rank
        self.frame_min = int(cols.frame.min()) if n else 0
        self.frame_span = (int(cols.frame.max()) - self.frame_min + 1) if n else 1
        self.row_key = self.track_of_row * self.frame_span + (cols.frame - self.frame_min)
        if n and np.any(np.diff(self.row_key) <= 0):
            raise TrackTableError("rows are not sorted by (recording, track_id, frame) without duplicates")
        self.dense: np.ndarray | None = None
        if n:
            self.id_min = int(self.uniq_ids[0])
            id_span = int(self.uniq_ids[-1]) - self.id_min + 1
            n_rec = int(cols.rec.max()) + 1
            if n_rec * id_span <= self._DENSE_LIMIT:
                self.dense = np.full((n_rec, id_span), -1, dtype=np.int64)
                self.dense[cols.rec[self.track_start], cols.track[self.track_start] - self.id_min] = (
                    np.arange(self.track_start.size)
                )

    def tracks(self, rec: np.ndarray, track_id: np.ndarray) -> np.ndarray:
        """Track index of each (recording code, track id), -1 where there is none. int64 [q]."""
        if self.dense is not None:
            off = track_id - self.id_min
            ok = (off >= 0) & (off < self.dense.shape[1]) & (rec >= 0) & (rec < self.dense.shape[0])
            return np.where(ok, self.dense[np.where(ok, rec, 0), np.where(ok, off, 0)], -1)
        rank = np.minimum(np.searchsorted(self.uniq_ids, track_id), self.uniq_ids.size - 1)
        tkey = rec * self.n_ids + rank
        ti = np.minimum(np.searchsorted(self.track_key, tkey), self.track_key.size - 1)
        ok = (self.uniq_ids[rank] == track_id) & (self.track_key[ti] == tkey)
        return np.where(ok, ti, -1)

    def rows(self, rec: np.ndarray, track_id: np.ndarray, frame: np.ndarray) -> np.ndarray:
        """Row of each (recording code, track id, frame) query, -1 where there is none. int64 [q]."""
        track_id = np.asarray(track_id, dtype=np.int64)
        out = np.full(track_id.shape, -1, dtype=np.int64)
        if self.row_key.size == 0 or track_id.size == 0:
            return out
        ti = self.tracks(np.asarray(rec, dtype=np.int64), track_id)
        t = np.maximum(ti, 0)
        first = self.first_frame[t]
        inside = (ti >= 0) & (frame >= first) & (frame <= self.last_frame[t])
        r = self.track_start[t] + (frame - first)
        arithmetic = inside & (r < self.track_end[t])
        hit = arithmetic & (self.frame[np.where(arithmetic, r, 0)] == frame)
        out[hit] = r[hit]
        # tracks with gaps: the arithmetic row is off; look those up exactly
        miss = np.flatnonzero(inside & ~hit)
        if miss.size:
            key = t[miss] * self.frame_span + (frame[miss] - self.frame_min)
            rr = np.minimum(np.searchsorted(self.row_key, key), self.row_key.size - 1)
            found = self.row_key[rr] == key
            out[miss[found]] = rr[found]
        return out


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


def road_coordinates(cols: Columns) -> tuple[np.ndarray, np.ndarray]:
    """(longitudinal, lateral) float64 [n]: x, y in road frames, else rotated by each recording's
    mean direction of travel (circular mean of heading) so that lanes run along the first axis."""
    lon = cols.x.copy()
    lat = cols.y.copy()
    other = ~cols.road_frame[cols.rec]
    if other.any():
        n_rec = cols.names.size
        s = np.bincount(cols.rec, np.sin(cols.heading), minlength=n_rec)
        c = np.bincount(cols.rec, np.cos(cols.heading), minlength=n_rec)
        theta = np.arctan2(s, c)[cols.rec]
        ct, st = np.cos(theta), np.sin(theta)
        lon = np.where(other, ct * cols.x + st * cols.y, lon)
        lat = np.where(other, -st * cols.x + ct * cols.y, lat)
    return lon, lat


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


def from_bands(
    cols: Columns,
    rows: np.ndarray | None = None,
    lane_width: float = LANE_WIDTH,
    max_range_m: float | None = None,
) -> np.ndarray:
    """Neighbour rows [n, 7] from lateral bands one lane wide in each target's own frame.

    Each target is compared with the vehicles of its (recording, frame) whose position along the
    recording's axis (:func:`road_coordinates`) is within reach: all of them, or with ``max_range_m``
    (for recordings not in a road frame, where :func:`limit_range` measures along the target's
    heading) only those within sqrt(range² + (1.5 lane widths)²) + 1 m, a bound on the distance of
    any neighbour in range. Vehicles farther away could only be picked to be dropped by
    :func:`limit_range`, so the neighbours left after it are the same as against all vehicles.
    Rows with a non-finite x, y or heading are in no band (nobody's neighbour, no neighbours).
    """
    out = np.full((cols.n, len(SLOTS)), -1, dtype=np.int64)
    sel = np.arange(cols.n) if rows is None else np.asarray(rows, dtype=np.int64)
    sel = sel[np.isfinite(cols.x[sel]) & np.isfinite(cols.y[sel]) & np.isfinite(cols.heading[sel])]
    if sel.size == 0:
        return out
    f_rel = cols.frame[sel] - cols.frame[sel].min()
    gkey = cols.rec[sel] * (int(f_rel.max()) + 1) + f_rel
    order = np.argsort(gkey, kind="stable")
    srt = sel[order]  # candidate order = tie-break order (the first of equals wins)
    g = gkey[order]
    axis = road_coordinates(cols)[0][srt]
    by_axis = np.lexsort((axis, g))  # positions in srt, sorted by (group, axis)
    g_ax = g[by_axis]
    lo = np.searchsorted(g_ax, g, side="left")  # default: the whole (recording, frame)
    hi = np.searchsorted(g_ax, g, side="right")
    reach = _band_reach(max_range_m, lane_width)
    windowed = ~cols.road_frame[cols.rec[srt]]
    if reach is not None and windowed.any():
        window = _axis_windows(g, axis, by_axis, reach)
        if window is not None:
            lo = np.where(windowed, window[0], lo)
            hi = np.where(windowed, window[1], hi)
    chunk = (np.cumsum(hi - lo) - 1) // _MAX_PAIRS  # pairs per chunk bounded by _MAX_PAIRS
    bounds = np.flatnonzero(np.r_[True, chunk[1:] != chunk[:-1]])
    for a, b in zip(bounds, np.append(bounds[1:], srt.size), strict=True):
        _bands_chunk(cols, srt, by_axis, np.arange(a, b), lo[a:b], hi[a:b], lane_width, out)
    return out


def _band_reach(max_range_m: float | None, lane_width: float) -> float | None:
    """Distance along the recording's axis beyond which no vehicle can be a neighbour in range."""
    if max_range_m is None or not np.isfinite(max_range_m):
        return None
    return float(np.hypot(max_range_m, 1.5 * lane_width)) + 1.0


def _axis_windows(
    g: np.ndarray, axis: np.ndarray, by_axis: np.ndarray, reach: float
) -> tuple[np.ndarray, np.ndarray] | None:
    """For each vehicle, the span [lo, hi) of ``by_axis`` (positions sorted by (group, axis)) holding
    the vehicles of its group within ``reach`` along the axis, or a little more (never less). int64 [m].

    One float64 key group_index * span + axis, span leaving ``reach`` of room on both sides so that
    no window crosses into another group; None (no windows) when the key would be too coarse for a
    1 m margin (ulp > 1 mm) or an axis value is not finite."""
    if not np.all(np.isfinite(axis)):
        return None
    new = np.r_[True, g[1:] != g[:-1]]
    gidx = np.cumsum(new) - 1  # g is sorted
    a_min = float(axis.min())
    span = float(axis.max()) - a_min + 2 * reach + 1.0
    if (int(gidx[-1]) + 1) * span > 4.5e12:
        return None
    base = gidx * span + reach - a_min
    key = (base + axis)[by_axis]  # sorted: by_axis sorts by (group, axis)
    lo = np.searchsorted(key, base + axis - reach, side="left")
    hi = np.searchsorted(key, base + axis + reach, side="right")
    return lo, hi


def _bands_chunk(
    cols: Columns,
    srt: np.ndarray,
    by_axis: np.ndarray,
    targets: np.ndarray,
    lo: np.ndarray,
    hi: np.ndarray,
    lane_width: float,
    out: np.ndarray,
) -> None:
    """Neighbours of the targets srt[targets] among the candidates srt[by_axis[lo:hi]] of each.

    Per slot, the candidate with the lowest score wins, the first in ``srt`` order among equals
    (the order an all-pairs search meets them in)."""
    sizes = hi - lo
    seg = np.repeat(np.arange(targets.size), sizes)
    starts = np.cumsum(sizes) - sizes
    cpos = by_axis[np.arange(seg.size) - starts[seg] + lo[seg]]  # candidate's position in srt
    tpos = targets[seg]
    keep = cpos != tpos
    seg, cpos = seg[keep], cpos[keep]
    if seg.size == 0:
        return
    i = srt[targets[seg]]
    j = srt[cpos]
    h = cols.heading[i]
    ddx = cols.x[j] - cols.x[i]
    ddy = cols.y[j] - cols.y[i]
    lon = np.cos(h) * ddx + np.sin(h) * ddy
    lat = -np.sin(h) * ddx + np.cos(h) * ddy
    half = 0.5 * (cols.length[i] + cols.length[j])
    w = lane_width
    along = np.cos(cols.heading[j] - h) > 0  # same direction of travel
    lat = np.where(along, lat, np.inf)  # opposing traffic falls in no band
    same = np.abs(lat) < w / 2
    left = (lat >= w / 2) & (lat < 1.5 * w)
    right = (lat <= -w / 2) & (lat > -1.5 * w)
    ahead = lon >= half
    behind = lon <= -half
    overlap = np.abs(lon) < half
    rules = {
        "F": (same & (lon > 0), lon),
        "FL": (left & ahead, lon),
        "L": (left & overlap, np.abs(lon)),
        "RL": (left & behind, -lon),
        "FR": (right & ahead, lon),
        "R": (right & overlap, np.abs(lon)),
        "RR": (right & behind, -lon),
    }
    for slot, (mask, score) in rules.items():
        k = np.flatnonzero(mask)
        if k.size == 0:
            continue
        ks, sc, cp = seg[k], score[k], cpos[k]
        first = np.r_[True, ks[1:] != ks[:-1]]  # pairs are grouped by target
        starts_k = np.flatnonzero(first)
        best = np.minimum.reduceat(sc, starts_k)
        run = np.cumsum(first) - 1
        cand = sc == best[run]  # NaN scores are never in a mask
        big = np.iinfo(np.int64).max
        pick = np.minimum.reduceat(np.where(cand, cp, big), starts_k)
        out[srt[targets[ks[starts_k]]], SLOTS.index(slot)] = srt[pick]


def limit_range(cols: Columns, rows: np.ndarray, max_range_m: float) -> np.ndarray:
    """Neighbour rows [n, 7] with -1 where the neighbour is more than ``max_range_m`` ahead or behind.

    The distance is longitudinal: along x in road frames, else along the target's heading
    (computed for those rows only; one [n, 7] temporary, reused in place).
    """
    got = rows >= 0
    lon = np.take(cols.x, rows, mode="clip")  # [n, 7]; -1 (none) reads row 0, masked below
    lon -= cols.x[:, None]
    other = np.flatnonzero(~cols.road_frame[cols.rec])
    if other.size:
        dx = lon[other]
        dy = np.take(cols.y, rows[other], mode="clip") - cols.y[other, None]
        h = cols.heading[other, None]
        lon[other] = np.cos(h) * dx + np.sin(h) * dy
    np.abs(lon, out=lon)
    got &= lon <= max_range_m
    return np.where(got, rows, -1)


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
