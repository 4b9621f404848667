"""The windows dataset: what the network learns from, in memory and on disk (docs/design.md §2).

On disk a windows dataset is a directory that training memory-maps:

- ``inputs.npy``   float32 [N, 4, 8, 30]: channels (x, y, v, a) in the window frame, physical units
  (m, m, m/s, m/s^2); rows FL, F, FR, L, T, R, RL, RR; time oldest -> t0; absent = 0
- ``present.npy``  bool [N, 8, 30]
- ``future.npy``   float32 [N, 5, 2]: target offsets at t0+1..5 s in the window frame (NaN if unknown)
- ``maneuver.npy`` int64 [N, 5]: 0 straight, 1 left, 2 right (-1 unknown)
- ``windows.parquet`` one row per window: recording, track_id, t0_ns, split, origin_x, origin_y,
  origin_heading (the window frame in the source frame)
- ``manifest.json`` parameters, sources, counts per split, label distribution, units, version

Normalisation (per channel, statistics from the training windows only): Mean and std are taken over *present* entries, so that the zeros of absent neighbours do not bias
them; after normalisation absent entries are exactly 0 again ("zero means absent").

Size: the dataset's one definition, in memory and on disk, with the checks every reader of it runs
(file shapes, manifest version, targets present): a reader that skipped one would be a second format.
"""

from __future__ import annotations

import contextlib
import json
import shutil
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from types import TracebackType
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq

from lanecast.io_adapters.errors import InputError
from lanecast.io_adapters.files import atomic_path, not_regular
from lanecast.io_adapters.windows_store.npy_append import SHARD_HEADER_BYTES, NpyAppender, save_npy

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
_ARRAYS = ("inputs", "present", "future", "maneuver")
#: the largest magnitude of an input or a target (m, m/s, m/s²): the track table's positions are
#: within ±1e9 m, and an input of 1e30 (finite) overflowed the float32 sums of the normalisation
#: statistics to inf, which train refused after an epoch as "bad normalisation statistics"
MAX_VALUE = 1e9
#: the files of a dataset directory (a new dataset replaces a directory holding only these)
DATASET_FILES: tuple[str, ...] = (*(f"{a}.npy" for a in _ARRAYS), "windows.parquet", "manifest.json")
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
        lengths = [getattr(self, name).shape[0] if getattr(self, name).ndim else -1 for name in _ARRAYS]
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
        for name in _ARRAYS:
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
        for start in range(0, len(self), _CHUNK):  # windows exist where their target is present
            absent = ~np.asarray(self.present[start : start + _CHUNK, TARGET_ROW])
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
            for start in range(0, len(self), _CHUNK):
                bad = bad_of(np.asarray(array[start : start + _CHUNK]))
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


def to_source_frame(
    xy: np.ndarray, origin_x: np.ndarray, origin_y: np.ndarray, heading: np.ndarray
) -> np.ndarray:
    """Window-frame points [N, ..., 2] to the source frame: origin + R(heading) @ xy (float64)."""
    c = np.cos(heading).reshape((-1,) + (1,) * (xy.ndim - 2))
    s = np.sin(heading).reshape(c.shape)
    x = xy[..., 0].astype(np.float64)
    y = xy[..., 1].astype(np.float64)
    ox = np.asarray(origin_x, dtype=np.float64).reshape(c.shape)
    oy = np.asarray(origin_y, dtype=np.float64).reshape(c.shape)
    return np.stack([ox + c * x - s * y, oy + s * x + c * y], axis=-1)


def to_window_frame(
    xy: np.ndarray, origin_x: np.ndarray, origin_y: np.ndarray, heading: np.ndarray
) -> np.ndarray:
    """Source-frame points [N, ..., 2] to the window frame: R(-heading) @ (xy - origin) (float64).

    The inverse of :func:`to_source_frame`.
    """
    c = np.cos(heading).reshape((-1,) + (1,) * (xy.ndim - 2))
    s = np.sin(heading).reshape(c.shape)
    dx = xy[..., 0] - np.asarray(origin_x, dtype=np.float64).reshape(c.shape)
    dy = xy[..., 1] - np.asarray(origin_y, dtype=np.float64).reshape(c.shape)
    return np.stack([c * dx + s * dy, -s * dx + c * dy], axis=-1)


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


