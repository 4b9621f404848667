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

Output: the samples of every vehicle in the section (:class:`Samples`), written by
:mod:`~lanecast.io_adapters.sim.to_highd` as highD's three CSV files ``NN_tracks.csv``,
``NN_tracksMeta.csv``, ``NN_recordingMeta.csv``; :func:`~lanecast.io_adapters.sim.recording.simulate` does both. Neighbour ids are
SUMO's own (``vehicle.getLeader``, ``getFollower``, ``getNeighbors``).

This module: the scenario's configuration and its checks, and the network and routes SUMO reads;
the libsumo loop that samples every vehicle in the section is :mod:`~lanecast.io_adapters.sim.sumo_run`.
"""

from __future__ import annotations

import os
import subprocess
from dataclasses import dataclass
from pathlib import Path

from lanecast.io_adapters.errors import InputError

FRAME_RATE = 25.0
STEP_S = 1.0 / FRAME_RATE
LANE_WIDTH_M = 3.75
MEDIAN_M = 4.0
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
#: the longest recording simulated: its samples are held in memory (10 minutes of a busy 3-lane
#: highway are about 3 M rows at 25 Hz), and SUMO's clock overflows for absurd lengths
MAX_MINUTES = 120.0
MAX_ROAD_M = 10_000.0  # section and approach lengths
# (type id, class, length m, width m, share within its class)
_CAR_TYPES = (
    ("car_s", "Car", 4.2, 1.75, 0.3),
    ("car_m", "Car", 4.7, 1.85, 0.5),
    ("car_l", "Car", 5.1, 2.0, 0.2),
)
_TRUCK_TYPES = (("truck_m", "Truck", 11.0, 2.5, 0.4), ("truck_l", "Truck", 16.5, 2.55, 0.6))


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
        if not 0 < self.minutes <= MAX_MINUTES:  # beyond, SUMO's clock overflows (a traceback)
            problems.append(
                ("minutes", f"{self.minutes}", f"a number of minutes above 0, at most {MAX_MINUTES:g}")
            )
        if not 0 <= self.seed < 2**31:
            problems.append(("seed", f"{self.seed}", "an integer in 0 … 2³¹−1"))
        if not 1 <= self.lanes_per_direction <= 6:
            problems.append(("lanes_per_direction", f"{self.lanes_per_direction}", "1 … 6"))
        if self.density not in DENSITY_RATES:
            problems.append(("density", repr(self.density), f"one of {sorted(DENSITY_RATES)}"))
        if not 0.0 <= self.truck_share <= 1.0:
            problems.append(("truck_share", f"{self.truck_share}", "a share in [0, 1]"))
        if not 50.0 <= self.section_length_m <= MAX_ROAD_M:
            problems.append(("section_length_m", f"{self.section_length_m}", f"50 … {MAX_ROAD_M:g} m"))
        if not 100.0 <= self.approach_length_m <= MAX_ROAD_M:
            problems.append(("approach_length_m", f"{self.approach_length_m}", f"100 … {MAX_ROAD_M:g} m"))
        if self.frame_rate not in (10.0, 20.0, 25.0, 50.0):
            problems.append(("frame_rate", f"{self.frame_rate}", "10, 20, 25 or 50 Hz"))
        elif not self.step_s < self.lane_change_duration_s <= 20.0:
            problems.append(
                (
                    "lane_change_duration_s",
                    f"{self.lane_change_duration_s}",
                    "longer than a step, at most 20 s",
                )
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
        if not 0.0 <= self.extra_warmup_s <= 3600.0:
            problems.append(("extra_warmup_s", f"{self.extra_warmup_s}", "0 … 3600 s"))
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
