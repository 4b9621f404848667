"""A highD-like recording simulated with Eclipse SUMO: a straight two-carriageway highway.

Why: lanecast needs highway data that anyone can regenerate (highD's licence forbids sharing it), with
lane changes and with neighbour ids that come from an independent source (SUMO's own leader, follower
and neighbour queries) so that lanecast's neighbour stage can be checked against them.

The road: two straight carriageways of ``lanes_per_direction`` lanes (3.75 m wide) separated by a
median, ``approach_length_m + section_length_m + approach_length_m`` long. Only the middle section is
"filmed"; the approach lets inserted vehicles settle, and the simulation runs a warm-up before frame 1
so that the section is in equilibrium. Cars and trucks (IDM car-following, LC2013 lane changing with
keep-right and overtaking) have spread desired speeds; lane changes take ``lane_change_duration_s``
with continuous lateral motion. One simulation step is one frame at 25 Hz.

Output: highD's three CSV files ``NN_tracks.csv``, ``NN_tracksMeta.csv``, ``NN_recordingMeta.csv`` in
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
``yVelocity`` (SUMO's lateral speed), so it spikes at the start and end of a lane change.

Size: the simulation (network, routes, the libsumo loop) and the conversion of its samples into
highD's files are two halves; they stay in one file while the scenario work of this wave (issue 10)
changes both; the cut is ``to_highd`` and its helpers into ``sim/to_highd.py``.
"""

from __future__ import annotations

import array
import contextlib
import io
import os
import shutil
import subprocess
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.csv as pacsv

from lanecast.io_adapters.contracts.track_runs import (
    along_track_derivative,
    lane_change_starts,
    row_extent,
    run_starts,
)
from lanecast.io_adapters.datasets.highd import NEIGHBOURS
from lanecast.io_adapters.errors import InputError
from lanecast.io_adapters.files import bar, check_output
from lanecast.io_adapters.sim.slow_signals import sinusoid_sum

FRAME_RATE = 25.0
STEP_S = 1.0 / FRAME_RATE
LANE_WIDTH_M = 3.75
MEDIAN_M = 4.0
TOP_MARGIN_M = 8.0  # image y of the upper carriageway's top marking
X_MARGIN_M = 10.0  # image x of the section's start (so that bounding boxes stay at x > 0)
SPEED_LIMIT_KMH = 130.0  # the default limit (German autobahn advisory speed, highD)
# Mean arrival rate per carriageway (vehicles/s, Poisson arrivals); "medium" gives about 1,000
# vehicles in 15 simulated minutes over both carriageways, like one highD recording.
DENSITY_RATES: dict[str, float] = {"low": 0.25, "medium": 0.56, "high": 1.0}
BOTTLENECKS = ("none", "on_ramp", "lane_drop", "slow_zone", "signal")
DRIVERS = ("uniform", "mixed")
BOTTLENECK_GAP_M = 50.0  # from the section's end to the bottleneck (the queue grows back into the section)
SIGNAL_GAP_M = 20.0  # a traffic light right after the section: its queue stands in the section
BOTTLENECK_LENGTH_M = 300.0  # the slow zone, the lane-drop taper, the ramp's acceleration lane
RAMP_LENGTH_M = 300.0
# (type id, class, length m, width m, share within its class)
_CAR_TYPES = (
    ("car_s", "Car", 4.2, 1.75, 0.3),
    ("car_m", "Car", 4.7, 1.85, 0.5),
    ("car_l", "Car", 5.1, 2.0, 0.2),
)
_TRUCK_TYPES = (("truck_m", "Truck", 11.0, 2.5, 0.4), ("truck_l", "Truck", 16.5, 2.55, 0.6))

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
# traci.constants.VAR_LEADER / VAR_FOLLOWER (checked by the tests), here to keep traci out of imports.
VAR_LEADER, VAR_FOLLOWER = 0x68, 0x78
# highD's neighbour columns, in the order of the track table's (one definition: the highD reader's).
_NEIGHBOUR_HIGHD = tuple(NEIGHBOURS)


