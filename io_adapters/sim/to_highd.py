"""Samples of the SUMO highway (:mod:`~lanecast.io_adapters.sim.sumo_highway`) → highD's three CSV files.

highD's image coordinates: x to the right, y **down**, ``x, y`` = bounding-box top-left corner,
``width`` = length along x, ``height`` = width along y. The upper carriageway (``drivingDirection``
1) drives towards −x, the lower one (2) towards +x. Lanes are numbered like highD, from the top of the
image across both carriageways, counting the space above the top marking as 1 and the median as one:
with N lanes per direction the upper lanes are 2 … N+1 (top = its right-most, slow lane) and the
lower lanes N+3 … 2N+2 (bottom = its slow lane); e.g. N = 3: upper 2, 3, 4 and lower 6, 7, 8.

Neighbour columns come from SUMO: ``precedingId``/``followingId`` from ``vehicle.getLeader`` and
``getFollower``; the left/right columns from ``vehicle.getNeighbors`` (left and right are taken in the
direction of travel). A neighbour that overlaps the vehicle longitudinally is ``…AlongsideId``; when
SUMO's nearest neighbour on a side is alongside, the preceding (following) one on that side is SUMO's
leader (follower) of that alongside vehicle. Ids of vehicles not in the section in that frame are 0.
``dhw`` is the bumper-to-bumper gap to the preceding vehicle, ``thw = dhw / |xVelocity|``, ``ttc =
dhw / closing speed`` (0 where undefined, as in highD); ``yAcceleration`` is the finite difference of
``yVelocity`` (SUMO's lateral speed, or of the smoothed lateral position where the scenario smooths
lane changes or adds the in-lane weave).

The lateral shaping of a scenario (lane changes smoothed into S-curves, the in-lane weave) is applied
here, on the samples, so that the simulation itself stays SUMO's.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from datetime import datetime
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.csv as pacsv

from lanecast.io_adapters.contracts.track_runs import (
    along_track_derivative,
    lane_change_starts,
    row_extent,
    run_starts,
)
from lanecast.io_adapters.datasets.highd.reader import NEIGHBOURS
from lanecast.io_adapters.datasets.highd.start_time import meta_fields
from lanecast.io_adapters.errors import InputError
from lanecast.io_adapters.sim.slow_signals import sinusoid_sum
from lanecast.io_adapters.sim.sumo_highway import HighwayConfig
from lanecast.io_adapters.sim.sumo_run import Samples

TOP_MARGIN_M = 8.0  # image y of the upper carriageway's top marking
X_MARGIN_M = 10.0  # image x of the section's start (so that bounding boxes stay at x > 0)

TRACKS_COLUMNS = (
    "frame,id,x,y,width,height,xVelocity,yVelocity,xAcceleration,yAcceleration,frontSightDistance,"
    "backSightDistance,dhw,thw,ttc,precedingXVelocity,precedingId,followingId,leftPrecedingId,"
    "leftAlongsideId,leftFollowingId,rightPrecedingId,rightAlongsideId,rightFollowingId,laneId"
).split(",")
TRACKS_META_COLUMNS = (
    "id,width,height,initialFrame,finalFrame,numFrames,class,drivingDirection,traveledDistance,"
    "minXVelocity,maxXVelocity,meanXVelocity,minDHW,minTHW,minTTC,numLaneChanges"
).split(",")
RECORDING_META_COLUMNS = (
    "id,frameRate,locationId,speedLimit,month,weekDay,startTime,duration,totalDrivenDistance,"
    "totalDrivenTime,numVehicles,numCars,numTrucks,upperLaneMarkings,lowerLaneMarkings"
).split(",")

# ----------------------------------------------------------------------------------------------
# highD tables


def lane_markings(samples: Samples) -> tuple[np.ndarray, np.ndarray, float]:
    """Image y of the upper and lower markings (top to bottom) and the offset: y_img = offset − y_net."""
    half = samples.lane_width_m / 2
    cu, cl = samples.lane_centres_upper, samples.lane_centres_lower
    offset = TOP_MARGIN_M + cu[0] + half
    upper_net = np.concatenate([[cu[0] + half], cu - half])  # lane 0 is the top (outer) lane
    lower_net = np.concatenate([[cl[-1] + half], (cl - half)[::-1]])  # lane 0 is the bottom lane
    return offset - upper_net, offset - lower_net, float(offset)


def highd_lane_id(lane_index: np.ndarray, direction: np.ndarray, lanes_per_direction: int) -> np.ndarray:
    """highD laneId from SUMO's lane index [R] and drivingDirection [R] (1 upper, 2 lower)."""
    n = lanes_per_direction
    return np.where(direction == 1, 2 + lane_index, 2 * n + 2 - lane_index).astype(np.int64)


