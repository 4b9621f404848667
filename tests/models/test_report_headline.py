"""Reports lead with the answer: the model's RMSE at 5 s beside constant velocity's, and flags for a
classifier that never predicts a class or is below always-straight."""

from __future__ import annotations

from typing import Any

from lanecast.models.reports.tables import headline


def _summary(rmse5: float, **maneuvers: Any) -> dict[str, Any]:
    return {
        "rmse": [0.1, 0.4, 0.8, 1.3, rmse5],
        "rmse_ci": {"low": [None] * 4 + [rmse5 - 0.1], "high": [None] * 4 + [rmse5 + 0.1], "level": 0.95},
        "n_windows": 1234,
        "predicted": None,
        "support": None,
        "maneuver_accuracy": None,
        "always_straight_accuracy": 0.9,
        **maneuvers,
    }


def test_the_headline_gives_the_model_against_constant_velocity_on_its_windows() -> None:
    metrics = {"stcnn": _summary(2.0), "cv": _summary(2.5), "ca": _summary(3.0), "meta": {}}
    assert headline(metrics) == [
        "ST-CNN (maneuver-based): RMSE at 5 s 2.00 m (95 % interval 1.90–2.10), 0.80× constant velocity's "
        "2.50 m, on 1,234 windows."
    ]


def test_a_class_never_predicted_and_an_accuracy_below_always_straight_are_flagged() -> None:
    stcnn = _summary(2.0, predicted=[5000, 300, 0], support=[4800, 250, 200], maneuver_accuracy=0.85)
    lines = headline({"stcnn": stcnn, "cv": _summary(2.5)})
    assert "ST-CNN (maneuver-based) never predicts 'right', which the data holds." in lines
    assert (
        "ST-CNN (maneuver-based)'s maneuver accuracy 0.850 is below always predicting straight (0.900)."
        in lines
    )
    fine = _summary(2.0, predicted=[4800, 250, 200], support=[4800, 250, 200], maneuver_accuracy=0.95)
    assert len(headline({"stcnn": fine, "cv": _summary(2.5)})) == 1
