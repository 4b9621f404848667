"""The forecasts table: one row per target and forecast time t0, in the source frame of the track
table; what ``predict`` and ``annotate`` write and what the log encoders read (docs/design.md).

Columns (:data:`SCHEMA`): ``recording``, ``track_id``, ``t0_ns``; ``horizon_s`` [5] (s after t0);
``x``, ``y`` [5] (m); ``maneuver_probs`` [5][3] (straight, left, right) and ``maneuver`` [5], null
for forecasters without a classifier (the kinematic baselines); the K alternatives ``alt_probs``
[K], ``alt_maneuvers`` [K][5], ``alt_x``, ``alt_y`` [K][5]; ``origin_x``, ``origin_y`` (m: the
target's centre at t0, where a drawn line starts); ``out_of_distribution`` (null where unknown).
A table another tool wrote needs :data:`REQUIRED` only; what-if forecasts add ``removed_slot``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc

from lanecast.io_adapters.contracts.windows import HORIZONS, MANEUVERS
from lanecast.io_adapters.errors import InputError

N_STEPS = HORIZONS  # forecast steps, 1 s apart
N_CLASSES = len(MANEUVERS)
_FLOATS, _POINTS, _CODES = pa.list_(pa.float32()), pa.list_(pa.float64()), pa.list_(pa.int8())
SCHEMA = pa.schema(
    [
        pa.field("recording", pa.string()),
        pa.field("track_id", pa.int64()),
        pa.field("t0_ns", pa.int64()),
        pa.field("horizon_s", _FLOATS),
        pa.field("x", _POINTS),
        pa.field("y", _POINTS),
        pa.field("maneuver_probs", pa.list_(_FLOATS)),
        pa.field("maneuver", _CODES),
        pa.field("alt_probs", _FLOATS),
        pa.field("alt_maneuvers", pa.list_(_CODES)),
        pa.field("alt_x", pa.list_(_POINTS)),
        pa.field("alt_y", pa.list_(_POINTS)),
        pa.field("origin_x", pa.float64()),
        pa.field("origin_y", pa.float64()),
        pa.field("out_of_distribution", pa.bool_()),
    ]
)
#: The columns every forecasts table has (the others have defaults where they are missing).
REQUIRED: tuple[str, ...] = ("recording", "track_id", "t0_ns", "x", "y", "maneuver_probs", "maneuver")
REMOVED_SLOT = "removed_slot"  # what-if forecasts: the neighbour slot removed (int)


def list_column(values: np.ndarray | None, n: int, type_: pa.DataType) -> pa.Array:
    """An [N, a, b, …] array as N rows of (nested) lists of ``type_`` (all null when ``values`` is None)."""
    if values is None:
        return pa.nulls(n, type_)
    leaf = type_
    while pa.types.is_list(leaf):
        leaf = leaf.value_type
    flat: pa.Array = pa.array(np.ascontiguousarray(values).reshape(-1), type=leaf)
    for size in reversed(values.shape[1:]):
        count = len(flat) // size
        flat = pa.ListArray.from_arrays(pa.array(np.arange(count + 1, dtype=np.int32) * size), flat)
    return flat


def check_columns(table: pa.Table, source: str | Path | None = None) -> None:
    """InputError naming the first of :data:`REQUIRED` the table lacks."""
    for name in REQUIRED:
        if name not in table.column_names:
            raise InputError(source, "forecasts table lacks a column", column=name)


def validate(table: pa.Table, source: str | Path | None = None) -> None:
    """The required columns, and forecast points ``x``, ``y`` that are lists of finite numbers:
    InputError naming ``source``, the column and the first bad row (a NaN point written into a log
    draws nothing and says nothing)."""
    check_columns(table, source)
    for name in ("x", "y"):
        column = table.column(name)
        if not (pa.types.is_list(column.type) or pa.types.is_fixed_size_list(column.type)):
            raise InputError(source, f"a {column.type} column", column=name, expected="lists of 5 numbers")
        values = pc.list_flatten(column)
        lengths = pc.list_value_length(column).fill_null(0).to_numpy(zero_copy_only=False)
        numbers = values.cast(pa.float64()).fill_null(np.nan).to_numpy(zero_copy_only=False)
        bad = ~np.isfinite(numbers)
        null_rows = np.asarray(column.is_null())
        if bad.any() or null_rows.any():
            row_of = np.repeat(np.arange(table.num_rows), lengths)
            row = int(np.concatenate([row_of[bad], np.flatnonzero(null_rows)]).min())
            raise InputError(
                source,
                f"row {row}: forecast point {column[row].as_py()}",
                column=name,
                expected="finite coordinates in metres",
            )
