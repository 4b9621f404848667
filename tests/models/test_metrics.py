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


def test_false_lane_changes_on_straight_data_lower_macro_f1() -> None:
    true = np.zeros((40, 5), np.int64)  # no lane change anywhere
    straight = M.confusion_matrix(true, np.zeros_like(true))
    assert M.macro_f1(straight) == 1.0  # left and right neither present nor predicted: left out
    for cls in (1, 2):
        pred = np.zeros_like(true)
        pred[3, 2] = cls  # one false lane-change step in 200
        conf = M.confusion_matrix(true, pred)
        f1 = M.f1_per_class(conf)
        assert f1[cls] == 0.0 and np.isnan(f1[3 - cls])  # predicted but absent: F1 = 0
        assert M.macro_f1(conf) == pytest.approx((2 * 199 / (2 * 199 + 1) + 0.0) / 2)
        assert M.macro_f1(conf) < M.macro_f1(straight)
        assert M.accuracy(conf) == pytest.approx(199 / 200)
        assert M.always_straight_accuracy(true) == 1.0
    np.testing.assert_array_equal(M.support(straight), [200, 0, 0])


def test_brier_score_by_hand() -> None:
    probs = np.array([[[0.7, 0.2, 0.1], [0.1, 0.8, 0.1]], [[1.0, 0.0, 0.0], [0.2, 0.2, 0.6]]])
    true = np.array([[0, 2], [0, -1]])  # the -1 step is skipped
    by_hand = [(0.3**2 + 0.2**2 + 0.1**2), (0.1**2 + 0.8**2 + 0.9**2), 0.0]
    assert M.brier_score(probs, true) == pytest.approx(np.mean(by_hand))
    uniform = np.full((1, 3, 3), 1 / 3)
    assert M.brier_score(uniform, np.array([[0, 1, 2]])) == pytest.approx(2 / 3)


def test_reliability_bins_by_hand() -> None:
    # class "left" (1): probabilities 0.05, 0.05 (never left), 0.95, 0.95 (left once of twice)
    p_left = np.array([0.05, 0.05, 0.95, 0.95])
    probs = np.stack([1 - p_left, p_left, np.zeros(4)], axis=-1)[None]  # [1, 4, 3]
    true = np.array([[0, 0, 1, 0]])
    rel = M.reliability(probs, true, bins=10)
    assert rel["count"][1, 0] == 2 and rel["count"][1, 9] == 2 and rel["count"][1].sum() == 4
    assert rel["confidence"][1, 9] == pytest.approx(0.95) and rel["frequency"][1, 9] == 0.5
    assert rel["frequency"][1, 0] == 0.0 and np.isnan(rel["frequency"][1, 5])
    assert rel["ece"][1] == pytest.approx((2 * 0.05 + 2 * 0.45) / 4)


def test_miss_rate_by_hand() -> None:
    err = np.array([[0.1, 0.5, 1.0, 1.5, 1.9], [0, 0, 0, 0, 2.0], [0, 0, 0, 0, 2.01], [9, 9, 9, 9, 0.0]])
    assert M.miss_rate(err) == 0.25  # only the 2.01 m final error exceeds 2 m (av2: FDE > 2 m)
    assert M.miss_rate(err, threshold_m=1.0) == 0.75  # 1.9, 2.0 and 2.01 exceed 1 m
    assert np.isnan(M.miss_rate(np.zeros((0, 5))))


def test_bootstrap_interval_is_seeded_and_brackets_the_rmse() -> None:
    err = np.random.default_rng(1).gamma(2.0, 0.5, size=(300, 5))
    low, high = M.rmse_ci(err, boots=400, seed=3)
    again = M.rmse_ci(err, boots=400, seed=3)
    np.testing.assert_array_equal(low, again[0])
    assert np.all(low < M.rmse(err)) and np.all(M.rmse(err) < high)
    assert np.all(high - low < 0.3 * M.rmse(err))
    assert np.all(np.isnan(M.rmse_ci(err[:1])[0]))


