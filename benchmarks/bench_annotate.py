"""Benchmark: annotating a drive log vs a plain copy of all its records, and peak memory.

Builds a synthetic drive log of about ``--size-mb`` MB: highway traffic as a SceneUpdate tracks topic
(written by ``registry.write_any(..., "mcap")``) plus a camera-like topic of incompressible
``--frame-kb`` KB payloads at 10 Hz (merged in with ``lanecast.io_adapters.logs.mcap.copy``). Then, each in its own
process (so that peak RSS is per task):

- plain copy: every record streamed into a new MCAP (``copy_mcap`` with nothing to merge), then,
  as annotate does, the output fsynced and the input's sha256 taken (here in a second pass over the
  cached file; annotate hashes the bytes its copy reads);
- annotate: ``lanecast.workflows.annotation.annotate_log.annotate_log`` (pass 1 tracks, the model, pass 2 copy + merge).

- annotate with precomputed forecasts (with origins): no reader, no model: copy, encode, merge.

The three tasks run in turn, ``--rounds`` times (order reversed every round); printed: medians with
min–max, MB of log per second, speed ratios to the plain copy with their per-round range, the model's
share and peak RSS. Goals: annotate excluding the model time >= 0.7 x the plain copy's speed, with
the model >= 0.6 x; peak RSS < 1.5 GB for a 1 GB log.

    .venv/bin/python benchmarks/bench_annotate.py [--size-mb 1024] [--frame-kb 200] [--vehicles 40] [--rounds 3]
"""

from __future__ import annotations

import argparse
import hashlib
import multiprocessing as mp
import os
import resource
import statistics
import sys
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa

sys.path.insert(0, str(Path(__file__).resolve().parent))

from interleave import Samples, machine_line, ratio, round_orders

S = 1_000_000_000


def synthetic_tracks(duration_s: float, vehicles: int, rate: float = 10.0, seed: int = 0) -> pa.Table:
    """``vehicles`` highway vehicles at a time on 3 lanes; each drives 60 s, a third change lane once."""
    from lanecast.io_adapters.contracts.track_table import RecordingMeta, TableMeta, build_table

    rng = np.random.default_rng(seed)
    life = 60.0
    n_tracks = max(int(vehicles * duration_s / life), vehicles)
    start = rng.uniform(-life / 2, duration_s - life / 2, n_tracks)
    k = np.arange(int(life * rate))
    t = start[:, None] + k[None, :] / rate  # [tracks, frames]
    speed = rng.uniform(22, 36, n_tracks)[:, None]
    lane = rng.integers(0, 3, n_tracks)[:, None]
    change = np.where(rng.random(n_tracks) < 0.33, rng.choice([-1, 1], n_tracks), 0)[:, None]
    t_change = rng.uniform(10, 50, n_tracks)[:, None]
    s = 1 / (1 + np.exp(-(k[None, :] / rate - t_change) * 1.5))  # smooth lane change
    x = rng.uniform(0, 100, n_tracks)[:, None] + speed * (k[None, :] / rate)
    y = (lane + change * s) * 3.75
    keep = (t >= 0) & (t <= duration_s)
    track = np.broadcast_to(np.arange(1, n_tracks + 1)[:, None], t.shape)
    lane_id = np.where(s > 0.5, lane + change, lane) + 1
    frame = np.rint(t * rate).astype(np.int64)
    n = int(keep.sum())
    cols = {
        "recording": np.full(n, "bench"),
        "track_id": track[keep],
        "frame": frame[keep],
        "time_ns": frame[keep] * int(S / rate),
        "x": x[keep],
        "y": np.broadcast_to(y, t.shape)[keep],
        "heading": np.zeros(n),
        "vx": np.broadcast_to(speed, t.shape)[keep],
        "vy": np.zeros(n),
        "ax": np.zeros(n),
        "ay": np.zeros(n),
        "length": np.full(n, 4.5),
        "width": np.full(n, 1.8),
        "lane_id": np.broadcast_to(lane_id, t.shape)[keep].astype(np.int32),
        "object_class": np.full(n, "car"),
    }
    return build_table(cols, TableMeta("bench", {"bench": RecordingMeta(rate, "map")}))


