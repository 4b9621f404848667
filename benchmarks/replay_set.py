"""Build the shipped model's replay set (``models/weights/stcnn-sumo.replay.npz``) from its card's recipe.

Fine-tuning rehearses the base model's training distribution (``lanecast.models.finetune``): a
compact copy of it, made the way the shipped training data was made (its card's ``training.data``:
the same scenarios, configs and seeds, each recording also as a measured copy and as an
interpolating tracker measures it, at the card's error levels; true futures), only shorter
(``--minutes`` per recording instead of 10-16), sampled to ``--windows`` windows spread evenly over
the recordings, and stored as float16 inputs (their precision, 1e-3 relative, is far below the
tracker noise the training adds). Train/val follows the card's split (seeded hash by track).

    .venv/bin/python benchmarks/replay_set.py --work /tmp/finetune-cache/replay --minutes 2 --windows 6000
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--work", type=Path, required=True, help="simulations and windows are cached here")
    ap.add_argument("--minutes", type=float, default=2.0, help="simulated minutes per training recording")
    ap.add_argument("--windows", type=int, default=6000, help="windows kept (train and val)")
    ap.add_argument("--out", type=Path, default=None, help="default: beside the shipped weights")
    args = ap.parse_args()

    from train_shipped import (
        INTERPOLATED_ID_OFFSET,
        STANDING_JITTER,
        measured_copy,
        simulate_one,
        windows_for,
    )

    from lanecast.io_adapters.windows_store.dataset import load_windows
    from lanecast.models.card import SHIPPED_STEM, WEIGHTS_DIR, read_card
    from lanecast.models.finetune import REPLAY_SUFFIX, save_replay

    started = time.perf_counter()
    card = read_card(WEIGHTS_DIR / f"{SHIPPED_STEM}.json")
    data = card["training"]["data"]
    recs = [(r["scenario"], r["recording_id"], r["seed"], args.minutes) for r in data["train_recordings"]]
    copies = data["measured_copies"]
    levels = copies["tracking_error_levels_m"]
    ilevels = copies["interpolating_tracker"]["tracking_error_levels_m"]
    jitter = set(copies["interpolating_tracker"].get("standing_vehicles_jitter_in", STANDING_JITTER))
    args.work.mkdir(parents=True, exist_ok=True)
    sims = [simulate_one(args.work, *r) for r in recs]
    measured = [
        measured_copy(
            args.work, s, r[0], r[1], r[2], levels[i % len(levels)], hold=r[0] not in STANDING_JITTER
        )
        for i, (r, s) in enumerate(zip(recs, sims, strict=True))
    ]
    interpolated = [
        measured_copy(
            args.work,
            s,
            r[0],
            r[1],
            r[2],
            ilevels[i % len(ilevels)],
            hold=r[0] not in jitter,
            interpolating=True,
        )
        for i, (r, s) in enumerate(zip(recs, sims, strict=True))
    ]
    per_dir = -(-args.windows // (3 * len(recs)))
    clean_of = dict(zip(measured, sims, strict=True)) | dict(zip(interpolated, sims, strict=True))
    windows = load_windows(
        windows_for(
            sims + measured + interpolated, args.work / "windows", "hash", per_dir, clean_of=clean_of
        ),
        mmap=False,
    )
    split = windows.index.column("split").to_numpy(zero_copy_only=False).astype(str)
    keep = np.flatnonzero(np.isin(split, ("train", "val")))
    out = args.out or WEIGHTS_DIR / f"{SHIPPED_STEM}{REPLAY_SUFFIX}"
    recipe = {
        "made_by": "benchmarks/replay_set.py",
        "from_card": f"{SHIPPED_STEM}.json",
        "weights_sha256": card.get("weights_sha256"),
        "recordings": [{"scenario": r[0], "recording_id": r[1], "seed": r[2], "minutes": r[3]} for r in recs],
        "measured_copies": {
            "levels_m": levels,
            "interpolating_levels_m": ilevels,
            "id_offset_interpolating": INTERPOLATED_ID_OFFSET,
        },
        "windows_per_recording": per_dir,
    }
    save_replay(windows, keep, out, recipe)
    counts = np.bincount(np.asarray(windows.maneuver[keep]).ravel(), minlength=3)
    print(
        json.dumps(
            {
                "out": str(out),
                "bytes": out.stat().st_size,
                "windows": int(keep.size),
                "split": {s: int(np.count_nonzero(split[keep] == s)) for s in ("train", "val")},
                "maneuver_step_counts": counts.tolist(),
                "seconds": round(time.perf_counter() - started, 1),
            }
        )
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
