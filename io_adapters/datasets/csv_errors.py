"""Where a bad text table goes wrong: line numbers and field counts of CSV and whitespace-separated
files, and the error for the first line with the wrong number of fields (docs/design.md §6).

The readers parse with Arrow or pandas at full speed and come here only when that fails or a
value is bad: these functions map a parsed row back to its line in an editor and find the first
line whose field count is off, column-wise on the file's bytes. Line breaks are counted as the
parsers count them: LF, CRLF and a lone CR.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pyarrow as pa

from lanecast.io_adapters.arrow_numpy import holds_any_byte
from lanecast.io_adapters.errors import InputError

# What a file that is not a plain text table starts with (its first bytes), and what it is.
_NOT_TEXT = (
    (b"\xff\xfe\x00\x00", "UTF-32 text"),
    (b"\x00\x00\xfe\xff", "UTF-32 text"),
    (b"\xff\xfe", "UTF-16 text"),
    (b"\xfe\xff", "UTF-16 text"),
    (b"\x1f\x8b", "gzip-compressed"),
    (b"PK\x03\x04", "a zip archive"),
    (b"BZh", "bzip2-compressed"),
    (b"\xfd7zXZ\x00", "xz-compressed"),
    (b"\x28\xb5\x2f\xfd", "zstd-compressed"),
)


SHOWN_CHARS = 40  # of a bad cell in a message: a damaged file's "cell" may be megabytes


def shown(cell: str) -> str:
    """``repr(cell)``, cut to SHOWN_CHARS characters (and its length) when longer: one short line."""
    if len(cell) <= SHOWN_CHARS:
        return repr(cell)
    return f"{cell[:SHOWN_CHARS]!r}… ({len(cell):,} characters)"


def not_text(head: bytes) -> str | None:
    """What a file is whose first bytes ``head`` show it is no UTF-8 text (another encoding, a
    compressed file), or None."""
    return next((kind for magic, kind in _NOT_TEXT if head.startswith(magic)), None)


def check_text(path: Path, head: bytes, what: str) -> None:
    """Refuse a file whose first bytes ``head`` show it is no UTF-8 text: another encoding, a
    compressed file or binary data (a NUL byte). ``what`` names the table expected."""
    kind = not_text(head)
    if kind is not None:
        raise InputError(path, f"the file is {kind}", offset=0, expected=f"{what} as UTF-8 text")
    if b"\x00" in head:
        at = head.index(b"\x00")
        raise InputError(path, "a NUL byte: binary data", offset=at, expected=f"{what} as UTF-8 text")


FIRST_LINE_BYTES = 1 << 16  # of a file read for its header line: no header is longer


def first_line(head: bytes) -> bytes:
    """The bytes of ``head`` before its first line break: LF, CRLF or a lone CR (an old Mac's line
    ends, which every parser here reads as line ends too)."""
    return re.split(rb"\r\n?|\n", head, maxsplit=1)[0]


def read_first_line(path: Path, limit: int = FIRST_LINE_BYTES) -> bytes:
    """The first line of ``path`` (:func:`first_line` of its first ``limit`` bytes)."""
    with path.open("rb") as fh:
        return first_line(fh.read(limit))


REPEATED_HEADER = "the header line again (two files joined into one?)"


def is_header(cells: Sequence[str | None], names: Sequence[str]) -> bool:
    """Whether the cells of a data line are the column names ``names`` (in any case, quoted or not):
    the header repeated, as where two files were joined into one."""
    if len(cells) != len(names):
        return False
    return all(
        c is not None and c.strip().strip('"').strip().lower() == n.strip().strip('"').strip().lower()
        for c, n in zip(cells, names, strict=True)
    )


def line_spans(data: bytes) -> tuple[np.ndarray, np.ndarray]:
    """Start and end (exclusive, without the newline and any CR) byte offsets of every line [L]."""
    arr = np.frombuffer(data, dtype=np.uint8)
    lone_cr = (arr == 13) & np.concatenate([arr[1:] != 10, [True]])
    newline = np.flatnonzero((arr == 10) | lone_cr)
    starts = np.concatenate([[0], newline + 1])
    ends = np.concatenate([newline, [arr.size]])
    if starts[-1] == arr.size:  # the file ends with a newline: no line after it
        starts, ends = starts[:-1], ends[:-1]
    has_cr = (ends > starts) & (arr[np.maximum(ends - 1, 0)] == 13)
    return starts, ends - has_cr


def _quotes_before(data: bytes, starts: np.ndarray) -> np.ndarray:
    """Double quotes before each byte on its own line, int64 [B] (``starts`` [L], starts[0] == 0):
    odd inside a quoted value (quotes never span lines in the tables lanecast reads; a line with an
    odd count is refused by check_balanced_quotes)."""
    arr = np.frombuffer(data, dtype=np.uint8)
    total = np.concatenate([[0], np.cumsum(arr == ord('"'))])  # quotes in data[:i]
    return total[:-1] - np.repeat(total[starts], np.diff(np.append(starts, arr.size)))


def field_counts(data: bytes, starts: np.ndarray, ends: np.ndarray, whitespace: bool) -> np.ndarray:
    """Number of fields on each line [L] (0 for a blank line), counted on the bytes; a comma inside
    a quoted value (``"12,5"``) separates no fields, as the CSV parser reads it."""
    arr = np.frombuffer(data, dtype=np.uint8)
    if whitespace:
        space = np.isin(arr, np.frombuffer(b" \t\r\n", dtype=np.uint8))
        marks = ~space
        marks[1:] &= space[:-1]  # the first byte of every token
    else:
        marks = arr == ord(",")
        if starts.size and b'"' in data:  # the common case, without quotes, at C speed
            marks &= _quotes_before(data, starts) % 2 == 0
    # Each segment runs to the next line's start; its newline and CR are neither commas nor tokens.
    counts = np.add.reduceat(marks.astype(np.int64), starts) if starts.size else np.zeros(0, np.int64)
    if whitespace:
        return counts
    return np.where(ends > starts, counts + 1, 0)


def blank_lines(data: bytes, starts: np.ndarray, ends: np.ndarray, whitespace: bool) -> np.ndarray:
    """bool [L]: lines the parser skips: whitespace-only (pandas, whitespace-separated), empty (Arrow CSV)."""
    if whitespace:
        return field_counts(data, starts, ends, whitespace=True) == 0
    return ends == starts


def record_lines(data: bytes, whitespace: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """(1-based line numbers int64 [R], field counts int64 [R]) of the lines a parser reads, a header
    included: ``lines[i]`` is the editor line of the parser's i-th record."""
    starts, ends = line_spans(data)
    keep = ~blank_lines(data, starts, ends, whitespace)
    counts = field_counts(data, starts, ends, whitespace)
    return np.flatnonzero(keep).astype(np.int64) + 1, counts[keep]