def _box_mean(values: np.ndarray, new_track: np.ndarray, half: int) -> np.ndarray:
    """Mean over rows i-half … i+half of each row's track, the track's end values repeated
    beyond its ends (rows sorted by track then frame). float64 [n]."""
    n = values.size
    idx = np.arange(n)
    start = np.maximum.accumulate(np.where(new_track, idx, 0))
    last = np.zeros(n, dtype=bool)
    last[:-1] = new_track[1:]
    last[-1] = True
    end = np.minimum.accumulate(np.where(last, idx, n - 1)[::-1])[::-1]
    lo, hi = idx - half, idx + half
    csum = np.concatenate([[0.0], np.cumsum(values)])
    a, b = np.maximum(lo, start), np.minimum(hi, end)
    inner = csum[b + 1] - csum[a]
    below = np.maximum(start - lo, 0) * values[start]
    above = np.maximum(hi - end, 0) * values[end]
    return (inner + below + above) / (2 * half + 1)


def smooth_lateral(y: np.ndarray, new_track: np.ndarray, width_s: float, rate_hz: float) -> np.ndarray:
    """Lateral positions [n] smoothed per track by a triangular kernel ``width_s`` wide (two box
    filters of half that width).

    SUMO moves a lane-changing vehicle sideways at constant speed (lateral acceleration spikes of
    ~15 m/s² at the start and end at 25 Hz); the triangle turns the ramp into an S-curve whose
    lateral acceleration peaks at about lane width / (duration × width_s / 2), e.g. 0.6 m/s² for a
    3.75 m change over 4 s with a 3 s kernel, like measured lane changes. Straight driving (constant
    y) is unchanged."""
    half = max(round(width_s * rate_hz / 4), 1)
    return _box_mean(_box_mean(y, new_track, half), new_track, half)


WANDER_PERIODS_S = (6.0, 40.0)  # range of the weave's periods at WANDER_SPEED_MS
WANDER_SPEED_MS = 30.0  # the weave advances with distance: its periods are these at 30 m/s


def lateral_wander(vehicle: np.ndarray, clock_s: np.ndarray, std_m: float, seed: int) -> np.ndarray:
    """Each vehicle's slow weave inside its lane, float64 [n] (m, to the left) for rows of
    ``vehicle`` int [n] at ``clock_s`` [n] (distance travelled / ``WANDER_SPEED_MS``: a weave is
    a path over the road, so a standing vehicle does not drift sideways and a slow one weaves
    slowly): :func:`~lanecast.io_adapters.sim.slow_signals.sinusoid_sum` with periods in
    ``WANDER_PERIODS_S`` and total std ``std_m``. Smooth (at 30 m/s lateral acceleration at most
    3·std·√(2/3)·(2π/6 s)², 0.4 m/s² for 0.15 m; median 0.03, p99 0.17), deterministic per seed.
    Real drivers hold the lane centre to a few decimetres; SUMO's vehicles hold it exactly, so
    without it a model never sees lateral motion that is not a lane change."""
    rng = np.random.default_rng([int(seed), 0x5A4E])
    return sinusoid_sum(vehicle, clock_s, std_m, WANDER_PERIODS_S, rng)


def _round(values: np.ndarray, decimals: int) -> np.ndarray:
    return np.round(values, decimals) + 0.0  # + 0.0 turns -0.0 into 0.0


#: recordingMeta's date fields when no start is given: the same arguments give the same files
DEFAULT_START = {"month": "01.2000", "weekDay": "Sat", "startTime": "12:00"}


