"""The highD reader of large recordings (read in pieces) gives the table of the whole read."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from conftest import _highd

from lanecast.io_adapters.contracts import track_table
from lanecast.io_adapters.datasets.highd import reader as highd
from lanecast.io_adapters.datasets.highd import stream as highd_stream


def test_a_highd_row_moved_to_the_end_reads_the_same_in_pieces(tmp_path: Path) -> None:
    """One row of vehicle 1 moved to the end of the file: the whole read sorts it back; read in
    pieces (a recording of 256 MiB and more) the block with vehicle 1's other rows was refused
    ("numFrames 60 … disagrees … 59 rows") although the whole file reads cleanly. Now the pieces
    read gives the whole read's table."""
    path = _highd(tmp_path)
    lines = path.read_text().splitlines()
    path.write_text("\n".join([*lines[:10], *lines[11:], lines[10]]) + "\n")
    whole = highd.read([path])
    (tmp_path / "spill").mkdir()
    spills = highd_stream.split_tracks(highd.recordings([path])[0], tmp_path / "spill", block_bytes=1 << 10)
    streamed = track_table.concat([track_table.read_parquet(p) for p in spills])
    assert streamed.num_rows == whole.num_rows == 120
    for name in ("x", "vx", "track_id", "frame"):
        np.testing.assert_array_equal(streamed.column(name).to_numpy(), whole.column(name).to_numpy())
