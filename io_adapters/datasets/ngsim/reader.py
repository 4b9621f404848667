"""NGSIM reader: US-101, I-80, Lankershim and Peachtree trajectories into the track table (docs/design.md §1).

Two source forms are read:

* the original whitespace-separated ``trajectories-*.txt`` files of US-101 and I-80: 18 columns,
  no header (:data:`TXT_COLUMNS`); their location comes from the ``location=`` option or the path;
* the 25-column CSV export with a header (names matched case-insensitively; the ``Location``
  column may mix lankershim, peachtree, us-101 and i-80 in one file).

Conversion (all NGSIM is 10 Hz, in feet): positions, lengths, speeds and accelerations are scaled by
0.3048; ``frame`` is ``Frame_ID`` and ``time_ns = Frame_ID * 1e8``. ``Local_Y`` (longitudinal) and
``Local_X`` (lateral, to the right) locate the *front bumper*; the track table holds the centre.

* Freeways (US-101, I-80, and ``unknown`` .txt files): road frame, ``x = (Local_Y - v_Length/2)``,
  ``y = -Local_X``, ``vx = v_Vel``, ``vy`` the gradient of ``y`` along the track over ±0.5 s,
  ``heading = atan2(vy, vx)`` (0 below 0.5 m/s).
* Arterials (Lankershim, Peachtree): vehicles drive both ways and turn, so the frame is ``local``
  (x = ``Local_Y``, y = ``-Local_X``), ``heading`` is the direction of motion of the front bumper
  (differences over ±0.5 s, trusted above 1 m/s where it agrees with ``v_Vel`` and does not run
  against the stated ``Direction``; held through stops and glitches, ``Direction`` as a last resort;
  then averaged over ±0.5 s so that it turns, never flips) and the centre is the front bumper moved
  back by half the length *along the heading* (for a southbound car that is +L/2 in x).
  ``vx, vy = v_Vel * (cos, sin)(heading)``.

``ax, ay`` are ``v_Acc`` along the heading, except where the vehicle stands still (``v_Vel`` 0 in
the row and in its track's rows before and after): there NGSIM's ``v_Acc`` holds single-frame
spikes of up to ±6 ft/s² that no motion follows (a speed that stays 0 cannot have accelerated), and
the acceleration is 0. One recording per (location, source file, period):
``ngsim-<location>-<file stem>``; when one file holds several recording periods, the periods become
``...-p1``, ``...-p2`` (ordered by time). A period is a cluster of the epoch
``Global_Time - 100 * Frame_ID``. The CSV export needs this: its Peachtree rows have two epochs,
11,700 apart (3 h 15 min if seconds: Peachtree's 12:45 and 16:00 periods), whose vehicle ids and
frames overlap, so that one recording per location would merge different vehicles. Within a recording, exact duplicate (vehicle, frame) rows are
dropped; duplicates with differing values keep the first row in file order and are reported on
stderr; both are counted in the recording metadata.

Integer columns are read as int64 (ids beyond 2^53 stay exact). Values that parse but cannot be
right are refused at their line and column: a Frame_ID whose time overflows, a Global_Time beyond
2^53 or one that puts a stray row of a vehicle in another recording period, a size that is not
positive, a negative speed, a Lane_ID outside int32.

Size: one reader for NGSIM's two file forms, its four locations and its data repairs (repeated
rows, mixed locations, heading flips), which are read together; the bad-line finder is shared
(``datasets/csv_errors.py``).
"""

from __future__ import annotations

import csv
import math
import re
import sys
import warnings
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.csv as pacsv

from lanecast.io_adapters.contracts import track_table
from lanecast.io_adapters.contracts.track_runs import along_track_derivative, row_extent, run_starts
from lanecast.io_adapters.datasets.csv_errors import (
    REPEATED_HEADER,
    check_field_counts,
    check_one_line_per_row,
    check_parseable,
    check_text,
    first_line,
    is_header,
    line_spans,
    not_text,
    record_lines,
    shown,
)
from lanecast.io_adapters.errors import InputError
from lanecast.io_adapters.files import COMPRESSED_SUFFIXES, not_regular, progress

if TYPE_CHECKING:
    import pandas as pd

FORMAT = "ngsim"
FEET = 0.3048
FRAME_RATE = 10.0
FRAME_NS = 100_000_000
GLOBAL_TIME_PER_FRAME = 100  # Global_Time is in ms: 100 per 10 Hz frame
PERIOD_GAP = 1_000  # epochs further apart than this (Global_Time units) are different periods
MIN_MOVING_SPEED = 0.5  # m/s; below it the motion gives no reliable heading
# m/s of front-bumper motion over ±0.5 s from which an arterial heading is taken: NGSIM positions
# jitter by ~0.1 m, a few degrees at this speed; slower motion holds the last reliable heading.
MIN_HEADING_SPEED = 1.0
GRADIENT_SPAN = 5  # rows either side for velocity directions: differences over ±0.5 s
MAX_TURN_FROM_DIRECTION = math.radians(135)  # motion further from the stated Direction is a glitch

# ft: no car is shorter (a Smart Fortwo is 8.8 ft); a file whose median car is, is in metres
MIN_MEDIAN_CAR_FT = 8.0

FREEWAYS = ("us-101", "i-80")
ARTERIALS = ("lankershim", "peachtree")
UNKNOWN_LOCATION = "unknown"

TXT_COLUMNS: tuple[str, ...] = (
    "Vehicle_ID",
    "Frame_ID",
    "Total_Frames",
    "Global_Time",
    "Local_X",
    "Local_Y",
    "Global_X",
    "Global_Y",
    "v_Length",
    "v_Width",
    "v_Class",
    "v_Vel",
    "v_Acc",
    "Lane_ID",
    "Preceding",
    "Following",
    "Space_Headway",
    "Time_Headway",
)
# The columns this reader uses (lower case); the integer ones must hold whole numbers.
USED_COLUMNS: tuple[str, ...] = (
    "vehicle_id",
    "frame_id",
    "global_time",
    "local_x",
    "local_y",
    "v_length",
    "v_width",
    "v_class",
    "v_vel",
    "v_acc",
    "lane_id",
    "preceding",
    "following",
)
INTEGER_COLUMNS = frozenset(
    {"vehicle_id", "frame_id", "global_time", "v_class", "lane_id", "preceding", "following"}
)
_CLASSES = ("unknown", "motorcycle", "car", "truck")  # index = v_Class (1, 2, 3), 0 = anything else
# Fallback heading of a vehicle that never moves, from the CSV's Direction (1 E, 2 N, 3 W, 4 S),
# with +x (Local_Y) northwards and +y (-Local_X) westwards as on the arterials.
_DIRECTION_HEADING = {1: -math.pi / 2, 2: 0.0, 3: math.pi / 2, 4: math.pi}
# The file names NGSIM publishes (without a location in them): US-101's three periods of
# 2005-06-15 and I-80's three of 2005-04-13.
KNOWN_FILES = {
    "trajectories-0750am-0805am": "us-101",
    "trajectories-0805am-0820am": "us-101",
    "trajectories-0820am-0835am": "us-101",
    "trajectories-0400-0415": "i-80",
    "trajectories-0500-0515": "i-80",
    "trajectories-0515-0530": "i-80",
}
_LOCATION_PATTERNS = (
    ("us-101", re.compile(r"(?<![a-z0-9])us[-_ ]?101(?!\d)")),
    ("i-80", re.compile(r"(?<![a-z0-9])i[-_ ]?80(?!\d)")),
    ("lankershim", re.compile(r"lankershim")),
    ("peachtree", re.compile(r"peachtree")),
)