def save_windows(windows: Windows, directory: str | Path) -> Path:
    """Write the dataset directory atomically (a reader never sees half of it); return its path.
    The manifest's ``n_windows`` is the count written (a subset or a concatenation keeps the
    manifest it was made from, whose count :func:`load_windows` would refuse)."""
    windows.check()
    directory = Path(directory)
    manifest = {**windows.manifest, "n_windows": len(windows)}
    with atomic_path(directory, directory=True, replaces=DATASET_FILES) as tmp:
        for name in _ARRAYS:
            np.save(tmp / f"{name}.npy", np.ascontiguousarray(getattr(windows, name)), allow_pickle=False)
        pq.write_table(windows.index.cast(INDEX_SCHEMA), tmp / "windows.parquet", compression="zstd")
        (tmp / "manifest.json").write_text(
            json.dumps(_jsonable(manifest), indent=2, sort_keys=True), encoding="utf-8"
        )
    return directory


def save_shard(directory: Path, arrays: dict[str, np.ndarray]) -> Path:
    """Write the four arrays of some windows as .npy files into ``directory`` (a worker's part of a
    dataset that :meth:`DatasetWriter.append_shard` then appends)."""
    directory.mkdir(parents=True, exist_ok=True)
    for name in _ARRAYS:
        save_npy(directory / f"{name}.npy", arrays[name], header_bytes=SHARD_HEADER_BYTES)
    return directory