def to_highd(
    samples: Samples, cfg: HighwayConfig, recording_id: int = 1, start: datetime | None = None
) -> dict[str, pa.Table]:
    """The three highD tables (``tracks``, ``tracksMeta``, ``recordingMeta``) from the samples."""
    order = np.lexsort((samples.frame, samples.vehicle))
    veh = samples.vehicle[order]
    frame = samples.frame[order]
    # Keep each vehicle's first contiguous run of frames (a track never comes back).
    new_track = run_starts(veh)
    run = np.cumsum(run_starts(veh, frame - np.arange(veh.size)))  # gap-free runs of frames
    first_run = run[new_track][np.cumsum(new_track) - 1]
    keep = run == first_run
    order, veh, frame = order[keep], veh[keep], frame[keep]
    starts = np.flatnonzero(run_starts(veh))

    # highD ids: 1 … V in order of first frame, then of departure.
    first_frames = frame[starts]
    vehicles = veh[starts]
    rank = np.lexsort((vehicles, first_frames))
    highd_id_of = np.zeros(samples.type_index.size, dtype=np.int64)
    highd_id_of[vehicles[rank]] = np.arange(1, vehicles.size + 1)
    track_id = highd_id_of[veh]
    # From here on rows are in highD's own order: by highD id, then frame.
    final = np.lexsort((frame, track_id))
    order, veh, frame, track_id = order[final], veh[final], frame[final], track_id[final]
    first, last = row_extent(run_starts(veh))

    types = samples.types
    lengths = np.array([t[2] for t in types])[samples.type_index[veh]]
    widths = np.array([t[3] for t in types])[samples.type_index[veh]]
    direction = samples.direction[veh]
    lower = direction == 2
    sign = np.where(lower, 1.0, -1.0)
    _, _, y_offset = lane_markings(samples)
    x_origin = cfg.approach_length_m - X_MARGIN_M
    x_front = samples.x_front[order] - x_origin
    x_left = np.where(lower, x_front - lengths, x_front)
    y_net = samples.y_centre[order]
    if cfg.lateral_smoothing_s > 0:
        y_net = smooth_lateral(y_net, run_starts(veh), cfg.lateral_smoothing_s, cfg.frame_rate)
    if cfg.lateral_wander_m > 0:
        travelled = np.abs(x_front - x_front[first])
        y_net = y_net + lateral_wander(veh, travelled / WANDER_SPEED_MS, cfg.lateral_wander_m, cfg.seed)
    if cfg.lateral_smoothing_s > 0 or cfg.lateral_wander_m > 0:
        y_vel = -along_track_derivative(y_net, frame, first, last, t_unit=cfg.step_s)  # image y points down
    else:
        y_vel = np.where(lower, -1.0, 1.0) * samples.speed_lat[order]
    y_top = y_offset - y_net - widths / 2
    image_length = cfg.section_length_m + 2 * X_MARGIN_M
    x_vel = sign * samples.speed[order]
    x_acc = sign * samples.accel[order]
    y_acc = along_track_derivative(y_vel, frame, first, last, t_unit=cfg.step_s)
    front_sight = np.where(lower, image_length - x_front, x_front)
    back_sight = np.where(lower, x_left, image_length - (x_left + lengths))

    # Neighbours: vehicle numbers → rows of the same frame (-1 where the neighbour has no row then).
    n_frames = int(frame.max()) + 2
    keys = veh * n_frames + frame
    key_order = np.argsort(keys)
    sorted_keys = keys[key_order]
    neighbour_ids: dict[str, np.ndarray] = {}
    pre_row = np.full(veh.size, -1, dtype=np.int64)
    for i, name in enumerate(NEIGHBOURS):  # 8 columns, each vectorised
        raw = samples.neighbours[order, i]
        wanted = raw * n_frames + frame
        pos = np.clip(np.searchsorted(sorted_keys, wanted), 0, keys.size - 1)
        found = (raw > 0) & (sorted_keys[pos] == wanted)
        rows = np.where(found, key_order[pos], -1)
        neighbour_ids[name] = np.where(found, track_id[np.maximum(rows, 0)], 0)
        if i == 0:
            pre_row = rows

    has_pre = pre_row >= 0
    pre = np.maximum(pre_row, 0)
    gap_m = np.where(lower, x_left[pre] - x_front, x_left - (x_left[pre] + lengths[pre]))
    dhw = np.where(has_pre, np.maximum(gap_m, 0.0), 0.0)
    speed_abs = np.abs(x_vel)
    thw = np.divide(dhw, speed_abs, out=np.zeros_like(dhw), where=has_pre & (speed_abs > 0.1))
    closing = speed_abs - np.abs(x_vel[pre])
    ttc = np.divide(dhw, closing, out=np.zeros_like(dhw), where=has_pre & (closing > 1e-3) & (dhw > 0))
    pre_xvel = np.where(has_pre, x_vel[pre], 0.0)
    lane_id = highd_lane_id(samples.lane_index[order], direction, cfg.lanes_per_direction)

    tracks = {
        "frame": frame,
        "id": track_id,
        "x": _round(x_left, 2),
        "y": _round(y_top, 2),
        "width": _round(lengths, 2),
        "height": _round(widths, 2),
        "xVelocity": _round(x_vel, 2),
        "yVelocity": _round(y_vel, 2),
        "xAcceleration": _round(x_acc, 4),
        "yAcceleration": _round(y_acc, 4),
        "frontSightDistance": _round(front_sight, 2),
        "backSightDistance": _round(back_sight, 2),
        "dhw": _round(dhw, 2),
        "thw": _round(thw, 2),
        "ttc": _round(ttc, 2),
        "precedingXVelocity": _round(pre_xvel, 2),
        **neighbour_ids,
        "laneId": lane_id,
    }
    tracks_table = pa.table({name: tracks[name] for name in TRACKS_COLUMNS})

    meta = _tracks_meta(tracks_table, samples, highd_id_of)
    recording = _recording_meta(meta, samples, cfg, recording_id, start)
    return {"tracks": tracks_table, "tracksMeta": meta, "recordingMeta": recording}


