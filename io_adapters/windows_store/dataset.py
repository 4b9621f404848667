"""The windows dataset on disk (docs/design.md §2): written atomically in one call
(:func:`save_windows`) or grown block by block (:class:`DatasetWriter`, with workers' shards), and
loaded memory-mapped with every file checked (:func:`load_windows`): file shapes, the index, the
manifest's format, version, layout and count. A reader that skipped one would be a second format.
"""

from __future__ import annotations

import contextlib
import json
import shutil
from collections.abc import Callable
from pathlib import Path
from types import TracebackType
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq

from lanecast.io_adapters.contracts.windows import (
    ARRAY_LAYOUT,
    ARRAYS,
    CHANNELS,
    DATASET_FILES,
    FORMAT_NAME,
    FORMAT_VERSION,
    HORIZONS,
    INDEX_SCHEMA,
    MANEUVERS,
    ROWS,
    SPLITS,
    Windows,
)
from lanecast.io_adapters.errors import InputError
from lanecast.io_adapters.files import ANY_FILES, atomic_path, not_regular
from lanecast.io_adapters.windows_store.npy_append import SHARD_HEADER_BYTES, NpyAppender, save_npy


def save_windows(windows: Windows, directory: str | Path) -> Path:
    """Write the dataset directory atomically (a reader never sees half of it); return its path.
    The manifest's ``n_windows`` is the count written (a subset or a concatenation keeps the
    manifest it was made from, whose count :func:`load_windows` would refuse)."""
    windows.check()
    directory = Path(directory)
    manifest = {**windows.manifest, "n_windows": len(windows)}
    with atomic_path(directory, directory=True, replaces=DATASET_FILES) as tmp:
        for name in ARRAYS:
            np.save(tmp / f"{name}.npy", np.ascontiguousarray(getattr(windows, name)), allow_pickle=False)
        _write_index(tmp, windows.index)
        _write_manifest(tmp, manifest)
    return directory


def _write_index(directory: Path, index: pa.Table) -> None:
    pq.write_table(index.cast(INDEX_SCHEMA), directory / "windows.parquet", compression="zstd")


def _write_manifest(directory: Path, manifest: dict[str, Any]) -> None:
    text = json.dumps(manifest, indent=2, sort_keys=True, default=_jsonable)
    (directory / "manifest.json").write_text(text, encoding="utf-8")


def save_shard(directory: Path, arrays: dict[str, np.ndarray]) -> Path:
    """Write the four arrays of some windows as .npy files into ``directory`` (a worker's part of a
    dataset that :meth:`DatasetWriter.append_shard` then appends)."""
    directory.mkdir(parents=True, exist_ok=True)
    for name in ARRAYS:
        save_npy(directory / f"{name}.npy", arrays[name], header_bytes=SHARD_HEADER_BYTES)
    return directory


class DatasetWriter:
    """A windows dataset grown on disk, block by block (or shard by shard), in a temporary directory
    renamed into place only when complete: an interrupted run leaves no half-written dataset.

    Memory: one block; the arrays are appended to their .npy files (:class:`NpyAppender`) and the
    manifest is computed from the finished files memory-mapped.
    """

    def __init__(self, directory: str | Path, *, replace_any: bool = False) -> None:
        self.directory = Path(directory)
        #: what an existing directory may hold to be replaced: a dataset's files, or anything (--force)
        self.replaces = ANY_FILES if replace_any else DATASET_FILES
        self._stack = contextlib.ExitStack()
        self._tmp: Path | None = None
        self._appenders: dict[str, NpyAppender] = {}

    def __enter__(self) -> DatasetWriter:
        self._tmp = self._stack.enter_context(
            atomic_path(self.directory, directory=True, replaces=self.replaces)
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
        lengths = {name: len(arrays[name]) for name in ARRAYS}
        if len(set(lengths.values())) != 1:
            raise ValueError(f"arrays of different lengths {lengths}")
        for name in ARRAYS:
            self._appenders[name].append(arrays[name])

    def append_shard(self, shard: Path) -> int:
        """Append the windows of a shard written by :func:`save_shard`, then remove it; its length."""
        counts = {name: self._appenders[name].append_npy(shard / f"{name}.npy") for name in ARRAYS}
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
        _write_index(self._tmp, index)
        arrays = {name: np.load(self._tmp / f"{name}.npy", mmap_mode="r") for name in ARRAYS}
        windows = Windows(index=index, **arrays)
        windows.check()
        windows.manifest = manifest(windows)
        _write_manifest(self._tmp, windows.manifest)
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
    for name in ARRAYS:
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


def _jsonable(value: Any) -> Any:
    """What ``json`` cannot write itself, as what it can (numpy arrays and numbers, paths)."""
    if isinstance(value, np.ndarray | np.generic):
        return value.tolist()
    if isinstance(value, Path):
        return str(value)
    raise TypeError(f"{type(value).__name__} is not JSON serialisable")
