"""Benchmark: reading a 15-minute SceneUpdate (protobuf) MCAP into the track table.

Compared, in the same run, with a bare loop that only decodes every message with the ``mcap``
reader (CRC validation on, ``mcap_protobuf`` decoder, one core). The goal is at least 0.7× the bare
loop's speed in wall time. lanecast is timed twice: with the threads it chooses (the free cores,
:func:`lanecast.io_adapters.cores.default_threads`) and held to one thread (``LANECAST_THREADS=1``,
what a loaded machine or a bulk worker gets). The two are timed in turn, ``--repeats`` rounds (order reversed every round): medians with
min–max (wall and CPU), best-of beside them, and the load average. The log comes from a synthetic table (``--tracks`` tracks of ``--frames`` frames at 25 Hz,
start times spread over ``--minutes``), so the figures need no dataset.

    .venv/bin/python benchmarks/bench_mcap_read.py [--tracks 1000] [--frames 600] [--minutes 15]
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pyarrow as pa

sys.path.insert(0, str(Path(__file__).resolve().parent))

from interleave import Samples, machine_line, ratio, round_orders

from lanecast.io_adapters.contracts import track_table
from lanecast.io_adapters.cores import THREADS_ENV, default_threads
from lanecast.io_adapters.logs.mcap import reader as mcap_reader
from lanecast.io_adapters.logs.mcap import writer as mcap_writer


def synthetic_table(
    n_tracks: int, n_frames: int, minutes: float, rate: float = 25.0, seed: int = 0
) -> pa.Table:
    """Highway-like tracks: constant speed plus a slow lateral sway, lanes 3.75 m apart."""
    rng = np.random.default_rng(seed)
    total = int(minutes * 60 * rate)
    start = rng.integers(0, max(total - n_frames, 1), n_tracks)
    k = np.arange(n_frames)
    frame = (start[:, None] + k[None, :]).ravel()
    track = np.repeat(np.arange(1, n_tracks + 1), n_frames)
    t = k[None, :] / rate
    speed = rng.uniform(20, 40, n_tracks)[:, None]
    lane = rng.integers(1, 4, n_tracks)[:, None]
    x = (rng.uniform(0, 50, n_tracks)[:, None] + speed * t).ravel()
    y = (lane * 3.75 + 0.3 * np.sin(0.5 * t + rng.uniform(0, 6, n_tracks)[:, None])).ravel()
    n = frame.size
    vx = np.broadcast_to(speed, (n_tracks, n_frames)).ravel()
    cls = np.where(rng.random(n_tracks) < 0.2, "truck", "car")
    cols = {
        "recording": np.full(n, "synthetic"),
        "track_id": track,
        "frame": frame,
        "time_ns": np.rint(frame * 1e9 / rate).astype(np.int64),
        "x": x,
        "y": y,
        "heading": np.zeros(n),
        "vx": vx,
        "vy": np.zeros(n),
        "ax": np.zeros(n),
        "ay": np.zeros(n),
        "length": np.repeat(np.where(cls == "truck", 12.0, 4.5), n_frames),
        "width": np.repeat(np.where(cls == "truck", 2.5, 1.8), n_frames),
        "lane_id": np.broadcast_to(lane, (n_tracks, n_frames)).ravel().astype(float),
        "object_class": np.repeat(cls, n_frames),
    }
    meta = track_table.TableMeta("synthetic", {"synthetic": track_table.RecordingMeta(rate)})
    return track_table.build_table(cols, meta)


def bare_loop(path: Path) -> int:
    """Decode every message with the mcap reader and do nothing else; returns the message count."""
    from mcap.reader import make_reader
    from mcap_protobuf.decoder import DecoderFactory

    n = 0
    with path.open("rb") as f:
        reader = make_reader(f, validate_crcs=True, decoder_factories=[DecoderFactory()])
        for _ in reader.iter_decoded_messages():
            n += 1
    return n


def one_thread(path: Path) -> pa.Table:
    """The reader held to one thread, as on a loaded machine."""
    os.environ[THREADS_ENV] = "1"
    try:
        return mcap_reader.read(path)
    finally:
        del os.environ[THREADS_ENV]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--tracks", type=int, default=1000)
    ap.add_argument("--frames", type=int, default=600)
    ap.add_argument("--minutes", type=float, default=15.0)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--log", type=Path, help="reuse or keep the generated log here")
    args = ap.parse_args()

    with tempfile.TemporaryDirectory() as tmp:
        path = args.log or Path(tmp) / "bench.mcap"
        if not path.exists():
            table = synthetic_table(args.tracks, args.frames, args.minutes)
            t0 = time.perf_counter()
            mcap_writer.write(table, path, "mcap")
            print(f"wrote {path}: {table.num_rows:,} rows in {time.perf_counter() - t0:.1f} s")
        size = path.stat().st_size
        print(machine_line("before"))
        fns = {
            "bare mcap decode loop": lambda: bare_loop(path),
            "lanecast read -> table": lambda: mcap_reader.read(path),
            "lanecast, 1 thread": lambda: one_thread(path),
        }
        print(f"lanecast's threads here: {default_threads()} (1-minute load {os.getloadavg()[0]:.2f})")
        for fn in fns.values():  # warm-up: imports, page cache
            fn()
        wall: dict[str, list[float]] = {name: [] for name in fns}
        cpu: dict[str, list[float]] = {name: [] for name in fns}
        for order in round_orders(list(fns), args.repeats):
            for name in order:
                t0, c0 = time.perf_counter(), time.process_time()
                fns[name]()
                wall[name].append(time.perf_counter() - t0)
                cpu[name].append(time.process_time() - c0)
        n_msgs = bare_loop(path)
        table = mcap_reader.read(path)
        assert isinstance(table, pa.Table)
        print(f"log: {size / 1e6:.1f} MB, {n_msgs:,} messages, {table.num_rows:,} objects")
        print(f"seconds, median (min–max; best) of {args.repeats} interleaved rounds")
        for name in fns:
            w, c = Samples(wall[name]), Samples(cpu[name])
            print(
                f"  {name:<24} wall {w.text('.2f', higher_is_better=False)}  CPU {c.text('.2f', higher_is_better=False)}"
                f"  {n_msgs / w.median:9,.0f} msg/s"
            )
        bare, ours, single = (Samples(wall[n]) for n in fns)
        bare_c, ours_c, single_c = (Samples(cpu[n]) for n in fns)
        print(
            f"speed relative to the bare loop: wall {ratio(bare, ours)}, CPU {ratio(bare_c, ours_c)} (goal >= 0.7 wall)"
        )
        print(f"  held to 1 thread: wall {ratio(bare, single)}, CPU {ratio(bare_c, single_c)}")
        best = min(wall["bare mcap decode loop"]) / min(wall["lanecast read -> table"])
        print(
            f"  (best-of only: {best:.2f}; median of per-round ratios {statistics.median(b / o for b, o in zip(wall['bare mcap decode loop'], wall['lanecast read -> table'], strict=True)):.2f})"
        )
        print(machine_line("after"))


if __name__ == "__main__":
    main()