def _tracks_meta(tracks: pa.Table, samples: Samples, highd_id_of: np.ndarray) -> pa.Table:
    """One row per track, aggregated column-wise over the tracks table (rows sorted by id, frame)."""
    tid = tracks.column("id").to_numpy()
    frame = tracks.column("frame").to_numpy()
    new_track = run_starts(tid)
    starts = np.flatnonzero(new_track)
    ends = np.concatenate([starts[1:], [tid.size]]) - 1
    counts = ends - starts + 1
    col = {
        name: tracks.column(name).to_numpy()
        for name in ("x", "width", "height", "xVelocity", "dhw", "thw", "ttc", "laneId")
    }
    speed = np.abs(col["xVelocity"])
    number_of = np.zeros(tid.max() + 1, dtype=np.int64)
    number_of[highd_id_of[highd_id_of > 0]] = np.flatnonzero(highd_id_of > 0)
    vnum = number_of[tid[starts]]
    classes = np.array([t[1] for t in samples.types])[samples.type_index[vnum]]

    def positive_min(values: np.ndarray) -> np.ndarray:
        masked = np.where(values > 0, values, np.inf)
        out = np.minimum.reduceat(masked, starts)
        return np.where(np.isfinite(out), out, -1.0)

    lane = col["laneId"]
    change = lane_change_starts(new_track, lane, np.ones(tid.size, dtype=bool)).astype(np.int64)
    return pa.table(
        {
            "id": tid[starts],
            "width": col["width"][starts],
            "height": col["height"][starts],
            "initialFrame": frame[starts],
            "finalFrame": frame[ends],
            "numFrames": counts,
            "class": pa.array(classes.tolist(), pa.string()),
            "drivingDirection": samples.direction[vnum],
            "traveledDistance": _round(np.abs(col["x"][ends] - col["x"][starts]), 2),
            "minXVelocity": _round(np.minimum.reduceat(speed, starts), 2),
            "maxXVelocity": _round(np.maximum.reduceat(speed, starts), 2),
            "meanXVelocity": _round(np.add.reduceat(speed, starts) / counts, 2),
            "minDHW": _round(positive_min(col["dhw"]), 2),
            "minTHW": _round(positive_min(col["thw"]), 2),
            "minTTC": _round(positive_min(col["ttc"]), 2),
            "numLaneChanges": np.add.reduceat(change, starts),
        }
    )


