"""The per-row fields of conv-social-pooling's ``traj`` matrix, computed for one dataset at once.

One dataset is one NGSIM file (or one highD driving direction): columns in file order, float32 as
the research script holds them after ``single(...)``. Every quantity is computed with the same
float32 arithmetic the script's single-precision matrix gives, so the results are equal element
for element, not merely close:

* lateral maneuver (1 keep, 2 lane id falls, 3 lane id rises) from the lane 40 rows before and
  after the row's first row at its frame, within the vehicle's rows in file order;
* longitudinal maneuver (1 normal, 2 braking) from the mean speed over the 30 rows before and the
  50 after: braking when their ratio is below 0.8 (a ratio that is NaN, as 0/0, is normal);
* 39 grid cells (13 in the left lane, 13 in the own lane, 13 in the right one) of neighbour ids
  within ±90 ft, 15 ft a cell, ``round`` halves away from zero; where two neighbours fall in one
  cell, the later one in file order is kept, as the script's loop overwrites.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

LANE_WINDOW = 40  # rows either side for the lateral maneuver
HISTORY_ROWS = 30  # rows back for the longitudinal maneuver and the history filter
FUTURE_ROWS = 50  # rows ahead for the longitudinal maneuver
BRAKE_RATIO = np.float32(0.8)
GRID_REACH_FT = np.float32(90.0)
GRID_CELL_FT = np.float32(15.0)
CELLS_PER_LANE = 13
GRID_CELLS = 3 * CELLS_PER_LANE
_ROWS_PER_CHUNK = 200_000  # grid queries at a time: bounds the candidate pairs in memory


@dataclass
class Vehicles:
    """The rows of one dataset grouped by vehicle id, each group in file order.

    ``order`` int64 [n]: file rows sorted stably by vehicle id; ``start``/``size`` int64 [n]: the
    group's first position in ``order`` and its row count, per sorted position; ``pos`` int64 [n]:
    the position within the group (all per sorted position)."""

    order: np.ndarray
    start: np.ndarray
    size: np.ndarray
    pos: np.ndarray


def vehicles(vehicle: np.ndarray) -> Vehicles:
    """Group rows by vehicle id, keeping file order within a vehicle (as ``traj(traj(:,2)==id,:)``)."""
    n = vehicle.size
    order = np.argsort(vehicle, kind="stable")
    ids = vehicle[order]
    new = np.ones(n, dtype=bool)
    new[1:] = ids[1:] != ids[:-1]
    starts = np.flatnonzero(new)
    sizes = np.diff(np.append(starts, n))
    group = np.cumsum(new) - 1
    start = starts[group]
    return Vehicles(order, start, sizes[group], np.arange(n) - start)


def round_half_away(x: np.ndarray) -> np.ndarray:
    """MATLAB's ``round`` for x ≥ 0 (halves up), exact in float32: ``floor(x + 0.5)`` is not (it
    rounds 0.49999997 to 1)."""
    whole = np.floor(x)
    return whole + (x - whole >= np.float32(0.5))


def first_row_at_frame(groups: Vehicles, frame: np.ndarray) -> np.ndarray:
    """Per sorted position: the group position of the vehicle's first row at the same frame
    (``find(vehtraj(:,3)==time)(1)``; the row itself unless a frame repeats)."""
    fs = frame[groups.order]
    by = np.lexsort((groups.pos, fs, groups.start))
    n = fs.size
    new = np.ones(n, dtype=bool)
    new[1:] = (groups.start[by][1:] != groups.start[by][:-1]) | (fs[by][1:] != fs[by][:-1])
    first = np.maximum.accumulate(np.where(new, np.arange(n), 0))
    ind = np.empty(n, dtype=np.int64)
    ind[by] = groups.pos[by][first]
    return ind


def maneuvers(
    groups: Vehicles, frame: np.ndarray, y: np.ndarray, lane: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Lateral (1–3) and longitudinal (1–2) maneuver of every row, float32 [n] each, file order."""
    i = first_row_at_frame(groups, frame)
    g0, last = groups.start, groups.size - 1
    ls, ys = lane[groups.order], y[groups.order]
    up, here, low = (
        ls[g0 + np.minimum(last, i + LANE_WINDOW)],
        ls[g0 + i],
        ls[g0 + np.maximum(0, i - LANE_WINDOW)],
    )
    lat_s = np.where((up > here) | (here > low), 3, np.where((up < here) | (here < low), 2, 1)).astype(
        np.float32
    )
    ub, lb = np.minimum(last, i + FUTURE_ROWS), np.maximum(0, i - HISTORY_ROWS)
    edge = (ub == i) | (lb == i)
    with np.errstate(divide="ignore", invalid="ignore"):
        v_hist = (ys[g0 + i] - ys[g0 + lb]) / (i - lb).astype(np.float32)
        v_fut = (ys[g0 + ub] - ys[g0 + i]) / (ub - i).astype(np.float32)
        braking = v_fut / v_hist < BRAKE_RATIO  # NaN compares False: normal
    lon_s = np.where(~edge & braking, 2, 1).astype(np.float32)
    lat, lon = np.empty_like(lat_s), np.empty_like(lon_s)
    lat[groups.order], lon[groups.order] = lat_s, lon_s
    return lat, lon


