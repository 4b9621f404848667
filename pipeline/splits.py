"""Train/val/test splits by track, never by window (docs/design.md §2): 70/10/20.

- ``pip``: the PiP convention (Song et al., ECCV 2020), per source recording by vehicle id:
  id <= round(0.7 * max id) train, <= round(0.8 * max id) val, the rest test. Recordings that
  come from the same source files (highD's two driving directions of one recording) are one
  source recording here, as in PiP; ``round`` is Python's (half to even).
- ``hash``: a seeded, stable hash of (recording, track_id): the same track lands in the same split
  on every machine and run; different seeds give independent splits.
- ``none``: every track in split ``none`` (e.g. annotating a log).
"""

from __future__ import annotations

import hashlib

import numpy as np

from lanecast.io_adapters.errors import InputError

SPLIT_METHODS = ("pip", "hash", "none")
FRACTIONS = (0.7, 0.1, 0.2)
_MASK64 = np.uint64(0xFFFFFFFFFFFFFFFF)


def pip_split(group: np.ndarray, track_id: np.ndarray) -> np.ndarray:
    """PiP split of tracks: group str [T] (source recording), track_id int64 [T] -> str [T]."""
    _, g = np.unique(np.asarray(group, dtype=str), return_inverse=True)
    max_id = np.full(g.max() + 1 if g.size else 0, np.iinfo(np.int64).min, dtype=np.int64)
    np.maximum.at(max_id, g, track_id)
    return pip_split_by_max(np.asarray(track_id, dtype=np.int64), max_id[g])


def pip_split_by_max(track_id: np.ndarray, max_id: np.ndarray) -> np.ndarray:
    """PiP split given each track's source-recording max id (int64 [T] each) -> str [T]."""
    train_max = np.rint(0.7 * max_id)
    val_max = np.rint(0.8 * max_id)
    return np.where(track_id <= train_max, "train", np.where(track_id <= val_max, "val", "test"))


def _splitmix64(z: np.ndarray) -> np.ndarray:
    with np.errstate(over="ignore"):
        z = z + np.uint64(0x9E3779B97F4A7C15)
        z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
        z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
        return z ^ (z >> np.uint64(31))


def hash_unit(recording: np.ndarray, track_id: np.ndarray, seed: int = 0) -> np.ndarray:
    """A stable pseudo-random number in [0, 1) per (recording, track_id, seed). float64 [T]."""
    names, inv = np.unique(np.asarray(recording, dtype=str), return_inverse=True)
    return hash_unit_codes(names, inv, track_id, seed)


def hash_unit_codes(names: np.ndarray, codes: np.ndarray, track_id: np.ndarray, seed: int = 0) -> np.ndarray:
    """:func:`hash_unit` with recordings given as names str [R] and codes int [T] into them."""
    rec_hash = np.array(
        [
            int.from_bytes(hashlib.blake2b(f"{seed}:{name}".encode(), digest_size=8).digest(), "little")
            for name in names
        ],
        dtype=np.uint64,
    )
    z = _splitmix64(rec_hash[codes] ^ _splitmix64(np.asarray(track_id, dtype=np.int64).astype(np.uint64)))
    return (z >> np.uint64(11)).astype(np.float64) / float(2**53)


def split_from_unit(u: np.ndarray) -> np.ndarray:
    """train < 0.7 <= val < 0.8 <= test, str [T]."""
    return np.where(u < FRACTIONS[0], "train", np.where(u < FRACTIONS[0] + FRACTIONS[1], "val", "test"))


def hash_split(recording: np.ndarray, track_id: np.ndarray, seed: int = 0) -> np.ndarray:
    """Seeded hash split of tracks -> str [T] (train < 0.7 <= val < 0.8 <= test)."""
    return split_from_unit(hash_unit(recording, track_id, seed))


def track_splits(
    recording: np.ndarray,
    track_id: np.ndarray,
    method: str = "pip",
    seed: int = 0,
    source_group: dict[str, str] | None = None,
) -> np.ndarray:
    """The split of each track (recording str [T], track_id int64 [T]) -> str [T].

    ``source_group`` maps a recording to its source recording for ``pip`` (default: itself).
    """
    recording = np.asarray(recording, dtype=str)
    track_id = np.asarray(track_id, dtype=np.int64)
    if method == "pip":
        groups = recording
        if source_group:
            names, inv = np.unique(recording, return_inverse=True)
            groups = np.array([source_group.get(str(name), str(name)) for name in names], dtype=str)[inv]
        return pip_split(groups, track_id)
    if method == "hash":
        return hash_split(recording, track_id, seed)
    if method == "none":
        return np.full(recording.shape, "none")
    raise InputError(None, f"unknown split method {method!r}", expected=f"one of {SPLIT_METHODS}")
