"""NGSIM motion in the track table's terms: centre, heading, velocity and acceleration of each row.

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
spikes of up to ±6 ft/s² that no motion follows, and the acceleration is 0.
"""

from __future__ import annotations

import math

import numpy as np

from lanecast.io_adapters.contracts.track_runs import along_track_derivative, row_extent, run_starts
from lanecast.io_adapters.datasets.ngsim.columns import FEET, FRAME_RATE

MIN_MOVING_SPEED = 0.5  # m/s; below it the motion gives no reliable heading
# m/s of front-bumper motion over ±0.5 s from which an arterial heading is taken: NGSIM positions
# jitter by ~0.1 m, a few degrees at this speed; slower motion holds the last reliable heading.
MIN_HEADING_SPEED = 1.0
GRADIENT_SPAN = 5  # rows either side for velocity directions: differences over ±0.5 s
MAX_TURN_FROM_DIRECTION = math.radians(135)  # motion further from the stated Direction is a glitch
# Fallback heading of a vehicle that never moves, from the CSV's Direction (1 E, 2 N, 3 W, 4 S),
# with +x (Local_Y) northwards and +y (-Local_X) westwards as on the arterials.
_DIRECTION_HEADING = {1: -math.pi / 2, 2: 0.0, 3: math.pi / 2, 4: math.pi}


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
    values: np.ndarray, valid: np.ndarray, first: np.ndarray, last: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Invalid rows take the nearest earlier valid row of their track, else the nearest later one."""
    n = values.size
    i = np.arange(n)
    before = np.maximum.accumulate(np.where(valid, i, -1))
    after = np.minimum.accumulate(np.where(valid, i, n)[::-1])[::-1]
    use_before = ~valid & (before >= first)
    use_after = ~valid & ~use_before & (after <= last)
    out = values.copy()
    out[use_before] = values[before[use_before]]
    out[use_after] = values[after[use_after]]
    return out, valid | use_before | use_after


def _wrap(angle: np.ndarray) -> np.ndarray:
    """Angles [n] wrapped into [-pi, pi)."""
    return (angle + np.pi) % (2 * np.pi) - np.pi


def kinematics(
    cols: dict[str, np.ndarray], rec: np.ndarray, vehicle: np.ndarray, frame: np.ndarray, freeway: np.ndarray
) -> dict[str, np.ndarray]:
    """x, y, heading, vx, vy, ax, ay [n] for rows sorted by (recording, vehicle, frame)."""
    first, last = row_extent(run_starts(rec, vehicle))  # per row: its track's first and last row
    t = frame / FRAME_RATE
    half_length = cols["v_length"] * FEET / 2
    speed = cols["v_vel"] * FEET
    i = np.arange(speed.size)
    standing_still = (speed == 0) & (speed[np.maximum(i - 1, first)] == 0)
    standing_still &= speed[np.minimum(i + 1, last)] == 0
    accel = np.where(standing_still, 0.0, cols["v_acc"] * FEET)  # no spikes at rest (module docstring)
    front_x = cols["local_y"] * FEET
    front_y = -cols["local_x"] * FEET

    # Arterials: heading from the motion of the front bumper, held through stops. Motion is trusted
    # only where it agrees with the recorded speed and, where the source gives Direction, is not
    # backwards against it (tracking glitches at a track's start run the bumper backwards, and a
    # heading of 180° held through a stop would flip, and swing the centre by a vehicle length,
    # when the vehicle moves off).
    gx = along_track_derivative(front_x, t, first, last, span=GRADIENT_SPAN)
    gy = along_track_derivative(front_y, t, first, last, span=GRADIENT_SPAN)
    motion = np.hypot(gx, gy)
    motion_angle = np.arctan2(gy, gx)
    direction = cols["direction"]
    fallback = np.zeros(direction.size)
    for code, angle in _DIRECTION_HEADING.items():
        fallback[direction == code] = angle
    stated = np.isin(direction, list(_DIRECTION_HEADING))
    against = stated & (np.abs(_wrap(motion_angle - fallback)) > MAX_TURN_FROM_DIRECTION)
    moving = (motion >= MIN_HEADING_SPEED) & (motion <= 2 * speed + 1.0) & ~against
    motion_heading, known = _fill_within_track(motion_angle, moving, first, last)
    arterial_heading = np.where(known, motion_heading, fallback)
    # Smoothed over ±0.5 s (mean direction): a held heading that meets the motion again after a
    # stop turns over a second, not in one frame (the centre sits half a length behind the bumper).
    arterial_heading = np.arctan2(
        track_mean(np.sin(arterial_heading), first, last, GRADIENT_SPAN),
        track_mean(np.cos(arterial_heading), first, last, GRADIENT_SPAN),
    )

    # Freeways: road frame, vx = v_Vel, vy from the lateral motion of y.
    vy_road = along_track_derivative(front_y, t, first, last, span=GRADIENT_SPAN)
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
