"""Metrics of forecasters on a windows dataset, the example scenes of a report, and ``metrics.json``.

The library behind ``lanecast evaluate``, ``lanecast train`` (validation and test metrics in the card)
and ``lanecast report`` (the same ``metrics.json`` for annotated logs). Torch-free: the forecasters
come in loaded.
"""

from __future__ import annotations

import json
import mmap
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa

from lanecast.io_adapters.contracts.windows import Windows, labelled
from lanecast.io_adapters.errors import InputError
from lanecast.io_adapters.files import atomic_path
from lanecast.io_adapters.ownership import GENERATOR
from lanecast.models.metrics import accuracy, confusion_matrix, macro_f1, summary
from lanecast.models.ood import target_speed
from lanecast.models.predictions import Forecaster, Predictions
from lanecast.models.reports.document import Scene
from lanecast.models.reports.tables import model_name


def vehicle_ids(index: pa.Table) -> np.ndarray:
    """One integer per (recording, track_id) of a windows index → int64 [N]."""
    rec = index.column("recording").to_numpy(zero_copy_only=False)
    _, rec_code = np.unique(rec.astype(str), return_inverse=True)
    track = index.column("track_id").to_numpy()
    _, code = np.unique(np.stack([rec_code.ravel(), track], axis=1), axis=0, return_inverse=True)
    return code.ravel().astype(np.int64)


def evaluate(
    windows: Windows,
    forecasters: Sequence[Forecaster],
    *,
    splits: tuple[str, ...] = ("test",),
    top_k: int = 3,
    batch_size: int = 4096,
) -> tuple[dict[str, Any], dict[str, Predictions], np.ndarray]:
    """Metrics of every forecaster on the labelled windows of ``splits``, the inputs read
    ``batch_size`` windows at a time (:func:`predict_in_batches`).

    Returns (model name → ``lanecast.models.metrics.summary``, model name → Predictions, window indices [M]).
    """
    idx = labelled(windows, splits)
    if len(idx) == 0:
        raise InputError(
            None,
            f"no labelled windows in split(s) {', '.join(splits)}",
            expected="windows with known futures",
        )
    future, maneuver = np.asarray(windows.future[idx]), np.asarray(windows.maneuver[idx])
    index = windows.index.take(idx)
    vehicle = vehicle_ids(index)
    recording = index.column("recording").to_numpy(zero_copy_only=False).astype(str)
    speed = target_speed(windows.inputs, idx)
    metrics: dict[str, Any] = {}
    preds = predict_in_batches(windows, idx, forecasters, top_k=top_k, batch_size=batch_size)
    for f in forecasters:
        p = preds[f.name]
        metrics[f.name] = summary(
            p.offsets,
            future,
            maneuver,
            vehicle,
            candidates=p.top_offsets,
            predicted_maneuver=p.maneuver,
            probs=p.probs,
            recording=recording,
            speed=speed,
        )
        ood = p.out_of_distribution
        metrics[f.name]["n_out_of_distribution"] = None if ood is None else int(np.count_nonzero(ood))
    return metrics, preds, idx


def predict_in_batches(
    windows: Windows,
    idx: np.ndarray,
    forecasters: Sequence[Forecaster],
    *,
    top_k: int = 3,
    batch_size: int = 4096,
) -> dict[str, Predictions]:
    """Every forecaster's predictions for the windows ``idx`` int [M], their inputs and presence
    read ``batch_size`` windows at a time, so that a memory-mapped dataset is never loaded (4 KB
    per window); what stays is the predictions (about 0.4 KB per window and forecaster). The
    batches are the ones each forecaster would cut from all inputs at once: the same predictions.
    """
    parts: dict[str, list[Predictions]] = {f.name: [] for f in forecasters}
    for start in range(0, len(idx), batch_size):
        rows = idx[start : start + batch_size]
        inputs, present = np.asarray(windows.inputs[rows]), np.asarray(windows.present[rows])
        for f in forecasters:
            parts[f.name].append(f.predict(inputs, present, top_k=top_k, batch_size=batch_size))
        release_pages(windows.inputs, windows.present)
    return {name: concat_predictions(p) for name, p in parts.items()}


def release_pages(*arrays: np.ndarray) -> None:
    """Drop the pages that reading memory-mapped ``arrays`` brought into this process (they stay in
    the page cache), so that resident memory does not grow with what was read; no-op for arrays in
    memory."""
    for array in arrays:
        if isinstance(array, np.memmap) and isinstance(array.base, mmap.mmap):
            array.base.madvise(mmap.MADV_DONTNEED)


