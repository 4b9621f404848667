"""conv-social-pooling's three sets from parsed datasets: its split, ``traj`` rows and ``tracks`` cells.

Each dataset's vehicles are split by id: ids up to ``round(0.7 · max id)`` train, up to
``round(0.8 · max id)`` validate, the rest test (the thresholds computed in float32, as the script's
single matrix gives them). ``traj`` is 47 float32 columns — dataset id, vehicle id, frame, local x,
local y, lane id, lateral and longitudinal maneuver, 39 grid cells — holding the rows the script's
filter keeps, datasets in id order, rows in file order. ``tracks`` is a cell array of dataset id ×
vehicle id (1-based, as MATLAB indexes it), each cell the vehicle's 3 × T float32 [frame; x; y]
of all its rows in the set, empty cells 0 × 0 doubles, sized to the largest dataset id and
vehicle id that has a track in the set.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from lanecast.io_adapters.datasets.csp import fields

SET_NAMES = ("TrainSet", "ValSet", "TestSet")
TRAIN_SHARE, VAL_END_SHARE = np.float32(0.7), np.float32(0.8)
COLUMNS = 8 + fields.GRID_CELLS


@dataclass
class Dataset:
    """One dataset's columns (float32 [n] each, file order) and where they came from."""

    ident: int
    source: str
    vehicle: np.ndarray
    frame: np.ndarray
    x: np.ndarray
    y: np.ndarray
    lane: np.ndarray


@dataclass
class SetParts:
    """One set's pieces, dataset by dataset: ``traj`` blocks and the tracks (dataset id, vehicle
    id, 3 × T float32)."""

    traj: list[np.ndarray] = field(default_factory=list)
    tracks: list[tuple[int, int, np.ndarray]] = field(default_factory=list)

    def rows(self) -> int:
        return sum(block.shape[0] for block in self.traj)


def set_of_rows(vehicle: np.ndarray) -> np.ndarray:
    """0 train, 1 validation, 2 test for every row (int8 [n]), by vehicle id."""
    if vehicle.size == 0:
        return np.zeros(0, dtype=np.int8)
    top = vehicle.max()
    ul1 = fields.round_half_away(TRAIN_SHARE * top)
    ul2 = fields.round_half_away(VAL_END_SHARE * top)
    return np.where(vehicle <= ul1, 0, np.where(vehicle <= ul2, 1, 2)).astype(np.int8)


def dataset_parts(ds: Dataset) -> list[SetParts]:
    """The three sets' pieces of one dataset."""
    groups = fields.vehicles(ds.vehicle)
    which = set_of_rows(ds.vehicle)
    keep = fields.kept_rows(groups, ds.frame)
    rows = np.flatnonzero(keep)
    traj = np.empty((rows.size, COLUMNS), dtype=np.float32)
    traj[:, 0] = np.float32(ds.ident)
    for col, values in enumerate((ds.vehicle, ds.frame, ds.x, ds.y, ds.lane), start=1):
        traj[:, col] = values[rows]
    lat, lon = fields.maneuvers(groups, ds.frame, ds.y, ds.lane)
    traj[:, 6], traj[:, 7] = lat[rows], lon[rows]
    traj[:, 8:] = fields.neighbour_grid(ds.vehicle, ds.frame, ds.y, ds.lane, rows)
    parts = [SetParts() for _ in SET_NAMES]
    kept_set = which[rows]
    for s, part in enumerate(parts):
        part.traj.append(traj[kept_set == s])
    # tracks: every row of every vehicle (the filter comes after them in the script)
    order = groups.order
    starts = np.flatnonzero(groups.pos == 0)
    ends = np.append(starts[1:], order.size)[: starts.size]
    track = np.stack([ds.frame[order], ds.x[order], ds.y[order]])
    for a, b in zip(starts.tolist(), ends.tolist(), strict=True):
        vid = int(ds.vehicle[order[a]])
        parts[int(which[order[a]])].tracks.append((ds.ident, vid, track[:, a:b].copy()))
    return parts


def tracks_cell(tracks: list[tuple[int, int, np.ndarray]]) -> np.ndarray:
    """The MATLAB cell array (numpy object array) of one set's tracks."""
    rows = max((d for d, _, _ in tracks), default=0)
    cols = max((v for _, v, _ in tracks), default=0)
    cell = np.empty((rows, cols), dtype=object)
    for index in np.ndindex(cell.shape):
        cell[index] = np.zeros((0, 0))
    for d, v, t in tracks:
        cell[d - 1, v - 1] = t
    return cell


def traj_matrix(parts: SetParts) -> np.ndarray:
    """One set's ``traj``: its datasets' blocks in id order, column-major as MATLAB stores it (the
    writer then copies it as it is, not element by element)."""
    traj = np.empty((parts.rows(), COLUMNS), dtype=np.float32, order="F")
    at = 0
    for block in parts.traj:
        traj[at : at + block.shape[0]] = block
        at += block.shape[0]
    return traj
