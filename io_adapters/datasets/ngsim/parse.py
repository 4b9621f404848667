"""Parsing one NGSIM file into float64/int64 columns of the used fields and each row's location.

The fast parse reads the integer columns as int64 (ids beyond 2^53 stay exact); where it fails
(a file that writes integers as ``12.0``, a bad cell) the file is read again as float64 or as text
for checks.py to name the line and column of the problem.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pyarrow as pa
import pyarrow.csv as pacsv

from lanecast.io_adapters import arrow_pandas
from lanecast.io_adapters.datasets import csv_errors
from lanecast.io_adapters.datasets.ngsim.checks import NAN_LITERALS, check_values, checked_ranges, integral
from lanecast.io_adapters.datasets.ngsim.columns import INTEGER_COLUMNS, TXT_COLUMNS, USED_COLUMNS
from lanecast.io_adapters.datasets.ngsim.locations import location_codes, location_from_path
from lanecast.io_adapters.datasets.ngsim.sniff import header_names, other_separator
from lanecast.io_adapters.errors import InputError

if TYPE_CHECKING:
    import pandas as pd


@dataclass
class Parsed:
    """The used columns of one file (float64 [n], lower-case names) and each row's location."""

    path: Path
    columns: dict[str, np.ndarray]
    location_code: np.ndarray  # int64 [n] into `locations`
    locations: list[str]
    location_source: str  # "column", "option", "path" or "default"
    direction: np.ndarray | None  # float64 [n], the CSV's Direction, or None
    header: bool  # the CSV export (a header line), not the .txt form

    def line(self, row: int) -> int:
        """The 1-based line of data row ``row`` (error path only: reads the file)."""
        return csv_errors.row_line(self.path, row, header=self.header, whitespace=not self.header)


def parse_file(path: Path, location: str | None) -> Parsed:
    """One .txt or CSV export; ``location`` (normalised) names the location of a file without a
    Location column, or keeps only its rows in one with."""
    if not path.is_file():
        raise InputError(path, "no such file")
    with path.open("rb") as fh:
        head = fh.read(1 << 16)
    if not head.strip() and path.stat().st_size <= len(head):
        raise InputError(path, "empty file", line=1, expected="NGSIM trajectory rows")
    first = csv_errors.first_line(head).decode("utf-8", errors="replace")
    if "," in first:
        return _parse_csv(path, first, location)
    sep = other_separator(first)
    if sep is not None:
        raise InputError(
            path,
            f"the header is separated by {sep}",
            line=1,
            expected="the NGSIM CSV export's comma-separated fields with decimal points",
        )
    return _parse_txt(path, location)


def _parse_txt(path: Path, location: str | None) -> Parsed:
    """The 18-column whitespace-separated form (no header)."""
    n_fields = len(TXT_COLUMNS)
    # Integer columns as int64 where every cell is a plain integer (ids above 2^53 stay exact),
    # else everything as float64 and the integers checked afterwards.
    arrow_pandas.allow()
    import pandas as pd  # here, not at the top: every other command is spared its import (~0.2 s)

    int_types = {
        i: np.int64 if n.lower() in INTEGER_COLUMNS else np.float64 for i, n in enumerate(TXT_COLUMNS)
    }
    try:
        with warnings.catch_warnings():  # pandas warns before it refuses a float cell as int64
            warnings.simplefilter("ignore", RuntimeWarning)
            frame = pd.read_csv(path, sep=r"\s+", header=None, dtype=int_types, engine="c")
        ok, error = frame.shape[1] == n_fields, f"{frame.shape[1]} columns"
    except (ValueError, OverflowError, pd.errors.ParserError):
        ok = False
    try:
        if not ok:
            frame = pd.read_csv(path, sep=r"\s+", header=None, dtype=np.float64, engine="c")
        ok, error = frame.shape[1] == n_fields, f"{frame.shape[1]} columns"
    except pd.errors.EmptyDataError as exc:
        raise InputError(path, "empty file", line=1, expected="NGSIM trajectory rows") from exc
    except (ValueError, pd.errors.ParserError) as exc:
        ok, error = False, str(exc)
    if not ok:
        csv_errors.check_field_counts(path, path.read_bytes(), TXT_COLUMNS, whitespace=True)
        try:
            frame = pd.read_csv(path, sep=r"\s+", header=None, dtype=str, engine="c", keep_default_na=False)
        except (ValueError, pd.errors.ParserError) as exc:
            # the parser's message names no line (a byte that is not UTF-8 "in position 4" of a block)
            csv_errors.check_parseable(path, path.read_bytes())
            raise InputError(path, f"cannot parse: {exc}", expected="18 numbers a line") from exc
        columns = {
            name.lower(): _coerce(frame[i], allow_missing=name.lower() not in USED_COLUMNS)
            for i, name in enumerate(TXT_COLUMNS)
        }
        check_values(path, columns, TXT_COLUMNS, header=False)
        raise InputError(path, f"cannot parse: {error}", expected="18 whitespace-separated numbers a line")
    columns = {name.lower(): frame[i].to_numpy() for i, name in enumerate(TXT_COLUMNS)}
    columns = {name: columns[name] for name in USED_COLUMNS}
    short_line = bool(frame.isna().to_numpy().any())  # the parser pads short lines with NaN
    if short_line or not all(np.isfinite(v).all() for v in columns.values()) or not integral(columns):
        csv_errors.check_field_counts(path, path.read_bytes(), TXT_COLUMNS, whitespace=True)
        check_values(path, columns, TXT_COLUMNS, header=False)
    columns = checked_ranges(path, columns, TXT_COLUMNS, header=False)
    loc, source = (location, "option") if location else location_from_path(path)
    return Parsed(path, columns, np.zeros(len(columns["vehicle_id"]), np.int64), [loc], source, None, False)


