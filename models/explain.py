"""What-if forecasts: the same window with neighbours removed, as in the paper's Figs. 4–5.

The paper removes a neighbour by setting its slot to zero ("absent"); here its rows of the physical
input are zeroed and its presence cleared, so after normalisation the network sees exactly the
zeros it sees when that neighbour is missing. The full scene and every what-if go through the
forecaster in one batch (so the full-scene forecast is the batch prediction's). The effect of a
removal is measured by how far the forecast trajectory moves (mean and 5 s displacement between the
two forecasts, m) and how much the maneuver probabilities change (largest absolute change over the
steps and classes); ``rank`` orders the removals by the trajectory shift.
Torch-free: any ``Forecaster`` (ST-CNN under torch or ONNX Runtime, or a baseline) will do.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from lanecast.io_adapters.contracts.windows import MANEUVERS, NEIGHBOUR_ROWS, ROWS
from lanecast.io_adapters.errors import InputError
from lanecast.models.predictions import Forecaster, Predictions

#: The neighbour slots, by name (every row but the target's).
NEIGHBOURS: tuple[str, ...] = NEIGHBOUR_ROWS


def remove_rows(
    inputs: np.ndarray, present: np.ndarray, rows: Sequence[int]
) -> tuple[np.ndarray, np.ndarray]:
    """The window without the vehicles in ``rows``: inputs float32 [4, 8, 30], present bool [8, 30] →
    copies with those rows zeroed in every channel and frame and marked absent."""
    out_inputs, out_present = np.array(inputs, np.float32), np.array(present, bool)
    out_inputs[:, list(rows)] = 0.0
    out_present[list(rows)] = False
    return out_inputs, out_present


def present_neighbours(present: np.ndarray) -> list[str]:
    """Names of the neighbour slots occupied at any history frame: present bool [8, 30]."""
    return [name for name in NEIGHBOURS if present[ROWS.index(name)].any()]


def parse_removals(spec: str, present: np.ndarray) -> list[tuple[str, ...]]:
    """``"F,RL,FL+F"`` → [("F",), ("RL",), ("FL", "F")]: comma-separated what-ifs, ``+`` removes
    several neighbours together. Every name must be a neighbour slot occupied in this window."""
    occupied = present_neighbours(present)
    removals: list[tuple[str, ...]] = []
    for group in spec.split(","):
        names = tuple(n.strip().upper() for n in group.split("+") if n.strip())
        if not names:
            continue
        for name in names:
            if name not in NEIGHBOURS:
                raise InputError(
                    None, f"no neighbour slot {name!r}", column="--remove", expected=", ".join(NEIGHBOURS)
                )
            if name not in occupied:
                raise InputError(
                    None,
                    f"slot {name} is empty in this window: there is nothing to remove",
                    column="--remove",
                    expected=", ".join(occupied) or "a window with neighbours",
                )
        removals.append(names)
    if not removals:
        raise InputError(
            None, f"--remove {spec!r} names no neighbour", column="--remove", expected="e.g. F,RL"
        )
    return removals


@dataclass
class WhatIf:
    """The full scene (index 0) and every what-if (1…S) of one window, forecast in one batch."""

    names: list[str]  # "full scene", "without F", "without FL + F", …
    removed: list[tuple[str, ...]]  # per scenario, the removed slots (empty for the full scene)
    inputs: np.ndarray  # float32 [S+1, 4, 8, 30] physical
    present: np.ndarray  # bool [S+1, 8, 30]
    predictions: Predictions  # of the S+1 scenarios

    def effects(self) -> list[dict[str, Any]]:
        """Per what-if (not the full scene): its change against the full scene, JSON-ready.

        shift_m [5]: distance between the two forecasts at 1–5 s (m); mean_shift_m, shift_5s_m;
        probability_change [5][3] (what-if − full, straight/left/right); max_probability_change;
        maneuver: the what-if's per-step maneuvers in words; maneuver_changed: whether any step differs.
        """
        p = self.predictions
        shift = np.hypot(*(p.offsets[1:] - p.offsets[:1]).transpose(2, 0, 1))  # [S, 5]
        out = []
        for s in range(1, len(self.names)):
            row: dict[str, Any] = {
                "scenario": self.names[s],
                "removed": list(self.removed[s]),
                "shift_m": [round(float(v), 4) for v in shift[s - 1]],
                "mean_shift_m": round(float(shift[s - 1].mean()), 4),
                "shift_5s_m": round(float(shift[s - 1, -1]), 4),
                "probability_change": None,
                "max_probability_change": None,
                "maneuver": None,
                "maneuver_changed": None,
            }
            if p.probs is not None and p.maneuver is not None:
                change = p.probs[s] - p.probs[0]
                row.update(
                    probability_change=np.round(change, 4).tolist(),
                    max_probability_change=round(float(np.abs(change).max()), 4),
                    maneuver=[MANEUVERS[int(m)] for m in p.maneuver[s]],
                    maneuver_changed=bool(np.any(p.maneuver[s] != p.maneuver[0])),
                )
            out.append(row)
        return out

    def rank(self) -> list[int]:
        """What-if indices (1…S) from the one that moved the forecast most (mean shift, then the
        largest probability change) to the least."""
        effects = self.effects()
        key = [(-e["mean_shift_m"], -(e["max_probability_change"] or 0.0)) for e in effects]
        return [1 + i for i in sorted(range(len(effects)), key=lambda i: key[i])]


def what_if(
    forecaster: Forecaster,
    inputs: np.ndarray,
    present: np.ndarray,
    removals: Sequence[tuple[str, ...]],
    *,
    top_k: int = 3,
) -> WhatIf:
    """Forecast one window (inputs float32 [4, 8, 30], present bool [8, 30]) as it is and with each
    group of neighbours in ``removals`` removed, in one batch."""
    scenes = [(np.asarray(inputs, np.float32), np.asarray(present, bool))]
    for names in removals:
        scenes.append(remove_rows(inputs, present, [ROWS.index(n) for n in names]))
    batch_inputs = np.stack([s[0] for s in scenes])
    batch_present = np.stack([s[1] for s in scenes])
    preds = forecaster.predict(batch_inputs, batch_present, top_k=top_k)
    return WhatIf(
        names=["full scene", *(f"without {' + '.join(n)}" for n in removals)],
        removed=[(), *(tuple(n) for n in removals)],
        inputs=batch_inputs,
        present=batch_present,
        predictions=preds,
    )


def what_if_all(
    forecaster: Forecaster, inputs: np.ndarray, present: np.ndarray, *, batch_size: int = 4096
) -> tuple[np.ndarray, np.ndarray, Predictions]:
    """Every window with each of its occupied neighbour slots removed in turn, in one prediction.

    inputs float32 [N, 4, 8, 30], present bool [N, 8, 30] → (window index int64 [M], removed slot
    int64 [M] (index into NEIGHBOURS), Predictions of the M what-ifs, top-1), ordered by window and
    slot; M is the number of occupied (window, slot) pairs.
    """
    slot_rows = np.array([ROWS.index(n) for n in NEIGHBOURS])
    occupied = np.asarray(present)[:, slot_rows].any(axis=2)  # [N, 7]
    window, slot = np.nonzero(occupied)
    cut_inputs = np.array(inputs[window], np.float32)
    cut_present = np.array(present[window], bool)
    m = np.arange(len(window))
    cut_inputs[m, :, slot_rows[slot]] = 0.0
    cut_present[m, slot_rows[slot]] = False
    preds = forecaster.predict(cut_inputs, cut_present, top_k=1, batch_size=batch_size)
    return window.astype(np.int64), slot.astype(np.int64), preds
