"""The forecasts table's contract: what forecasts_table builds, and the checks every reader runs."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyarrow as pa
import pytest

from lanecast.io_adapters.contracts import forecasts
from lanecast.io_adapters.contracts.windows import INDEX_SCHEMA
from lanecast.io_adapters.errors import InputError
from lanecast.io_adapters.logs.forecast_batch import batch_from_table
from lanecast.models.forecasts_from_predictions import forecasts_table
from lanecast.models.predictions import Predictions


def _predictions(n: int, k: int, classifier: bool) -> Predictions:
    rng = np.random.default_rng(0)
    probs = rng.dirichlet(np.ones(3), size=(n, forecasts.N_STEPS)).astype(np.float32)
    return Predictions(
        offsets=rng.normal(size=(n, forecasts.N_STEPS, 2)).astype(np.float32),
        probs=probs if classifier else None,
        maneuver=probs.argmax(-1).astype(np.int64) if classifier else None,
        top_sequences=rng.integers(0, 3, size=(n, k, forecasts.N_STEPS)) if classifier else None,
        top_probs=np.full((n, k), 1.0 / k, np.float32),
        top_offsets=rng.normal(size=(n, k, forecasts.N_STEPS, 2)).astype(np.float32),
    )


def _index(n: int) -> pa.Table:
    return pa.table(
        {
            "recording": ["r"] * n,
            "track_id": np.arange(n, dtype=np.int64),
            "t0_ns": np.full(n, 10**9, np.int64),
            "split": ["none"] * n,
            "origin_x": np.arange(n, dtype=np.float64),
            "origin_y": np.zeros(n),
            "origin_heading": np.full(n, np.pi / 2),
        },
        schema=INDEX_SCHEMA,
    )


@pytest.mark.parametrize("classifier", [True, False])
def test_forecasts_table_is_in_the_contract_schema(classifier: bool) -> None:
    preds = _predictions(4, 2, classifier)
    table = forecasts_table(_index(4), preds)
    assert table.schema == forecasts.SCHEMA
    forecasts.validate(table)
    # heading pi/2: a window-frame offset (dx, dy) lands at origin + (-dy, dx)
    x = np.array(table.column("x").to_pylist())
    np.testing.assert_allclose(x, np.arange(4)[:, None] - preds.offsets[..., 1], atol=1e-5)
    assert table.column("horizon_s")[0].as_py() == [1.0, 2.0, 3.0, 4.0, 5.0]
    assert table.column("maneuver").null_count == (0 if classifier else 4)
    batch = batch_from_table(table, frame_id="map")
    assert batch.points.shape == (4, forecasts.N_STEPS, 2) and batch.alt_points.shape == (4, 2, 5, 2)
    np.testing.assert_allclose(batch.origin[:, 0], np.arange(4))


def test_a_table_lacking_a_required_column_is_named(tmp_path: Path) -> None:
    table = forecasts_table(_index(2), _predictions(2, 1, True)).drop_columns(["maneuver"])
    with pytest.raises(InputError, match=r"f.parquet, column 'maneuver': forecasts table lacks a column"):
        forecasts.validate(table, tmp_path / "f.parquet")
    with pytest.raises(InputError, match="forecasts table lacks a column"):
        batch_from_table(table, frame_id="map")


def test_a_point_that_is_not_finite_is_named_with_its_row() -> None:
    table = forecasts_table(_index(3), _predictions(3, 1, True))
    y = table.column("y").to_pylist()
    y[2][3] = float("nan")
    table = table.set_column(
        table.schema.get_field_index("y"), "y", pa.array(y, forecasts.SCHEMA.field("y").type)
    )
    with pytest.raises(InputError, match=r"column 'y': row 2: forecast point .*finite coordinates in metres"):
        forecasts.validate(table)
