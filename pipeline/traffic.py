"""Traffic statistics of a track table, per recording (``lanecast info``, the training-mix table).

What says whether two recordings show the same kind of traffic: speeds (percentiles over all rows),
density (vehicles per km and per km and lane, from the mean number of vehicles present per frame
over the observed length of road), lane changes per vehicle and per vehicle-km (per vehicle alone
depends on how long a stretch is filmed), the lateral acceleration's percentiles (|a| across
the direction of travel: how smooth the lane changes are; None for a recording whose source
records no acceleration across the direction of travel, e.g. NGSIM's scalar ``v_Acc``, where every
row's is 0 and percentiles of 0.00 would claim perfectly smooth lane changes), and stop-and-go: speed dips per
vehicle-minute (a dip: the speed at least 3 m/s below the highest of the 20 s before it and of the
20 s after it, on the same vehicle; a wave passing a vehicle is a dip, braking into a queue that
only crawls is not). Column-wise over the whole table.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pyarrow as pa

from lanecast.io_adapters.contracts import track_table
from lanecast.pipeline.neighbour_columns import columns, road_coordinates

SPEED_PERCENTILES = (5, 25, 50, 75, 95)
LATERAL_PERCENTILES = (50, 95, 99)
LATERAL_RECORDED_MPS2 = 1e-6  # a recording whose every |lateral acceleration| is below records none
DIP_MPS = 3.0  # how far below the speeds around it a speed dip is
DIP_SPAN_S = 20.0  # … before and after it


def speed_dips(track: np.ndarray, speed: np.ndarray, rate_hz: float) -> int:
    """Number of speed dips (module docstring) in one recording: ``track`` int [N] sorted
    (contiguous tracks, frames in order), ``speed`` float [N] m/s, ``rate_hz`` frames per second.
    Sampled at 1 Hz; a run of dipped samples on one vehicle counts once."""
    if len(track) == 0:
        return 0
    starts = np.flatnonzero(np.r_[True, track[1:] != track[:-1]])
    position = np.arange(len(track)) - np.repeat(starts, np.diff(np.r_[starts, len(track)]))
    keep = position % max(round(rate_hz), 1) == 0
    t, v = track[keep], speed[keep]
    span = int(DIP_SPAN_S) + 1

    def running_max(values: np.ndarray, keys: np.ndarray) -> np.ndarray:
        """Max of each sample and the ``span - 1`` before it on the same vehicle (keys contiguous;
        NaN ignored): ``span`` passes over the arrays, no copy per window."""
        out = values.astype(np.float64, copy=True)
        for k in range(1, min(span, len(values))):
            earlier = np.where(keys[k:] == keys[:-k], values[:-k], np.nan)
            np.fmax(out[k:], earlier, out=out[k:])
        return out

    before = running_max(v, t)
    after = running_max(v[::-1], t[::-1])[::-1]
    dip = (v <= before - DIP_MPS) & (v <= after - DIP_MPS)
    first = dip.copy()
    first[1:] &= ~(dip[:-1] & (t[1:] == t[:-1]))
    return int(first.sum())


def traffic_statistics(table: pa.Table) -> dict[str, dict[str, Any]]:
    """{recording: statistics} for a validated, sorted track table (see the module docstring).

    Keys: vehicles, duration_s, speed_mps {p5 … p95, mean}, density_veh_per_km,
    density_veh_per_km_lane (None without lane ids), lanes, lane_changes, lane_changes_per_vehicle,
    lane_changes_per_vehicle_km, lateral_acc_abs_mps2 {p50, p95, p99} (None where the source records
    none), speed_dips_per_vehicle_min.
    """
    meta = track_table.read_meta(table)
    cols = columns(table)
    lon, _ = road_coordinates(cols)
    speed = np.hypot(cols.vx, cols.vy)
    lat_acc = np.abs(-np.sin(cols.heading) * cols.ax + np.cos(cols.heading) * cols.ay)
    change = np.zeros(cols.n, dtype=bool)
    change[track_table.lane_change_rows(table)] = True
    new_track = np.ones(cols.n, dtype=bool)
    if cols.n > 1:
        new_track[1:] = (cols.rec[1:] != cols.rec[:-1]) | (cols.track[1:] != cols.track[:-1])
    out: dict[str, dict[str, Any]] = {}
    for r, name in enumerate(cols.names):
        rows = cols.rec == r
        if not rows.any():
            continue
        rate = meta.recordings[str(name)].frame_rate
        frames = cols.frame[rows]
        n_frames = int(np.unique(frames).size)
        lo, hi = np.percentile(lon[rows], [0.5, 99.5])
        length_km = max(float(hi - lo), 1.0) / 1000.0
        per_frame = rows.sum() / max(n_frames, 1)
        lanes = int(np.unique(cols.lane[rows & cols.lane_known]).size) if cols.lane_known[rows].all() else 0
        vehicles = int(new_track[rows].sum())
        vehicle_km = float(speed[rows].sum() / rate / 1000.0)
        changes = int(change[rows].sum())
        sp = np.percentile(speed[rows], SPEED_PERCENTILES)
        recorded = bool(np.any(lat_acc[rows] > LATERAL_RECORDED_MPS2))
        la = np.percentile(lat_acc[rows], LATERAL_PERCENTILES)
        vehicle_min = rows.sum() / rate / 60.0
        dips = speed_dips(cols.track[rows], speed[rows], rate)
        out[str(name)] = {
            "vehicles": vehicles,
            "duration_s": float((frames.max() - frames.min() + 1) / rate),
            "speed_mps": {
                **{f"p{p}": round(float(v), 2) for p, v in zip(SPEED_PERCENTILES, sp, strict=True)},
                "mean": round(float(speed[rows].mean()), 2),
            },
            "density_veh_per_km": round(per_frame / length_km, 1),
            "density_veh_per_km_lane": round(per_frame / length_km / lanes, 1) if lanes else None,
            "lanes": lanes or None,
            "lane_changes": changes,
            "lane_changes_per_vehicle": round(changes / max(vehicles, 1), 3),
            "lane_changes_per_vehicle_km": round(changes / max(vehicle_km, 1e-9), 3),
            "lateral_acc_abs_mps2": {
                f"p{p}": round(float(v), 2) for p, v in zip(LATERAL_PERCENTILES, la, strict=True)
            }
            if recorded
            else None,
            "speed_dips_per_vehicle_min": round(dips / max(vehicle_min, 1e-9), 3),
        }
    return out
