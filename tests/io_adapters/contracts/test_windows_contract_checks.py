"""A damaged windows dataset (an edited array, a manifest of another format, an index with nulls
or a row twice, a FIFO under a file's name) is refused naming the file and what was expected."""

from __future__ import annotations

import json
import os
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from conftest import _edit_npy, _set_first, no_output, refused, synthetic_windows, windows_copy

from lanecast.io_adapters.errors import InputError
from lanecast.io_adapters.windows_store.dataset import load_windows, save_windows


def _drop_split(directory: Path) -> None:
    pq.write_table(
        pq.read_table(directory / "windows.parquet").drop_columns(["split"]), directory / "windows.parquet"
    )


def _manifest_set(directory: Path, **fields: object) -> None:
    manifest = json.loads((directory / "manifest.json").read_text())
    (directory / "manifest.json").write_text(json.dumps({**manifest, **fields}))


WINDOWS_DAMAGE: dict[str, tuple[Callable[[Path], object], str, str]] = {
    # case: (damage, file named, words): each was a traceback, a silent result or named no file
    "empty inputs.npy": (lambda d: (d / "inputs.npy").write_bytes(b""), "inputs.npy", "not a readable .npy array"),
    "manifest a list": (lambda d: (d / "manifest.json").write_text("[]"), "manifest.json", "not a JSON object"),
    "index without split": (_drop_split, "windows.parquet, column 'split'", "no column 'split'"),
    "maneuver 7": (_edit_npy("maneuver", _set_first(7)), "maneuver.npy", "window 1 holds 7"),
    "NaN input": (_edit_npy("inputs", _set_first(np.nan)), "inputs.npy", "window 0 holds nan"),
    "infinite future": (_edit_npy("future", _set_first(np.inf)), "future.npy", "window 0 holds inf"),
    "inputs short": (_edit_npy("inputs", lambda a: a[:-5]), "inputs.npy", "float32[55, 4, 8, 30]"),
    "no labelled windows": (_edit_npy("future", lambda a: a * np.nan), "win: no labelled", "known futures"),
    # no target in its own window: a ValueError drawing the report's scenes
    "target absent": (_edit_npy("present", np.zeros_like), "present.npy", "the target (row 4) is absent"),
    # a dataset of a newer format: read as if it were this one
    "format_version 99": (lambda d: _manifest_set(d, format_version=99), "manifest.json", "format_version 99"),
}  # fmt: skip


@pytest.mark.parametrize("case", sorted(WINDOWS_DAMAGE))
def test_damaged_windows_dataset(tmp_path: Path, capsys: pytest.CaptureFixture[str], case: str) -> None:
    damage, named, words = WINDOWS_DAMAGE[case]
    directory = windows_copy(tmp_path, damage)
    out = tmp_path / "report"
    refused(["evaluate", str(directory), "--out", str(out), "--split", "all"], capsys, named, words)
    no_output(out)


@pytest.mark.parametrize(
    ("column", "value", "shown"),
    [("track_id", None, "null"), ("recording", None, "null"), ("origin_x", float("nan"), "nan")],
)
def test_a_windows_index_with_nulls_is_refused_at_its_row(
    tmp_path: Path, column: str, value: object, shown: str
) -> None:
    """A null track_id in windows.parquet was trained on and evaluated silently."""
    directory = save_windows(synthetic_windows(n=20), tmp_path / "windows")
    index = pq.read_table(directory / "windows.parquet")
    values = index.column(column).to_pylist()
    values[7] = value
    i = index.schema.get_field_index(column)
    index = index.set_column(i, index.schema.field(column), pa.array(values, index.schema.field(column).type))
    pq.write_table(index, directory / "windows.parquet")
    with pytest.raises(InputError, match=f"row 7: {column} is {shown}") as err:
        load_windows(directory)
    assert err.value.path == str(directory / "windows.parquet") and err.value.column == column


def test_a_windows_index_row_written_twice_is_named(tmp_path: Path) -> None:
    """A row of windows.parquet repeated (the fuzzer's seed 100071) gave only "windows index has
    21 rows, the arrays 20 windows", naming no row."""
    directory = save_windows(synthetic_windows(n=20), tmp_path / "windows")
    index = pq.read_table(directory / "windows.parquet")
    pq.write_table(
        pa.concat_tables([index.slice(0, 12), index.slice(5, 1), index.slice(12)]),
        directory / "windows.parquet",
    )
    with pytest.raises(InputError, match="21 rows, the arrays 20 windows; row 12 repeats row 5") as err:
        load_windows(directory)
    assert err.value.path == str(directory / "windows.parquet")


@pytest.mark.parametrize("name", ["inputs.npy", "manifest.json"])
@pytest.mark.parametrize("entry", ["fifo", "device"])
def test_a_windows_file_that_is_no_regular_file_says_so(tmp_path: Path, name: str, entry: str) -> None:
    """inputs.npy or manifest.json of a windows dataset as a FIFO or a link to /dev/zero was
    "missing file of a windows dataset" (the file is there); now 'not a regular file', unopened."""
    directory = save_windows(synthetic_windows(n=20), tmp_path / "windows")
    (directory / name).unlink()
    if entry == "fifo":
        os.mkfifo(directory / name)
    else:
        (directory / name).symlink_to("/dev/zero")
    with pytest.raises(InputError) as err:
        load_windows(directory)
    assert err.value.path == str(directory / name) and "not a regular file" in str(err.value)
