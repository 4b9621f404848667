"""Where NGSIM rows were recorded: the four locations' names, from a Location column, an option,
the file name (or NGSIM's own file names) or a parent directory. The freeways (US-101, I-80) are
read in a road frame, the arterials (Lankershim, Peachtree) in their local frame."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pyarrow as pa

FREEWAYS = ("us-101", "i-80")
ARTERIALS = ("lankershim", "peachtree")
UNKNOWN_LOCATION = "unknown"

# The file names NGSIM publishes (without a location in them): US-101's three periods of
# 2005-06-15 and I-80's three of 2005-04-13.
KNOWN_FILES = {
    **dict.fromkeys(("trajectories-0750am-0805am", "trajectories-0805am-0820am"), "us-101"),
    "trajectories-0820am-0835am": "us-101",
    **dict.fromkeys(("trajectories-0400-0415", "trajectories-0500-0515", "trajectories-0515-0530"), "i-80"),
}
_LOCATION_PATTERNS = (
    ("us-101", re.compile(r"(?<![a-z0-9])us[-_ ]?101(?!\d)")),
    ("i-80", re.compile(r"(?<![a-z0-9])i[-_ ]?80(?!\d)")),
    ("lankershim", re.compile(r"lankershim")),
    ("peachtree", re.compile(r"peachtree")),
)


def normalise_location(name: str) -> str:
    """A location's canonical name (``US 101`` → ``us-101``), else its text as a slug."""
    low = name.strip().lower()
    for canonical, pattern in _LOCATION_PATTERNS:
        if pattern.fullmatch(low):
            return canonical
    slug = re.sub(r"[^a-z0-9]+", "-", low).strip("-")
    return slug or UNKNOWN_LOCATION


def is_freeway(location: str) -> bool:
    """US-101, I-80 and .txt files of unknown location (the 18-column form is the freeways')."""
    return location in FREEWAYS or location == UNKNOWN_LOCATION


def location_from_path(path: Path) -> tuple[str, str]:
    """(location, "path") named by the file name (or NGSIM's own name for it, ``KNOWN_FILES``),
    else by the nearest parent directory; else (unknown, "default")."""
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


def location_codes(trimmed: pa.Array) -> tuple[np.ndarray, list[str]]:
    """Per-row codes [n] into the sorted normalised names of the Location cells ``trimmed``."""
    encoded = trimmed.dictionary_encode()
    names = [normalise_location(str(v)) for v in encoded.dictionary.to_pylist()]
    unique = sorted(set(names))
    remap = np.array([unique.index(v) for v in names], dtype=np.int64)
    return remap[np.asarray(encoded.indices)], unique
