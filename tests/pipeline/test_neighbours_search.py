"""The band search (each vehicle against those of its frame within reach along the road) picks the
same neighbours as a brute-force search over all pairs of vehicles of each frame, on random scenes
with ties, band boundaries, opposing traffic, vehicles beyond the neighbour range, and on a subset
of rows (the others, given a non-finite position in the reference, take no part)."""

from __future__ import annotations

import numpy as np
import pyarrow as pa
import pytest
from conftest import LANE, make_track_table

from lanecast.pipeline import neighbour_bands as bands
from lanecast.pipeline import neighbour_columns as ncols
from lanecast.pipeline import neighbours as nbm

RANGE = ncols.NEIGHBOUR_RANGE_M


def brute_force_bands(cols: ncols.Columns, lane_width: float = LANE) -> np.ndarray:
    """Neighbour rows [n, 7] by the band rules (docs/design.md §2), every pair of vehicles of each
    (recording, frame) compared; the lowest score wins, the lowest row among equals."""
    out = np.full((cols.n, len(ncols.SLOTS)), -1, dtype=np.int64)
    ok = np.isfinite(cols.x) & np.isfinite(cols.y) & np.isfinite(cols.heading)
    key = cols.rec * (int(cols.frame.max()) + 1) + cols.frame
    for k in np.unique(key):
        rows = np.flatnonzero((key == k) & ok)
        for i in rows:
            j = rows[rows != i]
            h = np.full(j.size, cols.heading[i])
            dx, dy = cols.x[j] - cols.x[i], cols.y[j] - cols.y[i]
            lon = np.cos(h) * dx + np.sin(h) * dy
            lat = -np.sin(h) * dx + np.cos(h) * dy
            lat = np.where(np.cos(cols.heading[j] - h) > 0, lat, np.inf)
            half = 0.5 * (cols.length[i] + cols.length[j])
            w = lane_width
            same, left = np.abs(lat) < w / 2, (lat >= w / 2) & (lat < 1.5 * w)
            right = (lat <= -w / 2) & (lat > -1.5 * w)
            ahead, behind, overlap = lon >= half, lon <= -half, np.abs(lon) < half
            rules = {
                "FL": (left & ahead, lon),
                "F": (same & (lon > 0), lon),
                "FR": (right & ahead, lon),
                "L": (left & overlap, np.abs(lon)),
                "R": (right & overlap, np.abs(lon)),
                "RL": (left & behind, -lon),
                "RR": (right & behind, -lon),
            }
            for s, slot in enumerate(ncols.SLOTS):
                mask, score = rules[slot]
                if mask.any():
                    best = np.flatnonzero(mask & (score == score[mask].min()))[0]  # lowest row
                    out[i, s] = j[best]
    return out


def random_scene(seed: int, coordinate_frame: str, *, n_tracks: int = 60, n_frames: int = 40) -> pa.Table:
    """Vehicles scattered over 600 m of a 4-lane road in both directions (some across it, some at
    the same spot or exactly on a band boundary), rotated into a
    world frame unless ``coordinate_frame`` is road."""
    rng = np.random.default_rng(seed)
    track = np.repeat(np.arange(1, n_tracks + 1), n_frames)
    frame = np.tile(np.arange(n_frames), n_tracks)
    present = rng.random(track.size) < 0.6
    n = track.size
    x = np.round(rng.uniform(0, 600, n), 1)  # 0.1 m grid: ties along the road
    lane = rng.integers(0, 4, n)
    y = lane * LANE + np.where(rng.random(n) < 0.5, 0.0, rng.normal(0, 0.8, n))
    y = np.where(rng.random(n) < 0.05, y + LANE / 2, y)  # on a band boundary
    heading = np.where(rng.random(n) < 0.3, np.pi, 0.0)  # both directions
    heading = np.where(rng.random(n) < 0.3, heading + rng.normal(0, 0.05, n), heading)
    heading = np.where(rng.random(n) < 0.05, rng.uniform(-np.pi, np.pi, n), heading)  # turning
    twin = rng.random(n) < 0.1  # same spot as the previous row of that frame: exact ties
    x, y = np.where(twin, np.roll(x, n_frames), x), np.where(twin, np.roll(y, n_frames), y)
    length = rng.choice([4.5, 4.5, 12.0], n)
    if coordinate_frame != "road":
        c, s = np.cos(0.7), np.sin(0.7)
        x, y, heading = 1000 + c * x - s * y, -500 + s * x + c * y, heading + 0.7
    lane_id = np.where(rng.random(n) < 0.2, np.nan, lane + 1.0)  # missing lanes (bands ignore lanes)
    cols = {"track_id": track, "frame": frame, "x": x, "y": y, "heading": heading, "length": length}
    cols["lane_id"] = lane_id
    return make_track_table({k: v[present] for k, v in cols.items()}, coordinate_frame=coordinate_frame)


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("coordinate_frame", ["road", "map"])
def test_band_search_matches_brute_force(seed: int, coordinate_frame: str) -> None:
    table = random_scene(seed, coordinate_frame)
    cols = ncols.columns(table)
    assert cols.n > 1000
    expected = brute_force_bands(cols)
    assert (expected >= 0).sum() > 3 * cols.n  # crowded enough that most slots are taken
    # Without a range: every vehicle of the frame is a candidate.
    np.testing.assert_array_equal(bands.from_bands(cols), expected)
    # With the range (vehicles beyond it not compared in a world frame): the same after limit_range.
    limited = ncols.limit_range(cols, expected, RANGE)
    assert (limited != expected).sum() > 100  # the range matters in these scenes
    got = nbm.neighbour_rows(table, cols, method="bands").rows
    np.testing.assert_array_equal(got, limited)
    np.testing.assert_array_equal(
        ncols.limit_range(cols, bands.from_bands(cols, max_range_m=RANGE), RANGE), limited
    )


def test_band_search_on_a_subset_of_rows() -> None:
    """Rows left out are nobody's neighbour and get none."""
    table = random_scene(3, "map")
    cols = ncols.columns(table)
    rows = np.flatnonzero(cols.track % 3 != 0)
    keep = np.zeros(cols.n, dtype=bool)
    keep[rows] = True
    sub = ncols.Columns(**{**cols.__dict__, "x": np.where(keep, cols.x, np.nan)})
    got = ncols.limit_range(cols, bands.from_bands(cols, rows, max_range_m=RANGE), RANGE)
    np.testing.assert_array_equal(got, ncols.limit_range(cols, brute_force_bands(sub), RANGE))