def concat_predictions(parts: Sequence[Predictions]) -> Predictions:
    """Predictions of consecutive batches as one (fields that are None stay None)."""

    def cat(name: str) -> np.ndarray | None:
        values = [getattr(p, name) for p in parts]
        if any(v is None for v in values):
            return None
        return values[0] if len(values) == 1 else np.concatenate(values)

    top_probs, top_offsets, offsets = cat("top_probs"), cat("top_offsets"), cat("offsets")
    assert top_probs is not None and top_offsets is not None and offsets is not None
    return Predictions(
        offsets=offsets,
        probs=cat("probs"),
        maneuver=cat("maneuver"),
        top_sequences=cat("top_sequences"),
        top_probs=top_probs,
        top_offsets=top_offsets,
        out_of_distribution=cat("out_of_distribution"),
    )


def speed_band_note(metrics: dict[str, Any], model: str = "stcnn") -> str | None:
    """Where ``model`` is worse than constant velocity at some horizon, in bands of the target's speed
    (``metrics.per_speed_band``), as words to follow the model's name; None without both models' bands."""
    bands = (metrics.get(model) or {}).get("per_speed_band")
    cv = (metrics.get("cv") or {}).get("per_speed_band")
    if not bands or not cv:
        return None
    worse, unclear = [], []
    for band, row in bands.items():
        ratios = [m / c for m, c in zip(row["rmse"], cv[band]["rmse"], strict=True) if m is not None and c]
        if not ratios or max(ratios) <= 1:
            continue
        n = row["n_windows"]
        words = f"{band} ({n:,} window{'' if n == 1 else 's'}; up to {max(ratios):.2f}× its RMSE)"
        if _worse_beyond_intervals(row, cv[band]):
            worse.append(words)
        else:
            unclear.append(words)
    note = (
        "worse than constant velocity at some horizon for targets at " + ", ".join(worse)
        if worse
        else "no worse than constant velocity at any horizon in any band of target speed"
    )
    if unclear:
        note += "; worse by its RMSE but within the 95 % intervals (too few windows to tell) at " + ", ".join(
            unclear
        )
    return note


def _worse_beyond_intervals(model: dict[str, Any], cv: dict[str, Any]) -> bool:
    """Whether a band's model RMSE is above constant velocity's beyond both 95 % intervals at some
    horizon (bands without intervals, from older metrics, are judged by their RMSE alone)."""
    if "rmse_ci" not in model or "rmse_ci" not in cv:
        return any(m is not None and c and m > c for m, c in zip(model["rmse"], cv["rmse"], strict=True))
    lows, highs = model["rmse_ci"]["low"], cv["rmse_ci"]["high"]
    return any(lo is not None and hi is not None and lo > hi for lo, hi in zip(lows, highs, strict=True))


def out_of_distribution_note(
    preds: dict[str, Predictions], future: np.ndarray, model: str = "stcnn"
) -> str | None:
    """One line on the windows ``model`` flags as outside its training distribution: how many, and
    the RMSE at 5 s of every forecaster on them (None when the model gives no flags)."""
    flags = preds[model].out_of_distribution if model in preds else None
    if flags is None:
        return None
    n = int(np.count_nonzero(flags))
    text = (
        f"{n:,} of {flags.size:,} windows ({100 * n / max(flags.size, 1):.1f} %) out of the {model_name(model)}'s "
        "training distribution (target speed or acceleration outside its 0.5-99.5 percentiles)"
    )
    if n:
        err = {
            name: float(np.sqrt(np.mean(np.sum((p.offsets[flags, -1] - future[flags, -1]) ** 2, axis=-1))))
            for name, p in preds.items()
        }
        text += "; RMSE at 5 s on them: " + ", ".join(f"{model_name(k)} {v:.2f} m" for k, v in err.items())
    return text


def _distinct_tracks(
    candidates: np.ndarray, vehicle: np.ndarray, order_key: np.ndarray, count: int
) -> list[int]:
    """Up to ``count`` of ``candidates`` (indices) with the largest ``order_key``, one per vehicle."""
    picked: list[int] = []
    seen: set[int] = set()
    for i in candidates[np.argsort(-order_key[candidates], kind="stable")]:
        if int(vehicle[i]) not in seen:
            picked.append(int(i))
            seen.add(int(vehicle[i]))
        if len(picked) == count:
            break
    return picked


