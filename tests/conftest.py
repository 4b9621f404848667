"""Shared fixtures and factories for the whole test session.

Factories (plain functions, imported by the test modules with ``from conftest import …``):
- track tables: :func:`make_track_table` (columns → a validated one-recording table, defaults
  filled), :func:`table_of` and :func:`straight` (vehicles at 30 m/s in lanes), the seven-neighbour
  scene :data:`SEVEN` with its expected slots;
- windows datasets: :func:`synthetic_windows` (straight and lane-changing targets with a leader);
- drive logs and forecasts: :func:`make_mcap`, :func:`forecasts_for`, :func:`records`,
  :func:`assert_all_original_records_equal`.
"""

from __future__ import annotations

import json
import struct
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pytest
from mcap.records import Attachment, Channel, Header, Message, Metadata, Schema
from mcap.stream_reader import StreamReader
from mcap.writer import Writer

from lanecast.io_adapters.contracts.track_table import RecordingMeta, TableMeta, build_table, validate
from lanecast.io_adapters.contracts.windows import Windows

LANE = 3.75  # m, lane width of every hand-built scene
S = 1_000_000_000  # ns per second

# A short simulated highD recording: 2 simulated minutes at medium density on a 500 m section
# (vehicles stay 12-25 s in view, so 8 s windows fit), seed 7. Wall time: a few seconds.
SIM_RECORDING = {
    "minutes": 2.0,
    "seed": 7,
    "lanes_per_direction": 3,
    "density": "medium",
    "truck_share": 0.2,
    "section_length_m": 500.0,
    "approach_length_m": 400.0,
}


