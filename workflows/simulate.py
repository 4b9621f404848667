"""`lanecast simulate`: a highD-format recording of highway traffic simulated with Eclipse SUMO."""

from __future__ import annotations

import argparse
import time
from datetime import datetime
from pathlib import Path

from lanecast.io_adapters.sim import scenarios, sumo_highway
from lanecast.io_adapters.sim.scenarios import DRIVING, SCENARIOS
from lanecast.workflows.vocabulary import HelpFormatter, add_force_option

DENSITIES = ("low", "medium", "high")


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "simulate",
        help="simulate highway traffic with SUMO and write it as a highD recording",
        description=(
            "Drive Eclipse SUMO (libsumo) on a straight highway with two carriageways, cars and trucks with "
            "spread desired speeds and mixed driving styles, lane changes smoothed into S-curves and a slow weave "
            "inside the lane (--lateral-smoothing 0 --weave 0 --drivers uniform: SUMO's raw motion), and write "
            "the recorded middle section as "
            "highD's three CSV files (NN_tracks.csv, NN_tracksMeta.csv, NN_recordingMeta.csv; 25 Hz) into "
            "OUT_DIR. Neighbour ids come from SUMO. The same arguments (with --start) give byte-identical files; about 15 "
            "minutes at medium density give a recording of highD's size (about 1,000 vehicles). "
            "--scenario NAME simulates a named traffic scenario instead (its road, limit, demand, bottleneck "
            "and drivers; 10 Hz; --minutes, --seed, --recording-id still apply): "
            + "; ".join(f"{name}: {desc}" for name, (desc, _) in SCENARIOS.items())
        ),
        epilog=(
            "examples:\n"
            "  lanecast simulate --out sim/ --minutes 5 --seed 1\n"
            "  lanecast simulate --out sim-dense/ --minutes 5 --seed 7 --density high --lanes-per-direction 2\n"
            "  lanecast simulate --out sim-queue/ --minutes 5 --seed 3 --scenario stop_and_go\n"
            "  lanecast convert sim/ --out sim.parquet"
        ),
        formatter_class=HelpFormatter,
    )
    p.add_argument(
        "--out", required=True, type=Path, metavar="OUT_DIR", help="directory for the three CSV files"
    )
    p.add_argument("--minutes", type=float, required=True, help="simulated minutes to record")
    p.add_argument("--seed", type=int, required=True, help="SUMO's random seed")
    p.add_argument(
        "--scenario",
        choices=list(SCENARIOS),
        help="a named traffic scenario (replaces the road and traffic options below)",
    )
    p.add_argument("--lanes-per-direction", type=int, default=3, help="lanes per carriageway")
    p.add_argument("--density", choices=DENSITIES, default="medium", help="traffic density")
    p.add_argument("--truck-share", type=float, default=0.2, help="share of trucks, 0…1")
    p.add_argument("--recording-id", type=int, default=1, help="highD recording number NN")
    p.add_argument(
        "--start",
        type=start_time,
        metavar="YYYY-MM-DDTHH:MM",
        help="when the recording begins, local time (default: now); written as highD's month, weekday and "
        "time of day, where drive logs made from it begin. The same arguments and --start give "
        "byte-identical files",
    )
    p.add_argument(
        "--section-length",
        type=float,
        default=1000.0,
        metavar="M",
        help="length of the recorded section in metres (highD films about 420)",
    )
    p.add_argument(
        "--approach-length",
        type=float,
        default=1000.0,
        metavar="M",
        help="road before and after the section in metres, where traffic settles",
    )
    p.add_argument(
        "--lane-change-duration",
        type=float,
        default=DRIVING["lane_change_duration_s"],
        metavar="S",
        help="seconds a lane change takes, moving continuously sideways",
    )
    p.add_argument(
        "--lateral-smoothing",
        type=float,
        default=DRIVING["lateral_smoothing_s"],
        metavar="S",
        help="width of the kernel that smooths lateral motion into S-curves (0: SUMO's constant sideways "
        "speed, with lateral-acceleration spikes at the ends of every lane change)",
    )
    p.add_argument(
        "--weave",
        type=float,
        default=DRIVING["lateral_wander_m"],
        metavar="M",
        help="std of each driver's slow weave inside the lane (0: SUMO's exact lane centre)",
    )
    p.add_argument(
        "--drivers",
        choices=("uniform", "mixed"),
        default=DRIVING["drivers"],
        help="one car and one truck behaviour, or three driving styles (IDM and Krauss)",
    )
    add_force_option(
        p,
        help="replace the files of a recording of the same number already in OUT_DIR (by default a "
        "recording is never overwritten: the run is refused before simulating)",
    )
    p.set_defaults(func=run)


def start_time(text: str) -> datetime:
    """``--start``: an ISO date and time (local time unless it names its offset)."""
    try:
        when = datetime.fromisoformat(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(f"{text!r} is not a date and time like 2026-12-05T08:30") from exc
    if not 1970 <= when.year <= 2200:
        raise argparse.ArgumentTypeError(f"{text!r}: a year from 1970 to 2200")
    return when if when.tzinfo is not None else when.astimezone()


def run(args: argparse.Namespace) -> int:
    from lanecast.io_adapters.sim import recording, to_highd

    started = time.perf_counter()
    if args.scenario:
        config = scenarios.scenario_config(args.scenario, minutes=args.minutes, seed=args.seed)
    else:
        config = sumo_highway.HighwayConfig(
            minutes=args.minutes,
            seed=args.seed,
            lanes_per_direction=args.lanes_per_direction,
            density=args.density,
            truck_share=args.truck_share,
            section_length_m=args.section_length,
            approach_length_m=args.approach_length,
            lane_change_duration_s=args.lane_change_duration,
            lateral_smoothing_s=args.lateral_smoothing,
            lateral_wander_m=args.weave,
            drivers=args.drivers,
        )
    out = recording.simulate(
        args.out,
        minutes=args.minutes,
        seed=args.seed,
        recording_id=args.recording_id,
        config=config,
        overwrite=args.force,
        start=args.start or datetime.now().astimezone().replace(second=0, microsecond=0),
    )
    names = to_highd.file_names(args.recording_id)
    summary = to_highd.summary(out / names["tracksMeta"])
    print(
        f"wrote {out}: {', '.join(names.values())}; {summary['vehicles']:,} vehicles "
        f"({summary['cars']:,} cars, {summary['trucks']:,} trucks), {summary['lane_changes']:,} lane changes, "
        f"{args.minutes:g} simulated minute{'' if args.minutes == 1 else 's'}"
        + (f" of scenario {args.scenario}" if args.scenario else "")
        + f" in {time.perf_counter() - started:.1f} s"
    )
    return 0
