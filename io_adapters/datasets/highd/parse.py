"""Parsing one highD CSV into typed Arrow columns, with the checks that guard the parse.

The parse is vectorised (pyarrow.csv with explicit column types). Only after it or a check fails
does a second, equally vectorised pass locate the offending line, so that every error names the
file, the 1-based line (header = line 1), the column and what was expected.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.csv as pacsv

from lanecast.io_adapters.arrow_numpy import valid_mask
from lanecast.io_adapters.datasets import csv_errors
from lanecast.io_adapters.datasets.highd.sniff import header_names
from lanecast.io_adapters.errors import InputError

_ARROW_TYPES = {"int": pa.int64(), "float": pa.float64(), "str": pa.string()}
_EXPECTED = {"int": "an integer within int64", "float": "a number", "str": "a non-empty value"}
_NULL_TOKENS = tuple(pacsv.ConvertOptions().null_values)
_INT_RE = r"^\s*-?\d+\s*$"  # pyarrow reads no "+3" as int64
_FLOAT_RE = r"^\s*[-+]?(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?\s*$|^\s*[-+]?(inf|Inf|INF|infinity|Infinity)\s*$"


def convert_options(columns: Mapping[str, str]) -> pacsv.ConvertOptions:
    """The typed read of the required ``columns`` (name → "int", "float", "str"), empty cells null."""
    return pacsv.ConvertOptions(
        column_types={name: _ARROW_TYPES[kind] for name, kind in columns.items()},
        include_columns=list(columns),
        strings_can_be_null=True,
    )


def checked_header(path: Path, columns: Mapping[str, str], what: str) -> list[str]:
    """The header names of ``path``, refused at line 1 where the file is missing, empty, no UTF-8
    text, separated by other than commas, of a sister dataset, or lacks a required column."""
    if not path.is_file():
        raise InputError(path, f"missing {what} file", expected=f"{path.name} beside the other files")
    if path.stat().st_size == 0:
        raise InputError(path, "empty file", line=1, expected=f"a {what} header line")
    try:
        with path.open("rb") as fh:
            csv_errors.check_text(path, fh.read(4096), f"a highD {what} CSV")
        names = header_names(path)
    except OSError as exc:
        raise InputError(path, f"cannot read: {exc}") from exc
    if not names:
        raise InputError(path, "empty header line", line=1, expected=f"a {what} header line")
    if len(names) == 1 and (";" in names[0] or "\t" in names[0]):
        sep = "';'" if ";" in names[0] else "tabs"
        raise InputError(path, f"the header is separated by {sep}", line=1, expected="comma-separated fields")
    if "recordingId" in names and "id" not in names:
        raise InputError(
            path,
            "a recording of highD's sister datasets (inD, rounD, exiD, uniD: columns recordingId, "
            "trackId, xCenter), whose format and road geometry lanecast does not read",
            line=1,
            expected=f"a highD {what} CSV, whose vehicles and recordings are numbered in a column 'id'",
        )
    for name in columns:
        if name not in names:
            import difflib  # only where a header is wrong: not on every start

            close = difflib.get_close_matches(name, names, n=1)
            hint = f"; found {close[0]!r}" if close else ""
            raise InputError(
                path,
                f"no column {name!r} in the header{hint}",
                line=1,
                column=name,
                expected=f"the highD {what} column {name!r}",
            )
        if names.count(name) > 1:
            raise InputError(path, f"column {name!r} appears twice", line=1, column=name)
    return names


def read_csv(
    path: Path, columns: Mapping[str, str], what: str, may_be_empty: frozenset[str] = frozenset()
) -> pa.Table:
    """Parse the required ``columns`` of a highD CSV with explicit types; InputError on bad input:
    a bad header, a cell that does not parse as its type, an empty/NaN cell or an infinite float
    (but in ``may_be_empty``), a quoted value over line ends, no data row."""
    names = checked_header(path, columns, what)
    read_options = pacsv.ReadOptions(column_names=names, skip_rows=1)
    try:
        table = pacsv.read_csv(path, read_options=read_options, convert_options=convert_options(columns))
    except pa.ArrowInvalid as exc:
        _diagnose(path, names, columns)
        if csv_errors.record_lines(path.read_bytes())[0].size <= 1:  # a header with no line end
            raise InputError(path, "no data rows", line=2, expected=f"at least one {what} row") from exc
        raise InputError(path, f"cannot parse as CSV: {exc}", expected=f"a highD {what} file") from exc
    except OSError as exc:
        raise InputError(path, f"cannot read: {exc}") from exc
    if table.num_rows == 0:
        raise InputError(path, "no data rows", line=2, expected=f"at least one {what} row")
    csv_errors.check_one_line_per_row(path, table)
    check_cells(path, table, names, {k: v for k, v in columns.items() if k not in may_be_empty})
    return table


def _diagnose(path: Path, names: list[str], columns: Mapping[str, str]) -> None:
    """After a failed fast parse: find the first bad line (field count or cell) and raise there."""
    data = path.read_bytes()
    csv_errors.check_field_counts(path, data, names)
    try:
        table = pacsv.read_csv(
            path,
            read_options=pacsv.ReadOptions(column_names=names, skip_rows=1),
            convert_options=pacsv.ConvertOptions(
                column_types=dict.fromkeys(columns, pa.string()),
                include_columns=list(columns),
                strings_can_be_null=False,
                quoted_strings_can_be_null=False,
            ),
        )
    except pa.ArrowInvalid:
        csv_errors.check_parseable(path, data)
        return  # not a cell problem: the caller reports pyarrow's own message
    import pyarrow.compute as pc  # where a cell did not parse: not on every start

    first_bad: tuple[int, str] | None = None
    for name in names:
        kind = columns.get(name)
        if kind not in ("int", "float"):
            continue
        cells = table.column(name)
        ok = pc.or_(
            pc.match_substring_regex(cells, _INT_RE if kind == "int" else _FLOAT_RE),
            pc.is_in(cells, value_set=pa.array(_NULL_TOKENS)),
        )
        if kind == "int":  # digits that do not fit int64 (pyarrow's parse fails on them too)
            ok = pc.and_(ok, pc.invert(pc.match_substring_regex(cells, r"\d{19}")))
        bad = np.flatnonzero(~np.asarray(ok))
        if bad.size and (first_bad is None or bad[0] < first_bad[0]):
            first_bad = (int(bad[0]), name)
    if first_bad is None:
        return
    row, name = first_bad
    kind = columns[name]
    line = int(csv_errors.record_lines(data)[0][row + 1])
    if csv_errors.is_header([table.column(n)[row].as_py() for n in columns], list(columns)):
        raise InputError(path, csv_errors.REPEATED_HEADER, line=line, expected="one header line, at line 1")
    value = table.column(name)[row].as_py()
    raise InputError(
        path,
        f"cell {csv_errors.shown(value)} is not {_EXPECTED[kind]}",
        line=line,
        column=name,
        expected=_EXPECTED[kind],
    )


def check_cells(path: Path, table: pa.Table, names: list[str], columns: Mapping[str, str]) -> None:
    """Empty/NaN cells (parsed as null) and non-finite floats, reported at their line."""
    first_bad: tuple[int, str, str] | None = None
    for name in names:
        kind = columns.get(name)
        if kind is None:
            continue
        column = table.column(name)
        bad = np.zeros(0, dtype=np.int64)
        message = "empty or NaN cell"
        if column.null_count:
            bad = np.flatnonzero(~valid_mask(column))
        elif kind == "float" and not _all_finite(column):
            bad = np.flatnonzero(~np.isfinite(column.to_numpy()))
            message = "infinite value"
        if bad.size and (first_bad is None or bad[0] < first_bad[0]):
            first_bad = (int(bad[0]), name, message)
    if first_bad is not None:
        row, name, message = first_bad
        expected = "a finite number" if columns[name] == "float" else _EXPECTED[columns[name]]
        raise InputError(path, message, line=csv_errors.row_line(path, row), column=name, expected=expected)


def _all_finite(column: pa.ChunkedArray) -> bool:
    """Whether a float column without nulls holds only finite values, looked at chunk by chunk
    through views (no copy of the whole column)."""
    return all(bool(np.isfinite(chunk.to_numpy()).all()) for chunk in column.chunks)
