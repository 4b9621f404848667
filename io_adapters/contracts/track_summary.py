"""Per-recording figures of a track table (tracks, frames, duration, lane changes, vehicle classes).

The library behind ``lanecast info`` and the summary line of ``lanecast demo``.
"""

from __future__ import annotations

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc

from lanecast.io_adapters.contracts import track_table


def summarise(table: pa.Table) -> list[dict[str, object]]:
    """One dict per recording: tracks, rows, frames, duration (s), frame rate, lane changes, vehicles per class."""
    meta = track_table.read_meta(table)
    names = table.column("recording").cast(pa.string()).to_numpy(zero_copy_only=False)
    changes = np.zeros(table.num_rows, dtype=bool)
    changes[track_table.lane_change_rows(table)] = True
    starts = track_table.track_boundaries(table)
    out = []
    for name in sorted(meta.recordings):
        rows = names == name
        rate = meta.recordings[name].frame_rate
        frames = table.column("frame").to_numpy()[rows]
        first_rows = starts[:-1][rows[starts[:-1]]]
        classes = pc.value_counts(table.column("object_class").take(pa.array(first_rows)).cast(pa.string()))
        out.append(
            {
                "recording": name,
                "tracks": int(np.unique(table.column("track_id").to_numpy()[rows]).size),
                "rows": int(rows.sum()),
                "frames": int(np.unique(frames).size),
                "duration_s": float((frames.max() - frames.min() + 1) / rate) if frames.size else 0.0,
                "frame_rate": rate,
                "lane_changes": int(changes[rows].sum()),
                "classes": {c["values"]: c["counts"] for c in classes.to_pylist()},
            }
        )
    return out