def row_line(path: Path, row: int, *, header: bool = True, whitespace: bool = False) -> int:
    """The 1-based editor line of the parser's ``row``-th data record of ``path`` (``header``: the
    first record is the header line). Reads the file: for the error path only."""
    return int(record_lines(path.read_bytes(), whitespace)[0][row + int(header)])


def check_field_counts(path: Path, data: bytes, names: Sequence[str], *, whitespace: bool = False) -> None:
    """Raise InputError at the first read line whose number of fields is not ``len(names)``.

    The last line with too few fields is reported as truncated (a file cut short by a copy or a
    kill); ``column`` names the first missing field.
    """
    expected = len(names)
    lines, counts = record_lines(data, whitespace)
    wrong = np.flatnonzero(counts != expected)
    if wrong.size == 0:
        return
    i = int(wrong[0])
    if not whitespace:  # an open quote on this line or before runs its value on: say that
        check_balanced_quotes(path, data[: _line_end(data, int(lines[i]))])
    got = int(counts[i])
    truncated = i == lines.size - 1 and got < expected
    what = "truncated last line" if truncated else "wrong number of fields"
    sep = "whitespace-separated" if whitespace else "comma-separated"
    raise InputError(
        path,
        f"{what}: {got} fields, the header has {expected}" if not whitespace else f"{what}: {got} fields",
        line=int(lines[i]),
        column=names[got] if got < expected else None,
        expected=f"{expected} {sep} fields",
    )