def build_log(path: Path, size_mb: float, frame_kb: float, vehicles: int) -> float:
    """Write the benchmark log; return its duration (s)."""
    from lanecast.io_adapters.formats import registry
    from lanecast.io_adapters.logs.forecast_messages import ChannelSpec
    from lanecast.io_adapters.logs.mcap.copy import Merge, copy_mcap

    frames = int(size_mb * 1024 / frame_kb)
    duration = frames / 10.0
    base = path.with_name("tracks-only.mcap")
    registry.write_any(synthetic_tracks(duration, vehicles), base, "mcap")
    camera = ChannelSpec("/camera/front/compressed", "foxglove.CompressedImage", "", b"", "jpeg-bytes")
    rng = np.random.default_rng(1)

    def frames_iter() -> Iterator[tuple[int, int, bytes]]:
        for i in range(frames):
            yield i * S // 10 + 3_000_000, 0, rng.bytes(int(frame_kb * 1024))

    with open(path, "wb") as f:
        copy_mcap(base, f, Merge(channels=[camera], extra=frames_iter()))
    base.unlink()
    return duration


def _peak_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def _plain(src: str, out: str) -> dict[str, Any]:
    from lanecast.io_adapters.logs.mcap.copy import copy_mcap

    t = time.perf_counter()
    with open(out, "wb") as f:
        stats = copy_mcap(Path(src), f)
        f.flush()
        os.fsync(f.fileno())
    digest = hashlib.sha256()
    with open(src, "rb") as f:
        while block := f.read(1 << 23):
            digest.update(block)
    return {"seconds": time.perf_counter() - t, "peak_mb": _peak_mb(), "messages": stats.messages}


def _annotate(
    src: str, out: str, synthetic: bool, duration: float, vehicles: int, model: str | None
) -> dict[str, Any]:
    from lanecast.workflows.annotation.annotate_log import AnnotateOptions, annotate_log

    forecasts = None
    if synthetic:
        forecasts = synthetic_forecasts(duration, vehicles)
    t = time.perf_counter()
    options = AnnotateOptions(every_s=1.0, model_dir=Path(model) if model else None)
    counts = annotate_log(Path(src), Path(out), options, forecasts=forecasts)
    return {"seconds": time.perf_counter() - t, "peak_mb": _peak_mb(), **counts}


