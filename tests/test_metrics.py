"""Metrics against values computed by hand."""

from __future__ import annotations

import math

import numpy as np
import pytest

from lanecast.models import metrics as M


def _errors_as_offsets(errors: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Predictions displaced along x by ``errors`` [N, 5] from a zero ground truth."""
    pred = np.zeros((*errors.shape, 2))
    pred[..., 0] = errors
    return pred, np.zeros_like(pred)


def test_displacement_errors_are_euclidean() -> None:
    pred = np.array([[[3.0, 4.0]] * 5])
    assert M.displacement_errors(pred, np.zeros_like(pred)).tolist() == [[5.0] * 5]


def test_rmse_per_window_and_per_vehicle() -> None:
    # vehicle 7 has two windows with errors 1 and 3; vehicle 9 one window with error 2 (all horizons)
    err = np.array([[1.0] * 5, [3.0] * 5, [2.0] * 5])
    vehicle = np.array([7, 7, 9])
    np.testing.assert_allclose(M.rmse(err), [math.sqrt((1 + 9 + 4) / 3)] * 5)
    # per vehicle: mean squares 5 and 4, their mean 4.5
    np.testing.assert_allclose(M.rmse_per_vehicle(err, vehicle), [math.sqrt(4.5)] * 5)
    assert np.all(np.isnan(M.rmse(np.zeros((0, 5)))))


def test_ade_fde_min_over_candidates() -> None:
    err = np.array([[1.0, 2, 3, 4, 5], [0, 0, 0, 0, 10]])
    assert M.ade(err) == pytest.approx(25 / 10)
    assert M.fde(err) == pytest.approx(7.5)
    true = np.zeros((1, 5, 2))
    cands = np.zeros((1, 2, 5, 2))
    cands[0, 0, :, 0] = [1, 1, 1, 1, 1]  # ADE 1, FDE 1
    cands[0, 1, :, 0] = [0, 0, 0, 0, 2]  # ADE 0.4, FDE 2
    assert M.min_ade_fde(cands, true) == pytest.approx((0.4, 1.0))  # each minimum taken on its own


def test_confusion_precision_recall_f1() -> None:
    true = np.array([[0, 0, 0, 1, 1], [2, 2, 0, -1, -1]])
    pred = np.array([[0, 0, 1, 1, 0], [2, 0, 0, 2, 1]])
    conf = M.confusion_matrix(true, pred)
    assert conf.tolist() == [[3, 1, 0], [1, 1, 0], [1, 0, 1]]  # the -1 steps are not counted
    assert M.accuracy(conf) == pytest.approx(5 / 8)
    precision, recall = M.precision_recall(conf)
    np.testing.assert_allclose(precision, [3 / 5, 1 / 2, 1.0])
    np.testing.assert_allclose(recall, [3 / 4, 1 / 2, 1 / 2])
    f1 = [2 * (0.6 * 0.75) / 1.35, 0.5, 2 * 0.5 / 1.5]
    assert M.macro_f1(conf) == pytest.approx(np.mean(f1))


def test_always_straight_macro_f1_is_a_third_of_straight_f1() -> None:
    true = np.array([[0, 0, 0, 0, 1]] * 4)
    conf = M.confusion_matrix(true, np.zeros_like(true))
    assert M.macro_f1(conf) == pytest.approx((2 * 0.8 / 1.8 + 0) / 2)  # classes present: straight, left


def test_summary_keys_and_lane_change_subset() -> None:
    err = np.array([[1.0] * 5, [3.0] * 5])
    pred, true = _errors_as_offsets(err)
    maneuver = np.array([[0] * 5, [0, 0, 1, 1, 1]])
    s = M.summary(pred, true, maneuver, np.array([1, 2]), predicted_maneuver=np.zeros_like(maneuver))
    assert s["rmse_lane_change"] == [3.0] * 5  # only the second window changes lanes
    assert s["rmse"] == pytest.approx([math.sqrt(5)] * 5)
    assert s["n_windows"] == 2 and s["n_lane_change_windows"] == 1 and s["k"] == 1
    assert s["min_ade"] == s["ade"] == 2.0
    assert s["confusion"] == [[7, 0, 0], [3, 0, 0], [0, 0, 0]]
    assert s["precision"][1] is None  # 0/0 → null in JSON
    baseline = M.summary(pred, true, maneuver, np.array([1, 2]))
    assert baseline["maneuver_accuracy"] is None and baseline["confusion"] is None
