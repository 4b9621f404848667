"""Finding NGSIM files: is a file NGSIM (a CSV export header, or 18 numbers a line), and which files
of a folder are; a damaged one there is refused, not left out."""

from __future__ import annotations

import sys
from collections.abc import Iterator
from pathlib import Path

from lanecast.io_adapters.datasets.csv_errors import check_text, first_line, not_text
from lanecast.io_adapters.datasets.ngsim.columns import KEY_COLUMNS, TXT_COLUMNS, USED_COLUMNS
from lanecast.io_adapters.errors import InputError
from lanecast.io_adapters.files import COMPRESSED_SUFFIXES, not_regular

_TEXT_SUFFIXES = (".txt", ".csv")


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
        return set(KEY_COLUMNS) <= names or 2 * len(names & set(USED_COLUMNS)) > len(USED_COLUMNS)
    if other_separator(first):
        return True  # the reader says how the header is separated
    tokens = first.split()
    if len(tokens) != len(TXT_COLUMNS):
        return False
    # 18 fields, nearly all numbers: a .txt whose first row has a bad cell or two is still one (the
    # reader names the cell by line and column, as it does on any other line)
    return sum(_is_number(t) for t in tokens) >= len(TXT_COLUMNS) - 2


def txt_near_miss(head: bytes) -> tuple[int, str] | None:
    """(line, what is wrong) for the start ``head`` of a .txt that reads as NGSIM's but for its
    layout: a first row of numbers that are not 18, or a header line of NGSIM's names (its .txt
    files have none); None for anything else, which is no NGSIM file at all."""
    lines = head.decode("utf-8", errors="replace").lstrip("\ufeff").splitlines()
    line = next((i for i, text in enumerate(lines) if text.strip()), None)
    if line is None:
        return None
    tokens = lines[line].replace(",", " ").split()
    names = {t.strip('"').lower() for t in tokens}
    if set(KEY_COLUMNS) <= names:
        return line + 1, "a header line of NGSIM's column names; an NGSIM .txt starts with its first row"
    if len(tokens) >= 4 and sum(_is_number(t) for t in tokens) >= len(tokens) - 2:
        sep = "comma-separated" if "," in lines[line] else "whitespace-separated"
        return line + 1, f"{len(tokens)} {sep} fields in the first row"
    return None


def _is_number(token: str) -> bool:
    try:
        float(token)
    except ValueError:
        return False
    return True


def _unquoted(name: str) -> str:
    """A header field without the double quotes around it, as the CSV parser reads it."""
    stripped = name.strip()
    return stripped[1:-1] if len(stripped) >= 2 and stripped[0] == stripped[-1] == '"' else name


def header_names(first: str) -> list[str]:
    """The column names of the CSV header line ``first`` as pyarrow reads them: without a BOM or
    the quotes around a name, spaces kept."""
    return [_unquoted(raw) for raw in first.lstrip("\ufeff").rstrip("\r").split(",")]


def other_separator(first: str) -> str | None:
    """``';'`` or ``tabs`` where the line ``first`` is the CSV export's header separated by them
    (a spreadsheet saving with semicolons and decimal commas, or as tab-separated text), else None."""
    for sep, name in ((";", "';'"), ("\t", "tabs")):
        names = {cell.strip().strip('"').lower() for cell in first.lstrip("\ufeff").split(sep)}
        if set(KEY_COLUMNS) <= names:
            return name
    return None


def _entries(folder: Path) -> Iterator[Path]:
    """Everything below ``folder`` in name order, hidden entries (and what they hold) left out."""
    for p in sorted(Path(folder).rglob("*")):
        if not any(part.startswith(".") for part in p.relative_to(folder).parts):
            yield p


def _packed(p: Path) -> bool:
    """A compressed .txt or .csv (``*.txt.gz``, …)."""
    return p.suffix.lower() in COMPRESSED_SUFFIXES and p.with_suffix("").suffix.lower() in _TEXT_SUFFIXES


def files_in(folder: Path) -> list[Path]:
    """The NGSIM files (.txt, .csv) anywhere below ``folder``, in name order (hidden ones left out)."""
    return [p for p in _entries(folder) if p.suffix.lower() in _TEXT_SUFFIXES and p.is_file() and sniff(p)]


def compressed_in(folder: Path) -> list[Path]:
    """The compressed .txt and .csv files below ``folder`` (hidden ones left out)."""
    return [p for p in _entries(folder) if _packed(p) and p.is_file()]


def folder_files(folder: Path) -> list[Path]:
    """:func:`files_in`, refusing a damaged NGSIM file there instead of leaving it out: an empty or
    non-text ``.txt``/``.csv``, one named ``trajectories*`` that is not NGSIM, or a ``.txt``/``.csv``
    that is no regular file (a FIFO, a device, a link to nothing). Other text files (notes, other
    tables) are left out with a line on stderr."""
    found = files_in(folder)
    compressed = []
    for p in _entries(folder):
        packed = _packed(p)
        if packed or p.suffix.lower() in _TEXT_SUFFIXES:
            reason = not_regular(p)  # a FIFO would block the run, and left out its rows would be lost
            if reason is not None:
                raise InputError(p, reason, expected="NGSIM .txt or .csv files")
        if packed and p.is_file():
            compressed.append(p)
            continue
        if p in found or p.suffix.lower() not in _TEXT_SUFFIXES or not p.is_file():
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
