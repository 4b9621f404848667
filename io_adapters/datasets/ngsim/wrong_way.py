"""The check that no vehicle on a one-way NGSIM freeway (US-101, I-80) drives backwards: in the road
frame (x = Local_Y) its Local_Y would fall along its frames while v_Vel says it drives forward (a
column of another vehicle or in another unit, never a real vehicle)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lanecast.io_adapters.datasets.ngsim.columns import FEET, FRAME_RATE
from lanecast.io_adapters.datasets.ngsim.locations import is_freeway
from lanecast.io_adapters.datasets.ngsim.parse import Parsed
from lanecast.io_adapters.errors import InputError

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
    location_code: np.ndarray, period: np.ndarray, vehicle: np.ndarray, frame: np.ndarray, local_y: np.ndarray
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


def check_wrong_way(parsed: Parsed, period: np.ndarray) -> None:
    """Refuse a freeway vehicle of ``parsed`` driving backwards, at its first line; ``period`` [n]."""
    cols = parsed.columns
    freeway = np.array([is_freeway(loc) for loc in parsed.locations], dtype=bool)[parsed.location_code]
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
    raise InputError(
        parsed.path,
        f"vehicle {cols['vehicle_id'][row]:.0f} drives backwards on a one-way freeway: its Local_Y falls "
        f"by {found.fall:.1f} ft over {found.seconds:.1f} s ({found.fall / max(found.seconds, 1e-9):.1f} ft/s)",
        line=parsed.line(row),
        column="Local_Y",
        expected="Local_Y rising along a vehicle's frames (the direction of travel on US-101 and I-80)",
    )
