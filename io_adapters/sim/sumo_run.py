"""The libsumo loop of a simulated recording (:mod:`lanecast.io_adapters.sim.sumo_highway` writes
the network and routes it runs): every vehicle in the filmed section sampled at each 25 Hz step,
with SUMO's own leader, follower and side neighbours (:class:`Samples`), for
:mod:`~lanecast.io_adapters.sim.to_highd` to write as highD's CSV files."""

from __future__ import annotations

import array
import contextlib
import io
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np

from lanecast.io_adapters.errors import InputError
from lanecast.io_adapters.sim.sumo_highway import (
    LANE_WIDTH_M,
    HighwayConfig,
    vehicle_types,
    write_network,
    write_routes,
)

# traci.constants.VAR_LEADER / VAR_FOLLOWER (checked by the tests), here to keep traci out of imports.
VAR_LEADER, VAR_FOLLOWER = 0x68, 0x78


def import_libsumo() -> ModuleType:
    """Import libsumo without its stdout warning about the pyarrow version.

    libsumo bundles its own libarrow (23.0, under mangled names in ``libsumo.libs``) and prints a
    warning when pyarrow differs (here 26); both load side by side in one process, in either import
    order, without crashing (checked by tests/io_adapters/sim/test_sim_recording.py, which has pyarrow loaded first).
    """
    with contextlib.redirect_stdout(io.StringIO()):
        import libsumo
    return libsumo


@dataclass
class Samples:
    """What the simulation recorded, one row per (vehicle in the section, frame).

    Arrays of shape [R] (rows in the order recorded); ``neighbours`` int64 [R, 8] are vehicle numbers
    (0 = none) in the order of the highD reader's ``NEIGHBOURS``. Vehicle numbers start at 1 in order of departure.
    Per vehicle number v (arrays of shape [V + 1], index 0 unused): ``type_index`` into ``types`` and
    ``direction`` (1 upper, 2 lower).
    """

    frame: np.ndarray
    vehicle: np.ndarray
    x_front: np.ndarray  # network x of the front bumper centre (m)
    y_centre: np.ndarray  # network y (up) of the centre (m)
    speed: np.ndarray  # along the lane (m/s)
    accel: np.ndarray  # along the lane (m/s²)
    speed_lat: np.ndarray  # SUMO lateral speed, positive to the left of travel (m/s)
    lane_index: np.ndarray  # SUMO lane index, 0 = right-most
    neighbours: np.ndarray
    type_index: np.ndarray
    direction: np.ndarray
    types: list[tuple[str, str, float, float, float]]
    lane_centres_upper: np.ndarray  # network y of the upper lanes' centres, by lane index
    lane_centres_lower: np.ndarray
    wall_time_s: float
    lane_width_m: float = LANE_WIDTH_M


def _sumo_args(cfg: HighwayConfig, net: Path, routes: Path) -> list[str]:
    return [
        "sumo",
        "--net-file", str(net),
        "--route-files", str(routes),
        "--additional-files", str(net.parent / "highway.add.xml"),
        "--step-length", f"{cfg.step_s}",
        "--lanechange.duration", f"{cfg.lane_change_duration_s}",
        "--seed", str(int(cfg.seed)),
        "--begin", "0",
        "--no-step-log", "true",
        "--no-warnings", "true",
        "--time-to-teleport", "-1",
        "--collision.action", "warn",
        "--threads", "1",
    ]  # fmt: skip


def _side_neighbours(
    leads: list[tuple[str, float]],
    follows: list[tuple[str, float]],
    back: float,
    front: float,
    inside: dict[str, tuple[float, float]],
    results: dict[str, dict[int, Any]],
) -> list[str]:
    """SUMO ids (preceding, alongside, following) on one side of a vehicle ("" = none).

    ``leads``/``follows`` are SUMO's ``getNeighbors`` answers for that side ((id, gap) pairs);
    ``back, front`` the vehicle's extent along the road; ``inside`` the extents of the vehicles in
    the section. A neighbour that overlaps [back, front] is alongside; the preceding (following)
    one is then SUMO's leader (follower) of that alongside vehicle, unless it overlaps too.
    """

    def overlaps(other: str) -> bool:
        ext = inside.get(other)
        return ext is not None and ext[1] > back and ext[0] < front

    pre = along = fol = ""
    if leads:
        lead = leads[0][0] if len(leads) == 1 else min(leads, key=lambda p: p[1])[0]
        if overlaps(lead):
            along = lead
            nxt = results[lead][VAR_LEADER][0]
            pre = "" if overlaps(nxt) else nxt
        else:
            pre = lead
    if follows:
        foll = follows[0][0] if len(follows) == 1 else min(follows, key=lambda p: p[1])[0]
        if overlaps(foll):
            along = along or foll
            nxt = results[foll][VAR_FOLLOWER][0]
            fol = "" if overlaps(nxt) else nxt
        else:
            fol = foll
    return [pre, along, fol]


