"""Trajectory and maneuver metrics (docs/design.md §4): pure numpy functions, shapes in the docstrings.

Two RMSE conventions are offered because papers use both:

* per window (conv-social-pooling, the paper's tables): RMSE_h = sqrt(mean over windows of the
  squared Euclidean error at horizon h);
* per vehicle (PiP): the squared errors are first averaged over each vehicle's windows, then over
  vehicles, then the root is taken, so long tracks do not dominate.
"""

from __future__ import annotations

import itertools
from typing import Any

import numpy as np

N_CLASSES = 3


def displacement_errors(pred: np.ndarray, true: np.ndarray) -> np.ndarray:
    """Euclidean errors: pred, true float [N, H, 2] → float64 [N, H]."""
    return np.sqrt(np.sum((np.asarray(pred, np.float64) - np.asarray(true, np.float64)) ** 2, axis=-1))


def rmse(errors: np.ndarray) -> np.ndarray:
    """Per-window RMSE by horizon: errors [N, H] → [H] (NaN where N = 0)."""
    if errors.shape[0] == 0:
        return np.full(errors.shape[1], np.nan)
    return np.sqrt(np.mean(errors**2, axis=0))


def rmse_per_vehicle(errors: np.ndarray, vehicle: np.ndarray) -> np.ndarray:
    """Per-vehicle RMSE by horizon: errors [N, H], vehicle int [N] (any ids) → [H].

    sqrt(mean over vehicles of (mean over the vehicle's windows of the squared error)).
    """
    if errors.shape[0] == 0:
        return np.full(errors.shape[1], np.nan)
    _, codes = np.unique(vehicle, return_inverse=True)
    codes = codes.ravel()
    counts = np.bincount(codes).astype(np.float64)  # [V]
    sums = np.stack([np.bincount(codes, weights=errors[:, h] ** 2) for h in range(errors.shape[1])], 1)
    return np.sqrt(np.mean(sums / counts[:, None], axis=0))


def ade(errors: np.ndarray) -> float:
    """Average displacement error: mean of errors [N, H] over windows and horizons."""
    return float(np.mean(errors)) if errors.size else float("nan")


def fde(errors: np.ndarray) -> float:
    """Final displacement error: mean of errors [N, H] at the last horizon."""
    return float(np.mean(errors[:, -1])) if errors.size else float("nan")


def min_ade_fde(candidates: np.ndarray, true: np.ndarray) -> tuple[float, float]:
    """minADE / minFDE over K candidates: candidates [N, K, H, 2], true [N, H, 2] → (float, float).

    Per window the best candidate by ADE (resp. FDE) is taken independently, then averaged.
    """
    if candidates.shape[0] == 0:
        return float("nan"), float("nan")
    err = displacement_errors(candidates, np.asarray(true)[:, None])  # [N, K, H]
    return float(np.mean(err.mean(axis=2).min(axis=1))), float(np.mean(err[:, :, -1].min(axis=1)))


def lane_change_windows(maneuver: np.ndarray) -> np.ndarray:
    """Windows whose future holds a lane change: maneuver int [N, H] → bool [N]."""
    return np.any(maneuver > 0, axis=1)


def confusion_matrix(true: np.ndarray, pred: np.ndarray, n_classes: int = N_CLASSES) -> np.ndarray:
    """Counts [C, C], rows = true class, columns = predicted; entries with true < 0 (unknown) are skipped.

    true, pred: int arrays of the same shape (e.g. [N, 5] per-step labels).
    """
    t, p = np.asarray(true).ravel(), np.asarray(pred).ravel()
    keep = t >= 0
    return np.bincount(t[keep] * n_classes + p[keep], minlength=n_classes * n_classes).reshape(
        n_classes, n_classes
    )


def accuracy(confusion: np.ndarray) -> float:
    """Fraction correct: confusion [C, C] → float (NaN when empty)."""
    total = confusion.sum()
    return float(np.trace(confusion) / total) if total else float("nan")