class DatasetWriter:
    """A windows dataset grown on disk, block by block (or shard by shard), in a temporary directory
    renamed into place only when complete: an interrupted run leaves no half-written dataset.

    Memory: one block; the arrays are appended to their .npy files (:class:`NpyAppender`) and the
    manifest is computed from the finished files memory-mapped.
    """

    def __init__(self, directory: str | Path) -> None:
        self.directory = Path(directory)
        self._stack = contextlib.ExitStack()
        self._tmp: Path | None = None
        self._appenders: dict[str, NpyAppender] = {}

    def __enter__(self) -> DatasetWriter:
        self._tmp = self._stack.enter_context(
            atomic_path(self.directory, directory=True, replaces=DATASET_FILES)
        )
        self._appenders = {
            name: NpyAppender(self._tmp / f"{name}.npy", dtype, shape)
            for name, (dtype, shape) in ARRAY_LAYOUT.items()
        }
        return self

    def __exit__(
        self, kind: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        for appender in self._appenders.values():
            appender.abort()
        self._stack.__exit__(kind, exc, tb)

    @property
    def rows(self) -> int:
        return self._appenders["inputs"].rows

    @property
    def shard_root(self) -> Path:
        """A directory inside the temporary dataset where workers put their shards."""
        assert self._tmp is not None, "use DatasetWriter as a context manager"
        return self._tmp / "_shards"

    def take(self, n: int) -> tuple[np.ndarray, np.ndarray]:
        """Inputs [n, 4, 8, 30] and presence [n, 8, 30] of the next ``n`` windows, in the files'
        staging memory: fill them and :meth:`append` them with no copy (valid until then)."""
        return self._appenders["inputs"].reserve(n), self._appenders["present"].reserve(n)

    def append(self, arrays: dict[str, np.ndarray]) -> None:
        """Append windows: ``inputs``, ``present``, ``future``, ``maneuver`` with the same length
        (inputs and presence ideally those :meth:`take` gave)."""
        lengths = {name: len(arrays[name]) for name in _ARRAYS}
        if len(set(lengths.values())) != 1:
            raise ValueError(f"arrays of different lengths {lengths}")
        for name in _ARRAYS:
            self._appenders[name].append(arrays[name])

    def append_shard(self, shard: Path) -> int:
        """Append the windows of a shard written by :func:`save_shard`, then remove it; its length."""
        counts = {name: self._appenders[name].append_npy(shard / f"{name}.npy") for name in _ARRAYS}
        if len(set(counts.values())) != 1:
            raise InputError(shard, f"shard arrays of different lengths {counts}")
        shutil.rmtree(shard, ignore_errors=True)
        return counts["inputs"]

    def finish(self, index: pa.Table, manifest: Callable[[Windows], dict[str, Any]]) -> Windows:
        """Close the arrays, write the index and ``manifest(windows)`` (the dataset memory-mapped);
        the directory is renamed into place when the ``with`` block ends."""
        assert self._tmp is not None, "use DatasetWriter as a context manager"
        for appender in self._appenders.values():
            appender.close()
        shutil.rmtree(self.shard_root, ignore_errors=True)
        pq.write_table(index.cast(INDEX_SCHEMA), self._tmp / "windows.parquet", compression="zstd")
        arrays = {name: np.load(self._tmp / f"{name}.npy", mmap_mode="r") for name in _ARRAYS}
        windows = Windows(index=index, **arrays)
        windows.check()
        windows.manifest = manifest(windows)
        (self._tmp / "manifest.json").write_text(
            json.dumps(_jsonable(windows.manifest), indent=2, sort_keys=True), encoding="utf-8"
        )
        return windows


def load_windows(directory: str | Path, mmap: bool = True, check_values: bool = False) -> Windows:
    """Load a dataset written by :func:`save_windows` in one call; arrays memory-mapped (read-only).
    Every file is checked for its layout (and with ``check_values`` every value, a pass over the
    arrays: see :meth:`Windows.check_values`); InputError names the file at fault."""
    directory = Path(directory)
    if not directory.is_dir():
        raise InputError(
            directory,
            "not a directory" if directory.exists() else "no such windows directory",
            expected="a directory from `lanecast windows`",
        )
    if any(directory.glob("*.safetensors")) and not (directory / "manifest.json").exists():
        raise InputError(
            directory,
            "a model directory (the output of `lanecast train`), not a windows dataset",
            expected="a directory from `lanecast windows`; a model goes to --model or --init",
        )
    if not any((directory / name).exists() for name in DATASET_FILES):
        raise InputError(
            directory,
            "not a windows dataset (none of inputs.npy, windows.parquet, manifest.json is in it)",
            expected=f"a directory from `lanecast windows`: for a dataset or log, run `lanecast windows "
            f"{directory} --out windows/{directory.resolve().name or 'data'}` first and pass its --out",
        )
    for name in DATASET_FILES:
        path = directory / name
        if path.is_file():
            continue
        # a FIFO would block the load and /dev/zero fill memory: looked at with stat, never opened
        reason = not_regular(path) or ("a directory, not a file" if path.is_dir() else None)
        if reason is None:
            raise InputError(path, "missing file of a windows dataset")
        raise InputError(path, f"file of a windows dataset: {reason}", expected=f"the file {name}")
    arrays = {}
    for name in _ARRAYS:
        path = directory / f"{name}.npy"
        try:
            arrays[name] = np.load(path, mmap_mode="r" if mmap else None, allow_pickle=False)
        except (ValueError, OSError, EOFError) as exc:
            raise InputError(path, f"not a readable .npy array: {exc or 'empty file'}") from exc
    try:
        index = pq.read_table(directory / "windows.parquet")
    except (OSError, pa.ArrowInvalid) as exc:
        raise InputError(directory / "windows.parquet", f"damaged windows dataset: {exc}") from exc
    _check_index(directory / "windows.parquet", index)
    try:
        manifest = json.loads((directory / "manifest.json").read_text(encoding="utf-8-sig"))
    except (OSError, ValueError) as exc:
        raise InputError(directory / "manifest.json", f"damaged windows dataset: {exc}") from exc
    if not isinstance(manifest, dict):
        raise InputError(
            directory / "manifest.json", "not a JSON object", expected="the manifest of `lanecast windows`"
        )
    version = manifest.get("format_version", FORMAT_VERSION)  # test datasets may carry none
    if type(version) is not int or version != FORMAT_VERSION:
        raise InputError(
            directory / "manifest.json",
            f"format_version {version!r}",
            column="format_version",
            expected=f"{FORMAT_VERSION} (a dataset of this lanecast's `lanecast windows`)",
        )
    windows = Windows(index=index, manifest=manifest, **arrays)
    windows.check(directory)
    _check_manifest(directory / "manifest.json", manifest, len(windows))
    if check_values:
        windows.check_values(directory)
    return windows


#: manifest entries that fix how the arrays are read: a dataset whose manifest gives other values
#: (rows in another order, other channels or maneuver classes) would be learnt or scored wrongly
_LAYOUT_KEYS: dict[str, object] = {
    "rows": list(ROWS),
    "channels": list(CHANNELS),
    "maneuvers": list(MANEUVERS),
    "horizons": HORIZONS,
}


def _check_manifest(path: Path, manifest: dict[str, Any], n: int) -> None:
    """The manifest describes these arrays: the format lanecast writes, the layout constants of
    this lanecast (where the manifest states them; test datasets may carry none) and ``n``
    windows. A manifest of another dataset or format beside these arrays is refused, never read
    as if it described them."""
    fmt = manifest.get("format", FORMAT_NAME)
    if fmt != FORMAT_NAME:
        raise InputError(path, f"format {fmt!r}", column="format", expected=repr(FORMAT_NAME))
    for key, want in _LAYOUT_KEYS.items():
        if key in manifest and manifest[key] != want:
            raise InputError(path, f"{key} {manifest[key]!r}", column=key, expected=repr(want))
    count = manifest.get("n_windows", n)
    if type(count) is not int or count != n:
        raise InputError(
            path,
            f"n_windows {count!r}, but the arrays and windows.parquet hold {n} windows",
            column="n_windows",
            expected=f"{n} (the manifest written with these arrays)",
        )


def _repeated_row(index: pa.Table) -> tuple[int, int] | None:
    """(first, later) 0-based rows of the index for the same window (recording, track_id, t0_ns),
    the earliest such later row; None if every window is there once."""
    if index.num_rows < 2:
        return None
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


def _check_index(path: Path, index: pa.Table) -> None:
    """The windows index has INDEX_SCHEMA's columns and types, no nulls, finite origins, and every
    split is one of SPLITS."""
    for f in INDEX_SCHEMA:
        if f.name not in index.column_names:
            columns = ", ".join(f"{g.name} ({g.type})" for g in INDEX_SCHEMA)
            raise InputError(path, f"no column {f.name!r}", column=f.name, expected=f"columns {columns}")
        if index.schema.field(f.name).type != f.type:
            raise InputError(
                path, f"column type {index.schema.field(f.name).type}", column=f.name, expected=str(f.type)
            )
        column = index.column(f.name)
        bad = pc.is_null(column, nan_is_null=pa.types.is_floating(f.type))
        if pa.types.is_floating(f.type):
            bad = pc.or_(bad, pc.is_inf(column))
        if pc.any(bad).as_py():
            row = int(np.flatnonzero(np.asarray(bad))[0])
            value = column[row].as_py()
            raise InputError(
                path,
                f"row {row}: {f.name} is {'null' if value is None else value}",
                column=f.name,
                expected="a finite number" if pa.types.is_floating(f.type) else "a value in every row",
            )
    split = index.column("split")
    bad = np.flatnonzero(~np.asarray(pc.is_in(split, value_set=pa.array(SPLITS)).fill_null(False)))
    if bad.size:
        row = int(bad[0])
        raise InputError(
            path,
            f"row {row}: split {split[row].as_py()!r}",
            column="split",
            expected=f"one of {list(SPLITS)}",
        )


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


def _jsonable(value: Any) -> Any:
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return _jsonable(value.tolist())
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, Path):
        return str(value)
    return value


