"""What every forecaster returns and the interface it offers: the ST-CNN and the kinematic baselines alike.

Torch-free, so that the baselines, the evaluation and the reports do not load torch.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np


@dataclass
class Predictions:
    """What a forecaster says about N windows (window frame, metres)."""

    offsets: np.ndarray  # float32 [N, 5, 2]: trajectory for the most probable maneuvers
    probs: np.ndarray | None  # float32 [N, 5, 3]: per-step maneuver probabilities (None: no classifier)
    maneuver: np.ndarray | None  # int64 [N, 5]: per-step argmax
    top_sequences: np.ndarray | None  # int64 [N, K, 5]: K most probable maneuver sequences
    top_probs: np.ndarray  # float32 [N, K]: their probabilities (product of per-step probabilities)
    top_offsets: np.ndarray  # float32 [N, K, 5, 2]: trajectory regressed for each sequence
    #: bool [N]: the target's state lies outside the model's training distribution (lanecast.models.ood);
    #: None when unknown (baselines, cards without a distribution)
    out_of_distribution: np.ndarray | None = None


class Forecaster(Protocol):
    """Anything that predicts windows: the ST-CNN and the kinematic baselines."""

    @property
    def name(self) -> str:
        """The model's name in metrics and reports (``stcnn``, ``cv``, ``ca``, …)."""
        ...

    def predict(
        self, inputs: np.ndarray, present: np.ndarray, *, top_k: int = 3, batch_size: int = 4096
    ) -> Predictions: ...
