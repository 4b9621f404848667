"""Constant-velocity and constant-acceleration baselines are exact on their own kind of track."""

from __future__ import annotations

import numpy as np
import pytest

from lanecast.models.baselines import constant_acceleration, constant_velocity, extrapolate, kinematic_limits
from lanecast.models.predict import STCNNForecaster

T_HIST = (np.arange(30) - 29) * 0.1


def _window(vx: float, vy: float, ax: float = 0.0, ay: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """One window whose target moves with constant (vx, vy) and acceleration (ax, ay), at 0 at t0."""
    inputs = np.zeros((1, 4, 8, 30), np.float32)
    inputs[0, 0, 4] = vx * T_HIST + 0.5 * ax * T_HIST**2
    inputs[0, 1, 4] = vy * T_HIST + 0.5 * ay * T_HIST**2
    inputs[0, 2, 4] = np.hypot(vx + ax * T_HIST, vy + ay * T_HIST)
    present = np.zeros((1, 8, 30), bool)
    present[0, 4] = True
    return inputs, present


def test_constant_velocity_is_exact_on_a_constant_velocity_track() -> None:
    inputs, present = _window(30.0, -0.5)
    pred = constant_velocity().predict(inputs, present)
    expected = np.array([[30.0 * h, -0.5 * h] for h in range(1, 6)])  # by hand
    np.testing.assert_allclose(pred.offsets[0], expected, atol=1e-3)
    assert pred.probs is None and pred.maneuver is None
    np.testing.assert_array_equal(pred.top_offsets[:, 0], pred.offsets)
    assert pred.top_probs.tolist() == [[1.0]]


def test_constant_acceleration_is_exact_on_a_constant_acceleration_track() -> None:
    inputs, present = _window(20.0, 0.2, ax=1.0, ay=0.1)
    pred = constant_acceleration().predict(inputs, present)
    # x(5 s) = 20·5 + ½·1·25 = 112.5 m; y(5 s) = 0.2·5 + ½·0.1·25 = 2.25 m
    np.testing.assert_allclose(pred.offsets[0, -1], [112.5, 2.25], atol=2e-3)
    np.testing.assert_allclose(pred.offsets[0, 0], [20.5, 0.25], atol=2e-3)
    # constant velocity misses the acceleration by ½·a·h² (at 5 s: 12.5 m; the fit's lag adds a little)
    cv = constant_velocity().predict(inputs, present).offsets[0, -1, 0]
    assert 112.5 - cv == pytest.approx(12.5 + 5 * 0.2, abs=0.01)  # the 5-frame line's slope lags 0.2 s


def test_constant_acceleration_is_exact_on_constant_velocity_too() -> None:
    inputs, present = _window(25.0, 1.0)
    np.testing.assert_allclose(
        constant_acceleration().predict(inputs, present).offsets[0, -1], [125.0, 5.0], atol=2e-3
    )


def test_batches_do_not_change_results() -> None:
    rng = np.random.default_rng(0)
    inputs = rng.normal(size=(37, 4, 8, 30)).astype(np.float32)
    present = np.ones((37, 8, 30), bool)
    whole = constant_acceleration().predict(inputs, present).offsets
    np.testing.assert_array_equal(
        whole, constant_acceleration().predict(inputs, present, batch_size=5).offsets
    )


def test_bad_degree_or_span() -> None:
    inputs, _ = _window(1.0, 0.0)
    with pytest.raises(ValueError):
        extrapolate(inputs, degree=3, span=10)
    with pytest.raises(ValueError):
        extrapolate(inputs, degree=2, span=2)


def test_kinematic_limits_remove_reversing_and_sliding_and_keep_lane_changes() -> None:
    """By hand: reversing removed, then |y| ≤ x (a car 0.5 m on has not slid 0.8 m across); a lane
    change at highway speed (3.5 m across over 120 m along) is untouched."""
    offsets = np.array(
        [
            [[-0.2, 0.1], [0.5, 0.2], [0.3, 0.8], [1.0, 0.4], [0.9, -1.5]],
            [[25.0, 0.2], [50.0, 1.0], [74.0, 2.2], [98.0, 3.2], [121.0, 3.5]],
        ],
        np.float32,
    )  # [2, 5, 2]
    lane_change = offsets[1].copy()
    out = kinematic_limits(offsets)
    assert out is offsets  # in place
    np.testing.assert_allclose(out[0, :, 0], [0.0, 0.5, 0.5, 1.0, 1.0])
    np.testing.assert_allclose(out[0, :, 1], [0.0, 0.2, 0.5, 0.4, -1.0])
    np.testing.assert_array_equal(out[1], lane_change)


def test_the_shipped_model_never_forecasts_a_standing_car_behind_itself() -> None:
    """A car that stood for 3 s alone (speed 0, as NGSIM reports standing cars), and the same among
    standing neighbours: every forecast, top-K included, is at or ahead of it along the road."""
    inputs, present = _window(0.0, 0.0)
    queue_inputs, queue_present = inputs.copy(), present.copy()
    for row, x, y in ((1, 7.5, 0.0), (6, -7.5, 3.5)):  # F ahead, RL behind in the lane on the left
        queue_inputs[0, 0, row] = x
        queue_inputs[0, 1, row] = y
        queue_present[0, row] = True
    model = STCNNForecaster.load(None)
    for x, p in ((inputs, present), (queue_inputs, queue_present)):
        pred = model.predict(x, p, top_k=3)
        assert pred.top_offsets[..., 0].min() >= 0.0
        assert np.all(np.diff(pred.top_offsets[..., 0], axis=-1) >= 0.0)
        assert np.all(np.abs(pred.top_offsets[..., 1]) <= pred.top_offsets[..., 0])  # no sliding sideways
        assert np.abs(pred.offsets[0, 0]).max() < 0.5  # a standing car stays near where it is at 1 s
