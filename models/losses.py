"""The training losses and their weights (the paper's criteria, and the weightings beyond it that
``TrainConfig`` switches on): pure functions on arrays and tensors, shapes in each docstring."""

from __future__ import annotations

import numpy as np
import torch
from torch.nn import functional as F


def class_weights(maneuver: np.ndarray, power: float, classes: int = 3) -> np.ndarray:
    """Loss weight per class: maneuver int [N, 5] training labels → float32 [classes].

    w_c ∝ (1 / frequency_c)**power, scaled so the mean weight over the training steps is 1 (the loss
    keeps the plain NLL's scale). power 0 → all ones (plain NLL); 1 → fully balanced classes. An absent
    class gets weight 0 (its count is 0, so it never occurs in the loss anyway).
    """
    counts = np.bincount(np.asarray(maneuver).ravel(), minlength=classes)[:classes].astype(np.float64)
    freq = counts / max(counts.sum(), 1.0)
    w = np.where(counts > 0, np.power(np.where(counts > 0, freq, 1.0), -power), 0.0)
    return (w / max(float(np.sum(freq * w)), 1e-12)).astype(np.float32)


def future_stats(future: np.ndarray) -> tuple[np.ndarray, float]:
    """Offset normalisation: future [N, 5, 2] → (mean float32 [5, 2], one std over all centred entries)."""
    f = np.asarray(future, np.float64)
    mean = f.mean(axis=0)
    std = float(np.sqrt(np.mean((f - mean) ** 2)))
    return mean.astype(np.float32), (std if std > 1e-6 else 1.0)


def classifier_loss(
    logits: torch.Tensor, maneuver: torch.Tensor, weight: torch.Tensor | None = None
) -> torch.Tensor:
    """Sum over steps of the NLL, mean over the batch: logits [B, 5, 3], maneuver [B, 5] → scalar.

    ``weight`` float [3]: each step's NLL times the weight of its true class (not renormalised per
    batch, so it is the same per-step criterion in every batch); None = plain NLL.
    """
    return F.cross_entropy(
        logits.reshape(-1, logits.shape[-1]), maneuver.reshape(-1), weight=weight, reduction="sum"
    ) / len(logits)


def regressor_loss(
    pred: torch.Tensor, true: torch.Tensor, horizon_weight: torch.Tensor | None = None
) -> torch.Tensor:
    """Batch RMSE: sqrt(mean over windows and steps of the squared Euclidean error); [B, 5, 2] → scalar.

    ``horizon_weight`` float [5] (mean 1) weighs each step's squared error; None = all equal."""
    squared = torch.sum((pred - true) ** 2, dim=-1)  # [B, 5]
    if horizon_weight is not None:
        squared = squared * horizon_weight
    return torch.sqrt(torch.mean(squared))


def horizon_weights(residual: np.ndarray, power: float) -> np.ndarray:
    """Loss weight per horizon, float32 [5], mean 1: (r_last / r_h)**power with r_h the RMS over
    windows of ``residual`` [N, 5, 2] at step h (the centred, reference-relative training targets)."""
    rms = np.sqrt(np.mean(np.sum(np.asarray(residual, np.float64) ** 2, axis=-1), axis=0))  # [5]
    rms = np.maximum(rms, 1e-3)
    w = (rms[-1] / rms) ** power
    return (w / w.mean()).astype(np.float32)