# --------------------------------------------------------------------------------------------- sniff


def sniff(path: Path) -> bool:
    """True for an NGSIM CSV (header with Vehicle_ID, Frame_ID, Local_X, Local_Y) or .txt (18
    numbers), or a directory holding such files."""
    path = Path(path)
    if path.is_dir():  # compressed files too: the reader says to decompress them
        return bool(files_in(path) or compressed_in(path))
    if not path.is_file():
        return False
    try:
        with path.open("rb") as fh:
            head = fh.read(4096)
    except OSError:
        return False
    if not_text(head) is not None:  # a zip archive stored uncompressed starts with its member's header line
        return False
    first = first_line(head).decode("utf-8", errors="replace").lstrip("\ufeff").strip()
    if not first:  # blank lines before the first row of a .txt (which the reader skips)
        first = first_line(head.lstrip(b" \t\r\n")).decode("utf-8", errors="replace")
        if "," in first:
            return False
    if "," in first:
        names = {name.strip().lower() for name in header_names(first)}
        # the key columns, or most of the used ones (the reader then names what is missing)
        return {"vehicle_id", "frame_id", "local_x", "local_y"} <= names or 2 * len(
            names & set(USED_COLUMNS)
        ) > len(USED_COLUMNS)
    if _other_separator(first):
        return True  # the reader says how the header is separated
    tokens = first.split()
    if len(tokens) != len(TXT_COLUMNS):
        return False
    try:
        [float(t) for t in tokens]
    except ValueError:
        return False
    return True


def _unquoted(name: str) -> str:
    """A header field without the double quotes around it, as the CSV parser reads it."""
    stripped = name.strip()
    return stripped[1:-1] if len(stripped) >= 2 and stripped[0] == stripped[-1] == '"' else name


def files_in(folder: Path) -> list[Path]:
    """The NGSIM files (.txt, .csv) anywhere below ``folder``, in name order (hidden ones left out)."""
    return [
        p
        for p in sorted(Path(folder).rglob("*"))
        if p.suffix.lower() in (".txt", ".csv")
        and not any(part.startswith(".") for part in p.relative_to(folder).parts)
        and p.is_file()
        and sniff(p)
    ]


def compressed_in(folder: Path) -> list[Path]:
    """The compressed .txt and .csv files below ``folder`` (``*.txt.gz``, …; hidden ones left out)."""
    return [
        p
        for p in sorted(Path(folder).rglob("*"))
        if p.suffix.lower() in COMPRESSED_SUFFIXES
        and p.with_suffix("").suffix.lower() in (".txt", ".csv")
        and not any(part.startswith(".") for part in p.relative_to(folder).parts)
        and p.is_file()
    ]


def _folder_files(folder: Path) -> list[Path]:
    """:func:`files_in`, refusing a damaged NGSIM file there instead of leaving it out: an empty or
    non-text ``.txt``/``.csv``, one named ``trajectories*`` that is not NGSIM, or a ``.txt``/``.csv``
    that is no regular file (a FIFO, a device, a link to nothing). Other text files (notes, other
    tables) are left out with a line on stderr."""
    found = files_in(folder)
    packed = compressed_in(folder)
    compressed = []
    for p in sorted(Path(folder).rglob("*")):
        if p.suffix.lower() in COMPRESSED_SUFFIXES:
            named = p.with_suffix("").suffix.lower() in (".txt", ".csv")
        else:
            named = p.suffix.lower() in (".txt", ".csv")
        if named and not any(part.startswith(".") for part in p.relative_to(folder).parts):
            reason = not_regular(p)  # a FIFO would block the run, and left out its rows would be lost
            if reason is not None:
                raise InputError(p, reason, expected="NGSIM .txt or .csv files")
        if p in packed:
            compressed.append(p)
            continue
        if (
            p in found
            or p.suffix.lower() not in (".txt", ".csv")
            or any(part.startswith(".") for part in p.relative_to(folder).parts)
            or not p.is_file()
        ):
            continue
        with p.open("rb") as fh:
            head = fh.read(4096)
        check_text(p, head, "an NGSIM .txt or CSV file")
        if not head.strip():
            raise InputError(p, "empty file", line=1, expected="NGSIM trajectory rows")
        if p.name.lower().startswith("trajectories"):
            raise InputError(
                p, "not an NGSIM file: neither 18 numbers a line nor an NGSIM CSV header", line=1
            )
        print(f"lanecast: {p}: not an NGSIM file, left out", file=sys.stderr)
    for p in compressed:  # read nothing of a folder of them without a word, a copy beside its text with one
        with p.open("rb") as fh:
            kind = not_text(fh.read(8)) or "compressed"
        if not found:
            raise InputError(
                p, f"the file is {kind}", offset=0, expected="NGSIM .txt or .csv files: decompress it"
            )
        print(f"lanecast: {p}: {kind}, left out (decompress it to read it)", file=sys.stderr)
    return found


# ---------------------------------------------------------------------------------------------- read


def read(paths: Sequence[Path] | Path | str, **options: Any) -> pa.Table:
    """Read NGSIM files into one validated track table.

    Options: ``location`` (str) names the location of .txt files (us-101, i-80, lankershim,
    peachtree; default: inferred from the path, else ``unknown``) and, for a CSV with a Location
    column, keeps only that location's rows; ``split_periods`` (bool, default True) gives each
    recording period of a file its own recording (False: one per location and file, and rows of
    other periods at the same (vehicle, frame) count as conflicting duplicates).
    """
    if isinstance(paths, (str, Path)):
        paths = [Path(paths)]
    expanded: list[Path] = []
    for p in map(Path, paths):
        found = _folder_files(p) if p.is_dir() else [p]
        if not found:
            raise InputError(p, "no NGSIM files in this directory", expected="NGSIM .txt or .csv files")
        expanded += found
    paths = expanded
    if not paths:
        raise InputError(None, "no input files", expected="one or more NGSIM .txt or .csv files")
    location = options.get("location")
    if location is not None:
        location = _normalise_location(str(location))
    split_periods = bool(options.get("split_periods", True))
    parsed = [_parse_file(Path(p), location) for p in progress(paths, desc="ngsim", unit="file")]
    return _assemble(parsed, split_periods)


