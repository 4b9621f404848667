"""`lanecast info`: what is in a dataset, table or log: recordings, tracks, frames, duration, lane changes."""

from __future__ import annotations

import argparse
from pathlib import Path

from lanecast.io_adapters.formats import registry
from lanecast.workflows.vocabulary import HelpFormatter, add_location_option


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "info",
        help="summarise a dataset, track table or drive log",
        description=(
            "Print the format, recordings, tracks, frames, duration, frame rate and lane changes of PATH, "
            "and each recording's traffic statistics: speed percentiles, density, lane changes per vehicle "
            "and per vehicle-km, lateral-acceleration percentiles."
        ),
        epilog="examples:\n  lanecast info sim.parquet\n  lanecast info logs/sim.mcap",
        formatter_class=HelpFormatter,
    )
    p.add_argument(
        "paths",
        nargs="+",
        metavar="PATH",
        help="highD, NGSIM, MCAP, ROS 1/2 bag or track-table files or directories",
    )
    p.add_argument("--format", choices=sorted(registry.READERS), help="input format (default: detected)")
    add_location_option(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """One summary per input (a folder of drive logs is its logs): two logs of one simulation, or
    two recordings that share a name, are each described, not merged."""
    inputs = [[p] for p in registry.expand(args.paths)] if args.format is None else [args.paths]
    for paths in inputs:
        summarise_input(paths, args)
    return 0


def summarise_input(paths: list[Path], args: argparse.Namespace) -> None:
    from lanecast.io_adapters.contracts import track_table
    from lanecast.io_adapters.contracts.track_summary import summarise
    from lanecast.pipeline.traffic import traffic_statistics

    formats = sorted({args.format or registry.detect(p) for p in paths})
    table = registry.read_any(
        paths, fmt=args.format, **({"location": args.location} if args.location else {})
    )
    meta = track_table.read_meta(table)
    print(f"{', '.join(str(Path(p)) for p in paths)}")
    print(f"  format: {', '.join(formats)} (source: {meta.source_format}); units: m, m/s, m/s^2, rad, ns")
    rows = summarise(table)
    header = f"  {'recording':<28}{'tracks':>8}{'frames':>9}{'duration':>11}{'rate':>8}{'lane chg':>10}  vehicles by class"
    print(header)
    for r in rows:
        classes = ", ".join(f"{k} {v}" for k, v in sorted(r["classes"].items()))  # type: ignore[attr-defined]
        print(
            f"  {r['recording']:<28}{r['tracks']:>8,}{r['frames']:>9,}{r['duration_s']:>10.1f}s"
            f"{r['frame_rate']:>6g}Hz{r['lane_changes']:>10,}  {classes}"
        )
    print(
        "  traffic (speed percentiles p5/p50/p95; density; lane changes; |lateral acceleration| p50/p95/p99; "
        "stop-and-go: speed dips of 3 m/s per vehicle-minute):"
    )
    stats = traffic_statistics(table)
    width = max([28, *(len(n) + 2 for n in stats)])
    for name, st in stats.items():
        sp, la = st["speed_mps"], st["lateral_acc_abs_mps2"]
        per_lane = st["density_veh_per_km_lane"]
        lateral = f"{la['p50']:.2f}/{la['p95']:.2f}/{la['p99']:.2f} m/s²" if la else "not in the source"
        density = f"{st['density_veh_per_km']:.1f} veh/km" + (
            f" ({per_lane:.1f} per lane, {st['lanes']} lanes)" if per_lane is not None else ""
        )
        print(
            f"  {name:<{width}}speed {sp['p5']:.1f}/{sp['p50']:.1f}/{sp['p95']:.1f} m/s; {density}; "
            f"{st['lane_changes_per_vehicle']:.3f} lane changes per vehicle "
            f"({st['lane_changes_per_vehicle_km']:.2f} per vehicle-km); "
            f"lat. acc. {lateral}; "
            f"{st['speed_dips_per_vehicle_min']:.2f} speed dips per vehicle-minute"
        )
    for path in map(Path, paths):
        if path.suffix.lower() in (".mcap", ".bag") or (path / "metadata.yaml").is_file():
            print_topics(path)
    total_tracks = sum(int(r["tracks"]) for r in rows)  # type: ignore[call-overload]
    total_changes = sum(int(r["lane_changes"]) for r in rows)  # type: ignore[call-overload]
    print(
        f"  total: {len(rows)} recordings, {total_tracks:,} tracks, {table.num_rows:,} rows, {total_changes:,} lane changes"
    )


def print_topics(path: Path) -> None:
    """A log's topics with their message types and counts (lanecast's own forecasts among them)."""
    from lanecast.io_adapters.logs.topics import forecast_model, log_topics

    topics = log_topics(path)
    print(f"  topics of {path} ({len(topics)}; messages, type, encoding):")
    width = max([24, *(len(t.topic) + 2 for t in topics)])
    for t in topics:
        print(f"    {t.topic:<{width}}{t.messages:>9,}  {t.message_type or '(no schema)'} ({t.encoding})")
    model = forecast_model(path)
    if model:
        print(
            f"  forecasts by model: {model.get('model', '?')} (sha256 {model.get('model_sha256', '?')[:12]}), "
            f"trained on {model.get('model_trained_on', '?')}"
        )
