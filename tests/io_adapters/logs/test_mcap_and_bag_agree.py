"""One track table written as MCAP and as a ROS 2 bag reads back as the same table, kinematics included,
so the same data scores the same in either log."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyarrow as pa

from lanecast.io_adapters.datasets.highd import reader as highd
from lanecast.io_adapters.formats import registry


def _sorted(table: pa.Table) -> dict[str, np.ndarray]:
    recording = table.column("recording").cast(pa.string()).to_numpy(zero_copy_only=False)
    order = np.lexsort((table.column("frame").to_numpy(), table.column("track_id").to_numpy(), recording))
    return {
        c: np.asarray(
            table.column(c).cast(pa.string()) if c in ("recording", "object_class") else table.column(c)
        )[order]
        for c in table.column_names
    }


def test_mcap_and_ros2_bag_of_one_table_read_back_equal(sim_recording_dir: Path, tmp_path: Path) -> None:
    source = highd.read([sim_recording_dir])
    mcap = registry.write_any(source, tmp_path / "sim.mcap", "mcap")
    bag = registry.write_any(source, tmp_path / "sim-bag", "ros2")
    original, from_mcap, from_bag = (
        _sorted(t) for t in (source, registry.read_any([mcap]), registry.read_any([bag]))
    )
    for column in ("lane_id", "object_class"):
        np.testing.assert_array_equal(from_mcap[column], from_bag[column], err_msg=column)
    kinematics = ("x", "y", "heading", "vx", "vy", "ax", "ay", "length", "width")
    for column in kinematics:  # bags: body frame and back
        np.testing.assert_allclose(from_mcap[column], from_bag[column], rtol=1e-6, atol=1e-6, err_msg=column)
    for column in ("ax", "ay"):  # the table's own accelerations, not velocity differences
        np.testing.assert_allclose(from_mcap[column], original[column], rtol=1e-6, atol=1e-6, err_msg=column)
