"""`lanecast demo`: the whole pipeline on the shipped defaults, in a couple of minutes.

simulate a highway (SUMO) → convert it to a track table → write it as a drive log (MCAP) →
annotate the log with the shipped weights → score the forecasts in the annotated log against the
future recorded in it, beside the kinematic baselines → print where everything is.
"""

from __future__ import annotations

import argparse
import time
from datetime import datetime
from pathlib import Path

from lanecast.io_adapters.errors import InputError, OutputError
from lanecast.io_adapters.formats import registry
from lanecast.io_adapters.sim.scenarios import DRIVING
from lanecast.io_adapters.sim.sumo_highway import HighwayConfig
from lanecast.workflows.bulk.manifest import Manifest
from lanecast.workflows.vocabulary import HelpFormatter, add_model_option

# A seed the shipped weights never saw (benchmarks/train_shipped.py trains on seeds 11-15, tests on 901-902).
DEMO_SEED = 2026

# What the demo writes into --out; MARK says that a directory is a demo's, which a rerun redoes.
OUTPUTS = ("highd", "tracks.parquet", "logs", "annotated", "report")
MARK = ".lanecast-demo"


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "demo",
        help="simulate, convert, annotate and evaluate a highway with the shipped weights",
        description=(
            "Run the whole pipeline on a simulated highway: SUMO traffic → track table → MCAP drive log → "
            "forecasts written into a new MCAP (open it in Foxglove) → metrics and an HTML report."
        ),
        epilog="example:\n  lanecast demo --out lanecast-demo --minutes 5",
        formatter_class=HelpFormatter,
    )
    p.add_argument("--out", type=Path, default=Path("lanecast-demo"), help="output directory")
    p.add_argument("--minutes", type=float, default=5.0, help="simulated minutes")
    p.add_argument(
        "--seed",
        type=int,
        default=DEMO_SEED,
        help="simulation seed (one the shipped weights never saw)",
    )
    p.add_argument("--density", choices=("low", "medium", "high"), default="medium", help="traffic density")
    add_model_option(p)
    p.set_defaults(func=run)


def claim(out: Path) -> None:
    """Make ``out`` the demo's directory, before anything is simulated: a new or empty directory, a
    previous demo's (rerun: its outputs are made again), or one that holds none of the demo's
    outputs. A directory where a demo output's name is taken by something the demo did not write
    (``--out .`` beside a highD recording or a ``logs`` folder of one's own) is refused, not
    overwritten."""
    from lanecast.io_adapters.files import check_output

    check_output(out, directory=True)
    if (out / MARK).is_file():
        return
    taken = [name for name in OUTPUTS if (out / name).exists() or (out / name).is_symlink()]
    if taken and not made_by_an_earlier_demo(out):
        raise OutputError(
            out / taken[0],
            "exists and was not written by `lanecast demo`, which would overwrite it",
            expected="a new --out directory, or one a previous `lanecast demo` wrote",
        )
    try:
        out.mkdir(parents=True, exist_ok=True)
        (out / MARK).write_text(
            "written by `lanecast demo`: a rerun may replace its outputs\n", encoding="utf-8"
        )
    except OSError as exc:
        raise OutputError(out, f"cannot write here: {exc.strerror or exc}") from exc


def made_by_an_earlier_demo(out: Path) -> bool:
    """A demo's directory from before the mark (an earlier lanecast 0.1.0): its annotation manifest
    has the demo's log as its input, which a user's own folder does not."""
    try:
        inputs = Manifest(out / "annotated").latest()
    except InputError:
        return False
    return any(Path(i).parts[-2:] == ("logs", "highway.mcap") for i in inputs)


def shown(path: Path) -> str:
    """A path as printed: quoted where a shell would split it (spaces), so that it can be pasted."""
    import shlex

    return shlex.quote(str(path))


def run(args: argparse.Namespace) -> int:
    from lanecast.io_adapters.contracts import track_table
    from lanecast.io_adapters.contracts.track_summary import summarise
    from lanecast.io_adapters.datasets.highd import reader as highd
    from lanecast.io_adapters.sim.recording import simulate
    from lanecast.workflows.annotation.annotate_log import AnnotateOptions
    from lanecast.workflows.annotation.log_scores import report_logs
    from lanecast.workflows.bulk.runner import run_bulk

    out: Path = args.out
    started = time.perf_counter()
    config = HighwayConfig(minutes=args.minutes, seed=args.seed, density=args.density, **DRIVING)
    config.check()  # a wrong --minutes before --out is made
    claim(out)

    def step(text: str) -> None:
        print(f"[{time.perf_counter() - started:5.1f} s] {text}", flush=True)

    step(
        f"simulating {args.minutes:g} min of {args.density} highway traffic with SUMO (seed {args.seed}), "
        f"after {config.warmup_s:g} s in which the road fills"
    )
    sim_dir = simulate(
        out / "highd",
        minutes=args.minutes,
        seed=args.seed,
        show_progress=True,
        overwrite=True,  # the demo owns its folder (claim): a rerun makes it again
        config=config,
        start=datetime.now().astimezone().replace(second=0, microsecond=0),  # the log's date: now
    )
    table = highd.read([sim_dir])
    rows = summarise(table)
    vehicles = sum(int(r["tracks"]) for r in rows)  # type: ignore[call-overload]
    changes = sum(int(r["lane_changes"]) for r in rows)  # type: ignore[call-overload]
    step(
        f"highD-format recording in {shown(sim_dir)}: {vehicles} vehicles, {changes} lane changes, "
        f"{table.num_rows:,} rows"
    )

    parquet = track_table.write_parquet(table, out / "tracks.parquet")
    rate = track_table.read_meta(table).frame_rate
    step(f"track table (metres, {rate:g} Hz, road frame): {shown(parquet)}")

    log = registry.write_any(table, out / "logs" / "highway.mcap", "mcap")
    step(f"drive log (foxglove.SceneUpdate, protobuf): {shown(log)} ({log.stat().st_size / 1e6:.1f} MB)")

    annotated_dir = out / "annotated"
    result = run_bulk([log], annotated_dir, AnnotateOptions(model_dir=args.model, every_s=1.0))
    if result.failed:
        step(f"annotation failed: see {shown(annotated_dir / 'manifest.jsonl')}")
        return 1
    annotated = annotated_dir / log.name
    kept = " (kept: log, model and options unchanged since the last run)" if result.skipped else ""
    step(f"annotated log with /lanecast/forecast and /lanecast/prediction: {shown(annotated)}{kept}")

    report_dir = out / "report"
    status = report_logs([annotated_dir], report_dir)
    step(f"done. Open {shown(annotated)} in Foxglove; the report is {shown(report_dir / 'report.html')}")
    return status
