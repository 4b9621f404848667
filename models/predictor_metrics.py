"""Metrics of any predictor that gives several paths with confidences, from arrays alone.

The displacement metrics are those of :mod:`lanecast.models.metrics` (RMSE by horizon with bootstrap
intervals, ADE/FDE, minADE/minFDE over the paths, miss rate, rows per speed band); added here is
what a multi-path predictor from outside lanecast needs: a score of its confidences over its paths
and rows per object class. The predictor's trajectory is its most confident path.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from lanecast.models.metrics import (
    MISS_THRESHOLD_M,
    ade,
    displacement_errors,
    fde,
    miss_rate,
    per_speed_band,
    rmse,
    rmse_ci,
)

#: The probability an NLL is clipped at (a path given confidence 0 that turned out best).
MIN_PROBABILITY = 1e-6


def best_path(confidence: np.ndarray) -> np.ndarray:
    """int64 [N]: the most confident of each row's paths (confidence [N, K], NaN = no path; ties and
    rows without any confidence: the first path)."""
    c = np.where(np.isnan(confidence), -np.inf, confidence)
    return np.argmax(c, axis=1).astype(np.int64)


def closest_path(candidates: np.ndarray, true: np.ndarray) -> np.ndarray:
    """int64 [N]: the path with the smallest average displacement (candidates [N, K, H, 2] NaN-padded)."""
    err = np.linalg.norm(candidates - true[:, None], axis=-1).mean(axis=-1)
    return np.argmin(np.where(np.isnan(err), np.inf, err), axis=1).astype(np.int64)


def path_confidence_scores(
    candidates: np.ndarray, confidence: np.ndarray, true: np.ndarray
) -> dict[str, Any]:
    """Brier score and NLL of the confidences over the paths: each row's confidences normalised to
    sum 1 over its paths, the outcome being the path closest to what happened (smallest ADE).

    Rows with one path or confidences that are unknown, negative or sum to 0 are left out (counted as
    ``n_rows``' complement). Returns {"brier", "nll", "n_rows"}; NaN where no row qualifies.
    """
    have = ~np.isnan(confidence)
    k = have.sum(axis=1)
    c = np.where(have, confidence, 0.0)
    total = c.sum(axis=1)
    ok = (k >= 2) & (total > 0) & ~(c < 0).any(axis=1)
    if not ok.any():
        return {"brier": float("nan"), "nll": float("nan"), "n_rows": 0}
    p = c[ok] / total[ok, None]
    hit = closest_path(candidates[ok], true[ok])
    onehot = np.zeros_like(p)
    onehot[np.arange(p.shape[0]), hit] = 1.0
    brier = float(np.mean(((p - onehot) ** 2 * have[ok]).sum(axis=1)))
    nll = float(np.mean(-np.log(np.maximum(p[np.arange(p.shape[0]), hit], MIN_PROBABILITY))))
    return {"brier": brier, "nll": nll, "n_rows": int(ok.sum())}


def _json(values: np.ndarray | float) -> Any:
    arr = np.asarray(values, dtype=np.float64)
    if arr.ndim == 0:
        return float(arr) if np.isfinite(arr) else None
    return [_json(v) for v in arr]


def predictor_summary(
    candidates: np.ndarray,
    confidence: np.ndarray,
    true: np.ndarray,
    *,
    object_class: np.ndarray,
    speed: np.ndarray,
    boots: int = 1000,
) -> dict[str, Any]:
    """Every metric of one predictor, JSON-ready (NaN → null).

    candidates float [N, K, H, 2] its paths at the horizons (NaN-padded where it gave fewer than K);
    confidence [N, K] (NaN: unknown or no path); true [N, H, 2]; object_class str [N]; speed [N] m/s
    at t0. Keys: n, rmse [H], rmse_ci, ade, fde, min_ade, min_fde, k, miss_rate, miss_threshold_m,
    brier, nll, n_confidence_rows, per_class {class: {n, rmse}}, per_speed_band.
    """
    n = true.shape[0]
    if n == 0:  # nothing matched: every figure null, the shapes kept
        candidates, confidence = np.zeros((0, 1, *true.shape[1:])), np.zeros((0, 1))
    pred = candidates[np.arange(n), best_path(confidence)]
    err = displacement_errors(pred, true)
    # minADE/minFDE over the paths it gave (NaN paddings never the minimum)
    all_err = np.linalg.norm(candidates - true[:, None], axis=-1)
    min_ade = float(np.nanmin(all_err.mean(axis=-1), axis=1).mean()) if n else float("nan")
    min_fde = float(np.nanmin(all_err[..., -1], axis=1).mean()) if n else float("nan")
    low, high = rmse_ci(err, boots=boots) if boots > 0 else (np.full(err.shape[1], np.nan),) * 2
    conf = path_confidence_scores(candidates, confidence, true)
    per_class = {
        str(c): {"n": int((object_class == c).sum()), "rmse": _json(rmse(err[object_class == c]))}
        for c in np.unique(object_class.astype(str))
    }
    return {
        "n": int(n),
        "rmse": _json(rmse(err)),
        "rmse_ci": {"low": _json(low), "high": _json(high), "level": 0.95, "boots": boots},
        "ade": _json(ade(err)),
        "fde": _json(fde(err)),
        "min_ade": _json(min_ade),
        "min_fde": _json(min_fde),
        "k": int(candidates.shape[1]),
        "miss_rate": _json(miss_rate(err)),
        "miss_threshold_m": MISS_THRESHOLD_M,
        "brier": _json(conf["brier"]),
        "nll": _json(conf["nll"]),
        "n_confidence_rows": conf["n_rows"],
        "per_class": per_class,
        "per_speed_band": per_speed_band(err, speed),
    }
