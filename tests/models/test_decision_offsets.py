"""Decision offsets (lanecast.models.decision_offsets): chosen on validation for the macro-F1, folded into the
classifier's last bias so that every consumer applies them."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from conftest import synthetic_windows

from lanecast.models.decision_offsets import choose_offsets, fold_into_classifier, offset_macro_f1
from lanecast.models.stcnn import STCNN
from lanecast.models.train import TrainConfig, train


@pytest.fixture(scope="module")
def windows():
    return synthetic_windows()


def _overconfident_lane_changes(n: int = 4000, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Labels 95 % straight; a classifier whose left/right logits are 1.5 too high (as a class-
    weighted loss leaves them): log-probabilities [n, 5, 3] and labels [n, 5]."""
    rng = np.random.default_rng(seed)
    true = rng.choice(3, size=(n, 5), p=[0.95, 0.03, 0.02])
    logits = rng.normal(0.0, 1.0, size=(n, 5, 3)) + 2.5 * np.eye(3)[true]
    logits[..., 1:] += 1.5
    log_probs = logits - np.log(np.exp(logits).sum(-1, keepdims=True))
    return log_probs.astype(np.float32), true


def test_offsets_undo_an_over_predicted_class_and_raise_macro_f1() -> None:
    log_probs, true = _overconfident_lane_changes()
    chosen = choose_offsets(log_probs, true)
    assert chosen.offsets[0] == 0.0
    assert chosen.offsets[1] < -1.0 and chosen.offsets[2] < -1.0  # the +1.5 undone, and the 95 % prior
    assert chosen.macro_f1_after > chosen.macro_f1_before + 0.05
    assert chosen.macro_f1_after == offset_macro_f1(log_probs, true, chosen.offsets[1], chosen.offsets[2])
    # held-out data from the same classifier gains too (the offsets are not fitted noise)
    other_lp, other_true = _overconfident_lane_changes(seed=1)
    assert offset_macro_f1(other_lp, other_true, *chosen.offsets[1:]) > offset_macro_f1(
        other_lp, other_true, 0, 0
    )


def test_a_calibrated_classifier_keeps_its_decision() -> None:
    """Perfect predictions: every offset near 0 scores the same, and the smallest shift (0, 0) wins."""
    true = np.random.default_rng(2).choice(3, size=(500, 5), p=[0.9, 0.05, 0.05])
    log_probs = np.log(np.where(np.eye(3)[true] > 0, 0.98, 0.01)).astype(np.float32)
    chosen = choose_offsets(log_probs, true)
    assert chosen.offsets == (0.0, 0.0, 0.0)
    assert chosen.macro_f1_before == chosen.macro_f1_after == 1.0


def test_folding_adds_the_offsets_to_every_steps_logits() -> None:
    torch.manual_seed(0)
    model = STCNN().eval()
    x = torch.randn(7, 4, 8, 30)
    with torch.no_grad():
        before = model.classifier(x).clone()
        fold_into_classifier(model, (0.0, -1.2, 0.7))
        after = model.classifier(x)
    torch.testing.assert_close(
        after - before, torch.tensor([0.0, -1.2, 0.7]).expand(7, 5, 3), atol=1e-5, rtol=0
    )


def test_training_with_decision_offsets_records_and_applies_them(windows) -> None:
    """Same seed with and without: the regressor is identical, the classifier differs exactly by
    the recorded offsets in its last bias, and the card says what the validation macro-F1 became."""
    cfg = TrainConfig(epochs=1, batch_size=64, seed=5, threads=1, class_weight_power=1.0)
    plain = train(windows, cfg)
    shifted = train(windows, TrainConfig(**{**cfg.to_dict(), "model": cfg.model, "decision_offsets": True}))
    record = shifted.card["training"]["decision_offsets"]
    assert plain.card["training"]["decision_offsets"] is None
    assert record["val_macro_f1_after"] >= record["val_macro_f1_before"]
    offsets = torch.tensor(record["offsets"]).repeat(5)
    torch.testing.assert_close(
        shifted.model.classifier.fc2.bias, plain.model.classifier.fc2.bias + offsets, atol=1e-6, rtol=0
    )
    for name, value in plain.model.regressor.state_dict().items():
        torch.testing.assert_close(shifted.model.regressor.state_dict()[name], value)