@pytest.fixture(scope="session")
def sim_recording_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A directory with ``01_tracks.csv``, ``01_tracksMeta.csv``, ``01_recordingMeta.csv`` simulated once.

    highD format at 25 Hz, 3 lanes per direction (highD laneIds 2, 3, 4 upper and 6, 7, 8 lower),
    cars and trucks, lane changes with continuous lateral motion, neighbour ids from SUMO.
    Read it with ``lanecast.io_adapters.datasets.highd.reader.read([sim_recording_dir])``; treat it as read-only.
    """
    from lanecast.io_adapters.sim import recording

    out = tmp_path_factory.mktemp("sim") / "highd-sim"
    return recording.simulate(out, show_progress=False, **SIM_RECORDING)  # type: ignore[arg-type]


# ------------------------------------------------------------------------------------ track tables


def make_track_table(
    columns: Mapping[str, Any],
    *,
    rate: float = 10.0,
    recording: str = "r",
    coordinate_frame: str = "road",
) -> pa.Table:
    """A validated track table of one recording from per-row ``columns`` (``track_id``, ``frame``,
    ``x``, ``y`` at least). ``recording``, ``time_ns`` (frame / rate), ``heading``, ``vx``, ``vy``,
    ``ax``, ``ay`` (0), ``length`` (4.5 m), ``width`` (1.8 m) and ``object_class`` (car) default."""
    n = len(columns["track_id"])
    frame = np.asarray(columns["frame"])
    cols: dict[str, Any] = {
        "recording": [recording] * n,
        "time_ns": np.rint(frame / rate * 1e9).astype(np.int64),
        "heading": np.zeros(n),
        "vx": np.zeros(n),
        "vy": np.zeros(n),
        "ax": np.zeros(n),
        "ay": np.zeros(n),
        "length": np.full(n, 4.5),
        "width": np.full(n, 1.8),
        "object_class": ["car"] * n,
    }
    cols.update(columns)
    table = build_table(
        cols, TableMeta("test", {recording: RecordingMeta(rate, coordinate_frame=coordinate_frame)})
    )
    validate(table)
    return table


def staggered_cars(
    cars: int, frames: int, *, stagger: int, step_m: float, speed: float, rate: float
) -> pa.Table:
    """``cars`` cars in lanes 1, 2, … (3.5 m apart), each ``frames`` frames long, car k starting
    ``stagger`` * k frames later and 10 m * k farther along, moving ``step_m`` a frame; vx ``speed``."""
    k = np.arange(cars)
    f = (np.arange(frames)[None, :] + stagger * k[:, None]).ravel()
    columns = {
        "track_id": np.repeat(k + 1, frames),
        "frame": f,
        "x": f * step_m + np.repeat(k * 10.0, frames),
        "y": np.repeat(k * 3.5, frames),
        "vx": np.full(f.size, speed),
        "lane_id": np.repeat(k + 1.0, frames),
    }
    return make_track_table(columns, rate=rate)


def table_of(
    tracks: dict[int, dict[str, Any]], *, rotate: float = 0.0, rate: float = 10.0, recording: str = "r"
) -> pa.Table:
    """Tracks {id: {frame, x, y, lane, [vx, vy, ax, ay, heading, length]}} in a road frame (rotated
    by ``rotate`` into a world frame if not 0)."""
    parts: dict[str, list[np.ndarray]] = {}
    c, s = np.cos(rotate), np.sin(rotate)
    for tid, tr in tracks.items():
        n = tr["frame"].size
        vx = np.broadcast_to(tr.get("vx", 30.0), (n,)).astype(float)
        vy = np.broadcast_to(tr.get("vy", 0.0), (n,)).astype(float)
        ax = np.broadcast_to(tr.get("ax", 0.0), (n,)).astype(float)
        ay = np.broadcast_to(tr.get("ay", 0.0), (n,)).astype(float)
        values = {
            "track_id": np.full(n, tid),
            "frame": tr["frame"],
            "time_ns": np.rint(tr["frame"] / rate * 1e9).astype(np.int64),
            "x": c * tr["x"] - s * tr["y"],
            "y": s * tr["x"] + c * tr["y"],
            "heading": np.broadcast_to(tr.get("heading", 0.0), (n,)) + rotate,
            "vx": c * vx - s * vy,
            "vy": s * vx + c * vy,
            "ax": c * ax - s * ay,
            "ay": s * ax + c * ay,
            "length": np.broadcast_to(tr.get("length", 4.5), (n,)).astype(float),
            "width": np.full(n, 1.8),
            "lane_id": tr["lane"].astype(float),
        }
        for k, v in values.items():
            parts.setdefault(k, []).append(np.asarray(v))
    cols = {k: np.concatenate(v) for k, v in parts.items()}
    frame = "road" if rotate == 0.0 else "map"
    return make_track_table(cols, rate=rate, recording=recording, coordinate_frame=frame)


def straight(
    tid_lane_dx: dict[int, tuple[int, float]], frames: np.ndarray, **per_id: dict[int, float]
) -> dict[int, dict[str, Any]]:
    """Vehicles at 30 m/s (3 m per frame) in lane k at y = (k - 2) * 3.75 starting dx ahead of 0."""
    out = {}
    for tid, (lane, dx) in tid_lane_dx.items():
        tr = {
            "frame": frames,
            "x": dx + 3.0 * frames,
            "y": np.full(frames.size, (lane - 2) * LANE),
            "lane": np.full(frames.size, lane),
        }
        for name, values in per_id.items():
            if tid in values:
                tr[name] = np.full(frames.size, values[tid])
        out[tid] = tr
    return out


# T = 1 in lane 2; lane 3 left (+y), lane 1 right. Row order FL, F, FR, L, T, R, RL, RR.
SEVEN = {
    1: (2, 0.0),
    2: (2, 30.0),
    3: (3, 25.0),
    4: (3, 0.5),
    5: (3, -25.0),
    6: (1, 25.0),
    7: (1, -1.0),
    8: (1, -25.0),
}
ROW_OF_ID = {3: "FL", 2: "F", 6: "FR", 4: "L", 1: "T", 7: "R", 5: "RL", 8: "RR"}
# T's neighbours in slot order FL, F, FR, L, R, RL, RR
SEVEN_EXPECTED = [3, 2, 6, 4, 7, 5, 8]


# -------------------------------------------------------------------------------- windows datasets


HIST_T = (np.arange(30) - 29) * 0.1  # s, oldest → t0
FUT_T = np.arange(1.0, 6.0)  # s


def _lateral(t: np.ndarray, side: np.ndarray, tc: np.ndarray) -> np.ndarray:
    """Lateral position [N, T] of a lane change of ``side`` (+1 left, -1 right, 0 none) centred at tc."""
    s = 1.0 / (1.0 + np.exp(-(t[None, :] - tc[:, None]) / 0.5))
    s0 = 1.0 / (1.0 + np.exp(tc[:, None] / 0.5))
    return side[:, None] * LANE * (s - s0)


def synthetic_windows(n: int = 600, seed: int = 0, lane_change_share: float = 0.4) -> Windows:
    """Windows of straight and lane-changing targets at 20–35 m/s with a front vehicle F.

    Lane changers (left or right, crossing the lane boundary 0.5–2.5 s after t0) follow a slower F,
    straight drivers a faster one. Labels: every step within ±2 s of the crossing is the lane change.
    Each window is its own track, split 70/10/20 by track id; origins and headings are random.
    """
    rng = np.random.default_rng(seed)
    speed = rng.uniform(20, 35, n)
    side = np.where(rng.random(n) < lane_change_share, rng.choice([-1.0, 1.0], n), 0.0)
    tc = rng.uniform(0.5, 2.5, n)
    inputs = np.zeros((n, 4, 8, 30), np.float32)
    present = np.zeros((n, 8, 30), bool)
    inputs[:, 0, 4] = speed[:, None] * HIST_T
    inputs[:, 1, 4] = _lateral(HIST_T, side, tc)
    inputs[:, 2, 4] = speed[:, None]
    present[:, 4] = True
    f_speed = speed + np.where(side != 0, -6.0, 3.0)
    gap = rng.uniform(25, 40, n)
    inputs[:, 0, 1] = gap[:, None] + f_speed[:, None] * HIST_T
    inputs[:, 2, 1] = f_speed[:, None]
    present[:, 1] = True
    future = np.stack([speed[:, None] * FUT_T, _lateral(FUT_T, side, tc)], axis=-1).astype(np.float32)
    near = np.abs(FUT_T[None, :] - tc[:, None]) <= 2.0
    maneuver = np.where(near & (side[:, None] > 0), 1, np.where(near & (side[:, None] < 0), 2, 0)).astype(
        np.int64
    )
    ids = np.arange(n)
    split = np.where(ids % 10 < 7, "train", np.where(ids % 10 < 8, "val", "test"))
    index = pa.table(
        {
            "recording": pa.array(np.where(ids < n // 2, "syn-a", "syn-b")),
            "track_id": pa.array(ids, pa.int64()),
            "t0_ns": pa.array(np.full(n, 3_000_000_000), pa.int64()),
            "split": pa.array(split),
            "origin_x": pa.array(rng.uniform(-500, 500, n)),
            "origin_y": pa.array(rng.uniform(-500, 500, n)),
            "origin_heading": pa.array(rng.uniform(-np.pi, np.pi, n)),
        }
    )
    return Windows(inputs, present, future, maneuver, index, {"sources": ["synthetic"]})


# ------------------------------------------------------------------------ drive logs and forecasts


def make_mcap(
    path: Path,
    *,
    n: int = 300,
    profile: str = "",
    json_only: bool = False,
    payload: int = 16,
    chunk_size: int = 2000,
) -> Path:
    """A real MCAP in log-time order: 2 schemas, 3 channels (one schemaless), n messages at 10 Hz
    from t=0.05 s, one on every whole second (the forecast ticks), an attachment and a metadata record, several zstd chunks."""
    with open(path, "wb") as f:
        w = Writer(f, chunk_size=chunk_size)
        w.start(profile=profile, library="test-writer")
        s1 = w.register_schema("test.Pose", "jsonschema", b'{"type":"object"}')
        s2 = w.register_schema("test.Blob", "jsonschema" if json_only else "protobuf", b"\x0a\x03abc")
        c1 = w.register_channel("/pose", "json", s1, {"qos": "reliable"})
        c2 = w.register_channel("/blob", "json" if json_only else "protobuf", s2)
        c3 = w.register_channel("/raw", "json" if json_only else "cbor", 0)
        rng = np.random.default_rng(0)
        for i in range(n):
            t = 50_000_000 + i * 100_000_000
            if i % 10 == 0:
                t_tick = i * 100_000_000  # exactly on the 1 s forecast ticks
                w.add_message(c2, t_tick, rng.bytes(payload), t_tick, 0)
            w.add_message(c1, t, json.dumps({"i": i, "pad": "x" * payload}).encode(), t - 7, i)
            if i % 7 == 0:
                w.add_message(c3, t, b'{"r":1}', t, 3)
        w.add_attachment(11, 22, "calib.yaml", "application/yaml", b"k: 1\n")
        w.add_metadata("drive", {"vehicle": "ego-7", "site": "A9"})
        w.finish()
    return path


def forecasts_for(recording: str, t0_s: list[int], tracks: list[int], k: int = 2) -> pa.Table:
    """Hand-made forecasts: target i at t0 starts at (10 t0 + i, 3.5 i), moves 10 m/s along x;
    track 1 changes lane left (maneuver 0,0,1,1,1), others go straight; K alternatives offset in y."""
    rows: dict[str, list] = {
        c: [] for c in ("recording", "track_id", "t0_ns", "x", "y", "maneuver_probs", "maneuver")
    }
    extra: dict[str, list] = {
        c: [] for c in ("origin_x", "origin_y", "alt_x", "alt_y", "alt_probs", "alt_maneuvers")
    }
    for t0 in t0_s:
        for i in tracks:
            ox, oy = 10.0 * t0 + i, 3.5 * i
            left = i == 1
            man = [0, 0, 1, 1, 1] if left else [0] * 5
            probs = [[0.9, 0.05, 0.05] if m == 0 else [0.2, 0.7, 0.1] for m in man]
            xs = [ox + 10.0 * h for h in range(1, 6)]
            ys = [oy + (0.7 * h if left else 0.0) for h in range(1, 6)]
            rows["recording"].append(recording)
            rows["track_id"].append(i)
            rows["t0_ns"].append(t0 * S)
            rows["x"].append(xs)
            rows["y"].append(ys)
            rows["maneuver_probs"].append(probs)
            rows["maneuver"].append(man)
            extra["origin_x"].append(ox)
            extra["origin_y"].append(oy)
            extra["alt_x"].append([xs] * k)
            extra["alt_y"].append([[y + 0.5 * (j + 1) for y in ys] for j in range(k)])
            extra["alt_probs"].append([0.2 / (j + 1) for j in range(k)])
            extra["alt_maneuvers"].append([[0, 2, 2, 2, 2]] * k)
    return pa.table({**rows, **extra})


def mcap_record_spans(data: bytes) -> list[tuple[int, int, int]]:
    """(offset, opcode, body length) of the top-level records of an MCAP's bytes, up to the footer
    (its opcode 0x02 included): where a test cuts, swaps or edits records."""
    out, pos = [], 8
    while pos + 9 <= len(data):
        op, n = struct.unpack_from("<BQ", data, pos)
        out.append((pos, op, n))
        if op == 0x02:
            break
        pos += 9 + n
    return out


def mcap_contents(path: Path) -> tuple[Any, list[tuple[int, int, bytes]], list[Any]]:
    """(summary, messages as (channel id, log time, data) in file order, metadata records) of an
    MCAP, read by the mcap library: what a test needs to write it again with something changed."""
    from mcap.reader import make_reader

    with path.open("rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None
        messages = [(ch.id, m.log_time, m.data) for _s, ch, m in reader.iter_messages()]
        metadata = list(reader.iter_metadata())
    return summary, messages, metadata


def channel_record(channel_id: int, schema_id: int, topic: str, message_encoding: str) -> bytes:
    """The bytes of an MCAP Channel record (opcode 0x04, no channel metadata)."""
    body = struct.pack("<HH", channel_id, schema_id)
    for text in (topic, message_encoding):
        body += struct.pack("<I", len(text)) + text.encode()
    body += struct.pack("<I", 0)
    return struct.pack("<BQ", 0x04, len(body)) + body


def records(path: Path) -> dict[str, Any]:
    """Every record of an MCAP by kind (schemas, channels by id; messages in file order)."""
    out: dict[str, Any] = {
        "schemas": {},
        "channels": {},
        "messages": [],
        "attachments": [],
        "metadata": [],
    }
    with open(path, "rb") as f:
        for r in StreamReader(f, validate_crcs=True).records:
            if isinstance(r, Header):
                out["header"] = r
            elif isinstance(r, Schema):
                out["schemas"][r.id] = r
            elif isinstance(r, Channel):
                out["channels"][r.id] = r
            elif isinstance(r, Message):
                out["messages"].append(r)
            elif isinstance(r, Attachment):
                out["attachments"].append(r)
            elif isinstance(r, Metadata):
                out["metadata"].append(r)
    return out


def assert_all_original_records_equal(src: Path, dst: Path) -> tuple[dict[int, Channel], list[Message]]:
    """Every original schema, channel (same id), message (bytes, times, sequence, order), attachment
    and metadata record of ``src`` is in ``dst``; returns (dst channels, forecast messages)."""
    a, b = records(src), records(dst)
    assert b["header"].profile == a["header"].profile
    for sid, schema in a["schemas"].items():
        assert b["schemas"][sid] == schema
    for cid, channel in a["channels"].items():
        assert b["channels"][cid] == channel
    original_ids = set(a["channels"])
    copied = [m for m in b["messages"] if m.channel_id in original_ids]
    assert copied == a["messages"]  # dataclass equality: channel, sequence, log/publish time, data bytes
    assert b["attachments"] == a["attachments"]
    assert b["metadata"] == a["metadata"]
    added = [m for m in b["messages"] if m.channel_id not in original_ids]
    times = [m.log_time for m in b["messages"]]
    assert times == sorted(times)  # the input is in log-time order, so the merge must be too
    return b["channels"], added