@dataclass(frozen=True)
class HighwayConfig:
    """Everything that determines a simulated recording (same config → byte-identical files)."""

    minutes: float
    seed: int
    lanes_per_direction: int = 3
    density: str = "medium"
    truck_share: float = 0.2
    section_length_m: float = 1000.0
    approach_length_m: float = 1000.0
    lane_change_duration_s: float = 3.0
    speed_limit_kmh: float = SPEED_LIMIT_KMH
    lane_width_m: float = LANE_WIDTH_M
    #: Poisson arrivals per carriageway (vehicles/s); None: the rate of ``density``
    demand_per_s: float | None = None
    #: downstream of the section: "none", "on_ramp" (a merging ramp with an acceleration lane),
    #: "lane_drop" (the right-most lane ends), "slow_zone" (a stretch at ``bottleneck_speed_kmh``)
    #: or "signal" (a traffic light, ``signal_green_s`` green then ``signal_red_s`` red, queues)
    bottleneck: str = "none"
    bottleneck_speed_kmh: float = 40.0
    signal_green_s: float = 40.0
    signal_red_s: float = 30.0
    ramp_demand_per_s: float = 0.3
    #: "uniform" (one car and one truck behaviour) or "mixed" (three driving styles, IDM and Krauss)
    drivers: str = "uniform"
    #: width (s) of the triangular kernel that smooths lateral positions (0: SUMO's constant-speed
    #: sideways motion with acceleration spikes at its ends)
    lateral_smoothing_s: float = 0.0
    #: std (m) of each driver's slow weave inside the lane (real drivers do not hold the lane centre:
    #: a sum of slow sinusoids per vehicle, periods 6-40 s; 0: SUMO's exact lane centre)
    lateral_wander_m: float = 0.0
    #: extra warm-up before frame 1 (s), e.g. for a queue to grow back from a bottleneck
    extra_warmup_s: float = 0.0
    #: how often drivers decide (s; SUMO's actionStepLength; 0: every simulation step). Real drivers
    #: react after about 1 s; the delay makes a dense queue unstable, so that stop-and-go waves form
    #: and run upstream through it, where drivers deciding every step only crawl at the bottleneck's pace
    reaction_time_s: float = 0.0
    #: simulation steps = frames per second (highD: 25; 10 is what the windows use, 2.5× cheaper)
    frame_rate: float = FRAME_RATE

    @property
    def step_s(self) -> float:
        return 1.0 / self.frame_rate

    @property
    def road_length_m(self) -> float:
        return 2 * self.approach_length_m + self.section_length_m

    @property
    def speed_limit_mps(self) -> float:
        return self.speed_limit_kmh / 3.6

    @property
    def rate_per_s(self) -> float:
        return DENSITY_RATES[self.density] if self.demand_per_s is None else self.demand_per_s

    @property
    def warmup_s(self) -> float:
        """Long enough for a truck (≈ 20 m/s) inserted at t = 0 to cross the section's end."""
        return round((self.approach_length_m + self.section_length_m) / 20.0 + 20.0 + self.extra_warmup_s)

    @property
    def n_frames(self) -> int:
        return round(self.minutes * 60.0 * self.frame_rate)

    def check(self) -> None:
        """Raise InputError for parameters that cannot give a recording."""
        problems = []
        if not self.minutes > 0:
            problems.append(("minutes", f"{self.minutes}", "a positive number of minutes"))
        if not 0 <= self.seed < 2**31:
            problems.append(("seed", f"{self.seed}", "an integer in 0 … 2³¹−1"))
        if not 1 <= self.lanes_per_direction <= 6:
            problems.append(("lanes_per_direction", f"{self.lanes_per_direction}", "1 … 6"))
        if self.density not in DENSITY_RATES:
            problems.append(("density", repr(self.density), f"one of {sorted(DENSITY_RATES)}"))
        if not 0.0 <= self.truck_share <= 1.0:
            problems.append(("truck_share", f"{self.truck_share}", "a share in [0, 1]"))
        if not self.section_length_m >= 50.0:
            problems.append(("section_length_m", f"{self.section_length_m}", "at least 50 m"))
        if not self.approach_length_m >= 100.0:
            problems.append(("approach_length_m", f"{self.approach_length_m}", "at least 100 m"))
        if self.frame_rate not in (10.0, 20.0, 25.0, 50.0):
            problems.append(("frame_rate", f"{self.frame_rate}", "10, 20, 25 or 50 Hz"))
        elif not self.lane_change_duration_s > self.step_s:
            problems.append(
                ("lane_change_duration_s", f"{self.lane_change_duration_s}", "longer than a step")
            )
        if not 20.0 <= self.speed_limit_kmh <= 250.0:
            problems.append(("speed_limit_kmh", f"{self.speed_limit_kmh}", "20 … 250 km/h"))
        if not 2.5 <= self.lane_width_m <= 5.0:
            problems.append(("lane_width_m", f"{self.lane_width_m}", "2.5 … 5 m"))
        if self.demand_per_s is not None and not 0 < self.demand_per_s <= 5.0:
            problems.append(("demand_per_s", f"{self.demand_per_s}", "0 < vehicles/s <= 5"))
        if self.bottleneck not in BOTTLENECKS:
            problems.append(("bottleneck", repr(self.bottleneck), f"one of {BOTTLENECKS}"))
        if self.bottleneck == "lane_drop" and self.lanes_per_direction < 2:
            problems.append(("lanes_per_direction", "1", "at least 2 lanes for a lane drop"))
        if (
            self.bottleneck != "none"
            and self.approach_length_m < BOTTLENECK_GAP_M + BOTTLENECK_LENGTH_M + 100
        ):
            problems.append(
                ("approach_length_m", f"{self.approach_length_m}", "at least 700 m with a bottleneck")
            )
        if self.drivers not in DRIVERS:
            problems.append(("drivers", repr(self.drivers), f"one of {DRIVERS}"))
        if not 0.0 <= self.lateral_smoothing_s <= 10.0:
            problems.append(("lateral_smoothing_s", f"{self.lateral_smoothing_s}", "0 … 10 s"))
        if not 0.0 <= self.lateral_wander_m <= 0.5:
            problems.append(("lateral_wander_m", f"{self.lateral_wander_m}", "0 … 0.5 m"))
        if not self.extra_warmup_s >= 0.0:
            problems.append(("extra_warmup_s", f"{self.extra_warmup_s}", "a non-negative time"))
        if not 0.0 <= self.reaction_time_s <= 3.0:
            problems.append(("reaction_time_s", f"{self.reaction_time_s}", "0 … 3 s"))
        if problems:
            name, got, expected = problems[0]
            option = OPTIONS.get(name)
            what = f"{option} {got}: invalid" if option else f"invalid simulation parameter {name} = {got}"
            raise InputError(None, what, expected=expected)