@dataclass
class _Parsed:
    """The used columns of one file (float64 [n], lower-case names) and each row's location."""

    path: Path
    columns: dict[str, np.ndarray]
    location_code: np.ndarray  # int64 [n] into `locations`
    locations: list[str]
    location_source: str  # "column", "option", "path" or "default"
    direction: np.ndarray | None  # float64 [n], the CSV's Direction, or None


_KEY_COLUMNS = ("vehicle_id", "frame_id", "local_x", "local_y")


def _other_separator(first: str) -> str | None:
    """``';'`` or ``tabs`` where the line ``first`` is the CSV export's header separated by them
    (a spreadsheet saving with semicolons and decimal commas, or as tab-separated text), else None."""
    for sep, name in ((";", "';'"), ("\t", "tabs")):
        names = {cell.strip().strip('"').lower() for cell in first.lstrip("\ufeff").split(sep)}
        if set(_KEY_COLUMNS) <= names:
            return name
    return None


def _parse_file(path: Path, location: str | None) -> _Parsed:
    if not path.is_file():
        raise InputError(path, "no such file")
    with path.open("rb") as fh:
        head = fh.read(1 << 16)
    if not head.strip() and path.stat().st_size <= len(head):
        raise InputError(path, "empty file", line=1, expected="NGSIM trajectory rows")
    first = first_line(head).decode("utf-8", errors="replace")
    if "," in first:
        return _parse_csv(path, first, location)
    sep = _other_separator(first)
    if sep is not None:
        raise InputError(
            path,
            f"the header is separated by {sep}",
            line=1,
            expected="the NGSIM CSV export's comma-separated fields with decimal points",
        )
    return _parse_txt(path, location)


def _parse_txt(path: Path, location: str | None) -> _Parsed:
    """The 18-column whitespace-separated form (no header)."""
    n_fields = len(TXT_COLUMNS)
    # Integer columns as int64 where every cell is a plain integer (ids above 2^53 stay exact),
    # else everything as float64 and the integers checked afterwards.
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
        check_field_counts(path, path.read_bytes(), TXT_COLUMNS, whitespace=True)
        try:
            frame = pd.read_csv(path, sep=r"\s+", header=None, dtype=str, engine="c", keep_default_na=False)
        except (ValueError, pd.errors.ParserError) as exc:
            # the parser's message names no line (a byte that is not UTF-8 "in position 4" of a block)
            check_parseable(path, path.read_bytes())
            raise InputError(path, f"cannot parse: {exc}", expected="18 numbers a line") from exc
        columns = {
            name.lower(): _coerce(frame[i], allow_missing=name.lower() not in USED_COLUMNS)
            for i, name in enumerate(TXT_COLUMNS)
        }
        _check_values(path, columns, TXT_COLUMNS, header=False)
        raise InputError(path, f"cannot parse: {error}", expected="18 whitespace-separated numbers a line")
    columns = {name.lower(): frame[i].to_numpy() for i, name in enumerate(TXT_COLUMNS)}
    columns = {name: columns[name] for name in USED_COLUMNS}
    short_line = bool(frame.isna().to_numpy().any())  # the parser pads short lines with NaN
    if short_line or not all(np.isfinite(v).all() for v in columns.values()) or not _integral(columns):
        check_field_counts(path, path.read_bytes(), TXT_COLUMNS, whitespace=True)
        _check_values(path, columns, TXT_COLUMNS, header=False)
    columns = _checked_ranges(path, columns, TXT_COLUMNS, header=False)
    loc, source = (location, "option") if location else _location_from_path(path)
    n = len(columns["vehicle_id"])
    return _Parsed(path, columns, np.zeros(n, dtype=np.int64), [loc], source, None)


def header_names(first: str) -> list[str]:
    """The column names of the CSV header line ``first`` as pyarrow reads them: without a BOM or
    the quotes around a name, spaces kept."""
    return [_unquoted(raw) for raw in first.lstrip("\ufeff").rstrip("\r").split(",")]


def csv_columns(path: Path, first: str) -> tuple[dict[str, str], list[str], dict[str, pa.DataType]]:
    """The CSV export's columns from its header line ``first``: (lower-case stripped name → the name
    as pyarrow sees it, the columns to read, their types but for the integer ones). InputError at
    line 1 where a used column appears twice or is missing."""
    by_lower: dict[str, str] = {}  # lower-case stripped name -> the name as pyarrow sees it
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
    types: dict[str, pa.DataType] = {by_lower[n]: pa.float64() for n in USED_COLUMNS}
    if "direction" in by_lower:
        types[by_lower["direction"]] = pa.float64()
    if "location" in by_lower:
        types[by_lower["location"]] = pa.string()
    return by_lower, wanted, types


def _parse_csv(path: Path, first: str, location: str | None) -> _Parsed:
    """The 25-column CSV export (header; names matched case-insensitively)."""
    by_lower, wanted, types = csv_columns(path, first)
    header = [name.strip() for name in header_names(first)]
    # Integer columns as int64 (ids 2^53 and 2^53 + 1 stay distinct); a file that writes them with a
    # fraction ("12.0") is read as float64 and checked to hold exact whole numbers.
    int_types = {**types, **{by_lower[n]: pa.int64() for n in INTEGER_COLUMNS}}
    try:
        table = pacsv.read_csv(
            path,
            convert_options=pacsv.ConvertOptions(
                include_columns=wanted, column_types=int_types, strings_can_be_null=False
            ),
        )
    except pa.ArrowInvalid:
        table = None
    convert = pacsv.ConvertOptions(include_columns=wanted, column_types=types, strings_can_be_null=False)
    try:
        if table is None:
            table = pacsv.read_csv(path, convert_options=convert)
    except pa.ArrowInvalid as exc:
        if record_lines(path.read_bytes())[0].size < 2:
            raise InputError(
                path, "the file has a header but no rows", line=2, expected="NGSIM rows"
            ) from exc
        check_field_counts(path, path.read_bytes(), header)
        try:
            strings = pacsv.read_csv(
                path,
                convert_options=pacsv.ConvertOptions(
                    include_columns=wanted, column_types=dict.fromkeys(wanted, pa.string())
                ),
            )
        except pa.ArrowInvalid:
            check_parseable(path, path.read_bytes())
            raise InputError(path, f"cannot parse: {exc}", expected="NGSIM CSV rows") from exc
        checked = [n for n in (*USED_COLUMNS, "direction") if n in by_lower]
        columns = {
            n: _coerce(strings.column(by_lower[n]).to_pandas(), allow_missing=n == "direction")
            for n in checked
        }
        _check_values(path, columns, header, header=True)
        # every used cell is a number: what the typed read refused is a missing Direction written
        # as blanks (``, ,``, a tool that puts a space after each comma), read as missing
        if "direction" in by_lower:
            columns["direction"] = _coerce(strings.column(by_lower["direction"]).to_pandas())
        table = pa.table(
            {by_lower[n]: columns[n] for n in checked}
            | ({by_lower["location"]: strings.column(by_lower["location"])} if "location" in by_lower else {})
        )
    if table.num_rows == 0:
        raise InputError(path, "the file has a header but no rows", line=2, expected="NGSIM rows")
    check_one_line_per_row(path, table)
    columns = {n: table.column(by_lower[n]).to_numpy() for n in USED_COLUMNS}
    if not all(np.isfinite(v).all() for v in columns.values()) or not _integral(columns):
        check_field_counts(path, path.read_bytes(), header)
        _check_values(path, columns, header, header=True)
    columns = _checked_ranges(path, columns, header, header=True)
    direction = table.column(by_lower["direction"]).to_numpy() if "direction" in by_lower else None
    n = table.num_rows
    if "location" not in by_lower:
        loc, source = (location, "option") if location else _location_from_path(path)
        return _Parsed(path, columns, np.zeros(n, dtype=np.int64), [loc], source, direction)
    raw = pc.utf8_trim_whitespace(table.column(by_lower["location"])).combine_chunks()
    empty = np.asarray(pc.equal(raw, ""))
    if empty.any():
        row = int(np.flatnonzero(empty)[0])
        raise InputError(
            path,
            "empty Location",
            line=int(record_lines(path.read_bytes())[0][row + 1]),
            column=by_lower["location"].strip(),
            expected="a location name such as peachtree or us-101",
        )
    encoded = raw.dictionary_encode()
    names = [_normalise_location(str(v)) for v in encoded.dictionary.to_pylist()]
    unique_names = sorted(set(names))
    remap = np.array([unique_names.index(v) for v in names], dtype=np.int64)
    codes = remap[np.asarray(encoded.indices)]
    parsed = _Parsed(path, columns, codes, unique_names, "column", direction)
    if location is not None:
        parsed = _keep_location(parsed, location)
    return parsed


