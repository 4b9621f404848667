"""Benchmark: scoring a recorded predictor in a drive log vs annotating the log, and peak memory.

Builds the drive log of ``bench_annotate`` (highway traffic as a SceneUpdate tracks topic plus a
camera-like topic of incompressible payloads, about ``--size-mb`` MB), then a copy of it that holds a
recorded predictor: ``annotate --encoding autoware`` writes lanecast's forecasts as Autoware
``PredictedObjects`` (3 paths of 6 poses per object, every second). Then, each in its own process
(peak RSS per task), ``--rounds`` times in alternating order:

- annotate: ``annotate_log`` of the plain log with the model (pass 1 tracks, the model, pass 2 copy + merge);
- score: ``report_predictors`` of the predictor's log (tracks, the PredictedObjects decoded, matched
  to the log's future, the ST-CNN and constant velocity on the same objects, metrics with 1,000
  bootstrap resamples, the report written).

Printed: medians with min–max, MB of log per second, the ratio score / annotate, peak RSS, and the
phases of one scoring run. Goal: scoring costs no more than annotating (ratio <= 1).

    nice -n 10 .venv/bin/python benchmarks/bench_predictor_scores.py [--size-mb 1024] [--rounds 3]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_annotate import _annotate, _in_child, _peak_mb, build_log
from interleave import machine_line

TOPIC = "/lanecast/predicted_objects"


def _recorded_log(src: str, out: str) -> dict[str, Any]:
    from lanecast.workflows.annotation.annotate_log import AnnotateOptions, annotate_log

    return annotate_log(Path(src), Path(out), AnnotateOptions(every_s=1.0, encoding="autoware"))


def _score(log: str, out: str) -> dict[str, Any]:
    from lanecast.workflows.annotation.predictor_report import report_predictors

    t = time.perf_counter()
    report_predictors([Path(log)], Path(out), predictions=[TOPIC])
    return {"seconds": time.perf_counter() - t, "peak_mb": _peak_mb()}


def _phases(log: str) -> dict[str, Any]:
    """The seconds of each step of scoring one log (no report written)."""
    from lanecast.io_adapters.formats import registry
    from lanecast.models.runtime import load_forecaster
    from lanecast.workflows.annotation.predictor_report import predictor_metrics
    from lanecast.workflows.annotation.predictor_scores import add_lanecast, score_predictor
    from lanecast.workflows.annotation.recorded_predictions import read_predictions

    out: dict[str, Any] = {}
    t = time.perf_counter()
    tracks = registry.read_any([Path(log)])
    out["read tracks"] = time.perf_counter() - t
    t = time.perf_counter()
    (pred,) = read_predictions(Path(log), [TOPIC], checked=True)
    out["decode PredictedObjects"] = time.perf_counter() - t
    t = time.perf_counter()
    scored = score_predictor(pred, tracks)
    out["match to the future"] = time.perf_counter() - t
    t = time.perf_counter()
    add_lanecast(scored, tracks, [load_forecaster(None, quiet=True)])
    out["ST-CNN + constant velocity on the same objects"] = time.perf_counter() - t
    t = time.perf_counter()
    entry = predictor_metrics([scored])
    out["metrics (1,000 bootstrap resamples)"] = time.perf_counter() - t
    out["objects"] = entry["objects_predicted"]
    out["scored"] = entry["scored"]
    out["paths"] = int(pred.n_poses.size)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--size-mb", type=float, default=1024)
    ap.add_argument("--frame-kb", type=float, default=200)
    ap.add_argument("--vehicles", type=int, default=40)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--dir", type=Path, default=None, help="work directory (default: a temporary one)")
    args = ap.parse_args()
    print(machine_line())
    with tempfile.TemporaryDirectory(dir=args.dir) as tmp:
        work = Path(tmp)
        src = work / "drive.mcap"
        duration = build_log(src, args.size_mb, args.frame_kb, args.vehicles)
        recorded = work / "recorded.mcap"
        counts = _in_child(_recorded_log, str(src), str(recorded))
        size_mb = src.stat().st_size / 2**20
        rec_mb = recorded.stat().st_size / 2**20
        print(
            f"log: {size_mb:.0f} MB, {duration:.0f} s, {args.vehicles} vehicles at a time; with the recorded "
            f"predictor: {rec_mb:.0f} MB ({counts['forecast_targets']:,} predicted objects)"
        )
        runs: dict[str, list[dict[str, Any]]] = {"annotate": [], "score": []}
        for r in range(args.rounds):
            order = ["annotate", "score"] if r % 2 == 0 else ["score", "annotate"]
            for task in order:
                out = work / f"{task}-{r}"
                if task == "annotate":
                    res = _in_child(
                        _annotate, str(src), str(out) + ".mcap", False, duration, args.vehicles, None
                    )
                else:
                    res = _in_child(_score, str(recorded), str(out))
                runs[task].append(res)
                print(f"  round {r + 1} {task}: {res['seconds']:.1f} s, peak {res['peak_mb']:.0f} MB")
        med = {k: statistics.median(x["seconds"] for x in v) for k, v in runs.items()}
        for task, v in runs.items():
            secs = [x["seconds"] for x in v]
            mb = rec_mb if task == "score" else size_mb
            print(
                f"{task}: {med[task]:.1f} s ({min(secs):.1f}–{max(secs):.1f}), {mb / med[task]:.1f} MB/s, "
                f"peak {max(x['peak_mb'] for x in v):.0f} MB"
            )
        ratios = [s["seconds"] / a["seconds"] for s, a in zip(runs["score"], runs["annotate"], strict=True)]
        print(
            f"score / annotate: {med['score'] / med['annotate']:.2f}× (per round {min(ratios):.2f}–{max(ratios):.2f}; "
            "goal <= 1)"
        )
        phases = _in_child(_phases, str(recorded))
        print(
            "phases of one scoring run: "
            + "; ".join(f"{k} {v:.1f} s" if isinstance(v, float) else f"{k} {v:,}" for k, v in phases.items())
        )


if __name__ == "__main__":
    main()
