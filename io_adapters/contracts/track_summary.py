"""Per-recording figures of a track table (tracks, frames, duration, lane changes, vehicle classes).

The library behind ``lanecast info`` and the summary line of ``lanecast demo``.
"""

from __future__ import annotations

import numpy as np
import pyarrow as pa

from lanecast.io_adapters.arrow_numpy import dictionary_codes
from lanecast.io_adapters.contracts import track_table


def summarise(table: pa.Table) -> list[dict[str, object]]:
    """One dict per recording: tracks, rows, frames, duration (s), frame rate, lane changes, vehicles per class."""
    meta = track_table.read_meta(table)
    rec_names, rec_codes = track_table.recording_codes(table)
    class_names, class_codes = dictionary_codes(table.column("object_class"))
    changes = np.zeros(table.num_rows, dtype=bool)
    changes[track_table.lane_change_rows(table)] = True
    starts = track_table.track_boundaries(table)[:-1]
    code_of = {name: code for code, name in enumerate(rec_names.tolist())}
    all_frames, track_ids = table.column("frame").to_numpy(), table.column("track_id").to_numpy()
    out = []
    for name in sorted(meta.recordings):
        rows = rec_codes == code_of.get(name, -1)  # a recording without rows: none
        rate = meta.recordings[name].frame_rate
        frames = all_frames[rows]
        vehicles = np.bincount(class_codes[starts[rows[starts]]], minlength=class_names.size)
        out.append(
            {
                "recording": name,
                "tracks": int(np.unique(track_ids[rows]).size),
                "rows": int(rows.sum()),
                "frames": int(np.unique(frames).size),
                "duration_s": float((frames.max() - frames.min() + 1) / rate) if frames.size else 0.0,
                "frame_rate": rate,
                "lane_changes": int(changes[rows].sum()),
                "classes": {str(c): int(n) for c, n in zip(class_names, vehicles, strict=True) if n},
            }
        )
    return out