def _keep_location(parsed: _Parsed, location: str) -> _Parsed:
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
    return _Parsed(parsed.path, columns, np.zeros(int(keep.sum()), np.int64), [location], "column", direction)


_NAN_LITERALS = ("nan", "na", "n/a", "null", "#n/a", "")


def _coerce(cells: pd.Series, allow_missing: bool = False) -> np.ndarray:
    """Cells as float64 [n], NaN where a cell is not a number (for locating bad cells).

    With ``allow_missing`` (columns this reader does not use), missing-value cells such as NaN
    count as fine (0.0): only text that is not a number at all is flagged.
    """
    import pandas as pd  # only for text files (see _parse_txt)

    values = np.array(pd.to_numeric(cells, errors="coerce"), dtype=np.float64)  # a writable copy
    if allow_missing:
        missing = np.asarray(cells.astype(str).str.strip().str.lower().isin(_NAN_LITERALS))
        values[missing] = 0.0
    return values


def _integral(columns: dict[str, np.ndarray]) -> bool:
    return all(np.array_equal(columns[n], np.round(columns[n])) for n in INTEGER_COLUMNS)


def _normalise_location(name: str) -> str:
    low = name.strip().lower()
    for canonical, pattern in _LOCATION_PATTERNS:
        if pattern.fullmatch(low):
            return canonical
    slug = re.sub(r"[^a-z0-9]+", "-", low).strip("-")
    return slug or UNKNOWN_LOCATION


def _is_freeway(location: str) -> bool:
    """US-101, I-80 and .txt files of unknown location (the 18-column form is the freeways')."""
    return location in FREEWAYS or location == UNKNOWN_LOCATION


def _location_from_path(path: Path) -> tuple[str, str]:
    """The location named by the file name (or NGSIM's own name for it, ``KNOWN_FILES``), else by
    the nearest parent directory, else unknown."""
    for canonical, pattern in _LOCATION_PATTERNS:
        if pattern.search(path.name.lower()):
            return canonical, "path"
    if path.stem.lower() in KNOWN_FILES:
        return KNOWN_FILES[path.stem.lower()], "path"
    for part in (p.name for p in path.resolve().parents):
        for canonical, pattern in _LOCATION_PATTERNS:
            if pattern.search(part.lower()):
                return canonical, "path"
    return UNKNOWN_LOCATION, "default"


# ------------------------------------------------------------------------------ diagnosis of bad input


def _check_values(path: Path, columns: dict[str, np.ndarray], names: Sequence[str], *, header: bool) -> None:
    """Raise InputError at the first cell (row-major) of ``columns`` that is not a finite number.

    ``columns`` hold float64 [n] (lower-case names) with NaN where a cell did not parse; the cell's
    text is read back from the line to say what it was.
    """
    lower = [n.lower() for n in names]
    first_row, first_col = None, ""
    for name in columns:
        values = columns[name]
        bad = ~np.isfinite(values)
        if name in INTEGER_COLUMNS:
            bad |= np.isfinite(values) & (values != np.round(values))
        if bad.any():
            row = int(np.flatnonzero(bad)[0])
            if first_row is None or row < first_row:
                first_row, first_col = row, name
    if first_row is None:
        return
    data = path.read_bytes()
    line = int(record_lines(data, whitespace=not header)[0][first_row + (1 if header else 0)])
    starts, ends = line_spans(data)
    text = data[starts[line - 1] : ends[line - 1]].decode("utf-8", errors="replace")
    cells = next(csv.reader([text])) if header else text.split()  # "40,5" is one cell
    if is_header(cells, names):  # the CSV's header line, or the .txt columns' names, again
        raise InputError(
            path,
            REPEATED_HEADER
            if header
            else "column names in the data (a header line; two files joined into one?)",
            line=line,
            expected="one header line, at line 1" if header else "18 numbers a line, no header",
        )
    index = lower.index(first_col)
    cell = cells[index].strip() if index < len(cells) else ""
    integer = first_col in INTEGER_COLUMNS
    if cell == "":
        problem = "empty cell"
    elif cell.lower() in _NAN_LITERALS:
        problem = f"missing value {shown(cell)}"
    elif cell.lower().lstrip("+-") in {"inf", "infinity"}:
        problem = f"infinite value {shown(cell)}"
    elif math.isfinite(columns[first_col][first_row]):
        problem = f"{shown(cell)} is not a whole number"
    else:
        problem = f"{shown(cell)} is not a finite number"
    raise InputError(
        path,
        problem,
        line=line,
        column=names[index],
        expected="an integer" if integer else "a finite number",
    )


# ------------------------------------------------------------------------------- value ranges

EXACT_FLOAT_INT = 2**53  # integers read through float64 are exact only below this
MAX_FRAME_ID = 2**62 // FRAME_NS  # time_ns = Frame_ID * 1e8 stays well inside int64
INT32_MAX = 2**31 - 1
FLOAT32_MAX = float(np.finfo(np.float32).max)
MAX_POSITION_FT = 1e9  # Local_X/Local_Y beyond this are no road (NGSIM's are below 1e4)
MAX_SIZE_FT = 1000.0  # v_Length, v_Width: the longest road trains are under 200 ft


