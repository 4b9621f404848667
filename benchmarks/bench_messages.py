"""Encoding forecast messages: in bulk (lanecast) against the per-object encoders it replaced.

The per-object encoders (foxglove protobuf classes, ``json.dumps`` of dicts, rosbags' CDR
serializer) live in ``tests/io_adapters/logs/test_forecast_messages.py`` as the bulk encoders' oracle; this script
times both on the same forecasts (the test's generator: two recordings, 1–30 targets per frame, 3
alternatives), interleaved rounds, CPU seconds (the machine is shared: CPU time is steadier than wall).

    .venv/bin/python benchmarks/bench_messages.py [--seeds 30] [--rounds 5]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Callable
from pathlib import Path

import pyarrow as pa

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(ROOT / "tests" / "io_adapters" / "logs"))
sys.path.insert(0, str(ROOT / "tests"))
sys.path.insert(0, str(ROOT))

import test_forecast_messages as oracle  # noqa: E402
from interleave import Samples, machine_line, ratio, round_orders  # noqa: E402

from lanecast.io_adapters.logs import forecast_messages as fm  # noqa: E402


def cpu_seconds(fn: Callable[[], object]) -> float:
    start = time.process_time()
    fn()
    return time.process_time() - start


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, default=30, help="forecast tables generated and concatenated")
    ap.add_argument("--rounds", type=int, default=5)
    args = ap.parse_args()
    table = pa.concat_tables([oracle.forecasts(seed) for seed in range(args.seeds)])
    batch = fm.batch_from_table(table, frame_id="map", lifetime_s=1.0)
    frames = list(batch.frames())
    print(f"{table.num_rows:,} forecasts (3 alternatives each) in {len(frames):,} frames")
    print(machine_line("before"))
    drawing = fm.drawing_of(batch)

    def old_prediction() -> None:
        for f in frames:
            json.dumps(oracle.prediction_dict(f), separators=(",", ":"))

    fns: dict[str, Callable[[], object]] = {
        "bulk: /lanecast/prediction JSON": lambda: fm.prediction_texts(batch),
        "per object: /lanecast/prediction JSON": old_prediction,
        "bulk: SceneUpdate protobuf": lambda: fm.scene_update_protobuf(batch, fm.drawing_of(batch)),
        "per object: SceneUpdate protobuf": lambda: [oracle.scene_update_protobuf(f) for f in frames],
        "bulk: SceneUpdate JSON": lambda: fm.scene_update_json(batch, drawing),
        "per object: SceneUpdate JSON": lambda: [
            json.dumps(oracle.scene_update_dict(f), separators=(",", ":")) for f in frames
        ],
        "bulk: SceneUpdate CDR": lambda: fm.scene_update_cdr(batch, fm.drawing_of(batch)),
        "per object: SceneUpdate CDR": lambda: [oracle.scene_update_cdr(f) for f in frames],
    }
    for fn in fns.values():
        fn()
    times: dict[str, list[float]] = {name: [] for name in fns}
    for order in round_orders(list(fns), args.rounds):
        for name in order:
            times[name].append(cpu_seconds(fns[name]))
    print(f"CPU seconds, median (min–max; best) of {args.rounds} interleaved rounds")
    samples = {name: Samples(values) for name, values in times.items()}
    for name, s in samples.items():
        per = s.median / table.num_rows * 1e6
        print(f"  {name:<40}{s.text('.3f', higher_is_better=False)}  ({per:.0f} µs per forecast)")
    for what in ("/lanecast/prediction JSON", "SceneUpdate protobuf", "SceneUpdate JSON", "SceneUpdate CDR"):
        print(f"  {what}: bulk speed-up {ratio(samples['per object: ' + what], samples['bulk: ' + what])}")
    print(machine_line("after"))
    return 0


if __name__ == "__main__":
    sys.exit(main())
