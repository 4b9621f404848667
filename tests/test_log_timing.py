"""Frames of a drive log without lanecast's metadata: the rate and the grid estimated from the
message stamps, robust to stamps that jitter (a sensor's or a recorder's clock) and to gaps."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
from test_hostile_inputs import _entity, json_log

from lanecast.io_adapters.logs.frames_from_stamps import frames_of, nominal_rate
from lanecast.workflows.cli import main


def jittered(rate_hz: float, n: int, jitter_ms: float, seed: int = 0) -> np.ndarray:
    """n stamps (ns) of a rate_hz clock, each moved by up to ±jitter_ms, uniformly."""
    rng = np.random.default_rng(seed)
    period = 1e9 / rate_hz
    return (1_000_000_000 + np.arange(n) * period + rng.uniform(-jitter_ms, jitter_ms, n) * 1e6).astype(
        np.int64
    )


@pytest.mark.parametrize(
    ("stamps", "rate"),
    [
        (jittered(10.0, 200, 30.0), 10.0),  # the median interval alone said 10.14 Hz
        (jittered(25.0, 300, 10.0, seed=1), 25.0),
        (np.delete(jittered(10.0, 300, 0.0), np.arange(0, 300, 7)), 10.0),  # every 7th message lost
        (jittered(12.5, 200, 0.0), 12.5),  # not a whole rate: kept (13 Hz would skip frames)
        (jittered(7.3, 200, 0.0), 7.3),
    ],
)
def test_nominal_rate(stamps: np.ndarray, rate: float) -> None:
    assert nominal_rate(stamps) == pytest.approx(rate, rel=1e-6)


def test_jittered_stamps_get_one_frame_each() -> None:
    stamps = jittered(10.0, 200, 30.0)
    frames, rate = frames_of(stamps, None)
    assert rate == 10.0
    np.testing.assert_array_equal(frames, np.arange(200))


def test_a_log_stamped_with_jitter_converts_every_row(tmp_path: Path) -> None:
    """A 10 Hz topic whose stamps jitter by ±30 ms: before, 54 of 400 rows were dropped as repeated
    (track, frame) with exit 0 and a note on stderr."""
    stamps = jittered(10.0, 200, 30.0)
    messages = [
        (
            "/objects",
            int(t),
            [
                _entity(1, 2.0 * i, int(t) // 10**9, int(t) % 10**9),
                _entity(2, 50 + 2.0 * i, int(t) // 10**9, int(t) % 10**9),
            ],
        )
        for i, t in enumerate(stamps)
    ]
    log = json_log(tmp_path / "jitter.mcap", messages)
    out = tmp_path / "jitter.parquet"
    assert main(["convert", str(log), "--out", str(out)]) == 0
    table = pq.read_table(out).to_pandas()
    assert len(table) == 400
    for _, track in table.groupby("track_id"):
        np.testing.assert_array_equal(np.sort(track["frame"].to_numpy()), np.arange(200))
        np.testing.assert_allclose(np.sort(track["x"].to_numpy()) - track["x"].min(), 2.0 * np.arange(200))