_CHUNK = 1024  # windows per chunk: bounded memory on memory-mapped datasets


@dataclass(frozen=True)
class NormStats:
    """Per-channel mean and std (float32 [4], channels x, y, v, a; physical units)."""

    mean: np.ndarray
    std: np.ndarray

    def to_dict(self) -> dict[str, Any]:
        return {
            "channels": ["x", "y", "v", "a"],
            "mean": [float(v) for v in self.mean],
            "std": [float(v) for v in self.std],
        }

    @classmethod
    def from_dict(cls, doc: dict[str, Any]) -> NormStats:
        try:
            mean = np.asarray(doc["mean"], dtype=np.float32)
            std = np.asarray(doc["std"], dtype=np.float32)
        except (KeyError, TypeError, ValueError) as exc:
            raise InputError(
                None, f"bad normalisation statistics {doc!r}", expected="{mean: [4], std: [4]}"
            ) from exc
        if mean.shape != (4,) or std.shape != (4,) or not (np.all(np.isfinite(std)) and np.all(std > 0)):
            raise InputError(
                None, f"bad normalisation statistics {doc!r}", expected="4 means and 4 positive stds"
            )
        return cls(mean, std)


def compute_stats(inputs: np.ndarray, present: np.ndarray, rows: np.ndarray | None = None) -> NormStats:
    """Mean and std per channel over present entries.

    inputs float32 [N, 4, 8, 30], present bool [N, 8, 30]; ``rows`` int [M]: only these windows
    (ascending; e.g. the training split), read chunk by chunk so that a memory-mapped dataset is
    never loaded whole. Sums in float32 within a chunk of 1024 windows and in float64 across
    chunks (relative error ~1e-7). A channel with zero spread gets std 1.
    """
    if inputs.ndim != 4 or inputs.shape[1] != 4 or present.shape != (inputs.shape[0], *inputs.shape[2:]):
        raise InputError(
            None, f"inputs {inputs.shape} / present {present.shape}", expected="[N,4,8,30] / [N,8,30]"
        )
    total = np.zeros(4)
    total_sq = np.zeros(4)
    count = 0
    n = inputs.shape[0] if rows is None else len(rows)
    for start in range(0, n, _CHUNK):
        sel: slice | np.ndarray = (
            slice(start, start + _CHUNK) if rows is None else np.asarray(rows[start : start + _CHUNK])
        )
        m = np.asarray(present[sel])
        x = (np.asarray(inputs[sel]) * m[:, None]).reshape(m.shape[0], 4, -1)
        count += int(np.count_nonzero(m))
        # float32 sums over one chunk (<= 250k values per channel), float64 across chunks
        total += np.einsum("ncj->c", x).astype(np.float64)
        total_sq += np.einsum("ncj,ncj->c", x, x).astype(np.float64)
    if count == 0:
        raise InputError(
            None, "no present entries to compute normalisation statistics from", expected="training windows"
        )
    mean = total / count
    var = np.maximum(total_sq / count - mean**2, 0.0)
    std = np.sqrt(var)
    std[std < 1e-6] = 1.0
    return NormStats(mean.astype(np.float32), std.astype(np.float32))


def normalise(inputs: np.ndarray, present: np.ndarray, stats: NormStats) -> np.ndarray:
    """(inputs - mean) / std per channel; absent entries exactly 0. float32 [N, 4, 8, 30]."""
    x = np.asarray(inputs, dtype=np.float32)
    out = (x - stats.mean[None, :, None, None]) / stats.std[None, :, None, None]
    out *= np.asarray(present)[:, None, :, :]
    return out.astype(np.float32, copy=False)


def denormalise(normalised: np.ndarray, present: np.ndarray, stats: NormStats) -> np.ndarray:
    """Inverse of :func:`normalise` (absent entries 0). float32 [N, 4, 8, 30]."""
    out = normalised * stats.std[None, :, None, None] + stats.mean[None, :, None, None]
    out *= np.asarray(present)[:, None, :, :]
    return out.astype(np.float32, copy=False)