def _checked_ranges(
    path: Path, columns: dict[str, np.ndarray], names: Sequence[str], *, header: bool
) -> dict[str, np.ndarray]:
    """The columns with the integer ones as int64, after refusing values that parse but cannot be
    right: integers read through float64 beyond 2^53, a Frame_ID whose time overflows, a
    Global_Time beyond 2^53 ms, a size that is not positive, a negative speed, a Lane_ID that is
    negative or outside int32. InputError at the first such cell (file order), naming its line and column."""
    out = dict(columns)
    bad_rows: list[tuple[int, str, str]] = []

    def flag(name: str, bad: np.ndarray, expected: str) -> None:
        rows = np.flatnonzero(bad)
        if rows.size:
            bad_rows.append((int(rows[0]), name, expected))

    for name in INTEGER_COLUMNS:
        values = out[name]
        if values.dtype.kind == "f":
            flag(
                name,
                np.abs(values) >= EXACT_FLOAT_INT,
                "an integer written without a fraction, or below 2^53",
            )
    if not bad_rows:
        for name in INTEGER_COLUMNS:
            out[name] = out[name].astype(np.int64)
        flag("vehicle_id", out["vehicle_id"] < 0, "a vehicle id >= 0")  # NGSIM numbers from 1
        flag("frame_id", (out["frame_id"] < 0) | (out["frame_id"] > MAX_FRAME_ID), f"0 to {MAX_FRAME_ID}")
        flag(
            "global_time", (out["global_time"] < 0) | (out["global_time"] >= EXACT_FLOAT_INT), "0 to 2^53 ms"
        )
        # NGSIM numbers lanes from 1 (0 and >= 10 on the arterials' intersections and bays); a
        # negative one on a row or two would be two lane changes that never happened
        flag("lane_id", (out["lane_id"] < 0) | (out["lane_id"] > INT32_MAX), "a lane id >= 0 within int32")
        size = f"> 0 and <= {MAX_SIZE_FT:g} ft"  # no road vehicle is longer than a few hundred feet
        flag("v_length", ~((out["v_length"] > 0) & (out["v_length"] <= MAX_SIZE_FT)), f"a length {size}")
        flag("v_width", ~((out["v_width"] > 0) & (out["v_width"] <= MAX_SIZE_FT)), f"a width {size}")
        flag("v_vel", ~(out["v_vel"] >= 0), "a speed >= 0 ft/s")
        for name in ("v_length", "v_width", "v_vel", "v_acc"):  # float32 in the table
            flag(name, np.abs(out[name]) > FLOAT32_MAX / FEET, "a value within float32")
        limit = track_table.MAX_POSITION_M / FEET  # the track table's bounds (track_table.RANGES), in feet
        flag("v_vel", np.abs(out["v_vel"]) > limit, f"a speed within ±{limit:.4g} ft/s")
        flag("v_acc", np.abs(out["v_acc"]) > limit, f"an acceleration within ±{limit:.4g} ft/s^2")
        for name in ("local_x", "local_y"):  # differences over 0.1 s must stay float32 speeds
            flag(name, np.abs(out[name]) > MAX_POSITION_FT, f"a position within ±{MAX_POSITION_FT:g} ft")
    if not bad_rows:
        _check_feet(path, out, names, header=header)
        return out
    row, name, expected = min(bad_rows)
    line = int(record_lines(path.read_bytes(), whitespace=not header)[0][row + (1 if header else 0)])
    column = next(n for n in names if n.strip().lower() == name)
    raise InputError(path, f"{column} is {columns[name][row]}", line=line, column=column, expected=expected)


def _check_feet(path: Path, columns: dict[str, np.ndarray], names: Sequence[str], *, header: bool) -> None:
    """Refuse a file whose vehicle lengths are metres, not NGSIM's feet: cars (``v_Class`` 2; all
    vehicles if none is) shorter than ``MIN_MEDIAN_CAR_FT`` at the median would be read 3.3 times
    too small, and their positions and speeds with them. InputError at the first such car's line."""
    length = columns["v_length"]
    cars = columns["v_class"] == 2
    pool = cars if cars.any() else np.ones(length.size, dtype=bool)
    median = float(np.median(length[pool])) if pool.any() else MIN_MEDIAN_CAR_FT
    if median >= MIN_MEDIAN_CAR_FT:
        return
    row = int(np.flatnonzero(pool & (length < MIN_MEDIAN_CAR_FT))[0])
    line = int(record_lines(path.read_bytes(), whitespace=not header)[0][row + (1 if header else 0)])
    raise InputError(
        path,
        f"the median {'car' if cars.any() else 'vehicle'} length is {median:g}, no car is under "
        f"{MIN_MEDIAN_CAR_FT:g} ft: lengths (and so positions and speeds) look like metres",
        line=line,
        column=next(n for n in names if n.strip().lower() == "v_length"),
        expected=f"NGSIM's feet (cars of {MIN_MEDIAN_CAR_FT:g} ft and more)",
    )


# ------------------------------------------------------------------------------------------ assembly


def _periods(columns: dict[str, np.ndarray], split: bool) -> tuple[np.ndarray, np.ndarray]:
    """Period index per row [n] (0-based, in time order) and the epoch of each period [P]."""
    epoch = columns["global_time"] - GLOBAL_TIME_PER_FRAME * columns["frame_id"]
    if not split:
        return np.zeros(epoch.size, dtype=np.int64), np.array([epoch.min()])
    unique = np.unique(epoch)
    cluster_of_unique = np.concatenate([[0], np.cumsum(np.diff(unique) > PERIOD_GAP)])
    period = cluster_of_unique[np.searchsorted(unique, epoch)]
    starts = np.flatnonzero(np.concatenate([[True], np.diff(cluster_of_unique) > 0]))
    return period.astype(np.int64), unique[starts]