# ----------------------------------------------------------------------------------------------
# Scenario files


# The command-line options (`lanecast simulate`, `lanecast demo`) that set a HighwayConfig field.
OPTIONS = {
    "minutes": "--minutes", "seed": "--seed", "lanes_per_direction": "--lanes-per-direction",
    "density": "--density", "truck_share": "--truck-share", "section_length_m": "--section-length",
    "approach_length_m": "--approach-length", "lane_change_duration_s": "--lane-change-duration",
    "lateral_smoothing_s": "--lateral-smoothing", "lateral_wander_m": "--weave", "drivers": "--drivers",
}  # fmt: skip


def _sumo_home() -> Path:
    import sumo  # the eclipse-sumo wheel

    return Path(sumo.SUMO_HOME)


def road_edges(cfg: HighwayConfig) -> tuple[list[tuple[str, float]], list[str]]:
    """Nodes (name, along-road distance) of a carriageway and the suffixes of the edges between them.

    The original highway (uniform drivers, no bottleneck) is one edge. Scenarios (mixed drivers or a
    bottleneck) split it at the section's start and end: approach ``_in``, section (no suffix),
    ``_out``, and with a bottleneck ``_bn`` and ``_end``. (SUMO's neighbour queries then cross the
    junction at the section's start; measured on the shipped training recordings, 0.01 % of the
    left/right neighbour ids are on the wrong side, e.g. dense: 11 of 105,449 right-following.)
    """
    length = cfg.road_length_m
    if cfg.drivers == "uniform" and cfg.bottleneck == "none":
        return [("0", 0.0), ("1", length)], [""]
    a, b = cfg.approach_length_m, cfg.approach_length_m + cfg.section_length_m
    stops = [("0", 0.0), ("a", a), ("b", b)]
    names = ["_in", "", "_out"]
    if cfg.bottleneck != "none":
        c = b + (SIGNAL_GAP_M if cfg.bottleneck == "signal" else BOTTLENECK_GAP_M)
        stops += [("c", c), ("d", c + BOTTLENECK_LENGTH_M)]
        names += ["_bn", "_end"]
    return [*stops, ("1", length)], names