def csv_columns(path: Path, first: str) -> tuple[dict[str, str], list[str], dict[str, pa.DataType]]:
    """The CSV export's columns from its header line ``first``: (lower-case stripped name → the name
    as pyarrow sees it, the columns to read, their types with the integer ones as int64). InputError
    at line 1 where a used column appears twice or is missing."""
    by_lower: dict[str, str] = {}
    for raw in header_names(first):
        name = raw.strip()
        if name.lower() in by_lower and name.lower() in (*USED_COLUMNS, "location", "direction"):
            raise InputError(
                path,
                f"column {name!r} appears twice (as {by_lower[name.lower()].strip()!r} too)",
                line=1,
                column=name,
                expected="each NGSIM column once (names match in any case)",
            )
        by_lower.setdefault(name.lower(), raw)
    for name in USED_COLUMNS:
        if name not in by_lower:
            raise InputError(
                path,
                f"missing column {name!r}",
                line=1,
                column=name,
                expected=f"a header with {', '.join(USED_COLUMNS)} (any case)",
            )
    optional = [n for n in ("location", "direction") if n in by_lower]
    wanted = [by_lower[n] for n in (*USED_COLUMNS, *optional)]
    types = {
        by_lower[n]: pa.int64() if n in INTEGER_COLUMNS else pa.float64() for n in (*USED_COLUMNS, *optional)
    }
    if "location" in by_lower:
        types[by_lower["location"]] = pa.string()
    return by_lower, wanted, types


def _parse_csv(path: Path, first: str, location: str | None) -> Parsed:
    """The 25-column CSV export (header; names matched case-insensitively)."""
    by_lower, wanted, types = csv_columns(path, first)
    header = [name.strip() for name in header_names(first)]
    # Integer columns as int64 (ids 2^53 and 2^53 + 1 stay distinct); a file that writes them with a
    # fraction ("12.0") is read as float64 and checked to hold exact whole numbers.
    try:
        table = pacsv.read_csv(
            path,
            convert_options=pacsv.ConvertOptions(
                include_columns=wanted, column_types=types, strings_can_be_null=False
            ),
        )
    except pa.ArrowInvalid:
        table = _parse_csv_slowly(path, by_lower, wanted, types, header)
    if table.num_rows == 0:
        raise InputError(path, "the file has a header but no rows", line=2, expected="NGSIM rows")
    csv_errors.check_one_line_per_row(path, table)
    columns = {n: table.column(by_lower[n]).to_numpy() for n in USED_COLUMNS}
    if not all(np.isfinite(v).all() for v in columns.values()) or not integral(columns):
        csv_errors.check_field_counts(path, path.read_bytes(), header)
        check_values(path, columns, header, header=True)
    columns = checked_ranges(path, columns, header, header=True)
    direction = table.column(by_lower["direction"]).to_numpy() if "direction" in by_lower else None
    n = table.num_rows
    if "location" not in by_lower:
        loc, source = (location, "option") if location else location_from_path(path)
        return Parsed(path, columns, np.zeros(n, dtype=np.int64), [loc], source, direction, True)
    import pyarrow.compute as pc  # only for a CSV export's locations: not on every start

    raw = pc.utf8_trim_whitespace(table.column(by_lower["location"])).combine_chunks()
    empty = np.flatnonzero(np.asarray(pc.equal(raw, "")))
    if empty.size:
        raise InputError(
            path,
            "empty Location",
            line=csv_errors.row_line(path, int(empty[0])),
            column=by_lower["location"].strip(),
            expected="a location name such as peachtree or us-101",
        )
    codes, names = location_codes(raw)
    parsed = Parsed(path, columns, codes, names, "column", direction, True)
    return parsed if location is None else _keep_location(parsed, location)


