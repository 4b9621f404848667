"""Decision offsets: where the classifier's argmax puts the line between straight and a lane change.

A classifier trained with class-weighted NLL (``TrainConfig.class_weight_power``) over-predicts lane
changes on purpose, to learn them at all among ~97 % straight steps; its argmax then calls many
straight steps lane changes, which lowers the macro-F1 and feeds the regressor wrong maneuvers.
Adding a constant offset to each class's logit moves the decision without retraining. The offsets
are chosen on the validation split (never on test data) to maximise the per-step macro-F1, and
folded into the classifier's last bias, so the network keeps the paper's layers and every consumer
(batch predictor, ONNX export, reports) applies them with no extra code.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np
import torch

from lanecast.models.metrics import confusion_matrix, macro_f1
from lanecast.models.stcnn import STCNN

#: candidate offsets (added to the lane-change logits; straight stays 0)
GRID = np.round(np.arange(-3.0, 1.0001, 0.1), 2)


@dataclass(frozen=True)
class DecisionOffsets:
    """Chosen logit offsets per class (straight, left, right) and the macro-F1 they give."""

    offsets: tuple[float, float, float]
    macro_f1_before: float
    macro_f1_after: float

    def to_dict(self) -> dict[str, object]:
        return {
            "offsets": list(self.offsets),
            "val_macro_f1_before": self.macro_f1_before,
            "val_macro_f1_after": self.macro_f1_after,
            "chosen_by": "validation per-step macro-F1 over offsets in [-3, 1] step 0.1",
        }


def offset_macro_f1(log_probs: np.ndarray, true: np.ndarray, left: float, right: float) -> float:
    """Per-step macro-F1 of argmax(log_probs + (0, left, right)): log_probs float [N, H, 3],
    true int [N, H] (-1 unknown, skipped)."""
    pred = (log_probs + np.array([0.0, left, right], dtype=log_probs.dtype)).argmax(-1)
    return macro_f1(confusion_matrix(true, pred, 3))


def choose_offsets(log_probs: np.ndarray, true: np.ndarray, grid: np.ndarray = GRID) -> DecisionOffsets:
    """The (left, right) offsets on ``grid`` with the best macro-F1 on (log_probs [N, H, 3],
    true [N, H]); the smallest shift from 0 among ties, so without data the decision stays put."""
    before = offset_macro_f1(log_probs, true, 0.0, 0.0)
    best = (before, 0.0, 0.0, 0.0)
    for left in grid:
        for right in grid:
            score = offset_macro_f1(log_probs, true, float(left), float(right))
            shift = abs(float(left)) + abs(float(right))
            if score > best[0] or (score == best[0] and shift < best[3]):
                best = (score, float(left), float(right), shift)
    return DecisionOffsets((0.0, best[1], best[2]), before, best[0])


@torch.no_grad()
def classifier_log_probs(
    model: STCNN, batches: Iterable[tuple[torch.Tensor, torch.Tensor]]
) -> tuple[np.ndarray, np.ndarray]:
    """Log-probabilities float32 [N, H, C] and true maneuvers int64 [N, H] over (normalised inputs
    [B, 4, 8, 30], maneuvers [B, H]) batches."""
    model.eval()
    parts = [(torch.log_softmax(model.classifier(x), dim=2).numpy(), m.numpy()) for x, m in batches]
    return np.concatenate([p[0] for p in parts]), np.concatenate([p[1] for p in parts])


@torch.no_grad()
def fold_into_classifier(model: STCNN, offsets: tuple[float, float, float]) -> None:
    """Add ``offsets`` (one per class) to the classifier's output bias at every step, in place."""
    bias = model.classifier.fc2.bias.view(model.config.horizon, model.config.classes)
    bias += torch.tensor(offsets, dtype=bias.dtype, device=bias.device)
