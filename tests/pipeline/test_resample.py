"""Resampling to 10 Hz: exact values for linear and accelerating motion, heading across ±pi,
categorical columns from the nearest-earlier sample, gaps, metadata, irregular log timestamps."""

from __future__ import annotations

import numpy as np
import pyarrow as pa
import pytest
from conftest import make_track_table

from lanecast.io_adapters.contracts.track_table import (
    RecordingMeta,
    TableMeta,
    build_table,
    read_meta,
    validate,
)
from lanecast.pipeline.resample import resample

COLUMNS = ("x", "y", "heading", "vx", "vy", "ax", "ay", "length", "width")


def one_track(time_s: np.ndarray, rate: float, **values: np.ndarray | float) -> pa.Table:
    """A one-track table sampled at ``time_s``; columns default to 0 (lane 2, length 4.5)."""
    n = time_s.size
    cols: dict[str, object] = {
        "track_id": np.full(n, 7),
        "frame": np.arange(n),
        "time_ns": np.rint(time_s * 1e9).astype(np.int64),
        "lane_id": np.full(n, 2),
    }
    for name in COLUMNS:
        cols[name] = np.broadcast_to(np.asarray(values.get(name, 0.0), dtype=np.float64), (n,)).copy()
    cols["length"] = np.broadcast_to(np.asarray(values.get("length", 4.5)), (n,)).copy()
    for name in ("lane_id", "preceding_id"):
        if name in values:
            cols[name] = values[name]
    return make_track_table(cols, rate=rate)


def col(table: pa.Table, name: str) -> np.ndarray:
    return table.column(name).to_numpy()


def test_linear_motion_25hz_to_10hz_exact() -> None:
    t = np.arange(51) / 25.0  # 0 … 2.0 s
    out = resample(one_track(t, 25.0, x=5.0 + 20.0 * t, y=-3.0 + 0.5 * t, vx=20.0))
    validate(out)
    k = np.arange(21)
    np.testing.assert_array_equal(col(out, "frame"), k)
    np.testing.assert_array_equal(col(out, "time_ns"), k * 100_000_000)
    np.testing.assert_allclose(col(out, "x"), 5.0 + 2.0 * k, atol=1e-9)
    np.testing.assert_allclose(col(out, "y"), -3.0 + 0.05 * k, atol=1e-9)
    np.testing.assert_allclose(col(out, "vx"), 20.0, atol=1e-6)
    assert read_meta(out).recordings["r"].frame_rate == 10.0
    assert read_meta(out).recordings["r"].extra["native_frame_rate"] == 25.0


def test_accelerating_motion_exact_interpolation() -> None:
    """x = a t^2 / 2 at 25 Hz: even 10 Hz frames hit a sample, odd ones fall midway between two
    samples 0.04 s apart, where linear interpolation gives a/2 (t^2 + 0.02^2) exactly."""
    a = 2.0
    t = np.arange(101) / 25.0
    out = resample(one_track(t, 25.0, x=0.5 * a * t**2, vx=a * t, ax=a))
    tk = np.arange(41) * 0.1
    expected = np.where(np.arange(41) % 2 == 0, 0.5 * a * tk**2, 0.5 * a * (tk**2 + 0.02**2))
    np.testing.assert_allclose(col(out, "x"), expected, atol=1e-9)
    np.testing.assert_allclose(col(out, "vx"), a * tk, atol=1e-5)  # linear in t: exact (float32)
    np.testing.assert_allclose(col(out, "ax"), a, atol=1e-6)


def test_heading_interpolated_across_pi() -> None:
    t = np.array([0.0, 0.2])
    out = resample(one_track(t, 5.0, heading=np.array([3.0, -3.0])))
    h = col(out, "heading")
    # 0.1 s is midway: the short arc through pi, not 0.
    assert abs(abs(h[1]) - np.pi) < 1e-6
    np.testing.assert_allclose(h[[0, 2]], [3.0, -3.0], atol=1e-6)


def test_lane_and_neighbour_ids_from_nearest_earlier_sample() -> None:
    t = np.arange(26) / 25.0  # 0 … 1.0 s
    lane = np.where(np.arange(26) >= 13, 3, 2)  # changes at 0.52 s
    pre = np.where(np.arange(26) >= 12, 99, 42)  # changes at 0.48 s
    out = resample(one_track(t, 25.0, lane_id=lane, preceding_id=pre))
    # grid 0.5 s: nearest earlier sample is 0.48 s (lane 2, preceding 99); 0.6 s -> 0.6 s (lane 3)
    np.testing.assert_array_equal(col(out, "lane_id"), [2, 2, 2, 2, 2, 2, 3, 3, 3, 3, 3])
    np.testing.assert_array_equal(col(out, "preceding_id"), [42, 42, 42, 42, 42, 99, 99, 99, 99, 99, 99])


