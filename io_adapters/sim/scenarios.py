"""Named traffic scenarios for ``lanecast simulate --scenario NAME`` (docs/design.md §2, training data).

Each scenario is a :class:`~lanecast.io_adapters.sim.sumo_highway.HighwayConfig` without its
minutes and seed. Together they span what real highways show, from free flow to stop-and-go:
speed limits 60-130 km/h, 2-5 lanes per direction, lane widths 3.5-3.75 m, demand from light to
beyond a bottleneck's capacity (an on-ramp merge, a lane drop, a slow zone, a traffic light, each placed 50 m
downstream of the filmed section so that its queue grows back into it), trucks 10-25 %, and
mixed drivers (three car styles: IDM and Krauss with imperfection, headways 0.8-1.6 s, desired
speeds spread ±10 % around 0.9-1.1 × the limit). Lane changes last 4 s and their lateral motion is
smoothed into an S-curve (peak lateral acceleration ≈ 0.6 m/s²); between lane changes drivers
weave slowly inside their lane (std 0.15 m, periods 6-40 s) instead of holding its centre exactly.
Drivers decide every step (0.1 s), so a queue behind a slow zone crawls at the zone's pace; in
``waves`` they react after 1 s, which makes the queue unstable: stop-and-go waves run upstream
through it, as on a congested real freeway (speeds swinging between standing and 10 m/s).

The training mix of the shipped model (``benchmarks/train_shipped.py``) uses every scenario but
``waves``, which measures how the model meets a regime it never saw (docs/design.md).
"""

from __future__ import annotations

import dataclasses
from typing import Any

from lanecast.io_adapters.errors import InputError
from lanecast.io_adapters.sim.sumo_highway import HighwayConfig

#: How drivers move, in every scenario and in ``lanecast simulate`` without one: 4 s lane changes
#: smoothed by a 3 s kernel (no lateral-acceleration spikes), in-lane weave, mixed drivers.
DRIVING: dict[str, Any] = {
    "lane_change_duration_s": 4.0,
    "lateral_smoothing_s": 3.0,
    "lateral_wander_m": 0.15,
    "drivers": "mixed",
}

#: Shared by every scenario: a 600 m filmed section (highD films ~420 m; longer gives more windows
#: per vehicle), 10 Hz, and ``DRIVING``.
COMMON: dict[str, Any] = {
    "section_length_m": 600.0,
    "approach_length_m": 800.0,
    "frame_rate": 10.0,
    **DRIVING,
}

#: name -> (one-line description, parameters). Demand is vehicles/s per carriageway.
SCENARIOS: dict[str, tuple[str, dict[str, Any]]] = {
    "free_flow": (
        "3 lanes, 130 km/h, light traffic (1,260 veh/h per direction)",
        {"lanes_per_direction": 3, "speed_limit_kmh": 130.0, "demand_per_s": 0.35, "truck_share": 0.15},
    ),
    "dense": (
        "3 lanes, 120 km/h, near capacity (5,800 veh/h per direction), synchronised flow",
        {"lanes_per_direction": 3, "speed_limit_kmh": 120.0, "demand_per_s": 1.6, "truck_share": 0.2},
    ),
    "wide": (
        "5 lanes, 110 km/h, heavy traffic (7,900 veh/h per direction), few trucks",
        {"lanes_per_direction": 5, "speed_limit_kmh": 110.0, "demand_per_s": 2.2, "truck_share": 0.1},
    ),
    "on_ramp": (
        "3 lanes of 3.5 m, 100 km/h, an on-ramp merge downstream: congestion behind the merge",
        {
            "lanes_per_direction": 3,
            "lane_width_m": 3.5,
            "speed_limit_kmh": 100.0,
            "demand_per_s": 1.3,
            "bottleneck": "on_ramp",
            "ramp_demand_per_s": 0.6,
            "truck_share": 0.2,
            "extra_warmup_s": 120.0,
        },
    ),
    "lane_drop": (
        "3 lanes of 3.5 m dropping to 2, 80 km/h: forced merges and queues",
        {
            "lanes_per_direction": 3,
            "lane_width_m": 3.5,
            "speed_limit_kmh": 80.0,
            "demand_per_s": 1.25,
            "bottleneck": "lane_drop",
            "truck_share": 0.25,
            "extra_warmup_s": 120.0,
        },
    ),
    "stop_and_go": (
        "3 lanes, 100 km/h, a 15 km/h slow zone downstream (roadworks): braking into a slowly moving queue",
        {
            "lanes_per_direction": 3,
            "speed_limit_kmh": 100.0,
            "demand_per_s": 1.3,
            "bottleneck": "slow_zone",
            "bottleneck_speed_kmh": 15.0,
            "truck_share": 0.15,
            "extra_warmup_s": 120.0,
        },
    ),
    "waves": (
        "3 lanes of 3.5 m dropping to 2, 80 km/h, heavy demand, drivers reacting after 1 s: "
        "stop-and-go waves run upstream through the queue",
        {
            "lanes_per_direction": 3,
            "lane_width_m": 3.5,
            "speed_limit_kmh": 80.0,
            "demand_per_s": 1.6,
            "bottleneck": "lane_drop",
            "reaction_time_s": 1.0,
            "truck_share": 0.2,
            "extra_warmup_s": 120.0,
        },
    ),
    "urban": (
        "2 lanes of 3.5 m, 60 km/h, a 10 km/h slow zone downstream: slow, queued traffic",
        {
            "lanes_per_direction": 2,
            "lane_width_m": 3.5,
            "speed_limit_kmh": 60.0,
            "demand_per_s": 0.7,
            "bottleneck": "slow_zone",
            "bottleneck_speed_kmh": 10.0,
            "truck_share": 0.1,
            "extra_warmup_s": 120.0,
        },
    ),
    "signal": (
        "2 lanes of 3.5 m, 60 km/h, a traffic light downstream (40 s green, 50 s red): queues that stand and start",
        {
            "lanes_per_direction": 2,
            "lane_width_m": 3.5,
            "speed_limit_kmh": 60.0,
            "demand_per_s": 0.5,
            "bottleneck": "signal",
            "signal_red_s": 50.0,
            "truck_share": 0.1,
            "extra_warmup_s": 60.0,
        },
    ),
}


def scenario_config(name: str, *, minutes: float, seed: int, **overrides: Any) -> HighwayConfig:
    """The config of scenario ``name`` for ``minutes`` at ``seed`` (``overrides`` win).

    Raises InputError for an unknown name."""
    if name not in SCENARIOS:
        raise InputError(None, f"unknown scenario {name!r}", expected=f"one of {', '.join(SCENARIOS)}")
    params = {**COMMON, **SCENARIOS[name][1], **overrides}
    cfg = HighwayConfig(minutes=minutes, seed=seed, **params)
    cfg.check()
    return cfg


def describe(cfg: HighwayConfig) -> dict[str, Any]:
    """The config as a JSON-able dict (for manifests and model cards)."""
    return dataclasses.asdict(cfg)
