"""Training-batch augmentation on plain arrays: the per-window spread of derivative noise."""

from __future__ import annotations

import numpy as np
import pytest

from lanecast.models.augment import Augmentation, augment
from lanecast.models.train import TrainConfig


def batch(windows: int = 400) -> tuple[np.ndarray, np.ndarray]:
    """Inputs float32 [B, 4, 8, 16] at 20 m/s and 0 m/s², every entry present."""
    inputs = np.zeros((windows, 4, 8, 16), np.float32)
    inputs[:, 2] = 20.0
    return inputs, np.ones((windows, 8, 16), bool)


def jitter_level(inputs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per window: the share of entries hit by an outlier (their speed moved) and the RMS of the
    acceleration jitter on the others: float [B], float [B]."""
    outlier = np.abs(inputs[:, 2] - 20.0) > 0
    jitter = np.where(outlier, np.nan, inputs[:, 3]).reshape(len(inputs), -1)
    return outlier.mean(axis=(1, 2)), np.sqrt(np.nanmean(jitter**2, axis=1))


def test_without_spread_every_window_gets_the_same_level() -> None:
    inputs, present = batch()
    augment(
        inputs, present, Augmentation(acc_noise_mps2=0.5, derivative_outliers=0.1), np.random.default_rng(3)
    )
    share, level = jitter_level(inputs)
    assert 0.35 < level.min() and level.max() < 0.65
    assert share.max() < 0.25


def test_spread_gives_clean_and_noisy_windows_around_the_same_mean() -> None:
    """With spread 1 a window's acceleration jitter is anywhere from none to twice the level; the
    mean level and the mean outlier share stay those asked for; positions are untouched."""
    inputs, present = batch(2000)
    aug = Augmentation(acc_noise_mps2=0.5, derivative_outliers=0.1, derivative_noise_spread=1.0)
    augment(inputs, present, aug, np.random.default_rng(0))
    share, level = jitter_level(inputs)  # speed outliers mark the hit entries
    assert share.min() < 0.02 and share.max() > 0.17
    assert share.mean() == pytest.approx(0.1, abs=0.01)
    assert level.min() < 0.05 and level.max() > 0.9
    assert np.mean(level**2) == pytest.approx((0.5**2) * 4 / 3, rel=0.1)  # E[U(0, 2)²] = 4/3
    np.testing.assert_array_equal(inputs[:, :2], 0.0)


def test_spread_outside_zero_to_one_is_refused() -> None:
    with pytest.raises(ValueError, match="derivative_noise_spread"):
        TrainConfig(derivative_noise_spread=1.5)
    with pytest.raises(ValueError, match="derivative_noise_spread"):
        TrainConfig(derivative_noise_spread=-0.1)
