"""What the neighbour search works on (:mod:`lanecast.pipeline.neighbours`): the table's columns as
numpy arrays (:class:`Columns`), the row of a (recording, track, frame) (:class:`RowIndex`), the
slots and their source columns, road coordinates, and the longitudinal range a neighbour must lie
within."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
import pyarrow as pa

from lanecast.io_adapters.arrow_numpy import filled, valid_mask
from lanecast.io_adapters.contracts import track_table
from lanecast.io_adapters.contracts.track_runs import run_starts
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
        lane=filled(lane_col, 0).astype(np.int64),
        lane_known=valid_mask(lane_col),
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