def test_summary_per_recording_and_probabilities() -> None:
    err = np.array([[1.0] * 5, [3.0] * 5, [2.0] * 5])
    pred, true = _errors_as_offsets(err)
    maneuver = np.array([[0] * 5, [0, 0, 1, 1, 1], [0] * 5])
    probs = np.zeros((3, 5, 3))
    probs[..., 0] = 1.0
    s = M.summary(
        pred,
        true,
        maneuver,
        np.array([1, 2, 3]),
        predicted_maneuver=np.zeros_like(maneuver),
        probs=probs,
        recording=np.array(["a", "b", "a"]),
        boots=50,
    )
    assert s["support"] == [12, 3, 0] and s["predicted"] == [15, 0, 0]
    assert s["f1"][2] is None and s["f1"][1] == 0.0
    assert s["brier"] == pytest.approx(3 * 2 / 15)  # three wrong steps, each (1² + 1²)
    assert s["always_straight_accuracy"] == pytest.approx(12 / 15)
    assert s["maneuver_accuracy"] == pytest.approx(12 / 15)
    assert s["miss_rate"] == pytest.approx(1 / 3)  # final errors 1, 3, 2 m: only 3 m > 2 m
    assert s["rmse_ci"]["level"] == 0.95 and len(s["rmse_ci"]["low"]) == 5
    assert s["per_recording"]["a"]["n_windows"] == 2 and s["per_recording"]["b"]["n_lane_change_windows"] == 1
    assert s["per_recording"]["a"]["rmse"] == pytest.approx([np.sqrt(2.5)] * 5)
    assert s["per_recording"]["a"]["maneuver_macro_f1"] == 1.0


def test_rmse_per_band_of_target_speed() -> None:
    # speeds at the band edges fall into the band above: 0.2 is creeping, 25 is fast
    speed = np.array([0.0, 0.19, 0.2, 1.0, 25.0, 40.0])
    err = np.array([[1.0] * 5, [3.0] * 5, [2.0] * 5, [4.0] * 5, [5.0] * 5, [7.0] * 5])
    bands = M.per_speed_band(err, speed)
    assert list(bands) == ["< 0.2 m/s", "0.2–2 m/s", "≥ 25 m/s"]  # empty bands left out, in order
    assert [b["n_windows"] for b in bands.values()] == [2, 2, 2]
    assert bands["< 0.2 m/s"]["rmse"] == pytest.approx([np.sqrt(5.0)] * 5)
    assert bands["≥ 25 m/s"]["rmse"] == pytest.approx([np.sqrt(37.0)] * 5)
    pred, true = _errors_as_offsets(err)
    s = M.summary(pred, true, np.zeros((6, 5), int), np.arange(6), speed=speed, boots=0)
    assert s["per_speed_band"] == bands
    assert M.summary(pred, true, np.zeros((6, 5), int), np.arange(6), boots=0)["per_speed_band"] is None


def test_paired_rmse_difference_finds_a_clear_difference_and_none_between_equals() -> None:
    rng = np.random.default_rng(3)
    base = rng.gamma(2.0, 1.0, size=2000)  # per-window squared errors of B
    better = base * 0.81  # A: every window 10 % smaller error (RMSE × 0.9)
    diff, low, high = M.paired_rmse_difference(better, base)
    assert diff == pytest.approx(np.sqrt(better.mean()) - np.sqrt(base.mean()))
    assert diff == pytest.approx(-0.1 * np.sqrt(base.mean()))
    assert low <= diff <= high < 0  # significant: the interval excludes 0
    same = M.paired_rmse_difference(base, base.copy())
    assert same == (0.0, 0.0, 0.0)  # the same errors: no difference in any resample
    shuffled = rng.permutation(base)  # the same errors on other windows: as often worse as better
    diff, lo, hi = M.paired_rmse_difference(shuffled, base)
    assert diff == pytest.approx(0.0, abs=1e-12) and lo < 0 < hi  # not significant
    assert all(math.isnan(v) for v in M.paired_rmse_difference(base[:1], base[:1])[1:])
    with pytest.raises(ValueError, match="one shape"):
        M.paired_rmse_difference(base, base[:-1])
