"""The ``bands`` neighbour method (:mod:`lanecast.pipeline.neighbours`): lateral bands one lane wide
in the target's own frame instead of lanes, among vehicles heading the same way; each vehicle
compared only with those of its frame within reach along the road, in chunks of pairs."""

from __future__ import annotations

import numpy as np

from lanecast.pipeline.neighbour_columns import (
    _MAX_PAIRS,
    LANE_WIDTH,
    SLOTS,
    Columns,
    road_coordinates,
)


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
