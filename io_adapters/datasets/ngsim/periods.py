"""NGSIM's recording periods, and the checks that a bad cell makes no phantom recording.

A period is a cluster of the epoch ``Global_Time - 100 * Frame_ID``: the CSV export's Peachtree rows
have two epochs 11,700 apart (its 12:45 and 16:00 periods) whose vehicle ids and frames overlap, so
one recording per location would merge different vehicles. A period, a Location or a stretch of a
vehicle's frames of a row or two only is a bad cell (a Global_Time or Location gone wrong), refused
at its line.
"""

from __future__ import annotations

import numpy as np

from lanecast.io_adapters.datasets.ngsim.columns import GLOBAL_TIME_PER_FRAME
from lanecast.io_adapters.datasets.ngsim.parse import Parsed
from lanecast.io_adapters.errors import InputError

PERIOD_GAP = 1_000  # epochs further apart than this (Global_Time units) are different periods
MAX_STRAY_ROWS = 2  # rows of a vehicle in a period, next to its frames in another, taken as a bad cell


def clusters(epochs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(period index of each of the sorted unique ``epochs`` [E], the first epoch of each period [P])."""
    cluster = np.concatenate([[0], np.cumsum(np.diff(epochs) > PERIOD_GAP)]).astype(np.int64)
    return cluster, epochs[np.flatnonzero(np.concatenate([[True], np.diff(cluster) > 0]))]


def periods(columns: dict[str, np.ndarray], split: bool) -> tuple[np.ndarray, np.ndarray]:
    """Period index per row [n] (0-based, in time order) and the epoch of each period [P]."""
    epoch = columns["global_time"] - GLOBAL_TIME_PER_FRAME * columns["frame_id"]
    if not split:
        return np.zeros(epoch.size, dtype=np.int64), np.array([epoch.min()])
    unique = np.unique(epoch)
    cluster, starts = clusters(unique)
    return cluster[np.searchsorted(unique, epoch)], starts


def few_rows(sizes: np.ndarray) -> int | None:
    """The index of a count of at most MAX_STRAY_ROWS among several ``sizes`` (rows per period or per
    location of a file): a phantom recording made of a bad cell or two; None if there is none."""
    return int(np.argmin(sizes)) if sizes.size > 1 and sizes.min() <= MAX_STRAY_ROWS else None


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


def check_small_location(parsed: Parsed) -> None:
    """Refuse a Location that only a row or two of a file with other locations have."""
    sizes = np.bincount(parsed.location_code, minlength=len(parsed.locations))
    small = few_rows(sizes)
    if small is None:
        return
    others = [loc for i, loc in enumerate(parsed.locations) if i != small]
    raise InputError(
        parsed.path,
        f"Location {parsed.locations[small]!r} on {int(sizes[small])} row(s) only would make a recording "
        "of its own",
        line=parsed.line(int(np.flatnonzero(parsed.location_code == small)[0])),
        column="Location",
        expected=f"the location of the vehicle's other rows ({', '.join(others)})",
    )


def check_period_continuity(parsed: Parsed, period: np.ndarray) -> None:
    """Refuse a Global_Time that puts one frame of a vehicle in another recording period than the
    frame before it (a phantom recording made of one bad cell); ``period`` [n] per row of ``parsed``."""
    cols = parsed.columns
    small = few_rows(np.bincount(period))
    if small is not None:
        odd = int(np.flatnonzero(period == small)[0])
        raise InputError(
            parsed.path,
            f"Global_Time {cols['global_time'][odd]} and Frame_ID {cols['frame_id'][odd]} put this row in a "
            f"recording period of its own ({int(np.bincount(period).min())} rows)",
            line=parsed.line(odd),
            column="Global_Time",
            expected="Global_Time = epoch + 100 * Frame_ID with the epoch of a recording period",
        )
    pair = stray_pair(parsed.location_code, cols["vehicle_id"], cols["frame_id"], period)
    if pair is None:
        return
    odd, other = pair
    other_line = parsed.line(other)
    raise InputError(
        parsed.path,
        f"Global_Time {cols['global_time'][odd]} puts frame {cols['frame_id'][odd]} of vehicle "
        f"{cols['vehicle_id'][odd]} in another recording period than its neighbouring frame (line {other_line})",
        line=parsed.line(odd),
        column="Global_Time",
        expected=f"Global_Time = epoch + 100 * Frame_ID with the epoch of line {other_line}",
    )
