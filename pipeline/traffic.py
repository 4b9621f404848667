"""Traffic statistics of a track table, per recording (``lanecast info``, the training-mix table).

What says whether two recordings show the same kind of traffic: speeds (percentiles over all rows),
density (vehicles per km and per km and lane, from the mean number of vehicles present per frame
over the observed length of road), lane changes per vehicle and per vehicle-km (per vehicle alone
depends on how long a stretch is filmed), and the lateral acceleration's percentiles (|a| across
the direction of travel: how smooth the lane changes are). Column-wise over the whole table.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pyarrow as pa

from lanecast.io_adapters.contracts import track_table
from lanecast.pipeline.neighbours import columns, road_coordinates

SPEED_PERCENTILES = (5, 25, 50, 75, 95)
LATERAL_PERCENTILES = (50, 95, 99)


def traffic_statistics(table: pa.Table) -> dict[str, dict[str, Any]]:
    """{recording: statistics} for a validated, sorted track table (see the module docstring).

    Keys: vehicles, duration_s, speed_mps {p5 … p95, mean}, density_veh_per_km,
    density_veh_per_km_lane (None without lane ids), lanes, lane_changes, lane_changes_per_vehicle,
    lane_changes_per_vehicle_km, lateral_acc_abs_mps2 {p50, p95, p99}.
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
        la = np.percentile(lat_acc[rows], LATERAL_PERCENTILES)
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
            },
        }
    return out
