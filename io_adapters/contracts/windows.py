"""The windows dataset: what the network learns from (docs/design.md §2): the layout constants,
the index schema and :class:`Windows` with the checks every reader of it runs. On disk
(``lanecast.io_adapters.windows_store.dataset``) a windows dataset is a directory that training
memory-maps:

- ``inputs.npy``   float32 [N, 4, 8, 30]: channels (x, y, v, a) in the window frame, physical units
  (m, m, m/s, m/s^2); rows FL, F, FR, L, T, R, RL, RR; time oldest -> t0; absent = 0
- ``present.npy``  bool [N, 8, 30]
- ``future.npy``   float32 [N, 5, 2]: target offsets at t0+1..5 s in the window frame (NaN if unknown)
- ``maneuver.npy`` int64 [N, 5]: 0 straight, 1 left, 2 right (-1 unknown)
- ``windows.parquet`` one row per window: recording, track_id, t0_ns, split, origin_x, origin_y,
  origin_heading (the window frame in the source frame)
- ``manifest.json`` parameters, sources, counts per split, label distribution, units, version
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa

from lanecast.io_adapters.errors import InputError

#: Vehicle rows of the window tensor, in their fixed, spatially coherent order.
ROWS: tuple[str, ...] = ("FL", "F", "FR", "L", "T", "R", "RL", "RR")
#: Row of the target vehicle.
TARGET_ROW = ROWS.index("T")
FORMAT_VERSION = 1  # manifest.json's format_version (pipeline.make_windows writes it)
FORMAT_NAME = "lanecast-windows"  # manifest.json's format
#: The neighbour slots (every row but the target's), in row order.
NEIGHBOUR_ROWS: tuple[str, ...] = tuple(r for r in ROWS if r != "T")
CHANNELS: tuple[str, ...] = ("x", "y", "v", "a")
CHANNEL_UNITS: tuple[str, ...] = ("m", "m", "m/s", "m/s^2")
HISTORY = 30  # frames at 10 Hz, t0 included
HORIZONS = 5  # future steps, 1 s apart
#: Times of the future steps after t0 (s).
HORIZON_S: tuple[float, ...] = tuple(float(step) for step in range(1, HORIZONS + 1))
#: Maneuver classes, by label index.
MANEUVERS: tuple[str, ...] = ("straight", "left", "right")
#: One colour per maneuver (RGB 0–1), shared by every picture lanecast draws: the report's scenes and
#: the Foxglove annotations (``/lanecast/forecast``). Straight grey, left blue (as in the paper's
#: figures), right orange (Okabe–Ito, readable by colour-blind viewers, on white and on Foxglove's
#: dark background); UNKNOWN_COLOUR for forecasters without a classifier (the kinematic baselines).
MANEUVER_COLOURS: tuple[tuple[float, float, float], ...] = (
    (0.45, 0.45, 0.45),
    (0.0, 0.45, 0.70),
    (0.90, 0.62, 0.0),
)
UNKNOWN_COLOUR: tuple[float, float, float] = (0.80, 0.47, 0.65)
SPLITS: tuple[str, ...] = ("train", "val", "test", "none")

INDEX_SCHEMA = pa.schema(
    [
        pa.field("recording", pa.string()),
        pa.field("track_id", pa.int64()),
        pa.field("t0_ns", pa.int64()),
        pa.field("split", pa.string()),
        pa.field("origin_x", pa.float64()),
        pa.field("origin_y", pa.float64()),
        pa.field("origin_heading", pa.float64()),
    ]
)
ARRAYS = ("inputs", "present", "future", "maneuver")  # the array files, by name
CHUNK = 1024  # windows per chunk: bounded memory on memory-mapped datasets
#: the largest magnitude of an input or a target (m, m/s, m/s²): the track table's positions are
#: within ±1e9 m, and an input of 1e30 (finite) overflowed the float32 sums of the normalisation
#: statistics to inf, which train refused after an epoch as "bad normalisation statistics"
MAX_VALUE = 1e9
#: the files of a dataset directory (a new dataset replaces a directory holding only these)
DATASET_FILES: tuple[str, ...] = (*(f"{a}.npy" for a in ARRAYS), "windows.parquet", "manifest.json")
#: dtype and shape of one window in each array file
ARRAY_LAYOUT: dict[str, tuple[np.dtype, tuple[int, ...]]] = {
    "inputs": (np.dtype(np.float32), (4, len(ROWS), HISTORY)),
    "present": (np.dtype(np.bool_), (len(ROWS), HISTORY)),
    "future": (np.dtype(np.float32), (HORIZONS, 2)),
    "maneuver": (np.dtype(np.int64), (HORIZONS,)),
}


@dataclass
class Windows:
    """N windows: network inputs, targets and one index row per window (see the module docstring)."""

    inputs: np.ndarray  # float32 [N, 4, 8, 30]
    present: np.ndarray  # bool [N, 8, 30]
    future: np.ndarray  # float32 [N, 5, 2]
    maneuver: np.ndarray  # int64 [N, 5]
    index: pa.Table  # INDEX_SCHEMA, N rows
    manifest: dict[str, Any] = field(default_factory=dict)

    def __len__(self) -> int:
        return int(self.inputs.shape[0])

    def check(self, directory: Path | None = None) -> None:
        """Raise InputError if the arrays disagree with each other or with the contract; with the
        dataset's ``directory``, naming the file at fault (an array whose length differs from the
        others', or windows.parquet when the arrays agree)."""
        lengths = [getattr(self, name).shape[0] if getattr(self, name).ndim else -1 for name in ARRAYS]
        n = max(set(lengths), key=lengths.count)  # what most arrays say
        if all(length != self.index.num_rows for length in lengths) and len(set(lengths)) == 1:
            repeated = _repeated_row(self.index) if self.index.num_rows > n else None
            raise InputError(
                None if directory is None else directory / "windows.parquet",
                f"windows index has {self.index.num_rows} rows, the arrays {n} windows"
                + ("" if repeated is None else f"; row {repeated[1]} repeats row {repeated[0]}"),
                expected=f"{n} rows",
            )
        n = self.index.num_rows if self.index.num_rows in lengths else n
        for name in ARRAYS:
            dtype, shape = ARRAY_LAYOUT[name][0], (n, *ARRAY_LAYOUT[name][1])
            arr = getattr(self, name)
            if arr.shape != shape or arr.dtype != dtype:
                raise InputError(
                    None if directory is None else directory / f"{name}.npy",
                    f"windows array {name!r} is {arr.dtype}{list(arr.shape)}",
                    expected=f"{np.dtype(dtype)}{list(shape)}",
                )
        if self.index.num_rows != n:
            raise InputError(None, f"windows index has {self.index.num_rows} rows", expected=f"{n} rows")

    def check_values(self, directory: Path | None = None) -> None:
        """Raise InputError at the first window whose values cannot be: inputs that are not
        finite or beyond ±MAX_VALUE, a future that is infinite or beyond it (unknown is NaN), a
        maneuver label outside -1…2. Reads
        the arrays chunk by chunk (memory-mapped datasets stay so); train and evaluate call it."""
        limit = f"within ±{MAX_VALUE:g}"
        checks: tuple[tuple[str, Callable[[np.ndarray], np.ndarray], str], ...] = (
            ("inputs", lambda a: ~(np.abs(a) <= MAX_VALUE), f"finite inputs {limit} (absent entries are 0)"),
            ("future", lambda a: np.abs(a) > MAX_VALUE, f"finite offsets {limit}, NaN where unknown"),
            ("maneuver", lambda a: (a < -1) | (a >= len(MANEUVERS)), "labels -1 (unknown), 0, 1, 2"),
        )
        for start in range(0, len(self), CHUNK):  # windows exist where their target is present
            absent = ~np.asarray(self.present[start : start + CHUNK, TARGET_ROW])
            if absent.any():
                window, frame = np.unravel_index(int(np.flatnonzero(absent)[0]), absent.shape)
                raise InputError(
                    None if directory is None else directory / "present.npy",
                    f"window {start + int(window)}: the target (row {TARGET_ROW}) is absent at history "
                    f"frame {int(frame)}",
                    expected="the target present in every history frame",
                )
        for name, bad_of, expected in checks:
            array = getattr(self, name)
            for start in range(0, len(self), CHUNK):
                bad = bad_of(np.asarray(array[start : start + CHUNK]))
                if bad.any():
                    at = np.unravel_index(int(np.flatnonzero(bad)[0]), bad.shape)
                    raise InputError(
                        None if directory is None else directory / f"{name}.npy",
                        f"window {start + int(at[0])} holds {array[start + int(at[0])][at[1:]]}",
                        expected=expected,
                    )

    def origin(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(x [N], y [N], heading [N]) of every window frame in the source frame (float64)."""
        return (
            self.index.column("origin_x").to_numpy(),
            self.index.column("origin_y").to_numpy(),
            self.index.column("origin_heading").to_numpy(),
        )


def labelled(windows: Windows, splits: tuple[str, ...]) -> np.ndarray:
    """Indices [M] of windows in ``splits`` whose future and maneuvers are all known."""
    split = windows.index.column("split").to_numpy(zero_copy_only=False)
    ok = np.isin(split, list(splits))
    ok &= np.all(np.isfinite(np.asarray(windows.future)), axis=(1, 2))
    ok &= np.all(np.asarray(windows.maneuver) >= 0, axis=1)
    return np.flatnonzero(ok)


def empty_windows(manifest: dict[str, Any] | None = None) -> Windows:
    """A dataset with no windows (all arrays with N = 0)."""
    return Windows(
        inputs=np.zeros((0, 4, 8, HISTORY), np.float32),
        present=np.zeros((0, 8, HISTORY), bool),
        future=np.zeros((0, HORIZONS, 2), np.float32),
        maneuver=np.zeros((0, HORIZONS), np.int64),
        index=INDEX_SCHEMA.empty_table(),
        manifest=dict(manifest or {}),
    )


def _repeated_row(index: pa.Table) -> tuple[int, int] | None:
    """(first, later) 0-based rows of the index for the same window (recording, track_id, t0_ns),
    the earliest such later row; None if every window is there once."""
    if index.num_rows < 2:
        return None
    import pyarrow.compute as pc  # not on every start

    recording = pc.dictionary_encode(index.column("recording")).combine_chunks().indices.to_numpy()
    track, t0 = index.column("track_id").to_numpy(), index.column("t0_ns").to_numpy()
    order = np.lexsort((np.arange(index.num_rows), t0, track, recording))  # stable: first copy first
    same = (np.diff(recording[order]) == 0) & (np.diff(track[order]) == 0) & (np.diff(t0[order]) == 0)
    new_window = np.r_[True, ~same]  # per sorted position: the first copy of its window
    repeats = np.flatnonzero(~new_window)
    if not repeats.size:
        return None
    first_copy = np.maximum.accumulate(np.where(new_window, np.arange(index.num_rows), 0))
    at = repeats[np.argmin(order[repeats])]  # the repeat that comes first in the file
    return int(order[first_copy[at]]), int(order[at])


def subset(windows: Windows, mask_or_indices: np.ndarray | list[int] | slice) -> Windows:
    """The windows selected by a boolean mask [N], integer indices or a slice (arrays copied)."""
    sel = mask_or_indices
    if not isinstance(sel, slice):
        sel = np.asarray(sel)
        if sel.dtype == bool:
            if sel.shape != (len(windows),):
                raise InputError(None, f"mask of shape {sel.shape}", expected=f"({len(windows)},)")
            sel = np.flatnonzero(sel)
    rows = np.arange(len(windows))[sel]
    return Windows(
        inputs=np.asarray(windows.inputs[rows]),
        present=np.asarray(windows.present[rows]),
        future=np.asarray(windows.future[rows]),
        maneuver=np.asarray(windows.maneuver[rows]),
        index=windows.index.take(pa.array(rows, pa.int64())),
        manifest=dict(windows.manifest),
    )


def concat_windows(parts: list[Windows], manifest: dict[str, Any] | None = None) -> Windows:
    """Concatenate datasets (e.g. one per recording) into one."""
    if not parts:
        return empty_windows(manifest)
    return Windows(
        inputs=np.concatenate([p.inputs for p in parts]),
        present=np.concatenate([p.present for p in parts]),
        future=np.concatenate([p.future for p in parts]),
        maneuver=np.concatenate([p.maneuver for p in parts]),
        index=pa.concat_tables([p.index.cast(INDEX_SCHEMA) for p in parts]),
        manifest=dict(manifest if manifest is not None else parts[0].manifest),
    )