def _assemble(files: list[_Parsed], split_periods: bool) -> pa.Table:
    names: list[str] = []
    metas: dict[str, track_table.RecordingMeta] = {}
    origin: dict[str, Path] = {}
    parts: list[dict[str, np.ndarray]] = []
    for parsed in files:
        cols = parsed.columns
        period, epochs = _periods(cols, split_periods)
        _check_small_location(parsed)
        _check_period_continuity(parsed, period)
        _check_wrong_way(parsed, period)
        key = parsed.location_code * len(epochs) + period
        n_rows = key.size
        code = np.empty(n_rows, dtype=np.int64)
        for loc_index, loc in enumerate(parsed.locations):
            loc_keys = np.unique(key[parsed.location_code == loc_index])
            for rank, k in enumerate(loc_keys, start=1):
                rows = key == k
                name = f"ngsim-{loc}-{parsed.path.stem}" + (f"-p{rank}" if loc_keys.size > 1 else "")
                if name in metas:
                    raise InputError(
                        parsed.path,
                        f"recording {name!r} also comes from {origin[name]}",
                        expected="input files with distinct names per location",
                    )
                origin[name] = parsed.path
                gt = cols["global_time"][rows]
                metas[name] = track_table.RecordingMeta(
                    frame_rate=FRAME_RATE,
                    coordinate_frame="road" if _is_freeway(loc) else "local",
                    source_files=[str(parsed.path)],
                    extra=_recording_extra(
                        loc,
                        parsed.location_source,
                        int(epochs[k % len(epochs)]),
                        int(gt.min()),
                        rank,
                        loc_keys.size,
                    ),
                )
                code[rows] = len(names)
                names.append(name)
        direction = parsed.direction if parsed.direction is not None else np.full(n_rows, np.nan)
        parts.append({**cols, "recording": code, "direction": direction})
    merged = parts[0] if len(parts) == 1 else {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
    return _to_track_table(merged, names, metas, [str(p.path) for p in files])


MAX_STRAY_ROWS = 2  # rows of a vehicle in a period, next to its frames in another, taken as a bad cell


def small_period(period: np.ndarray) -> int | None:
    """The period (index into ``period``'s values) of at most MAX_STRAY_ROWS rows when a file has
    more than one: a phantom recording period made of a bad cell or two; None if there is none."""
    sizes = np.bincount(period)
    if sizes.size > 1 and sizes.min() <= MAX_STRAY_ROWS:
        return int(np.argmin(sizes))
    return None


def stray_pair(
    location_code: np.ndarray, vehicle: np.ndarray, frame: np.ndarray, period: np.ndarray
) -> tuple[int, int] | None:
    """(stray row, its neighbour) [indices into the arrays, [n] each]: the first row of a vehicle
    put by its Global_Time in another period than its neighbouring frame (frame +-1) while one of
    the two (location, vehicle, period) groups has at most MAX_STRAY_ROWS rows; None if none is."""
    order = np.lexsort((frame, vehicle, location_code))
    veh, fr = vehicle[order], frame[order]
    loc, per = location_code[order], period[order]
    cut = (loc[1:] == loc[:-1]) & (veh[1:] == veh[:-1]) & (fr[1:] - fr[:-1] == 1)
    cut &= per[1:] != per[:-1]
    if not cut.any():
        return None
    # One vehicle id may well drive in two periods (the CSV's Peachtree periods reuse ids and
    # frames); a stray row or two of it in another period next to its own frames may not.
    _, group = np.unique(np.stack([loc, veh, per]), axis=1, return_inverse=True)
    size = np.bincount(group.ravel())[group.ravel()]
    stray = cut & ((size[1:] <= MAX_STRAY_ROWS) | (size[:-1] <= MAX_STRAY_ROWS))
    if not stray.any():
        return None
    i = int(np.flatnonzero(stray)[0])
    a, b = int(order[i]), int(order[i + 1])
    return (a, b) if size[i] <= size[i + 1] else (b, a)


def small_location(rows_per_location: np.ndarray) -> int | None:
    """The location (index) of at most MAX_STRAY_ROWS rows in a file of several: a Location cell
    gone bad (a phantom recording of a row or two); None if there is none."""
    if rows_per_location.size > 1 and rows_per_location.min() <= MAX_STRAY_ROWS:
        return int(np.argmin(rows_per_location))
    return None


def _check_small_location(parsed: _Parsed) -> None:
    """Refuse a Location that only a row or two of a file with other locations have."""
    sizes = np.bincount(parsed.location_code, minlength=len(parsed.locations))
    small = small_location(sizes)
    if small is None:
        return
    row = int(np.flatnonzero(parsed.location_code == small)[0])
    line = int(record_lines(parsed.path.read_bytes())[0][row + 1])
    others = [loc for i, loc in enumerate(parsed.locations) if i != small]
    raise InputError(
        parsed.path,
        f"Location {parsed.locations[small]!r} on {int(sizes[small])} row(s) only would make a recording "
        "of its own",
        line=line,
        column="Location",
        expected=f"the location of the vehicle's other rows ({', '.join(others)})",
    )


def _has_header(parsed: _Parsed) -> bool:
    with parsed.path.open("rb") as fh:
        first = fh.readline().decode(errors="replace")
    return parsed.location_source == "column" or "," in first


def _check_period_continuity(parsed: _Parsed, period: np.ndarray) -> None:
    """Refuse a Global_Time that puts one frame of a vehicle in another recording period than the
    frame before it (a phantom recording made of one bad cell); ``period`` [n] per row of ``parsed``."""
    cols = parsed.columns
    small = small_period(period)
    if small is not None:
        sizes = np.bincount(period)
        odd = int(np.flatnonzero(period == small)[0])
        header = _has_header(parsed)
        line = int(
            record_lines(parsed.path.read_bytes(), whitespace=not header)[0][odd + (1 if header else 0)]
        )
        raise InputError(
            parsed.path,
            f"Global_Time {cols['global_time'][odd]} and Frame_ID {cols['frame_id'][odd]} put this row in a "
            f"recording period of its own ({int(sizes.min())} rows)",
            line=line,
            column="Global_Time",
            expected="Global_Time = epoch + 100 * Frame_ID with the epoch of a recording period",
        )
    pair = stray_pair(parsed.location_code, cols["vehicle_id"], cols["frame_id"], period)
    if pair is None:
        return
    odd, other = pair
    header = _has_header(parsed)
    lines = record_lines(parsed.path.read_bytes(), whitespace=not header)[0]
    line = int(lines[odd + (1 if header else 0)])
    other_line = int(lines[other + (1 if header else 0)])
    raise InputError(
        parsed.path,
        f"Global_Time {cols['global_time'][odd]} puts frame {cols['frame_id'][odd]} of vehicle "
        f"{cols['vehicle_id'][odd]} in another recording period than its neighbouring frame (line {other_line})",
        line=line,
        column="Global_Time",
        expected=f"Global_Time = epoch + 100 * Frame_ID with the epoch of line {other_line}",
    )


WRONG_WAY_FPS = 1.0 / FEET  # ft/s: a freeway vehicle whose Local_Y falls faster than 1 m/s drives backwards
MIN_WRONG_WAY_FRAMES = 10  # frames (1 s): a shorter track's direction is noise


@dataclass(frozen=True)
class WrongWay:
    """A freeway track driving backwards: its first row (index into the arrays given), its net
    fall of Local_Y (ft) and its duration (s)."""

    row: int
    fall: float
    seconds: float


def wrong_way(
    location_code: np.ndarray,
    period: np.ndarray,
    vehicle: np.ndarray,
    frame: np.ndarray,
    local_y: np.ndarray,
) -> WrongWay | None:
    """The track (location, period, vehicle; arrays [n] of freeway rows only) that comes first in
    the arrays among those whose Local_Y falls along their frames, or None. Stop-and-go noise is
    no wrong way: the track's net motion and most of its steps must go backwards."""
    if not frame.size:
        return None
    order = np.lexsort((frame, vehicle, period, location_code))
    key = np.stack([location_code[order], period[order], vehicle[order]])
    starts = np.flatnonzero(np.r_[True, (key[:, 1:] != key[:, :-1]).any(axis=0)])
    ends = np.r_[starts[1:], order.size] - 1
    y, fr = local_y[order], frame[order]
    seconds = (fr[ends] - fr[starts]) / FRAME_RATE
    steps = ends - starts
    down = np.r_[np.diff(y) < 0, False]  # row i to row i+1 moves back
    down[ends] = False  # the step from a track's last row leads into the next track
    falling = np.add.reduceat(down.astype(np.int64), starts)
    repeat = np.r_[fr[1:] == fr[:-1], False]  # one id driving twice (periods not split): not one track
    repeat[ends] = False
    long_enough = (steps >= MIN_WRONG_WAY_FRAMES) & (np.add.reduceat(repeat.astype(np.int64), starts) == 0)
    net = (y[ends] - y[starts]) / np.where(seconds > 0, seconds, 1.0)
    wrong = np.flatnonzero(long_enough & (net < -WRONG_WAY_FPS) & (2 * falling > steps))
    if not wrong.size:
        return None
    first_rows = np.minimum.reduceat(order, starts)  # each track's first row in the arrays
    k = int(wrong[np.argmin(first_rows[wrong])])
    return WrongWay(int(first_rows[k]), float(y[starts[k]] - y[ends[k]]), float(seconds[k]))


def _check_wrong_way(parsed: _Parsed, period: np.ndarray) -> None:
    """Refuse a vehicle on a one-way freeway (US-101, I-80) whose Local_Y falls along its frames: in
    the road frame (x = Local_Y) it would drive backwards at the speed v_Vel says it drives forward
    (a column of another vehicle or another unit, never a real vehicle). ``period`` [n]."""
    cols = parsed.columns
    freeway = np.array([_is_freeway(loc) for loc in parsed.locations], dtype=bool)[parsed.location_code]
    rows = np.flatnonzero(freeway)
    found = wrong_way(
        parsed.location_code[rows],
        period[rows],
        cols["vehicle_id"][rows],
        cols["frame_id"][rows],
        cols["local_y"][rows],
    )
    if found is None:
        return
    row = int(rows[found.row])
    header = _has_header(parsed)
    line = int(record_lines(parsed.path.read_bytes(), whitespace=not header)[0][row + (1 if header else 0)])
    raise InputError(
        parsed.path,
        f"vehicle {cols['vehicle_id'][row]:.0f} drives backwards on a one-way freeway: its Local_Y falls "
        f"by {found.fall:.1f} ft over {found.seconds:.1f} s ({found.fall / max(found.seconds, 1e-9):.1f} ft/s)",
        line=line,
        column="Local_Y",
        expected="Local_Y rising along a vehicle's frames (the direction of travel on US-101 and I-80)",
    )


def _recording_extra(
    location: str, source: str, epoch: int, start: int, period: int, n_periods: int
) -> dict[str, Any]:
    freeway = _is_freeway(location)
    return {
        "location": location,
        "location_source": source,
        "road_type": "freeway" if freeway else "arterial",
        "global_time_start": start,
        "global_time_epoch": epoch,
        "global_time_note": "Global_Time as given by the source (ms); epoch = Global_Time - 100 * Frame_ID",
        "period": period if n_periods > 1 else None,
        "time": "time_ns = Frame_ID * 1e8 (frame = Frame_ID at 10 Hz)",
        "units": "converted from feet (x 0.3048)",
        "centre": (
            "x = Local_Y - v_Length/2, y = -Local_X (road frame: x along travel, y left)"
            if freeway
            else "front bumper (Local_Y, -Local_X) moved back by v_Length/2 along the heading"
        ),
        "heading": (
            "atan2(vy, vx); vy = gradient of y over +-0.5 s; 0 below 0.5 m/s"
            if freeway
            else "direction of motion of the front bumper (differences over +-0.5 s, above 1 m/s, agreeing "
            "with v_Vel and Direction), held through stops, averaged over +-0.5 s"
        ),
        "lane_id": "NGSIM Lane_ID as given (arterials: 0 and >= 10 are intersections, turn bays)",
    }


def _to_track_table(
    cols: dict[str, np.ndarray],
    names: list[str],
    metas: dict[str, track_table.RecordingMeta],
    files: list[str],
) -> pa.Table:
    n = cols["vehicle_id"].size
    rec = cols["recording"]
    vehicle = cols["vehicle_id"].astype(np.int64)
    frame = cols["frame_id"].astype(np.int64)
    if not _is_sorted(rec, vehicle, frame):
        order = np.lexsort((np.arange(n), frame, vehicle, rec))  # stable: file order within a key
        cols = {k: v[order] for k, v in cols.items()}
        rec, vehicle, frame = rec[order], vehicle[order], frame[order]

    same_key = np.zeros(n, dtype=bool)
    same_key[1:] = (rec[1:] == rec[:-1]) & (vehicle[1:] == vehicle[:-1]) & (frame[1:] == frame[:-1])
    first_of_key = np.maximum.accumulate(np.where(same_key, 0, np.arange(n)))
    identical = np.ones(n, dtype=bool)
    for name in (*USED_COLUMNS, "direction"):
        v = cols[name]
        identical &= (v == v[first_of_key]) | (np.isnan(v) & np.isnan(v[first_of_key]))
    n_rec = len(names)
    exact = np.bincount(rec[same_key & identical], minlength=n_rec)
    conflicting = np.bincount(rec[same_key & ~identical], minlength=n_rec)
    for k in np.flatnonzero(conflicting).tolist():
        source = ", ".join(metas[names[k]].source_files)
        print(
            f"lanecast: {source}: {conflicting[k]:,} rows repeat a (Vehicle_ID, Frame_ID) of recording "
            f"{names[k]!r} with different values; kept the first of each in file order",
            file=sys.stderr,
        )
    rows_read = np.bincount(rec, minlength=n_rec)
    for i, name in enumerate(names):
        extra = metas[name].extra
        extra["rows_read"] = int(rows_read[i])
        extra["duplicate_rows_dropped"] = int(exact[i])
        extra["conflicting_duplicates_dropped"] = int(conflicting[i])

    if same_key.any():
        keep = ~same_key
        cols = {k: v[keep] for k, v in cols.items()}
        rec, vehicle, frame = rec[keep], vehicle[keep], frame[keep]
    freeway = np.array([metas[name].coordinate_frame == "road" for name in names])[rec]
    kin = _kinematics(cols, rec, vehicle, frame, freeway)

    cls = cols["v_class"].astype(np.int64)
    cls_code = np.where((cls >= 1) & (cls <= 3), cls, 0).astype(np.int32)
    columns: dict[str, Any] = {
        "recording": pa.DictionaryArray.from_arrays(pa.array(rec.astype(np.int32)), pa.array(names)),
        "track_id": vehicle,
        "frame": frame,
        "time_ns": frame * FRAME_NS,
        **kin,
        "length": (cols["v_length"] * FEET).astype(np.float32),
        "width": (cols["v_width"] * FEET).astype(np.float32),
        "lane_id": cols["lane_id"].astype(np.int32),
        "object_class": pa.DictionaryArray.from_arrays(pa.array(cls_code), pa.array(_CLASSES)),
        "preceding_id": pa.array(cols["preceding"], mask=cols["preceding"] == 0, type=pa.int64()),
        "following_id": pa.array(cols["following"], mask=cols["following"] == 0, type=pa.int64()),
    }
    meta = track_table.TableMeta(FORMAT, metas, files)
    table = track_table.build_table(columns, meta)
    track_table.validate(table, source=", ".join(files))
    return table


def _is_sorted(rec: np.ndarray, vehicle: np.ndarray, frame: np.ndarray) -> bool:
    """Rows already in (recording, vehicle, frame) order (as the original .txt files are) [n]."""
    same_rec = rec[1:] == rec[:-1]
    same_vehicle = same_rec & (vehicle[1:] == vehicle[:-1])
    ordered = (
        (rec[1:] > rec[:-1])
        | (same_rec & (vehicle[1:] > vehicle[:-1]))
        | (same_vehicle & (frame[1:] >= frame[:-1]))
    )
    return bool(ordered.all())


# ---------------------------------------------------------------------------------------- kinematics


@dataclass
class _Tracks:
    """Per-row track extent on sorted rows: ``first[i]``, ``last[i]`` (inclusive) row of i's track."""

    first: np.ndarray
    last: np.ndarray


def _tracks(rec: np.ndarray, vehicle: np.ndarray) -> _Tracks:
    return _Tracks(*row_extent(run_starts(rec, vehicle)))


def track_mean(values: np.ndarray, first: np.ndarray, last: np.ndarray, span: int) -> np.ndarray:
    """Mean of ``values`` [n] over rows i-span … i+span clipped to each row's track [first, last]."""
    # One masked add per offset (not a running sum): a row's mean depends on its own track only,
    # to the last bit, whatever the rows of other tracks hold.
    i = np.arange(values.size)
    total = np.zeros(values.size)
    count = np.zeros(values.size)
    for k in range(-span, span + 1):
        j = i + k
        inside = (j >= first) & (j <= last)
        total += np.where(inside, values[np.clip(j, 0, values.size - 1)], 0.0)
        count += inside
    return total / count


def _fill_within_track(
    values: np.ndarray, valid: np.ndarray, tracks: _Tracks
) -> tuple[np.ndarray, np.ndarray]:
    """Invalid rows take the nearest earlier valid row of their track, else the nearest later one."""
    n = values.size
    i = np.arange(n)
    before = np.maximum.accumulate(np.where(valid, i, -1))
    after = np.minimum.accumulate(np.where(valid, i, n)[::-1])[::-1]
    use_before = ~valid & (before >= tracks.first)
    use_after = ~valid & ~use_before & (after <= tracks.last)
    out = values.copy()
    out[use_before] = values[before[use_before]]
    out[use_after] = values[after[use_after]]
    return out, valid | use_before | use_after


def _wrap(angle: np.ndarray) -> np.ndarray:
    """Angles [n] wrapped into [-pi, pi)."""
    return (angle + np.pi) % (2 * np.pi) - np.pi


def _kinematics(
    cols: dict[str, np.ndarray], rec: np.ndarray, vehicle: np.ndarray, frame: np.ndarray, freeway: np.ndarray
) -> dict[str, np.ndarray]:
    """x, y, heading, vx, vy, ax, ay [n] for rows sorted by (recording, vehicle, frame)."""
    tracks = _tracks(rec, vehicle)
    t = frame / FRAME_RATE
    half_length = cols["v_length"] * FEET / 2
    speed = cols["v_vel"] * FEET
    i = np.arange(speed.size)
    standing_still = (speed == 0) & (speed[np.maximum(i - 1, tracks.first)] == 0)
    standing_still &= speed[np.minimum(i + 1, tracks.last)] == 0
    accel = np.where(standing_still, 0.0, cols["v_acc"] * FEET)  # module docstring: no spikes at rest
    front_x = cols["local_y"] * FEET
    front_y = -cols["local_x"] * FEET

    # Arterials: heading from the motion of the front bumper, held through stops. Motion is trusted
    # only where it agrees with the recorded speed and, where the source gives Direction, is not
    # backwards against it (tracking glitches at a track's start run the bumper backwards, and a
    # heading of 180° held through a stop would flip, and swing the centre by a vehicle length,
    # when the vehicle moves off).
    gx = along_track_derivative(front_x, t, tracks.first, tracks.last, span=GRADIENT_SPAN)
    gy = along_track_derivative(front_y, t, tracks.first, tracks.last, span=GRADIENT_SPAN)
    motion = np.hypot(gx, gy)
    motion_angle = np.arctan2(gy, gx)
    direction = cols["direction"]
    fallback = np.zeros(direction.size)
    for code, angle in _DIRECTION_HEADING.items():
        fallback[direction == code] = angle
    stated = np.isin(direction, list(_DIRECTION_HEADING))
    against = stated & (np.abs(_wrap(motion_angle - fallback)) > MAX_TURN_FROM_DIRECTION)
    moving = (motion >= MIN_HEADING_SPEED) & (motion <= 2 * speed + 1.0) & ~against
    motion_heading, known = _fill_within_track(motion_angle, moving, tracks)
    arterial_heading = np.where(known, motion_heading, fallback)
    # Smoothed over ±0.5 s (mean direction): a held heading that meets the motion again after a
    # stop turns over a second, not in one frame (the centre sits half a length behind the bumper).
    arterial_heading = np.arctan2(
        track_mean(np.sin(arterial_heading), tracks.first, tracks.last, GRADIENT_SPAN),
        track_mean(np.cos(arterial_heading), tracks.first, tracks.last, GRADIENT_SPAN),
    )

    # Freeways: road frame, vx = v_Vel, vy from the lateral motion of y.
    vy_road = along_track_derivative(front_y, t, tracks.first, tracks.last, span=GRADIENT_SPAN)
    road_heading = np.where(speed >= MIN_MOVING_SPEED, np.arctan2(vy_road, speed), 0.0)

    heading = np.where(freeway, road_heading, arterial_heading)
    cos, sin = np.cos(heading), np.sin(heading)
    x = np.where(freeway, front_x - half_length, front_x - half_length * cos)
    y = np.where(freeway, front_y, front_y - half_length * sin)
    vx = np.where(freeway, speed, speed * cos)
    vy = np.where(freeway, vy_road, speed * sin)
    return {
        "x": x,
        "y": y,
        "heading": heading.astype(np.float32),
        "vx": vx.astype(np.float32),
        "vy": vy.astype(np.float32),
        "ax": (accel * cos).astype(np.float32),
        "ay": (accel * sin).astype(np.float32),
    }
