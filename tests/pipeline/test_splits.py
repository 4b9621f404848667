"""Splits by track: the PiP convention by hand, the seeded hash split (stable, seeded, 70/10/20),
highD's two directions as one source recording, and no track in two splits of a windows dataset."""

from __future__ import annotations

import numpy as np
import pytest

from lanecast.io_adapters.contracts.track_table import RecordingMeta, TableMeta, build_table
from lanecast.io_adapters.errors import InputError
from lanecast.pipeline.make_windows import make_windows
from lanecast.pipeline.splits import hash_split, hash_unit, pip_split, track_splits


def test_pip_split_by_hand() -> None:
    ids = np.arange(1, 11)  # max 10: train <= 7, val <= 8, test 9, 10
    got = pip_split(np.full(10, "a"), ids)
    assert got.tolist() == ["train"] * 7 + ["val"] + ["test"] * 2


def test_pip_split_rounds_like_python_and_is_per_recording() -> None:
    # max 15: round(10.5) = 10 (half to even), round(12.0) = 12; max 25: round(17.5) = 18, round(20) = 20
    rec = np.r_[np.full(15, "a"), np.full(25, "b")]
    ids = np.r_[np.arange(1, 16), np.arange(1, 26)]
    got = pip_split(rec, ids)
    a, b = got[:15], got[15:]
    assert (a == "train").sum() == 10 and (a == "val").sum() == 2 and (a == "test").sum() == 3
    assert (b == "train").sum() == 18 and (b == "val").sum() == 2 and (b == "test").sum() == 5


def test_pip_groups_recordings_from_the_same_source() -> None:
    """highD's upper and lower halves share ids and files: the max id is over both."""
    rec = np.array(["h-01-upper", "h-01-upper", "h-01-lower", "h-01-lower"])
    ids = np.array([1, 7, 8, 10])
    groups = {"h-01-upper": "01", "h-01-lower": "01"}
    assert track_splits(rec, ids, "pip", source_group=groups).tolist() == ["train", "train", "val", "test"]
    # without grouping the upper half has max id 7: 7 > round(0.8 * 7) = 6 -> test; lower as before
    assert track_splits(rec, ids, "pip").tolist() == ["train", "test", "val", "test"]


def test_hash_split_is_stable_seeded_and_70_10_20() -> None:
    rec = np.repeat(["highd-01-upper", "highd-02-lower"], 10_000)
    ids = np.tile(np.arange(10_000), 2)
    a = hash_split(rec, ids, seed=0)
    np.testing.assert_array_equal(a, hash_split(rec, ids, seed=0))
    b = hash_split(rec, ids, seed=1)
    assert (a != b).mean() > 0.3
    for split, share in (("train", 0.7), ("val", 0.1), ("test", 0.2)):
        assert abs((a == split).mean() - share) < 0.01
    # the same id in another recording is an independent draw
    assert (a[:10_000] != a[10_000:]).mean() > 0.3
    # pinned value: the hash depends on nothing but (recording, track id, seed)
    assert float(hash_unit(np.array(["highd-01-upper"]), np.array([7]), 0)[0]) == 0.6203828826404878


def test_unknown_split_method() -> None:
    with pytest.raises(InputError, match="unknown split method"):
        track_splits(np.array(["a"]), np.array([1]), "random")


def test_no_track_in_two_splits() -> None:
    n_tracks, n = 40, 120
    t = np.arange(n) / 10.0
    cols: dict[str, object] = {
        "recording": np.repeat(["a", "b"], n_tracks // 2 * n),
        "track_id": np.repeat(np.r_[np.arange(1, 21), np.arange(1, 21)], n),
        "frame": np.tile(np.arange(n), n_tracks),
        "time_ns": np.tile(np.rint(t * 1e9).astype(np.int64), n_tracks),
        "x": np.tile(30.0 * t, n_tracks) + np.repeat(np.arange(n_tracks) * 50.0, n),
        "y": np.zeros(n * n_tracks),
        "heading": np.zeros(n * n_tracks),
        "vx": np.full(n * n_tracks, 30.0),
        "vy": np.zeros(n * n_tracks),
        "ax": np.zeros(n * n_tracks),
        "ay": np.zeros(n * n_tracks),
        "length": np.full(n * n_tracks, 4.5),
        "width": np.full(n * n_tracks, 1.8),
        "lane_id": np.full(n * n_tracks, 1),
        "object_class": ["car"] * (n * n_tracks),
    }
    table = build_table(cols, TableMeta("test", {"a": RecordingMeta(10.0), "b": RecordingMeta(10.0)}))
    for method in ("pip", "hash"):
        w = make_windows(table, split=method, seed=5)
        assert len(w) == n_tracks * 5
        keys = list(
            zip(w.index.column("recording").to_pylist(), w.index.column("track_id").to_pylist(), strict=True)
        )
        splits = w.index.column("split").to_pylist()
        seen: dict[tuple[str, int], str] = {}
        for key, split in zip(keys, splits, strict=True):
            assert seen.setdefault(key, split) == split
        assert set(splits) <= {"train", "val", "test"}
        counts = w.manifest["counts"]
        assert sum(counts.values()) == len(w)
        if method == "pip":
            # ids 1..20 per recording: train <= 14, val <= 16, test 17..20
            expected = {"train": 2 * 14 * 5, "val": 2 * 2 * 5, "test": 2 * 4 * 5, "none": 0}
            assert counts == expected
            assert w.manifest["tracks"] == {"train": 28, "val": 4, "test": 8}