def example_scenes(
    windows: Windows, idx: np.ndarray, pred: Predictions, count: int, *, failures: int = 6
) -> list[Scene]:
    """Scenes for the report (deterministic choices): up to ``count`` examples (a correctly predicted
    left and right lane change, a straight window, the largest 5 s error), then a failure gallery of up
    to ``failures`` scenes (kind "failure"): the largest errors at 5 s, false lane changes (a lane
    change predicted in a window whose future is straight, most confident first) and missed ones
    (a lane change in the future, straight predicted throughout), at most one scene per vehicle."""
    if pred.maneuver is None or pred.probs is None or (count <= 0 and failures <= 0):
        return []
    true = np.asarray(windows.maneuver[idx])
    future = np.asarray(windows.future[idx])
    err5 = np.hypot(*(pred.offsets[:, -1] - future[:, -1]).T)
    picks: list[tuple[str, str, int]] = []
    for cls, label in ((1, "left lane change"), (2, "right lane change")):
        hit = np.flatnonzero(np.any(true == cls, axis=1) & np.any(pred.maneuver == cls, axis=1))
        if hit.size:
            picks.append(
                ("example", f"{label}, predicted", int(hit[np.argmax(pred.probs[hit, :, cls].max(axis=1))]))
            )
    straight = np.flatnonzero(np.all(true == 0, axis=1))
    if straight.size:
        picks.append(("example", "straight driving", int(straight[straight.size // 2])))
    picks.append(("example", "largest error at 5 s", int(np.argmax(err5))))
    picks = picks[: max(count, 0)]
    if failures > 0:
        vehicle = vehicle_ids(windows.index.take(idx))
        lane_change_prob = 1.0 - pred.probs[:, :, 0].min(axis=1)  # the most confident lane-change step
        false_change = np.flatnonzero(np.all(true == 0, axis=1) & np.any(pred.maneuver > 0, axis=1))
        missed = np.flatnonzero(np.any(true > 0, axis=1) & np.all(pred.maneuver == 0, axis=1))
        n_false = min(2, failures // 3) if false_change.size else 0
        n_missed = min(1, failures // 3) if missed.size else 0
        for i in _distinct_tracks(false_change, vehicle, lane_change_prob, n_false):
            picks.append(("failure", "false lane change", i))
        for i in _distinct_tracks(missed, vehicle, err5, n_missed):
            picks.append(("failure", "missed lane change", i))
        shown = {i for _, _, i in picks}
        rest = np.setdiff1d(np.arange(len(idx)), list(shown))
        for i in _distinct_tracks(rest, vehicle, err5, failures - n_false - n_missed):
            picks.append(("failure", "large error at 5 s", i))
    scenes = []
    rec = windows.index.column("recording").to_numpy(zero_copy_only=False)
    tid = windows.index.column("track_id").to_numpy()
    t0 = windows.index.column("t0_ns").to_numpy()
    for kind, title, i in picks:
        w = int(idx[i])
        scenes.append(
            Scene(
                title=f"{title}: {rec[w]} track {tid[w]} at t0 = {t0[w] / 1e9:.1f} s (error at 5 s {err5[i]:.2f} m)",
                inputs=np.asarray(windows.inputs[w]),
                present=np.asarray(windows.present[w]),
                future=future[i],
                offsets=pred.offsets[i],
                maneuver=pred.maneuver[i],
                alternatives=pred.top_offsets[i],
                alt_probs=pred.top_probs[i],
                probs=pred.probs[i],
                alt_maneuvers=None if pred.top_sequences is None else pred.top_sequences[i],
                kind=kind,
            )
        )
    return scenes


def write_metrics(path: Path, metrics: dict[str, Any], meta: dict[str, Any]) -> Path:
    """metrics.json: one key per model name plus ``meta``."""
    with atomic_path(path) as tmp:
        tmp.write_text(
            json.dumps({**metrics, "meta": {**meta, "generator": GENERATOR}}, indent=2, allow_nan=False)
            + "\n",
            encoding="utf-8",
        )
    return path


def always_straight(windows: Windows, idx: np.ndarray) -> dict[str, Any]:
    """Maneuver accuracy and macro-F1 of always predicting straight (the reference a classifier must beat)."""
    true = np.asarray(windows.maneuver[idx])
    conf = confusion_matrix(true, np.zeros_like(true))
    return {"maneuver_accuracy": accuracy(conf), "maneuver_macro_f1": macro_f1(conf)}