def run_simulation(
    cfg: HighwayConfig, workdir: Path, on_second: Callable[[], object] | None = None
) -> Samples:
    """Run SUMO (libsumo, in process) on the scenario in ``workdir`` and sample the section.

    Subscriptions keep the per-step cost low: a vehicle on the approach is subscribed to its
    position only; from 60 m before the section on to its full state (position, speeds,
    acceleration, lane, leader, follower); once past the section it is unsubscribed. The four
    ``getNeighbors`` queries are made only for vehicles in the section. ``on_second()`` is called
    after every second of simulated time (for progress bars).
    """
    started = time.perf_counter()
    net = write_network(cfg, workdir)
    routes = write_routes(cfg, workdir)
    types = vehicle_types(cfg.truck_share, cfg.drivers)
    type_of = {t[0]: i for i, t in enumerate(types)}
    libsumo = import_libsumo()
    from traci import constants as tc

    POS, SPEED, ACC, LAT, LANE = (
        tc.VAR_POSITION,
        tc.VAR_SPEED,
        tc.VAR_ACCELERATION,
        tc.VAR_SPEED_LAT,
        tc.VAR_LANE_INDEX,
    )
    LEAD, FOLL = tc.VAR_LEADER, tc.VAR_FOLLOWER
    full = [POS, SPEED, ACC, LAT, LANE, LEAD, FOLL]
    search = float(cfg.section_length_m + 50.0)
    params = {LEAD: search, FOLL: search}

    road = cfg.road_length_m
    s0 = cfg.approach_length_m  # the section along the direction of travel (same for both directions)
    s1 = cfg.approach_length_m + cfg.section_length_m
    s_watch = s0 - 60.0
    warm_steps = round(cfg.warmup_s * cfg.frame_rate)
    total_steps = warm_steps + cfg.n_frames

    number: dict[str, int] = {}
    half_length: dict[str, float] = {}
    lower: dict[str, bool] = {}
    watched: set[str] = set()
    type_index = [0]
    direction = [0]
    rows = array.array("d")  # 16 values per row (see the extend below), compact for ~1 M rows
    if libsumo.simulation.isLoaded():
        libsumo.close()
    libsumo.start(_sumo_args(cfg, net, routes))
    try:
        vehicle = libsumo.vehicle
        neighbours_of = vehicle.getNeighbors
        centres_u = np.array(
            [libsumo.lane.getShape(f"upper_{i}")[0][1] for i in range(cfg.lanes_per_direction)]
        )
        centres_l = np.array(
            [libsumo.lane.getShape(f"lower_{i}")[0][1] for i in range(cfg.lanes_per_direction)]
        )
        for step in range(1, total_steps + 1):
            libsumo.simulationStep()
            for vid in libsumo.simulation.getDepartedIDList():
                vehicle.subscribe(vid, [POS])
                number[vid] = len(number) + 1
                t = type_of[vehicle.getTypeID(vid)]
                type_index.append(t)
                half_length[vid] = types[t][2] / 2
                lower[vid] = vid.startswith("lower")
                direction.append(2 if lower[vid] else 1)
            if on_second is not None and step % round(cfg.frame_rate) == 0:
                on_second()
            results = vehicle.getAllSubscriptionResults()
            # Along-road extent (back, front) of the vehicles in the section; staged subscriptions.
            inside: dict[str, tuple[float, float]] = {}
            for vid, r in results.items():
                xf = r[POS][0]
                s_front = xf if lower[vid] else road - xf
                centre = s_front - half_length[vid]
                if centre < s_watch:
                    continue
                if vid not in watched:
                    vehicle.subscribe(vid, full, parameters=params)
                    watched.add(vid)
                elif centre > s1:
                    vehicle.unsubscribe(vid)
                    watched.discard(vid)
                elif centre >= s0 and LEAD in r:
                    inside[vid] = (s_front - 2 * half_length[vid], s_front)
            if step <= warm_steps:
                continue
            frame = step - warm_steps

            for vid, (back, front) in inside.items():
                r = results[vid]
                ids = [r[LEAD][0], r[FOLL][0]]
                for lead_mode, foll_mode in ((2, 0), (3, 1)):  # left, right (in the direction of travel)
                    ids += _side_neighbours(
                        neighbours_of(vid, lead_mode),
                        neighbours_of(vid, foll_mode),
                        back,
                        front,
                        inside,
                        results,
                    )
                pos = r[POS]
                rows.extend(
                    (frame, number[vid], pos[0], pos[1], r[SPEED], r[ACC], r[LAT], r[LANE],
                     *(number[n] if n in inside else 0 for n in ids))
                )  # fmt: skip
    finally:
        libsumo.close()
    if not rows:
        raise InputError(None, "the simulation recorded no vehicle in the section", expected="a longer run")
    data = np.frombuffer(rows, dtype=np.float64).reshape(-1, 16)
    return Samples(
        frame=data[:, 0].astype(np.int64),
        vehicle=data[:, 1].astype(np.int64),
        x_front=data[:, 2],
        y_centre=data[:, 3],
        speed=data[:, 4],
        accel=data[:, 5],
        speed_lat=data[:, 6],
        lane_index=data[:, 7].astype(np.int64),
        neighbours=data[:, 8:16].astype(np.int64),
        type_index=np.asarray(type_index, dtype=np.int64),
        direction=np.asarray(direction, dtype=np.int64),
        types=types,
        lane_centres_upper=centres_u,
        lane_centres_lower=centres_l,
        wall_time_s=time.perf_counter() - started,
        lane_width_m=cfg.lane_width_m,
    )
