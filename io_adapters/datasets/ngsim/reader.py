"""NGSIM reader: US-101, I-80, Lankershim and Peachtree trajectories into the track table (docs/design.md §1).

Two source forms are read (columns.py): the original whitespace-separated ``trajectories-*.txt``
files of US-101 and I-80, whose location comes from the ``location=`` option or the path, and the
CSV export with a header, whose ``Location`` column may mix all four locations in one file.

The format's entry points (``FORMAT``, ``sniff``, ``read``); the work is done beside it, one concern
a module: sniff.py (which files are NGSIM), parse.py (text → typed columns), checks.py (cells,
ranges, units), periods.py and wrong_way.py (consistency across rows), convert.py and kinematics.py
(the track table), stream.py (a large CSV export a recording at a time).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import pyarrow as pa

from lanecast.io_adapters.datasets.ngsim.columns import TXT_COLUMNS, USED_COLUMNS
from lanecast.io_adapters.datasets.ngsim.convert import FORMAT, assemble
from lanecast.io_adapters.datasets.ngsim.locations import ARTERIALS, FREEWAYS, normalise_location
from lanecast.io_adapters.datasets.ngsim.parse import parse_file
from lanecast.io_adapters.datasets.ngsim.periods import PERIOD_GAP
from lanecast.io_adapters.datasets.ngsim.sniff import folder_files, sniff
from lanecast.io_adapters.errors import InputError
from lanecast.io_adapters.progress import progress

__all__ = ["ARTERIALS", "FORMAT", "FREEWAYS", "PERIOD_GAP", "TXT_COLUMNS", "USED_COLUMNS", "read", "sniff"]


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
        found = folder_files(p) if p.is_dir() else [p]
        if not found:
            raise InputError(p, "no NGSIM files in this directory", expected="NGSIM .txt or .csv files")
        expanded += found
    if not expanded:
        raise InputError(None, "no input files", expected="one or more NGSIM .txt or .csv files")
    location = options.get("location")
    if location is not None:
        location = normalise_location(str(location))
    split_periods = bool(options.get("split_periods", True))
    parsed = [parse_file(p, location) for p in progress(expanded, desc="ngsim", unit="file")]
    return assemble(parsed, split_periods)
