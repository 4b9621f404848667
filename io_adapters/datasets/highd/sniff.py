"""Finding highD files: is a path highD, and which three files make one recording.

A recording is ``NN_tracks.csv``, ``NN_tracksMeta.csv`` and ``NN_recordingMeta.csv`` in one
directory. A damaged file (empty, UTF-16, another separator) is still highD by its name and
companions, for the reader to name what is wrong with it.
"""

from __future__ import annotations

import errno
import os
import re
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from lanecast.io_adapters.datasets.csv_errors import read_first_line
from lanecast.io_adapters.datasets.highd.columns import COLUMNS_BY_KIND, KINDS
from lanecast.io_adapters.errors import InputError
from lanecast.io_adapters.files import COMPRESSED_SUFFIXES, NOT_REGULAR

NAME = re.compile(r"^(?P<prefix>.+)_(?P<kind>tracks|tracksMeta|recordingMeta)\.csv$")


@dataclass(frozen=True)
class Recording:
    """The three files of one highD recording (``prefix`` is the ``NN`` of ``NN_tracks.csv``)."""

    directory: Path
    prefix: str

    def path(self, kind: str) -> Path:
        return self.directory / f"{self.prefix}_{kind}.csv"

    @property
    def paths(self) -> list[Path]:
        return [self.path(kind) for kind in KINDS]


def header_names(path: Path) -> list[str]:
    """The column names of the first line of ``path`` (stripped of blanks, quotes and a BOM)."""
    text = read_first_line(path).decode("utf-8-sig", errors="replace")
    return [name.strip().strip('"') for name in text.split(",")] if text.strip() else []


def _looks_like(path: Path, kind: str) -> bool:
    """Header shares at least half of the required columns of ``kind`` (tolerates a misnamed one)."""
    try:
        names = set(header_names(path))
    except OSError:
        return False
    required = COLUMNS_BY_KIND[kind]
    return len(names & set(required)) * 2 >= len(required)


def _named_files(directory: Path, *, regular: bool = True) -> list[tuple[Path, re.Match[str]]]:
    """The regular files of ``directory`` named as highD's, with their match (``regular=False``:
    any entry but a directory: a FIFO or a link to nothing too)."""
    named = ((p, NAME.match(p.name)) for p in sorted(directory.glob("*_*.csv")))
    return [(p, m) for p, m in named if m is not None and (p.is_file() if regular else not p.is_dir())]


def _is_highd(path: Path, match: re.Match[str]) -> bool:
    """Named as highD and its header is highD's, or all three files of its recording are there."""
    prefix = match.group("prefix")
    return _looks_like(path, match.group("kind")) or all(
        (path.parent / f"{prefix}_{kind}.csv").is_file() for kind in KINDS
    )


def sniff(path: Path) -> bool:
    """A highD file (by name, and its header or its two companion files) or a directory holding one."""
    path = Path(path)
    if path.is_dir():  # any of a recording's files: one missing is the reader's to name
        return any(_is_highd(p, m) for p, m in _named_files(path))
    match = NAME.match(path.name)
    return match is not None and path.is_file() and _is_highd(path, match)


def recordings(paths: Sequence[str | Path]) -> list[Recording]:
    """The distinct recordings named by ``paths`` (any of their three files, or directories)."""
    found: dict[tuple[Path, str], Recording] = {}
    for raw in paths:
        path = Path(raw)
        match = NAME.match(path.name)
        if path.is_dir() and match is None:
            # Every recording any of whose files is here (a FIFO or a link to nothing too): one whose
            # tracks file is missing is refused naming it, not left out.
            prefixes = sorted({m.group("prefix") for _, m in _named_files(path, regular=False)})
            if not prefixes:
                raise InputError(path, "no highD recording in this directory", expected="NN_tracks.csv files")
            candidates = [Recording(path, prefix) for prefix in prefixes]
        elif match is None:
            raise InputError(
                path,
                "not a highD file name",
                expected="NN_tracks.csv, NN_tracksMeta.csv or NN_recordingMeta.csv",
            )
        elif not path.is_file():
            raise InputError(path, not_a_file(path), expected=f"the highD {match.group('kind')} CSV file")
        else:
            candidates = [Recording(path.parent, match.group("prefix"))]
        for rec in candidates:
            found.setdefault((rec.directory.resolve(), rec.prefix), rec)
    return list(found.values())


def not_a_file(path: Path) -> str:
    """Why ``path``, which is no regular file, cannot be read: missing (and, where a compressed copy
    lies beside it, which), a directory, or a FIFO, socket or device (which nothing may open)."""
    if path.is_dir():
        return "a directory, not a file"
    if path.exists():
        return NOT_REGULAR
    if path.is_symlink():
        try:
            os.stat(path)
        except OSError as exc:
            return "a symbolic link loop" if exc.errno == errno.ELOOP else "a symbolic link to a missing file"
    packed = [path.with_name(path.name + s) for s in COMPRESSED_SUFFIXES]
    found = [p.name for p in packed if p.is_file()]
    return f"no such file ({found[0]} beside it is compressed: decompress it)" if found else "no such file"


def check_present(rec: Recording) -> None:
    """Refuse a recording one of whose three files is missing or no regular file, naming it."""
    for kind in KINDS:
        path = rec.path(kind)
        if path.is_file():
            continue
        reason = not_a_file(path)
        what = f"{'tracks' if kind == 'tracks' else 'companion'} file of highD recording {rec.prefix!r}"
        raise InputError(
            path,
            f"missing {what}{reason.removeprefix('no such file')}"
            if reason.startswith("no such file")
            else f"{what}: {reason}",
            expected=f"a file {path.name}"
            + (f" beside {rec.path('tracks').name}" if kind != "tracks" else ""),
        )
