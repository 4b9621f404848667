"""Frames of a drive log without lanecast's metadata: the rate and the grid estimated from the
message stamps, robust to stamps that jitter (a sensor's or a recorder's clock) and to gaps."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
from conftest import _entity, json_log

from lanecast.io_adapters.contracts import track_table
from lanecast.io_adapters.errors import LogError
from lanecast.io_adapters.logs.frames_from_stamps import frames_of, nominal_rate
from lanecast.io_adapters.logs.mcap import reader as mcap_reader
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


def _jittered_log(path: Path, jitter_ms: float, seed: int, twice_at: int | None = None) -> Path:
    """A foreign 10 Hz JSON log of 2 cars, 200 messages stamped ±jitter_ms (uniform); car k at
    x = 50 k + 2 i in message i. ``twice_at``: message i sent again 1 ms later with other x."""
    import numpy as np
    from conftest import _entity, json_log

    rng = np.random.default_rng(seed)
    stamps = 1_000_000_000 + np.arange(200) * 100_000_000 + rng.uniform(-jitter_ms, jitter_ms, 200) * 1e6
    messages = []
    for i, t in enumerate(stamps.astype(np.int64).tolist()):
        messages.append(
            ("/objects", t, [_entity(k, 50 * k + 2.0 * i, t // 10**9, t % 10**9) for k in (1, 2)])
        )
        if i == twice_at:
            t += 1_000_000
            messages.append(
                ("/objects", t, [_entity(k, 50 * k + 2.0 * i + 1, t // 10**9, t % 10**9) for k in (1, 2)])
            )
    return json_log(path, messages)


@pytest.mark.parametrize("seed", [0, 3])
def test_stamps_jittering_by_45_ms_at_10_hz_convert_every_row_on_its_frame(tmp_path: Path, seed: int) -> None:
    """A 10 Hz topic stamped ±45 ms (a recorder's clock; the grid laid through the stamps is a few
    ms off their mean phase): two stamps rounded onto one frame, its neighbour empty, and convert
    refused the log as 'track 1 has two different objects on frame 1'. Each stamp now takes the
    free frame beside it: every row converts, on the frame of its message."""
    import numpy as np

    out = tmp_path / "jitter.parquet"
    assert main(["convert", str(_jittered_log(tmp_path / "jitter.mcap", 45.0, seed)), "--out", str(out)]) == 0
    table = track_table.read_parquet(out).to_pandas()
    assert len(table) == 400
    for k, track in table.groupby("track_id"):
        track = track.sort_values("frame")
        np.testing.assert_array_equal(track["frame"].to_numpy(), np.arange(200))
        np.testing.assert_allclose(track["x"].to_numpy(), 50 * int(k) + 2.0 * np.arange(200))


def test_a_message_sent_twice_with_other_values_is_still_refused_not_spread(tmp_path: Path) -> None:
    """The spreading of jittered stamps does not hide a conflict: a message sent again 1 ms later
    with other positions is too far from the next frame to take it, and stays refused."""
    log = _jittered_log(tmp_path / "twice.mcap", 10.0, 0, twice_at=100)
    with pytest.raises(LogError, match="track 1 has two different objects on frame 100") as err:
        mcap_reader.read(log)
    import re

    stamps = re.search(r"stamped (\d+) ns and (\d+) ns", str(err.value))
    assert err.value.column == "time_ns" and stamps is not None
    assert int(stamps.group(2)) - int(stamps.group(1)) == 1_000_000