def write_network(cfg: HighwayConfig, directory: Path) -> Path:
    """Write plain nodes/edges (and lane connections) for the two carriageways; build
    ``highway.net.xml`` with netconvert.

    The lower carriageway runs along y = −median/2 towards +x, the upper one along +median/2 towards
    −x; each edge spreads its lanes to its right, so lane 0 (the slow lane) is the outermost. Each
    carriageway is the edges of :func:`road_edges`; the filmed section is ``lower``/``upper``, and
    ``…_bn`` is the bottleneck (the slow zone, the lanes after a drop, or the ramp's acceleration
    lane beside the main lanes, fed by ``…_ramp``).
    """
    length = cfg.road_length_m
    half = MEDIAN_M / 2
    lanes = cfg.lanes_per_direction
    w = cfg.lane_width_m
    c = road_edges(cfg)[0][-3][1] if cfg.bottleneck != "none" else 0.0
    stops, names = road_edges(cfg)
    nodes, edges, connections = [], [], []
    for side, sign in (("lower", 1.0), ("upper", -1.0)):
        p = side[0]

        def xy(s: float, off: float = 0.0, sign: float = sign) -> str:
            # along-road distance s (and offset to the right of travel) -> network coordinates
            x = s if sign > 0 else length - s
            y = -sign * (half + off)
            return f'x="{x:.2f}" y="{y:.2f}"'

        for name, at in stops:
            kind = "traffic_light" if name == "c" and cfg.bottleneck == "signal" else "priority"
            nodes.append(f'  <node id="{p}{name}" {xy(at)} type="{kind}"/>')
        for (n0, _), (n1, _), suffix in zip(stops[:-1], stops[1:], names, strict=True):
            n_lanes, speed = lanes, cfg.speed_limit_mps
            if suffix == "_bn" and cfg.bottleneck == "slow_zone":
                speed = cfg.bottleneck_speed_kmh / 3.6
            if suffix in ("_bn", "_end") and cfg.bottleneck == "lane_drop":
                n_lanes = lanes - 1
            if suffix == "_bn" and cfg.bottleneck == "on_ramp":
                n_lanes = lanes + 1
            edges.append(
                f'  <edge id="{side}{suffix}" from="{p}{n0}" to="{p}{n1}" numLanes="{n_lanes}" '
                f'speed="{speed:.4f}" width="{w}" spreadType="right"/>'
            )
        if cfg.bottleneck == "on_ramp":
            nodes.append(f'  <node id="{p}r" {xy(c - RAMP_LENGTH_M, lanes * w + 30.0)} type="priority"/>')
            edges.append(
                f'  <edge id="{side}_ramp" from="{p}r" to="{p}c" numLanes="1" '
                f'speed="{min(cfg.speed_limit_mps, 80 / 3.6):.4f}" width="{w}" spreadType="right"/>'
            )
            connections.append(f'  <connection from="{side}_ramp" to="{side}_bn" fromLane="0" toLane="0"/>')
            for i in range(lanes):
                connections.append(
                    f'  <connection from="{side}_out" to="{side}_bn" fromLane="{i}" toLane="{i + 1}"/>'
                )
                connections.append(
                    f'  <connection from="{side}_bn" to="{side}_end" fromLane="{i + 1}" toLane="{i}"/>'
                )
        if cfg.bottleneck == "lane_drop":
            for i in range(1, lanes):
                connections.append(
                    f'  <connection from="{side}_out" to="{side}_bn" fromLane="{i}" toLane="{i - 1}"/>'
                )
    (directory / "highway.nod.xml").write_text(
        "<nodes>\n" + "\n".join(nodes) + "\n</nodes>\n", encoding="utf-8"
    )
    (directory / "highway.edg.xml").write_text(
        "<edges>\n" + "\n".join(edges) + "\n</edges>\n", encoding="utf-8"
    )
    lanes_str = "G" * lanes
    (directory / "highway.add.xml").write_text(
        "<additional>\n"
        + "".join(
            f'  <tlLogic id="{p}c" type="static" programID="lanecast" offset="{offset:g}">\n'
            f'    <phase duration="{cfg.signal_green_s:g}" state="{lanes_str}"/>\n'
            f'    <phase duration="3" state="{"y" * lanes}"/>\n'
            f'    <phase duration="{cfg.signal_red_s:g}" state="{"r" * lanes}"/>\n'
            "  </tlLogic>\n"
            for p, offset in (("l", 0.0), ("u", cfg.signal_green_s / 2))
            if cfg.bottleneck == "signal"
        )
        + "</additional>\n",
        encoding="utf-8",
    )
    (directory / "highway.con.xml").write_text(
        "<connections>\n" + "\n".join(connections) + ("\n" if connections else "") + "</connections>\n",
        encoding="utf-8",
    )
    net = directory / "highway.net.xml"
    home = _sumo_home()
    cmd = [
        str(home / "bin" / "netconvert"),
        "--node-files", str(directory / "highway.nod.xml"),
        "--edge-files", str(directory / "highway.edg.xml"),
        "--connection-files", str(directory / "highway.con.xml"),
        "--output-file", str(net),
        "--offset.disable-normalization", "true",
        "--no-turnarounds", "true",
        "--no-warnings", "true",
    ]  # fmt: skip
    done = subprocess.run(cmd, capture_output=True, text=True, env={**os.environ, "SUMO_HOME": str(home)})
    if done.returncode != 0:
        raise RuntimeError(f"netconvert failed: {done.stderr.strip()}")
    return net