def _parse_csv_slowly(
    path: Path, by_lower: dict[str, str], wanted: list[str], types: dict[str, pa.DataType], header: list[str]
) -> pa.Table:
    """The CSV export where the int64 read failed: as float64 (integers written ``12.0``), else as
    text, each cell checked (InputError at the first bad one)."""
    floats = {c: pa.float64() if t == pa.int64() else t for c, t in types.items()}
    try:
        return pacsv.read_csv(
            path,
            convert_options=pacsv.ConvertOptions(
                include_columns=wanted, column_types=floats, strings_can_be_null=False
            ),
        )
    except pa.ArrowInvalid as exc:
        failure = exc
    if csv_errors.record_lines(path.read_bytes())[0].size < 2:
        raise InputError(
            path, "the file has a header but no rows", line=2, expected="NGSIM rows"
        ) from failure
    csv_errors.check_field_counts(path, path.read_bytes(), header)
    try:
        strings = pacsv.read_csv(
            path,
            convert_options=pacsv.ConvertOptions(
                include_columns=wanted, column_types=dict.fromkeys(wanted, pa.string())
            ),
        )
    except pa.ArrowInvalid:
        csv_errors.check_parseable(path, path.read_bytes())
        raise InputError(path, f"cannot parse: {failure}", expected="NGSIM CSV rows") from failure
    checked = [n for n in (*USED_COLUMNS, "direction") if n in by_lower]
    arrow_pandas.allow()
    columns = {
        n: _coerce(strings.column(by_lower[n]).to_pandas(), allow_missing=n == "direction") for n in checked
    }
    check_values(path, columns, header, header=True)
    # every used cell is a number: what the typed read refused is a missing Direction written as
    # blanks (``, ,``, a tool that puts a space after each comma), read as missing
    if "direction" in by_lower:
        columns["direction"] = _coerce(strings.column(by_lower["direction"]).to_pandas())
    location = {by_lower["location"]: strings.column(by_lower["location"])} if "location" in by_lower else {}
    return pa.table({by_lower[n]: columns[n] for n in checked} | location)


def _keep_location(parsed: Parsed, location: str) -> Parsed:
    if location not in parsed.locations:
        raise InputError(
            parsed.path,
            f"no rows of location {location!r}",
            column="Location",
            expected=f"one of {parsed.locations}",
        )
    keep = parsed.location_code == parsed.locations.index(location)
    direction = None if parsed.direction is None else parsed.direction[keep]
    columns = {k: v[keep] for k, v in parsed.columns.items()}
    return Parsed(
        parsed.path, columns, np.zeros(int(keep.sum()), np.int64), [location], "column", direction, True
    )


def _coerce(cells: pd.Series, allow_missing: bool = False) -> np.ndarray:
    """Cells as float64 [n], NaN where a cell is not a number (for locating bad cells). With
    ``allow_missing`` (columns this reader does not use), missing-value cells such as NaN count as
    fine (0.0): only text that is not a number at all is flagged."""
    arrow_pandas.allow()
    import pandas as pd  # only for bad or text files (see _parse_txt)

    values = np.array(pd.to_numeric(cells, errors="coerce"), dtype=np.float64)  # a writable copy
    if allow_missing:
        values[np.asarray(cells.astype(str).str.strip().str.lower().isin(NAN_LITERALS))] = 0.0
    return values