def precision_recall(confusion: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-class precision and recall: confusion [C, C] → ([C], [C]); NaN where undefined (0/0)."""
    c = confusion.astype(np.float64)
    tp = np.diag(c)
    with np.errstate(invalid="ignore", divide="ignore"):
        return tp / c.sum(axis=0), tp / c.sum(axis=1)


def f1_per_class(confusion: np.ndarray) -> np.ndarray:
    """F1 = 2PR/(P+R) per class: confusion [C, C] → [C]; 0 where the class is predicted or present but
    never right, NaN where it is neither present nor predicted (0/0: nothing to score)."""
    c = confusion.astype(np.float64)
    tp = np.diag(c)
    denominator = c.sum(axis=0) + c.sum(axis=1)  # predicted + true: 2TP + FP + FN
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(denominator > 0, 2 * tp / denominator, np.nan)


def support(confusion: np.ndarray) -> np.ndarray:
    """True count per class (the rows' sums): confusion [C, C] → int [C]."""
    return np.asarray(confusion).sum(axis=1)


def macro_f1(confusion: np.ndarray) -> float:
    """Mean F1 over every class that is present in the ground truth **or predicted**: confusion [C, C].

    A class predicted but absent counts with F1 = 0 (every prediction of it is false), so false lane
    changes on data without lane changes lower the score; only a class neither present nor predicted
    is left out (its F1 is 0/0). Always-straight on all-straight data scores 1.
    """
    f1 = f1_per_class(confusion)
    scored = np.isfinite(f1)
    return float(np.mean(f1[scored])) if scored.any() else float("nan")


def always_straight_accuracy(true: np.ndarray) -> float:
    """Accuracy of always predicting straight (class 0): true int [N, H] (−1 unknown, skipped) → float."""
    t = np.asarray(true).ravel()
    t = t[t >= 0]
    return float(np.mean(t == 0)) if t.size else float("nan")


def brier_score(probs: np.ndarray, true: np.ndarray) -> float:
    """Multi-class Brier score of per-step probabilities, mean over the known steps.

    probs float [N, H, C] (rows sum to 1), true int [N, H] (−1 unknown, skipped) → float in [0, 2]:
    mean over steps of sum_c (p_c − [true = c])². 0 is perfect; always 1/C everywhere scores 1 − 1/C.
    """
    p = np.asarray(probs, np.float64).reshape(-1, np.shape(probs)[-1])
    t = np.asarray(true).ravel()
    keep = t >= 0
    if not keep.any():
        return float("nan")
    p, t = p[keep], t[keep]
    one_hot = np.eye(p.shape[1])[t]
    return float(np.mean(np.sum((p - one_hot) ** 2, axis=1)))


def reliability(probs: np.ndarray, true: np.ndarray, bins: int = 10) -> dict[str, Any]:
    """Per-class (one-vs-rest) reliability table of per-step probabilities, and the calibration error.

    probs float [N, H, C], true int [N, H] (−1 skipped). For every class c the probabilities p_c of
    all steps fall into ``bins`` equal bins over [0, 1]; per bin: the mean p_c ("confidence"), the
    fraction of those steps whose true class is c ("frequency") and the count. A calibrated model has
    frequency = confidence. ``ece`` per class: sum over bins of count/total · |frequency − confidence|.
    Returns {"bins": B, "confidence": [C][B], "frequency": [C][B], "count": [C][B], "ece": [C]}
    with NaN where a bin is empty.
    """
    c = np.shape(probs)[-1]
    p = np.asarray(probs, np.float64).reshape(-1, c)
    t = np.asarray(true).ravel()
    keep = t >= 0
    p, t = p[keep], t[keep]
    edges_bin = np.minimum((p * bins).astype(np.int64), bins - 1)  # [M, C]
    confidence = np.full((c, bins), np.nan)
    frequency = np.full((c, bins), np.nan)
    count = np.zeros((c, bins), np.int64)
    ece = np.full(c, np.nan)
    for k in range(c):
        n = np.bincount(edges_bin[:, k], minlength=bins)
        sum_p = np.bincount(edges_bin[:, k], weights=p[:, k], minlength=bins)
        hits = np.bincount(edges_bin[:, k], weights=(t == k).astype(np.float64), minlength=bins)
        with np.errstate(invalid="ignore", divide="ignore"):
            confidence[k], frequency[k] = sum_p / n, hits / n
        count[k] = n
        if n.sum():
            filled = n > 0
            ece[k] = float(np.sum(n[filled] * np.abs(frequency[k, filled] - confidence[k, filled])) / n.sum())
    return {"bins": bins, "confidence": confidence, "frequency": frequency, "count": count, "ece": ece}


#: A forecast misses when its final displacement error exceeds this (Argoverse 2's miss rate).
MISS_THRESHOLD_M = 2.0


def miss_rate(errors: np.ndarray, threshold_m: float = MISS_THRESHOLD_M) -> float:
    """Fraction of windows whose error at the last horizon exceeds ``threshold_m``: errors [N, H] → float."""
    return float(np.mean(errors[:, -1] > threshold_m)) if errors.shape[0] else float("nan")


def rmse_ci(
    errors: np.ndarray, *, boots: int = 1000, level: float = 0.95, seed: int = 0
) -> tuple[np.ndarray, np.ndarray]:
    """Percentile bootstrap confidence interval of the per-window RMSE by horizon.

    errors [N, H] → (low [H], high [H]). Windows are resampled with replacement ``boots`` times
    (seeded, so a report is reproducible); NaN when N < 2. Windows of one vehicle overlap, so the
    interval is somewhat optimistic (it treats windows as independent).
    """
    n, h = errors.shape
    if n < 2:
        return np.full(h, np.nan), np.full(h, np.nan)
    rng = np.random.default_rng(seed)
    sq = np.asarray(errors, np.float64) ** 2
    stats = np.empty((boots, h))
    chunk = max(1, 1_000_000 // n)  # bounded memory: chunk × N indices at a time
    for start in range(0, boots, chunk):
        b = min(chunk, boots - start)
        idx = rng.integers(0, n, size=(b, n))
        stats[start : start + b] = np.sqrt(sq[idx].mean(axis=1))
    tail = (1 - level) / 2 * 100
    return np.percentile(stats, tail, axis=0), np.percentile(stats, 100 - tail, axis=0)


def paired_rmse_difference(
    squared_a: np.ndarray, squared_b: np.ndarray, *, boots: int = 2000, level: float = 0.95, seed: int = 0
) -> tuple[float, float, float]:
    """RMSE of A minus RMSE of B on the same windows, with a paired percentile bootstrap interval.

    squared_a, squared_b [N]: each window's squared error of A and of B (at one horizon). The same
    resampled windows score both, so what the windows share (their difficulty) cancels and the
    interval is of the difference itself. → (difference, low, high) in metres; NaN when N < 2. As
    :func:`rmse_ci`, it treats overlapping windows as independent (somewhat optimistic)."""
    a, b = np.asarray(squared_a, np.float64), np.asarray(squared_b, np.float64)
    if a.shape != b.shape or a.ndim != 1:
        raise ValueError(f"paired squared errors of one shape [N] expected, got {a.shape} and {b.shape}")
    n = a.size
    difference = float(np.sqrt(a.mean()) - np.sqrt(b.mean())) if n else float("nan")
    if n < 2:
        return difference, float("nan"), float("nan")
    rng = np.random.default_rng(seed)
    stats = np.empty(boots)
    chunk = max(1, 1_000_000 // n)
    for start in range(0, boots, chunk):
        idx = rng.integers(0, n, size=(min(chunk, boots - start), n))
        stats[start : start + len(idx)] = np.sqrt(a[idx].mean(axis=1)) - np.sqrt(b[idx].mean(axis=1))
    tail = (1 - level) / 2 * 100
    return difference, float(np.percentile(stats, tail)), float(np.percentile(stats, 100 - tail))


#: Edges (m/s) of the target-speed bands of ``per_speed_band``: standing, creeping, congested, slow,
#: flowing, fast. A model trained on simulation can beat constant velocity overall and still lose in
#: one band of real traffic (creeping queues, say); the bands show where.
SPEED_BAND_EDGES_MPS = (0.2, 2.0, 8.0, 16.0, 25.0)


def speed_band_labels(edges: tuple[float, ...] = SPEED_BAND_EDGES_MPS) -> list[str]:
    """Labels of the bands cut at ``edges``: ["< 0.2 m/s", "0.2–2 m/s", …, "≥ 25 m/s"]."""
    inner = [f"{lo:g}–{hi:g} m/s" for lo, hi in itertools.pairwise(edges)]
    return [f"< {edges[0]:g} m/s", *inner, f"≥ {edges[-1]:g} m/s"]


def per_speed_band(
    errors: np.ndarray, speed: np.ndarray, edges: tuple[float, ...] = SPEED_BAND_EDGES_MPS
) -> dict[str, dict[str, Any]]:
    """RMSE per window by horizon within bands of the target's speed at t0: errors [N, H], speed
    [N] (m/s) → {band label: {"n_windows", "rmse" [H], "rmse_ci" {"low" [H], "high" [H]}}}, bands in
    order, empty bands left out. The 95 % bootstrap interval (200 resamples, seeded; null below two
    windows) is what a band is judged by: a band of a few windows says little."""
    band = np.digitize(np.asarray(speed, dtype=np.float64), edges)
    out: dict[str, dict[str, Any]] = {}
    for i, label in enumerate(speed_band_labels(edges)):
        sel = band == i
        if sel.any():
            low, high = rmse_ci(errors[sel], boots=200)
            out[label] = {
                "n_windows": int(sel.sum()),
                "rmse": _finite_or_none(rmse(errors[sel])),
                "rmse_ci": {"low": _finite_or_none(low), "high": _finite_or_none(high)},
            }
    return out


def _finite_or_none(values: np.ndarray | float) -> object:
    """JSON-ready: floats (NaN → None), arrays → nested lists."""
    arr = np.asarray(values, dtype=np.float64)
    if arr.ndim == 0:
        return None if not np.isfinite(arr) else float(arr)
    return [_finite_or_none(v) for v in arr]


def _maneuver_metrics(true: np.ndarray, pred: np.ndarray, probs: np.ndarray | None) -> dict[str, Any]:
    """The maneuver keys of ``summary`` (true, pred int [N, 5]; probs float [N, 5, 3] or None)."""
    conf = confusion_matrix(true, pred)
    precision, recall = precision_recall(conf)
    out: dict[str, Any] = {
        "maneuver_accuracy": _finite_or_none(accuracy(conf)),
        "maneuver_macro_f1": _finite_or_none(macro_f1(conf)),
        "f1": _finite_or_none(f1_per_class(conf)),
        "support": support(conf).tolist(),
        "predicted": conf.sum(axis=0).tolist(),
        "precision": _finite_or_none(precision),
        "recall": _finite_or_none(recall),
        "confusion": conf.tolist(),
    }
    if probs is not None and np.isfinite(probs).all():
        rel = reliability(probs, true)
        out.update(
            brier=_finite_or_none(brier_score(probs, true)),
            reliability={
                "bins": rel["bins"],
                "confidence": _finite_or_none(rel["confidence"]),
                "frequency": _finite_or_none(rel["frequency"]),
                "count": rel["count"].tolist(),
            },
            ece=_finite_or_none(rel["ece"]),
        )
    return out


def summary(
    offsets: np.ndarray,
    future: np.ndarray,
    maneuver: np.ndarray,
    vehicle: np.ndarray,
    *,
    candidates: np.ndarray | None = None,
    predicted_maneuver: np.ndarray | None = None,
    probs: np.ndarray | None = None,
    recording: np.ndarray | None = None,
    speed: np.ndarray | None = None,
    boots: int = 1000,
) -> dict[str, Any]:
    """Every metric of docs/design.md §4 for one model, JSON-ready (NaN → null).

    offsets, future float [N, 5, 2] (m); maneuver int [N, 5] ground truth; vehicle int [N] vehicle
    ids (for the per-vehicle RMSE); candidates [N, K, 5, 2] (minADE/minFDE, default: offsets);
    predicted_maneuver int [N, 5] (maneuver metrics; None → null, e.g. for kinematic baselines);
    probs float [N, 5, 3] per-step probabilities (Brier score, reliability); recording str [N]
    (per-recording rows); speed float [N] the target's speed at t0 in m/s (rows per speed band);
    ``boots`` bootstrap resamples of the confidence intervals (0: none).
    Keys: rmse, rmse_per_vehicle, rmse_lane_change (per window, 1–5 s), rmse_ci and
    rmse_lane_change_ci ({"low", "high", "level"}), ade, fde, miss_rate (FDE > miss_threshold_m),
    min_ade, min_fde, k, maneuver_accuracy, always_straight_accuracy, maneuver_macro_f1 (over the
    classes present or predicted, see ``macro_f1``), f1, support, predicted, precision, recall (per
    class straight/left/right), confusion (rows true, columns predicted, per future step), brier,
    reliability, ece, n_windows, n_lane_change_windows, per_recording, per_speed_band.
    """
    err = displacement_errors(offsets, future)
    lc = lane_change_windows(maneuver)
    cand = offsets[:, None] if candidates is None else candidates
    min_ade, min_fde = min_ade_fde(cand, future)

    def ci(e: np.ndarray) -> dict[str, Any] | None:
        if boots <= 0:
            return None
        low, high = rmse_ci(e, boots=boots)
        return {"low": _finite_or_none(low), "high": _finite_or_none(high), "level": 0.95, "boots": boots}

    out: dict[str, Any] = {
        "rmse": _finite_or_none(rmse(err)),
        "rmse_per_vehicle": _finite_or_none(rmse_per_vehicle(err, vehicle)),
        "rmse_lane_change": _finite_or_none(rmse(err[lc])),
        "rmse_ci": ci(err),
        "rmse_lane_change_ci": ci(err[lc]),
        "ade": _finite_or_none(ade(err)),
        "fde": _finite_or_none(fde(err)),
        "miss_rate": _finite_or_none(miss_rate(err)),
        "miss_threshold_m": MISS_THRESHOLD_M,
        "min_ade": _finite_or_none(min_ade),
        "min_fde": _finite_or_none(min_fde),
        "k": int(cand.shape[1]),
        "maneuver_accuracy": None,
        "always_straight_accuracy": _finite_or_none(always_straight_accuracy(maneuver)),
        "maneuver_macro_f1": None,
        "f1": None,
        "support": support(confusion_matrix(maneuver, np.zeros_like(maneuver))).tolist(),
        "predicted": None,
        "precision": None,
        "recall": None,
        "confusion": None,
        "brier": None,
        "reliability": None,
        "ece": None,
        "n_windows": int(err.shape[0]),
        "n_lane_change_windows": int(lc.sum()),
        "per_recording": None,
        "per_speed_band": None,
    }
    if predicted_maneuver is not None:
        out.update(_maneuver_metrics(maneuver, predicted_maneuver, probs))
    if recording is not None:
        out["per_recording"] = per_recording(err, maneuver, predicted_maneuver, np.asarray(recording))
    if speed is not None:
        out["per_speed_band"] = per_speed_band(err, speed)
    return out


def per_recording(
    errors: np.ndarray, maneuver: np.ndarray, predicted: np.ndarray | None, recording: np.ndarray
) -> dict[str, dict[str, Any]]:
    """One compact row per recording (or log): errors [N, H], maneuver int [N, H], predicted int [N, H]
    or None, recording str [N] → {name: {n_windows, n_lane_change_windows, rmse, rmse_lane_change,
    fde, miss_rate, maneuver_accuracy, always_straight_accuracy, maneuver_macro_f1}}."""
    names, code = np.unique(recording.astype(str), return_inverse=True)
    code = code.ravel()
    rows: dict[str, dict[str, Any]] = {}
    for i, name in enumerate(names):
        sel = code == i
        e, m = errors[sel], maneuver[sel]
        lc = lane_change_windows(m)
        conf = None if predicted is None else confusion_matrix(m, predicted[sel])
        rows[str(name)] = {
            "n_windows": int(sel.sum()),
            "n_lane_change_windows": int(lc.sum()),
            "rmse": _finite_or_none(rmse(e)),
            "rmse_lane_change": _finite_or_none(rmse(e[lc])),
            "fde": _finite_or_none(fde(e)),
            "miss_rate": _finite_or_none(miss_rate(e)),
            "maneuver_accuracy": None if conf is None else _finite_or_none(accuracy(conf)),
            "always_straight_accuracy": _finite_or_none(always_straight_accuracy(m)),
            "maneuver_macro_f1": None if conf is None else _finite_or_none(macro_f1(conf)),
        }
    return rows
