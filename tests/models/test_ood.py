"""Out-of-distribution flags: the card's training distribution, flags per window, and where they show."""

from __future__ import annotations

import json

import numpy as np
import pyarrow as pa

from lanecast.models.forecasts_from_predictions import forecasts_table
from lanecast.models.ood import distribution, out_of_distribution, target_state
from lanecast.models.predictions import Predictions


def windows_at(speed: np.ndarray, acc: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    n = speed.size
    inputs = np.zeros((n, 4, 8, 30), np.float32)
    present = np.zeros((n, 8, 30), bool)
    inputs[:, 2, 4, :] = speed[:, None]
    inputs[:, 3, 4, :] = acc[:, None]
    present[:, 4] = True
    present[: n // 2, 1] = True  # F present in the first half
    return inputs, present


def test_distribution_and_flags() -> None:
    rng = np.random.default_rng(0)
    speed = rng.uniform(20.0, 35.0, 2000)
    acc = rng.normal(0.0, 0.5, 2000)
    inputs, present = windows_at(speed, acc)
    dist = distribution(inputs, present)
    assert 20.0 <= dist["speed_mps"]["p0.5"] < 20.2 and 34.8 < dist["speed_mps"]["p99.5"] <= 35.0
    assert dist["neighbours_present"]["p25"] == 0.0 and dist["neighbours_present"]["p75"] == 1.0
    test_in, test_present = windows_at(np.array([8.3, 27.0, 27.0, 50.0]), np.array([0.0, 0.0, -4.0, 0.0]))
    flags = out_of_distribution(test_in, test_present, dist)
    assert flags is not None
    assert flags.tolist() == [True, False, True, True]  # queue speed, normal, hard braking, too fast
    assert out_of_distribution(test_in, test_present, None) is None
    state = target_state(test_in, test_present)
    assert state["speed_mps"].tolist() == [8.300000190734863, 27.0, 27.0, 50.0]


def three_forecasts() -> tuple[pa.Table, Predictions]:
    """A windows index of three targets at one t0 and their predictions, the second flagged."""
    n = 3
    preds = Predictions(
        offsets=np.zeros((n, 5, 2), np.float32),
        probs=np.full((n, 5, 3), 1 / 3, np.float32),
        maneuver=np.zeros((n, 5), np.int64),
        top_sequences=np.zeros((n, 1, 5), np.int64),
        top_probs=np.ones((n, 1), np.float32),
        top_offsets=np.zeros((n, 1, 5, 2), np.float32),
        out_of_distribution=np.array([False, True, False]),
    )
    index = pa.table(
        {
            "recording": ["r"] * n,
            "track_id": pa.array([1, 2, 3], pa.int64()),
            "t0_ns": pa.array([0, 0, 0], pa.int64()),
            "origin_x": [0.0, 10.0, 20.0],
            "origin_y": [0.0, 0.0, 0.0],
            "origin_heading": [0.0, 0.0, 0.0],
        }
    )
    return index, preds


def test_flags_reach_the_forecasts_table() -> None:
    index, preds = three_forecasts()
    n = index.num_rows
    table = forecasts_table(index, preds)
    assert table.column("out_of_distribution").to_pylist() == [False, True, False]
    preds.out_of_distribution = None  # baselines: unknown
    table = forecasts_table(index, preds)
    assert table.column("out_of_distribution").null_count == n


def test_flags_reach_the_prediction_message() -> None:
    from lanecast.io_adapters.logs.forecast_messages import frames_from_table, prediction_dict

    index, preds = three_forecasts()
    doc = prediction_dict(next(iter(frames_from_table(forecasts_table(index, preds), frame_id="map"))))
    assert [t["out_of_distribution"] for t in doc["targets"]] == [False, True, False]
    preds.out_of_distribution = None  # baselines: unknown
    doc = prediction_dict(next(iter(frames_from_table(forecasts_table(index, preds), frame_id="map"))))
    assert [t["out_of_distribution"] for t in doc["targets"]] == [None, None, None]
    json.dumps(doc)