def neighbour_grid(
    vehicle: np.ndarray, frame: np.ndarray, y: np.ndarray, lane: np.ndarray, queries: np.ndarray
) -> np.ndarray:
    """The 39 grid cells of the file rows ``queries`` (int64 [m]): float32 [m, 39] of neighbour
    vehicle ids, 0 where empty. Every row of the dataset is a candidate neighbour."""
    n = vehicle.size
    grid = np.zeros((queries.size, GRID_CELLS), dtype=np.float32)
    if queries.size == 0:
        return grid
    fi, li = frame.astype(np.int64), lane.astype(np.int64)
    lmin = int(li.min())
    width = int(li.max()) - lmin + 3  # room for the lanes either side of every lane
    code = (fi - int(fi.min())) * width + (li - lmin + 1)
    y64 = y.astype(np.float64)
    span = float(y64.max() - y64.min()) + 4 * float(GRID_REACH_FT)
    blocks, block = np.unique(code, return_inverse=True)
    key = block * span + (y64 - y64.min())
    by_key = np.lexsort((np.arange(n), key))
    key_sorted = key[by_key]
    for first in range(0, queries.size, _ROWS_PER_CHUNK):
        out = np.arange(first, min(queries.size, first + _ROWS_PER_CHUNK))
        rows = queries[out]
        slot = np.empty(n, dtype=np.int64)  # file row -> its row in the output
        slot[rows] = out
        flat_parts, nbr_parts = [], []
        for side, base in ((-1, 0), (0, CELLS_PER_LANE), (1, 2 * CELLS_PER_LANE)):
            want = code[rows] + side
            at = np.minimum(np.searchsorted(blocks, want), blocks.size - 1)
            found = blocks[at] == want
            q, b = rows[found], at[found]
            centre = b * span + (y64[q] - y64.min())
            lo = np.searchsorted(key_sorted, centre - (float(GRID_REACH_FT) + 1.0), side="left")
            hi = np.searchsorted(key_sorted, centre + (float(GRID_REACH_FT) + 1.0), side="right")
            for step in range(int((hi - lo).max(initial=0))):
                live = lo + step < hi
                k, other = q[live], by_key[lo[live] + step]
                dy = y[other] - y[k]  # float32, as the script subtracts singles
                ok = np.abs(dy) < GRID_REACH_FT
                if side == 0:
                    ok &= dy != 0
                k, other, dy = k[ok], other[ok], dy[ok]
                cell = round_half_away((dy + GRID_REACH_FT) / GRID_CELL_FT).astype(np.int64)
                flat_parts.append(slot[k] * GRID_CELLS + base + cell)
                nbr_parts.append(other)
        if not flat_parts:
            continue
        flat, nbr = np.concatenate(flat_parts), np.concatenate(nbr_parts)
        last_wins = np.lexsort((nbr, flat))
        flat, nbr = flat[last_wins], nbr[last_wins]
        keep = np.ones(flat.size, dtype=bool)
        keep[:-1] = flat[1:] != flat[:-1]
        grid.reshape(-1)[flat[keep]] = vehicle[nbr[keep]]
    return grid


def track_extent(groups: Vehicles, frame: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per file row: whether its vehicle has more than 30 rows, the frame of the vehicle's 31st
    row (0 where it has none) and of its last row (``tracks{ds,id}(1,31)`` and ``(1,end)``)."""
    fs = frame[groups.order]
    long_enough_s = groups.size > HISTORY_ROWS
    f31_s = np.where(long_enough_s, fs[np.minimum(groups.start + HISTORY_ROWS, fs.size - 1)], 0)
    flast_s = fs[groups.start + groups.size - 1]
    long_enough, f31, flast = (np.empty_like(a) for a in (long_enough_s, f31_s, flast_s))
    long_enough[groups.order], f31[groups.order], flast[groups.order] = long_enough_s, f31_s, flast_s
    return long_enough, f31.astype(np.float32), flast


def kept_rows(groups: Vehicles, frame: np.ndarray) -> np.ndarray:
    """The script's filter: rows with 30 rows of their vehicle before them (the 31st row's frame
    ≤ t) and a later row beyond t + 1. A vehicle of 30 rows or fewer keeps none (the script stops
    there with an index error)."""
    long_enough, f31, flast = track_extent(groups, frame)
    return long_enough & (f31 <= frame) & (flast > frame + np.float32(1))
