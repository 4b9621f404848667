"""The forecasts table: ``Predictions`` (window frame) mapped to the source frame, one row per window.

Torch-free, shared by every engine: torch (``lanecast.models.predict``), ONNX Runtime
(``lanecast.models.onnx_predict``) and the kinematic baselines (``lanecast.models.baselines``).
"""

from __future__ import annotations

import numpy as np
import pyarrow as pa

from lanecast.io_adapters.contracts.window_frame import to_source_frame
from lanecast.io_adapters.contracts.windows import HORIZON_S
from lanecast.io_adapters.errors import InputError
from lanecast.models.predictions import Predictions


def forecasts_table(index: pa.Table, preds: Predictions) -> pa.Table:
    """Forecasts in the source frame, one row per window.

    index: the windows' index (recording, track_id, t0_ns, origin_x, origin_y, origin_heading).
    Columns: recording, track_id, t0_ns, horizon_s list[5], x, y list[5] (m, source frame),
    maneuver_probs list[5] of list[3] (straight, left, right; null for baselines), maneuver list[5]
    (null for baselines), the K alternatives: alt_probs list[K], alt_maneuvers list[K] of list[5],
    alt_x, alt_y list[K] of list[5], and origin_x, origin_y (m, source frame): the target's centre
    at t0, where the drawn line starts (kept from the window, never interpolated again), and
    out_of_distribution (bool: the target's state lies outside the model's training distribution;
    null where unknown, e.g. baselines).
    """
    n = index.num_rows
    ox, oy, heading = (index.column(c).to_numpy() for c in ("origin_x", "origin_y", "origin_heading"))
    xy = to_source_frame(preds.offsets, ox, oy, heading)  # [N, 5, 2]
    alt = to_source_frame(preds.top_offsets, ox, oy, heading)  # [N, K, 5, 2]
    bad = ~np.isfinite(alt).all(axis=(1, 2, 3)) | ~np.isfinite(xy).all(axis=(1, 2))
    if bad.any():  # a forecast is never NaN (nor written as NaN into a log)
        i = int(np.flatnonzero(bad)[0])
        raise InputError(
            None,
            f"{int(bad.sum()):,} of {n:,} windows give forecasts that are not finite (first: recording "
            f"{index.column('recording')[i]}, track {index.column('track_id')[i]}, t0 {index.column('t0_ns')[i]} ns)",
            expected="positions and speeds the model's normalisation can represent",
        )
    horizon = np.broadcast_to(np.asarray(HORIZON_S, np.float32), (n, len(HORIZON_S)))
    columns: dict[str, pa.Array] = {
        "recording": index.column("recording").combine_chunks(),
        "track_id": index.column("track_id").combine_chunks(),
        "t0_ns": index.column("t0_ns").combine_chunks(),
        "horizon_s": nested(horizon),
        "x": nested(xy[..., 0]),
        "y": nested(xy[..., 1]),
        "maneuver_probs": nested(preds.probs, n, (5, 3), pa.float32()),
        "maneuver": nested(preds.maneuver, n, (5,), pa.int8()),
        "alt_probs": nested(preds.top_probs),
        "alt_maneuvers": nested(preds.top_sequences, n, (preds.top_probs.shape[1], 5), pa.int8()),
        "alt_x": nested(alt[..., 0]),
        "alt_y": nested(alt[..., 1]),
        "origin_x": pa.array(ox, pa.float64()),
        "origin_y": pa.array(oy, pa.float64()),
        "out_of_distribution": pa.array(preds.out_of_distribution, pa.bool_())
        if preds.out_of_distribution is not None
        else pa.nulls(n, pa.bool_()),
    }
    return pa.table(columns)


def nested(
    values: np.ndarray | None, n: int = 0, shape: tuple[int, ...] = (), dtype: pa.DataType | None = None
) -> pa.Array:
    """An [N, a, b, …] array as N rows of nested lists (all null when ``values`` is None)."""
    if values is None:
        inner: pa.DataType = dtype or pa.float32()
        for _ in shape:
            inner = pa.list_(inner)
        return pa.nulls(n, inner)
    flat: pa.Array = pa.array(np.ascontiguousarray(values).reshape(-1), type=dtype)
    for size in reversed(values.shape[1:]):
        count = len(flat) // size
        flat = pa.ListArray.from_arrays(pa.array(np.arange(count + 1, dtype=np.int32) * size), flat)
    return flat
