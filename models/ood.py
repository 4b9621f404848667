"""Where a model is valid: its training distribution and out-of-distribution flags (docs/design.md §4).

A model trained on free-flowing traffic says nothing reliable about a queue at 2 m/s. The card
records the distribution of the target's state at t0 over the training windows (speed, longitudinal
acceleration, neighbours present as a density proxy: percentiles, mean, std), and a window whose
target speed or acceleration lies outside the central ``RANGE`` percentiles of training is flagged,
in the forecasts table, in ``/lanecast/prediction`` and in reports.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from lanecast.io_adapters.contracts.windows import ROWS

TARGET_ROW = ROWS.index("T")
NEIGHBOUR_ROW_INDICES = [i for i, r in enumerate(ROWS) if r != "T"]
PERCENTILES = (0.5, 5.0, 25.0, 50.0, 75.0, 95.0, 99.5)
RANGE = ("p0.5", "p99.5")  # a window outside this range of any checked quantity is flagged
CHECKED = ("speed_mps", "lon_acc_mps2")


def target_speed(inputs: np.ndarray, rows: np.ndarray | None = None) -> np.ndarray:
    """The target's speed at t0 (m/s): inputs float32 [N, 4, 8, 30] → float64 [N], or [M] for the
    window indices ``rows`` int [M] (from a memory map, only those values are read)."""
    return np.asarray(inputs[slice(None) if rows is None else rows, 2, TARGET_ROW, -1], dtype=np.float64)


def target_state(inputs: np.ndarray, present: np.ndarray) -> dict[str, np.ndarray]:
    """The target's state at t0: inputs float32 [N, 4, 8, 30], present bool [N, 8, 30] →
    speed_mps, lon_acc_mps2 (float64 [N]) and neighbours_present (int64 [N], 0-7)."""
    return {
        "speed_mps": target_speed(inputs),
        "lon_acc_mps2": np.asarray(inputs[:, 3, TARGET_ROW, -1], dtype=np.float64),
        "neighbours_present": np.asarray(present[:, NEIGHBOUR_ROW_INDICES, -1]).sum(axis=1).astype(np.int64),
    }


def distribution(inputs: np.ndarray, present: np.ndarray) -> dict[str, dict[str, float]]:
    """Percentiles (``p0.5`` … ``p99.5``), mean and std of each target-state quantity over windows."""
    out: dict[str, dict[str, float]] = {}
    for name, values in target_state(inputs, present).items():
        v = values.astype(np.float64)
        if v.size == 0:
            continue
        q = np.percentile(v, PERCENTILES)
        out[name] = {f"p{p:g}": round(float(x), 4) for p, x in zip(PERCENTILES, q, strict=True)}
        out[name].update(mean=round(float(v.mean()), 4), std=round(float(v.std()), 4))
    return out


def out_of_distribution(
    inputs: np.ndarray, present: np.ndarray, training: dict[str, Any] | None
) -> np.ndarray | None:
    """bool [N]: the window's target speed or acceleration lies outside the training range
    (``RANGE`` percentiles of the card's distribution); None when the card has no distribution."""
    if not training:
        return None
    state = target_state(inputs, present)
    flags = np.zeros(len(inputs), dtype=bool)
    for name in CHECKED:
        d = training.get(name)
        if not d:
            continue
        lo, hi = d[RANGE[0]], d[RANGE[1]]
        flags |= (state[name] < lo) | (state[name] > hi)
    return flags
