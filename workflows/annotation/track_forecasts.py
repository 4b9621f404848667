"""Forecasts for a track table (a library for the commands that predict, e.g. annotating drive logs).

track table → windows without requiring a future (``lanecast.pipeline.make_windows``) → ST-CNN in batches
(``lanecast.models.runtime``: ONNX Runtime, else torch) → one row per (track, t0) with the 5 future points in the source's own frame.
This module is not a command: it has no ``register``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyarrow as pa

from lanecast.io_adapters.contracts.windows import Windows
from lanecast.io_adapters.errors import InputError
from lanecast.models.explain import what_if_all
from lanecast.models.forecasts_from_predictions import forecasts_table
from lanecast.models.predictions import Forecaster
from lanecast.models.runtime import load_forecaster
from lanecast.pipeline.make_windows import make_windows
from lanecast.pipeline.neighbour_columns import NEIGHBOUR_RANGE_M

#: Rate of the windows (Hz); ``every_s`` is converted to a stride in these frames.
WINDOW_RATE_HZ = 10.0


def forecast_windows(
    windows: Windows,
    model_dir: Path | str | None = None,
    *,
    top_k: int = 3,
    batch_size: int = 4096,
    forecaster: Forecaster | None = None,
) -> pa.Table:
    """Forecasts table for ready windows (see ``lanecast.models.forecasts_from_predictions.forecasts_table`` for the columns)."""
    forecaster = forecaster or load_forecaster(model_dir)
    preds = forecaster.predict(windows.inputs, windows.present, top_k=top_k, batch_size=batch_size)
    return forecasts_table(windows.index, preds)


def forecast_table(
    table: pa.Table,
    model_dir: Path | str | None = None,
    *,
    every_s: float = 1.0,
    top_k: int = 3,
    batch_size: int = 4096,
    t0_ns: np.ndarray | None = None,
    forecaster: Forecaster | None = None,
    validated: bool = False,
) -> pa.Table:
    """Forecast every target with 3 s of history, every ``every_s`` seconds of its track.

    table: a track table (any rate, validated by make_windows unless ``validated``: a reader's
    table is, and is not checked twice). model_dir: a model directory or file
    (None: the shipped model); ``forecaster`` (an already loaded forecaster or baseline)
    takes precedence. ``t0_ns``: forecast only at these times instead.
    Returns columns recording, track_id, t0_ns, horizon_s list[5] (s), x, y list[5] (m, source frame),
    maneuver_probs list[5] of list[3] (straight, left, right), maneuver list[5] (0 straight, 1 left,
    2 right), alt_probs list[K], alt_maneuvers list[K] of list[5], alt_x, alt_y list[K] of list[5]
    (the K most probable maneuver sequences and their trajectories, most probable first), origin_x,
    origin_y (the target's centre at t0).
    An empty table (0 rows, same columns) when no target has 3 s of history.
    """
    forecaster = forecaster or load_forecaster(model_dir)
    windows = windows_to_forecast(table, forecaster, every_s=every_s, t0_ns=t0_ns, validated=validated)
    return forecast_windows(windows, model_dir, top_k=top_k, batch_size=batch_size, forecaster=forecaster)


def windows_to_forecast(
    table: pa.Table,
    forecaster: Forecaster,
    *,
    every_s: float = 1.0,
    t0_ns: np.ndarray | None = None,
    validated: bool = False,
) -> Windows:
    """The windows ``forecast_table`` predicts: every ``every_s`` seconds (or at ``t0_ns``), no future
    needed, neighbours within the model card's range."""
    stride = round(every_s * WINDOW_RATE_HZ)
    if stride < 1:
        raise InputError(None, f"every_s={every_s}", expected=f"at least {1 / WINDOW_RATE_HZ:g} s")
    card = getattr(forecaster, "card", None) or {}
    neighbour_range = (card.get("windows") or {}).get("neighbour_range_m") or NEIGHBOUR_RANGE_M
    return make_windows(
        table,
        stride=stride,
        require_future=False,
        split="none",
        t0_ns=t0_ns,
        allow_empty=True,
        neighbour_range=float(neighbour_range),
        validated=validated,
    )


def what_if_table(windows: Windows, forecaster: Forecaster, *, batch_size: int = 4096) -> pa.Table:
    """What-if forecasts (``lanecast.models.explain.what_if_all``): one row per window and occupied
    neighbour slot, the forecast with that neighbour removed, in the columns of a forecasts table plus
    ``removed_slot`` (int8, index into the neighbour slots FL F FR L R RL RR)."""
    window, slot, preds = what_if_all(forecaster, windows.inputs, windows.present, batch_size=batch_size)
    table = forecasts_table(windows.index.take(pa.array(window)), preds)
    return table.append_column("removed_slot", pa.array(slot.astype(np.int8)))
