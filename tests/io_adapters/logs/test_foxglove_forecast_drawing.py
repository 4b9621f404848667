"""The Foxglove drawing of forecasts: an alternative on the main forecast's path is not drawn over it."""

from __future__ import annotations

import numpy as np
import pyarrow as pa
from conftest import forecasts_for

from lanecast.io_adapters.logs.forecast_batch import batch_from_table
from lanecast.io_adapters.logs.foxglove.forecast_drawing import ALT_ALPHA, MAIN_ALPHA, drawing_of


def test_an_alternative_on_the_main_path_is_transparent_and_the_others_are_drawn() -> None:
    table = forecasts_for("rec", [3, 4], [1, 2], k=2)
    alt_x = [[x, x] for x in table.column("x").to_pylist()]
    alt_y = [[y, [v + 1.0 for v in y]] for y in table.column("y").to_pylist()]  # first = main line
    table = table.set_column(table.schema.get_field_index("alt_x"), "alt_x", pa.array(alt_x))
    table = table.set_column(table.schema.get_field_index("alt_y"), "alt_y", pa.array(alt_y))
    drawing = drawing_of(batch_from_table(table, frame_id="map"))
    np.testing.assert_array_equal(drawing.rgba[:, 0, 3], MAIN_ALPHA)
    np.testing.assert_array_equal(drawing.rgba[:, 1, 3], 0.0)
    np.testing.assert_array_equal(drawing.rgba[:, 2, 3], ALT_ALPHA)