def _line_end(data: bytes, line: int) -> int:
    """Byte offset just past 1-based ``line`` (its line break included)."""
    starts, _ = line_spans(data)
    return int(starts[line]) if line < starts.size else len(data)


def check_balanced_quotes(path: Path, data: bytes) -> None:
    """Raise InputError at the first line with an odd number of double quotes: its open quote runs
    the value on over the line ends after it (no dataset lanecast reads quotes across lines)."""
    if b'"' not in data:  # the common case, at C speed
        return
    starts, ends = line_spans(data)
    quotes = np.concatenate([[0], np.cumsum(np.frombuffer(data, dtype=np.uint8) == ord('"'))])
    odd = np.flatnonzero((quotes[ends] - quotes[starts]) % 2 == 1)
    if odd.size:
        raise InputError(
            path,
            "a double quote opens a value that runs on over the line ends after it",
            line=int(odd[0]) + 1,
            expected="values without unbalanced double quotes, one row per line",
        )


MAX_LINE_BYTES = 1 << 20  # pyarrow's CSV block: a longer row straddles blocks and is not parsed


def check_parseable(path: Path, data: bytes) -> None:
    """Where even a parse of every cell as text failed: raise InputError at the first line that is
    no UTF-8, longer than ``MAX_LINE_BYTES`` or whose open quote runs on over the lines after it
    (the parser's own message names no line)."""
    at = 0
    while at < len(data):  # decoded a block at a time: no copy of a large file as text
        end = min(at + (16 << 20), len(data))
        for _ in range(3):  # not inside a character (of at most 4 bytes)
            if end < len(data) and data[end] & 0xC0 == 0x80:
                end -= 1
        try:
            data[at:end].decode("utf-8")
        except UnicodeDecodeError as exc:
            offset = at + exc.start
            starts, _ = line_spans(data)
            line = int(np.searchsorted(starts, offset, side="right"))
            raise InputError(
                path,
                f"bytes that are not UTF-8 ({data[offset : offset + 4]!r}…: {exc.reason})",
                line=line,
                offset=offset,
                expected="UTF-8 text (save the file as UTF-8)",
            ) from exc
        at = end
    starts, ends = line_spans(data)
    long = np.flatnonzero(ends - starts > MAX_LINE_BYTES)
    if long.size:
        i = int(long[0])
        raise InputError(
            path,
            f"a line of {int(ends[i] - starts[i]):,} bytes",
            line=i + 1,
            expected=f"rows of at most {MAX_LINE_BYTES:,} bytes",
        )
    check_balanced_quotes(path, data)


def holds_line_ends(values: pa.Array | pa.ChunkedArray) -> bool:
    """Whether a parsed string value holds a line end: a double quote in the file opened it, and the
    parser read the lines after it as part of that one value."""
    return holds_any_byte(values, b"\r\n")


def check_one_line_per_row(path: Path, table: pa.Table) -> None:
    """Raise InputError when a string value of ``table``, parsed from the CSV ``path``, ran on over
    line ends and swallowed the rows after it, at the line of the unbalanced quote (the file is read
    again only then; a number column cannot swallow lines silently: its parse fails)."""
    strings = (c for c in table.columns if pa.types.is_string(c.type) or pa.types.is_large_string(c.type))
    if not any(holds_line_ends(c) for c in strings):
        return
    check_balanced_quotes(path, path.read_bytes())
    raise InputError(path, "a quoted value runs on over line ends", expected="one row per line")