# Driving styles of the "mixed" drivers: (style, share among cars, vType attributes). Desired speeds
# (speedFactor × the lane's limit), headways (tau), accelerations and imperfection (Krauss sigma)
# spread between styles and, through speedFactor's distribution, within each.
_CAR_STYLES = (
    (
        "calm",
        0.3,
        'carFollowModel="IDM" accel="1.2" decel="2.5" emergencyDecel="9" tau="1.6" minGap="2.5" '
        'speedFactor="normc(0.92,0.08,0.7,1.15)" lcSpeedGain="0.3" lcKeepRight="1.0"',
    ),
    (
        "normal",
        0.5,
        'carFollowModel="Krauss" sigma="0.5" accel="2.0" decel="4.0" emergencyDecel="9" tau="1.2" '
        'minGap="2.0" speedFactor="normc(1.0,0.1,0.75,1.3)" lcSpeedGain="0.7" lcKeepRight="0.8"',
    ),
    (
        "brisk",
        0.2,
        'carFollowModel="IDM" accel="2.6" decel="3.5" emergencyDecel="9" tau="0.8" minGap="1.5" '
        'speedFactor="normc(1.1,0.1,0.85,1.4)" lcSpeedGain="1.5" lcKeepRight="0.5" lcAssertive="1.5"',
    ),
)
_TRUCK_STYLE = (
    'carFollowModel="Krauss" sigma="0.3" accel="0.6" decel="2.5" emergencyDecel="7" tau="1.8" minGap="3.0" '
    'maxSpeed="25" speedFactor="normc(1.0,0.05,0.9,1.1)" lcSpeedGain="0.2" lcKeepRight="2.0"'
)