def test_gap_splits_the_track_without_interpolating_across() -> None:
    f = np.r_[np.arange(0, 21), np.arange(30, 61)]  # 25 Hz frames; 0.4 s gap after 0.8 s
    t = f / 25.0
    out = resample(one_track(t, 25.0, x=10.0 * t))
    np.testing.assert_array_equal(col(out, "frame"), np.r_[np.arange(0, 9), np.arange(12, 25)])
    np.testing.assert_allclose(col(out, "x"), col(out, "frame") * 1.0, atol=1e-9)


def test_short_jitter_is_not_a_gap() -> None:
    t = np.array([0.0, 0.04, 0.08, 0.135, 0.16, 0.2])  # 0.055 s < 1.5 periods of 0.04 s
    out = resample(one_track(t, 25.0, x=t * 10.0))
    np.testing.assert_array_equal(col(out, "frame"), [0, 1, 2])
    np.testing.assert_allclose(col(out, "x"), [0.0, 1.0, 2.0], atol=1e-9)


def test_ten_hz_input_is_unchanged() -> None:
    t = np.arange(40) / 10.0
    table = one_track(t, 10.0, x=np.sin(t), y=np.cos(t), heading=0.3)
    out = resample(table)
    for name in ("frame", "time_ns", "x", "y", "heading", "lane_id", "track_id"):
        np.testing.assert_array_equal(col(out, name), col(table, name))


def test_irregular_log_timestamps_with_epoch_offset() -> None:
    rng = np.random.default_rng(0)
    t = np.cumsum(rng.uniform(0.03, 0.05, 200))
    epoch = 1_700_000_000.0
    table = one_track(t, 25.0, x=3.0 * t, y=-1.0 * t)
    table = table.set_column(
        table.schema.get_field_index("time_ns"),
        table.schema.field("time_ns"),
        pa.array(np.int64(epoch * 1e9) + np.rint(t * 1e9).astype(np.int64)),
    )
    out = resample(table)
    time_s = (col(out, "time_ns") - np.int64(epoch * 1e9)) / 1e9
    assert np.all(col(out, "time_ns") % 100_000_000 == 0)
    np.testing.assert_array_equal(col(out, "frame"), col(out, "time_ns") // 100_000_000)
    np.testing.assert_allclose(col(out, "x"), 3.0 * time_s, atol=1e-6)
    np.testing.assert_allclose(col(out, "y"), -time_s, atol=1e-6)
    assert time_s[0] >= t[0] and time_s[-1] <= t[-1]


def test_one_frame_recording_gives_at_most_one_row() -> None:
    assert resample(one_track(np.array([0.04]), 25.0)).num_rows == 0  # no 0.1 s multiple inside
    assert resample(one_track(np.array([0.1]), 25.0)).num_rows == 1


@pytest.mark.parametrize("rate", [25.0, 30.0, 12.5])
def test_several_tracks_at_once(rate: float) -> None:
    """Two tracks with different spans are resampled independently in one pass."""
    a = one_track(np.arange(0, 30) / rate, rate, x=np.arange(30) / rate)
    cols = {
        name: np.concatenate([a.column(name).to_numpy(zero_copy_only=False)] * 2) for name in a.column_names
    }
    cols["track_id"] = np.r_[np.full(30, 1), np.full(30, 2)]
    cols["x"] = np.r_[np.arange(30) / rate, 100 + 2 * np.arange(30) / rate]
    cols["time_ns"] = np.r_[a.column("time_ns").to_numpy(), a.column("time_ns").to_numpy() + 50_000_000]
    table = build_table(cols, TableMeta("test", {"r": RecordingMeta(rate)}))
    out = resample(table)
    tid = col(out, "track_id")
    t1 = col(out, "time_ns")[tid == 1] / 1e9
    t2 = col(out, "time_ns")[tid == 2] / 1e9
    np.testing.assert_allclose(col(out, "x")[tid == 1], t1, atol=1e-9)
    np.testing.assert_allclose(col(out, "x")[tid == 2], 100 + 2 * (t2 - 0.05), atol=1e-9)