def _recording_meta(
    meta: pa.Table, samples: Samples, cfg: HighwayConfig, recording_id: int, start: datetime | None
) -> pa.Table:
    """recordingMeta's one row; ``start`` gives ``month``, ``weekDay`` and ``startTime`` (a drive
    log written from the recording begins then), None the fixed 01.2000, Sat, 12:00."""
    upper, lower, _ = lane_markings(samples)
    when = meta_fields(start) if start is not None else DEFAULT_START
    classes = np.asarray(meta.column("class").to_pylist())
    return pa.table(
        {
            "id": [recording_id],
            "frameRate": [int(cfg.frame_rate)],
            "locationId": [0],  # not a highD location: simulated
            "speedLimit": [round(cfg.speed_limit_mps, 2)],
            "month": [when["month"]],
            "weekDay": [when["weekDay"]],
            "startTime": [when["startTime"]],
            "duration": [round(cfg.n_frames / cfg.frame_rate, 2)],
            "totalDrivenDistance": [round(float(np.sum(meta.column("traveledDistance").to_numpy())), 2)],
            "totalDrivenTime": [
                round(float(np.sum(meta.column("numFrames").to_numpy())) / cfg.frame_rate, 2)
            ],
            "numVehicles": [meta.num_rows],
            "numCars": [int(np.sum(classes == "Car"))],
            "numTrucks": [int(np.sum(classes == "Truck"))],
            "upperLaneMarkings": [";".join(f"{v:.2f}" for v in upper)],
            "lowerLaneMarkings": [";".join(f"{v:.2f}" for v in lower)],
        }
    )


# ----------------------------------------------------------------------------------------------
# Writing


def _write_csv(table: pa.Table, path: Path) -> None:
    with path.open("wb") as fh:
        fh.write((",".join(table.column_names) + "\n").encode())
        pacsv.write_csv(table, fh, pacsv.WriteOptions(include_header=False, quoting_style="none"))


def file_names(recording_id: int) -> dict[str, str]:
    """highD's file names for a recording id: ``NN_tracks.csv`` etc."""
    return {kind: f"{recording_id:02d}_{kind}.csv" for kind in ("tracks", "tracksMeta", "recordingMeta")}


def refuse_existing_recording(out_dir: Path, recording_id: int) -> None:
    """A recording is never overwritten: refuse when any of its three files is already in ``out_dir``."""
    existing = [Path(out_dir) / n for n in file_names(recording_id).values() if (Path(out_dir) / n).exists()]
    if existing:
        raise InputError(
            existing[0],
            "already exists: a simulation never overwrites a recording",
            expected="a new --out directory, another --recording-id, or --force to replace it",
        )


def write_highd(
    tables: dict[str, pa.Table], out_dir: Path, recording_id: int = 1, *, overwrite: bool = False
) -> Path:
    """Write the three CSV files atomically: built in a temporary directory, then renamed into place.

    The directory gets the permissions of an ordinarily created one; existing files of the same
    recording are refused unless ``overwrite``."""
    out_dir = Path(out_dir)
    if not overwrite:
        refuse_existing_recording(out_dir, recording_id)
    out_dir.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out_dir.name}.tmp-", dir=out_dir.parent))
    umask = os.umask(0)
    os.umask(umask)
    tmp.chmod(0o777 & ~umask)  # mkdtemp makes it owner-only
    try:
        names = file_names(recording_id)
        for kind, name in names.items():
            _write_csv(tables[kind], tmp / name)
        if not out_dir.exists():
            os.replace(tmp, out_dir)
        else:
            for name in names.values():
                os.replace(tmp / name, out_dir / name)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return out_dir


def summary(tracks_meta: Path) -> dict[str, int]:
    """Vehicles, cars, trucks and lane changes of a written ``NN_tracksMeta.csv``."""
    meta = pacsv.read_csv(
        tracks_meta,
        convert_options=pacsv.ConvertOptions(
            include_columns=["class", "numLaneChanges"], column_types={"class": pa.string()}
        ),
    )
    classes = np.asarray(meta.column("class").to_pylist())
    return {
        "vehicles": meta.num_rows,
        "cars": int(np.sum(classes == "Car")),
        "trucks": int(np.sum(classes == "Truck")),
        "lane_changes": int(np.sum(meta.column("numLaneChanges").to_numpy())),
    }