def vehicle_types(truck_share: float, drivers: str = "uniform") -> list[tuple[str, str, float, float, float]]:
    """(type id, highD class, length, width, probability) of every vehicle type in the mix; with
    ``drivers="mixed"`` every car size comes in each driving style of ``_CAR_STYLES``."""
    if drivers == "mixed":
        types = [
            (f"{t}_{style}", c, ln, w, p * share * (1.0 - truck_share))
            for t, c, ln, w, p in _CAR_TYPES
            for style, share, _ in _CAR_STYLES
        ]
    else:
        types = [(t, c, ln, w, p * (1.0 - truck_share)) for t, c, ln, w, p in _CAR_TYPES]
    types += [(t, c, ln, w, p * truck_share) for t, c, ln, w, p in _TRUCK_TYPES]
    return [t for t in types if t[4] > 0]


def _type_attributes(type_id: str, cls: str, drivers: str) -> str:
    if drivers == "mixed":
        if cls != "Car":
            return f'vClass="truck" laneChangeModel="LC2013" lcCooperative="1.0" {_TRUCK_STYLE}'
        style = {name: attrs for name, _, attrs in _CAR_STYLES}[type_id.rsplit("_", 1)[1]]
        return f'vClass="passenger" maxSpeed="55" laneChangeModel="LC2013" lcCooperative="1.0" {style}'
    if cls == "Car":
        return (
            'vClass="passenger" carFollowModel="IDM" accel="1.6" decel="3.0" emergencyDecel="9" tau="1.2" '
            'minGap="2.0" maxSpeed="55" speedFactor="normc(0.95,0.12,0.65,1.35)" '
            'laneChangeModel="LC2013" lcKeepRight="1.0" lcSpeedGain="1.5" lcCooperative="1.0"'
        )
    return (
        'vClass="truck" carFollowModel="IDM" accel="0.6" decel="2.5" emergencyDecel="7" tau="1.6" '
        'minGap="2.5" maxSpeed="26" speedFactor="normc(0.64,0.04,0.55,0.72)" '
        'laneChangeModel="LC2013" lcKeepRight="2.0" lcSpeedGain="0.5" lcCooperative="1.0"'
    )


def write_routes(cfg: HighwayConfig, directory: Path) -> Path:
    """Vehicle types and one Poisson flow per carriageway (plus one per on-ramp)."""
    lines = ["<routes>"]
    types = vehicle_types(cfg.truck_share, cfg.drivers)
    reaction = f' actionStepLength="{cfg.reaction_time_s:g}"' if cfg.reaction_time_s > 0 else ""
    for type_id, cls, length, width, _ in types:
        attrs = _type_attributes(type_id, cls, cfg.drivers) + reaction
        lines.append(f'  <vType id="{type_id}" length="{length}" width="{width}" {attrs}/>')
    ids = " ".join(t[0] for t in types)
    probs = " ".join(f"{t[4]:.6f}" for t in types)
    lines.append(f'  <vTypeDistribution id="mix" vTypes="{ids}" probabilities="{probs}"/>')
    end = cfg.warmup_s + cfg.minutes * 60.0 + 10.0
    suffixes = road_edges(cfg)[1]
    for name in ("lower", "upper"):
        lines.append(f'  <route id="r_{name}" edges="{" ".join(name + x for x in suffixes)}"/>')
        lines.append(
            f'  <flow id="{name}" route="r_{name}" type="mix" begin="0" end="{end:.2f}" '
            f'period="exp({cfg.rate_per_s})" departLane="random" departSpeed="max"/>'
        )
        if cfg.bottleneck == "on_ramp":
            lines.append(f'  <route id="r_{name}_ramp" edges="{name}_ramp {name}_bn {name}_end"/>')
            lines.append(
                f'  <flow id="{name}_ramp" route="r_{name}_ramp" type="mix" begin="0" end="{end:.2f}" '
                f'period="exp({cfg.ramp_demand_per_s})" departLane="0" departSpeed="max"/>'
            )
    lines.append("</routes>")
    path = directory / "highway.rou.xml"
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


