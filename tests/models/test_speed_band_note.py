"""A band of target speed is called worse than constant velocity only when its intervals say so."""

from __future__ import annotations

import numpy as np

from lanecast.models.evaluation import speed_band_note
from lanecast.models.metrics import per_speed_band


def test_one_window_worse_is_not_called_worse_but_many_clearly_worse_are() -> None:
    rng = np.random.default_rng(0)
    speed = np.r_[np.full(300, 20.0), 1.0]  # 300 windows flowing, one creeping
    cv_err = rng.normal(0, 1.0, (301, 5, 2))
    model_err = cv_err * 0.8
    model_err[-1] *= 3.0  # the lone creeping window: 2.4x constant velocity's error
    bands_cv = per_speed_band(np.linalg.norm(cv_err, axis=2), speed)
    bands_model = per_speed_band(np.linalg.norm(model_err, axis=2), speed)
    assert bands_model["0.2–2 m/s"]["rmse_ci"]["low"] == [None] * 5  # one window: no interval
    note = speed_band_note({"stcnn": {"per_speed_band": bands_model}, "cv": {"per_speed_band": bands_cv}})
    assert note is not None and note.startswith("no worse than constant velocity")
    assert "within the 95 % intervals (too few windows to tell) at 0.2–2 m/s (1 window;" in note

    model_err[:300] *= 1.5  # now 1.2x constant velocity on 300 windows: beyond the intervals
    bands_model = per_speed_band(np.linalg.norm(model_err, axis=2), speed)
    note = speed_band_note({"stcnn": {"per_speed_band": bands_model}, "cv": {"per_speed_band": bands_cv}})
    assert note is not None and note.startswith(
        "worse than constant velocity at some horizon for targets at 16–25 m/s (300 windows"
    )
