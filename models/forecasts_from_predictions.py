"""The forecasts table: ``Predictions`` (window frame) mapped to the source frame, one row per window.

Torch-free, shared by every engine: torch (``lanecast.models.predict``), ONNX Runtime
(``lanecast.models.onnx_predict``) and the kinematic baselines (``lanecast.models.baselines``).
"""

from __future__ import annotations

import numpy as np
import pyarrow as pa

from lanecast.io_adapters.contracts import forecasts
from lanecast.io_adapters.contracts.window_frame import to_source_frame
from lanecast.io_adapters.contracts.windows import HORIZON_S
from lanecast.io_adapters.errors import InputError
from lanecast.models.predictions import Predictions


def forecasts_table(index: pa.Table, preds: Predictions) -> pa.Table:
    """Forecasts in the source frame, one row per window, in the forecasts contract's schema
    (``lanecast.io_adapters.contracts.forecasts``).

    index: the windows' index (recording, track_id, t0_ns, origin_x, origin_y, origin_heading).
    ``origin_x``/``origin_y`` are kept from the window (the drawn line starts there, never
    interpolated again).
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
    arrays: dict[str, np.ndarray | None] = {
        "horizon_s": horizon,
        "x": xy[..., 0],
        "y": xy[..., 1],
        "maneuver_probs": preds.probs,
        "maneuver": preds.maneuver,
        "alt_probs": preds.top_probs,
        "alt_maneuvers": preds.top_sequences,
        "alt_x": alt[..., 0],
        "alt_y": alt[..., 1],
        "origin_x": ox,
        "origin_y": oy,
        "out_of_distribution": preds.out_of_distribution,
    }
    columns = [
        index.column(f.name).combine_chunks().cast(f.type)
        if f.name in ("recording", "track_id", "t0_ns")
        else forecasts.list_column(arrays[f.name], n, f.type)
        for f in forecasts.SCHEMA
    ]
    return pa.Table.from_arrays(columns, schema=forecasts.SCHEMA)