# ----------------------------------------------------------------------------------------------
# Simulation


def import_libsumo() -> ModuleType:
    """Import libsumo without its stdout warning about the pyarrow version.

    libsumo bundles its own libarrow (23.0, under mangled names in ``libsumo.libs``) and prints a
    warning when pyarrow differs (here 26); both load side by side in one process, in either import
    order, without crashing (checked by tests/test_simulate.py, which has pyarrow loaded first).
    """
    with contextlib.redirect_stdout(io.StringIO()):
        import libsumo
    return libsumo


@dataclass
class Samples:
    """What the simulation recorded, one row per (vehicle in the section, frame).

    Arrays of shape [R] (rows in the order recorded); ``neighbours`` int64 [R, 8] are vehicle numbers
    (0 = none) in the order of ``_NEIGHBOUR_HIGHD``. Vehicle numbers start at 1 in order of departure.
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


def to_highd(samples: Samples, cfg: HighwayConfig, recording_id: int = 1) -> dict[str, pa.Table]:
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
    for i, name in enumerate(_NEIGHBOUR_HIGHD):  # 8 columns, each vectorised
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
    recording = _recording_meta(meta, samples, cfg, recording_id)
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


def _recording_meta(meta: pa.Table, samples: Samples, cfg: HighwayConfig, recording_id: int) -> pa.Table:
    upper, lower, _ = lane_markings(samples)
    classes = np.asarray(meta.column("class").to_pylist())
    return pa.table(
        {
            "id": [recording_id],
            "frameRate": [int(cfg.frame_rate)],
            "locationId": [0],  # not a highD location: simulated
            "speedLimit": [round(cfg.speed_limit_mps, 2)],
            "month": ["01.2000"],  # format fields of highD; a simulation has no calendar date
            "weekDay": ["Sat"],
            "startTime": ["12:00"],
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
            expected="a new --out directory, another --recording-id, or remove the files first",
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


def simulate(
    out_dir: Path,
    *,
    minutes: float,
    seed: int,
    lanes_per_direction: int = 3,
    density: str = "medium",
    truck_share: float = 0.2,
    recording_id: int = 1,
    section_length_m: float = 1000.0,
    approach_length_m: float = 1000.0,
    lane_change_duration_s: float = 3.0,
    show_progress: bool = True,
    overwrite: bool = False,
    config: HighwayConfig | None = None,
) -> Path:
    """Simulate ``minutes`` of highway traffic and write a highD recording into ``out_dir``.

    ``config`` (e.g. a named scenario's, :mod:`lanecast.io_adapters.sim.scenarios`) replaces every
    other simulation argument. Returns ``out_dir``. The same arguments give byte-identical files. An
    existing recording of the same number in ``out_dir`` is refused before simulating, unless
    ``overwrite``.
    """
    cfg = config or HighwayConfig(
        minutes=minutes,
        seed=seed,
        lanes_per_direction=lanes_per_direction,
        density=density,
        truck_share=truck_share,
        section_length_m=section_length_m,
        approach_length_m=approach_length_m,
        lane_change_duration_s=lane_change_duration_s,
    )
    cfg.check()
    if not 1 <= recording_id <= 99:
        raise InputError(None, f"invalid recording id {recording_id}", expected="1 … 99")
    check_output(out_dir, directory=True)  # a file there, or on its path: before minutes of simulation
    if not overwrite:
        refuse_existing_recording(Path(out_dir), recording_id)
    total_s = cfg.warmup_s + cfg.n_frames / cfg.frame_rate
    with tempfile.TemporaryDirectory(prefix="lanecast-sumo-") as work:
        if show_progress:
            with bar(desc="simulating", total=round(total_s), unit="sim s") as progress_bar:
                samples = run_simulation(cfg, Path(work), lambda: progress_bar.update(1))
        else:
            samples = run_simulation(cfg, Path(work))
    tables = to_highd(samples, cfg, recording_id)
    return write_highd(tables, Path(out_dir), recording_id, overwrite=overwrite)
