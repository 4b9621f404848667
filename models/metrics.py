"""Trajectory and maneuver metrics (DESIGN.md §4): pure numpy functions, shapes in the docstrings.

Two RMSE conventions are offered because papers use both:

* per window (conv-social-pooling, the paper's tables): RMSE_h = sqrt(mean over windows of the
  squared Euclidean error at horizon h);
* per vehicle (PiP): the squared errors are first averaged over each vehicle's windows, then over
  vehicles, then the root is taken, so long tracks do not dominate.
"""

from __future__ import annotations

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


def macro_f1(confusion: np.ndarray) -> float:
    """Mean over classes present in the ground truth of F1 = 2PR/(P+R) (0 where P or R is undefined/0)."""
    precision, recall = precision_recall(confusion)
    present = confusion.sum(axis=1) > 0
    with np.errstate(invalid="ignore", divide="ignore"):
        f1 = np.nan_to_num(2 * precision * recall / (precision + recall))
    return float(np.mean(f1[present])) if present.any() else float("nan")


def _finite_or_none(values: np.ndarray | float) -> object:
    """JSON-ready: floats (NaN → None), arrays → nested lists."""
    arr = np.asarray(values, dtype=np.float64)
    if arr.ndim == 0:
        return None if not np.isfinite(arr) else float(arr)
    return [_finite_or_none(v) for v in arr]


def summary(
    offsets: np.ndarray,
    future: np.ndarray,
    maneuver: np.ndarray,
    vehicle: np.ndarray,
    *,
    candidates: np.ndarray | None = None,
    predicted_maneuver: np.ndarray | None = None,
) -> dict[str, Any]:
    """Every metric of DESIGN.md §4 for one model, JSON-ready (NaN → null).

    offsets, future float [N, 5, 2] (m); maneuver int [N, 5] ground truth; vehicle int [N] vehicle
    ids (for the per-vehicle RMSE); candidates [N, K, 5, 2] (minADE/minFDE, default: offsets);
    predicted_maneuver int [N, 5] (maneuver metrics; None → null, e.g. for kinematic baselines).
    Keys: rmse, rmse_per_vehicle, rmse_lane_change (per window, 1–5 s), ade, fde, min_ade, min_fde, k,
    maneuver_accuracy, maneuver_macro_f1, precision, recall (per class straight/left/right),
    confusion (rows true, columns predicted, per future step), n_windows, n_lane_change_windows.
    """
    err = displacement_errors(offsets, future)
    lc = lane_change_windows(maneuver)
    cand = offsets[:, None] if candidates is None else candidates
    min_ade, min_fde = min_ade_fde(cand, future)
    out: dict[str, Any] = {
        "rmse": _finite_or_none(rmse(err)),
        "rmse_per_vehicle": _finite_or_none(rmse_per_vehicle(err, vehicle)),
        "rmse_lane_change": _finite_or_none(rmse(err[lc])),
        "ade": _finite_or_none(ade(err)),
        "fde": _finite_or_none(fde(err)),
        "min_ade": _finite_or_none(min_ade),
        "min_fde": _finite_or_none(min_fde),
        "k": int(cand.shape[1]),
        "maneuver_accuracy": None,
        "maneuver_macro_f1": None,
        "precision": None,
        "recall": None,
        "confusion": None,
        "n_windows": int(err.shape[0]),
        "n_lane_change_windows": int(lc.sum()),
    }
    if predicted_maneuver is not None:
        conf = confusion_matrix(maneuver, predicted_maneuver)
        precision, recall = precision_recall(conf)
        out.update(
            maneuver_accuracy=_finite_or_none(accuracy(conf)),
            maneuver_macro_f1=_finite_or_none(macro_f1(conf)),
            precision=_finite_or_none(precision),
            recall=_finite_or_none(recall),
            confusion=conf.tolist(),
        )
    return out