def synthetic_forecasts(duration: float, vehicles: int) -> pa.Table:
    """``vehicles`` straight-ahead forecasts per second, with origins and 3 alternatives."""
    t0 = np.repeat(np.arange(3, int(duration)), vehicles)
    n = t0.size
    tid = np.tile(np.arange(1, vehicles + 1), n // vehicles)
    ox, oy = 30.0 * t0, 3.75 * (tid % 3)
    h = np.arange(1, 6)
    xs, ys = ox[:, None] + 30.0 * h, np.broadcast_to(oy[:, None], (n, 5))
    lst = pa.list_
    return pa.table(
        {
            "recording": pa.array(["bench"] * n),
            "track_id": tid,
            "t0_ns": t0 * S,
            "x": pa.array(xs.tolist(), lst(pa.float64())),
            "y": pa.array(ys.tolist(), lst(pa.float64())),
            "maneuver_probs": pa.array([[[0.9, 0.05, 0.05]] * 5] * n, lst(lst(pa.float64()))),
            "maneuver": pa.array([[0] * 5] * n, lst(pa.int64())),
            "origin_x": ox,
            "origin_y": oy,
            "alt_probs": pa.array([[0.9, 0.06, 0.04]] * n, lst(pa.float64())),
            "alt_maneuvers": pa.array([[[0] * 5, [1] * 5, [2] * 5]] * n, lst(lst(pa.int64()))),
            "alt_x": pa.array([[r] * 3 for r in xs.tolist()], lst(lst(pa.float64()))),
            "alt_y": pa.array(
                [[r, [v + 3.75 for v in r], [v - 3.75 for v in r]] for r in ys.tolist()],
                lst(lst(pa.float64())),
            ),
        }
    )


def model_for_timing(directory: Path) -> Path | None:
    """The shipped model if there is one, else an untrained seeded ST-CNN (same cost per window)."""
    from lanecast.models.checkpoint import SHIPPED_STEM, WEIGHTS_DIR, save_checkpoint

    if (WEIGHTS_DIR / f"{SHIPPED_STEM}.safetensors").exists():
        return None
    import torch

    from lanecast.models.stcnn import STCNN

    torch.manual_seed(0)
    norm = {
        "inputs": {"mean": [0.0, 0.0, 28.0, 0.0], "std": [30.0, 3.0, 5.0, 1.0]},
        "future": {"mean": [0.0] * 10, "std": 30.0},
    }
    save_checkpoint(STCNN(), {"normalisation": norm}, directory)
    print("model: no shipped model; timing an untrained seeded ST-CNN (same cost per window)")
    return directory


def _in_child(fn: Any, *args: Any) -> dict[str, Any]:
    ctx = mp.get_context("spawn")
    with ctx.Pool(1) as pool:
        result: dict[str, Any] = pool.apply(fn, args)
    return result


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--size-mb", type=float, default=1024)
    ap.add_argument("--frame-kb", type=float, default=200)
    ap.add_argument("--vehicles", type=int, default=40)
    ap.add_argument("--rounds", type=int, default=3, help="interleaved rounds (each task once per round)")
    ap.add_argument("--dir", type=Path, default=None, help="working directory (default: a temporary one)")
    ap.add_argument("--model", type=Path, default=None, help="model directory (default: the shipped model)")
    args = ap.parse_args()
    print(machine_line("before"))
    if args.dir is not None:
        args.dir.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=args.dir) as tmp:
        src = Path(tmp) / "drive.mcap"
        t = time.perf_counter()
        duration = build_log(src, args.size_mb, args.frame_kb, args.vehicles)
        size_mb = src.stat().st_size / 2**20
        print(
            f"log: {size_mb:.0f} MB, {duration:.0f} s, {args.vehicles} vehicles at a time "
            f"(built in {time.perf_counter() - t:.0f} s)"
        )
        model = args.model or model_for_timing(Path(tmp) / "model")
        out = str(Path(tmp) / "out.mcap")
        tasks = {
            "plain copy": (_plain, (str(src), out)),
            "annotate (model)": (
                _annotate,
                (str(src), out, False, duration, args.vehicles, str(model) if model else None),
            ),
            "annotate (precomputed forecasts)": (
                _annotate,
                (str(src), out, True, duration, args.vehicles, None),
            ),
        }
        results: dict[str, list[dict[str, Any]]] = {name: [] for name in tasks}
        for order in round_orders(list(tasks), args.rounds):
            for name in order:
                fn, fn_args = tasks[name]
                results[name].append(_in_child(fn, *fn_args))
                os.unlink(out)
            print(f"round done ({machine_line()})", flush=True)

    def samples(name: str, key: str = "seconds") -> Samples:
        return Samples([r[key] for r in results[name]])

    plain, model_run, pre = (samples(n) for n in tasks)
    without_model = Samples([r["seconds"] - r["model_s"] for r in results["annotate (model)"]])
    print(
        f"\nwall seconds, median (min–max) of {args.rounds} interleaved rounds, each task in its own process"
    )
    for name in tasks:
        s = samples(name)
        peak = max(r["peak_mb"] for r in results[name])
        print(
            f"  {name:<34}{s.text('.1f', higher_is_better=False)} s   {size_mb / s.median:6.1f} MB/s   peak RSS {peak:6.0f} MB"
        )
    last = results["annotate (model)"][-1]
    print(
        f"  annotate (model), last run: read tracks {last['read_s']:.1f} s, model {last['model_s']:.1f} s, "
        f"copy + merge {last['write_s']:.1f} s; {last['forecast_targets']:,} forecasts in {last['forecast_frames']:,} frames"
    )
    print(f"annotate excluding the model / plain copy (speed): {ratio(plain, without_model)}   (goal >= 0.7)")
    print(f"annotate with the model / plain copy (speed)     : {ratio(plain, model_run)}   (goal >= 0.6)")
    print(f"annotate, precomputed forecasts / plain copy     : {ratio(plain, pre)}")
    print(
        f"model share of annotate: {100 * statistics.median(r['model_s'] / r['seconds'] for r in results['annotate (model)']):.0f} %; "
        f"peak RSS of annotate {max(r['peak_mb'] for r in results['annotate (model)']):.0f} MB (goal < 1536 MB for a 1 GB log)"
    )
    print(machine_line("after"))


if __name__ == "__main__":
    main()
