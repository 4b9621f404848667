"""Shared fixtures and factories for the whole test session.

The tests mirror the code: ``tests/<package>/<subpackage>/test_<module>.py`` (a format's hostile
inputs in ``test_<format>_checks.py`` beside its reader's tests, a command's in
``tests/workflows/test_cli_<command>.py``). Test folders have no ``__init__.py`` and every test
module has a basename of its own across the tree; pytest's default import mode puts this folder on
``sys.path``, so test modules import these factories with ``from conftest import …``. For that
reason there is one conftest.py, here: a second one below would take the name ``conftest``.

Factories (plain functions) and fixtures, by section:
- paths: :data:`TESTS` (this folder), :data:`REPO`, the fixture files :data:`HIGHD`,
  :data:`US101`, :data:`PEACHTREE`;
- track tables: :func:`make_track_table` (columns → a validated one-recording table, defaults
  filled), :func:`table_of` and :func:`straight` (vehicles at 30 m/s in lanes), the seven-neighbour
  scene :data:`SEVEN` with its expected slots; copies of a Parquet table with one edit;
- windows datasets: :func:`synthetic_windows` (straight and lane-changing targets with a leader),
  damaged copies (:func:`windows_copy`);
- drive logs and forecasts: :func:`make_mcap`, :func:`forecasts_for`, :func:`records`,
  :func:`assert_all_original_records_equal`; MCAP records byte by byte (:func:`mcap_record_spans`,
  :func:`chunk_records`, :func:`fix_crcs`) and logs of JSON SceneUpdates (:func:`json_log`); ROS 1
  bag records (:func:`_ros1_records`) and the ``table``/``log`` fixtures of the damage tests;
- highD recordings and NGSIM exports with one cell or line changed; model cards with one field
  changed; command-line runs that must be refused in one line (:func:`refused`, :func:`cli`).

Size: over 500 lines because every factory more than one test module uses lives here (pytest
offers no other place that test modules share without a package); the sections above keep it
navigable.
"""

from __future__ import annotations

import json
import shutil
import struct
import zlib
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from mcap.records import Attachment, Channel, Header, Message, Metadata, Schema
from mcap.stream_reader import StreamReader
from mcap.writer import Writer

from lanecast.io_adapters.contracts import track_table
from lanecast.io_adapters.contracts.track_table import RecordingMeta, TableMeta, build_table, validate
from lanecast.io_adapters.contracts.windows import Windows
from lanecast.io_adapters.logs.mcap import reader as mcap_reader
from lanecast.io_adapters.logs.mcap import writer as mcap_writer
from lanecast.io_adapters.logs.rosbag import writer as rosbag_writer
from lanecast.workflows.cli import main

TESTS = Path(__file__).resolve().parent  # the tests folder
REPO = TESTS.parent
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


def assert_same_table(
    a: pa.Table, b: pa.Table, *, acceleration_atol: tuple[float, float] = (1e-5, 1e-5)
) -> None:
    """Same rows of a track table written and read back: ids, frames, times, classes and lanes
    equal, positions within 1 mm, sizes, headings and velocities within 1e-5, the accelerations
    ``ax``, ``ay`` within ``acceleration_atol`` (a log that carries none gives them back as
    differences of the velocities); the same recordings, frame rates, coordinate frames and
    source files."""
    assert a.num_rows == b.num_rows
    for name in ("recording", "object_class"):
        assert a.column(name).cast(pa.string()).to_pylist() == b.column(name).cast(pa.string()).to_pylist()
    for name in ("track_id", "frame", "time_ns"):
        np.testing.assert_array_equal(a.column(name).to_numpy(), b.column(name).to_numpy())
    assert a.column("lane_id").to_pylist() == b.column("lane_id").to_pylist()
    for name in ("x", "y"):
        np.testing.assert_allclose(a.column(name).to_numpy(), b.column(name).to_numpy(), atol=1e-3, rtol=0)
    for name in ("length", "width", "heading", "vx", "vy"):
        np.testing.assert_allclose(a.column(name).to_numpy(), b.column(name).to_numpy(), atol=1e-5, rtol=0)
    for name, atol in zip(("ax", "ay"), acceleration_atol, strict=True):
        np.testing.assert_allclose(a.column(name).to_numpy(), b.column(name).to_numpy(), atol=atol, rtol=0)
    ra, rb = track_table.read_meta(a).recordings, track_table.read_meta(b).recordings
    assert {n: (r.frame_rate, r.coordinate_frame, r.source_files) for n, r in ra.items()} == {
        n: (r.frame_rate, r.coordinate_frame, r.source_files) for n, r in rb.items()
    }


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


# ------------------------ MCAP records, byte by byte (offsets, opcodes, CRCs) for the damage tests


OP_CHUNK, OP_MESSAGE_INDEX, OP_CHUNK_INDEX, OP_SUMMARY_OFFSET, OP_FOOTER = 0x06, 0x07, 0x08, 0x0E, 0x02


def chunk_records(d: bytes, chunk: int) -> tuple[int, list[tuple[int, int, int]]]:
    """(file offset of the records, [(offset in the records, opcode, body length)]) of an
    uncompressed chunk at ``chunk``."""
    (comp,) = struct.unpack_from("<I", d, chunk + 9 + 28)
    assert comp == 0, "the test logs are written uncompressed"
    start = chunk + 9 + 32 + 8
    (n,) = struct.unpack_from("<Q", d, start - 8)
    out, pos = [], 0
    while pos < n:
        op, length = struct.unpack_from("<BQ", d, start + pos)
        out.append((pos, op, length))
        pos += 9 + length
    return start, out


def fix_crcs(d: bytearray) -> None:
    """Every CRC recomputed (chunks, data section, summary): a writer that meant the change."""
    for o, op, _n in mcap_record_spans(bytes(d)):
        if op == OP_CHUNK:
            start, _ = chunk_records(bytes(d), o)
            (n,) = struct.unpack_from("<Q", d, start - 8)
            struct.pack_into("<I", d, o + 9 + 24, zlib.crc32(bytes(d[start : start + n])))
        if op == 0x0F:
            struct.pack_into("<I", d, o + 9, zlib.crc32(bytes(d[:o])))
        if op == OP_FOOTER:
            (start,) = struct.unpack_from("<Q", d, o + 9)
            struct.pack_into("<I", d, o + 25, zlib.crc32(bytes(d[start : o + 25])))


def uncompressed(src: Path, dst: Path) -> Path:
    """``src`` written again by the mcap library with small uncompressed chunks and every index."""
    from mcap.records import Channel, Header, Message, Metadata, Schema
    from mcap.stream_reader import StreamReader
    from mcap.writer import CompressionType, Writer

    with src.open("rb") as f, dst.open("wb") as out:
        w = Writer(out, chunk_size=2000, compression=CompressionType.NONE, enable_data_crcs=True)
        seen: set[int] = set()  # schema ids, and channel ids negated
        for r in StreamReader(f).records:
            if isinstance(r, Header):
                w.start(r.profile, r.library)
            elif isinstance(r, Schema) and r.id not in seen:  # ids 1, 2, … as in the source
                seen.add(r.id)
                w.register_schema(r.name, r.encoding, r.data)
            elif isinstance(r, Channel) and -r.id not in seen:
                seen.add(-r.id)
                w.register_channel(r.topic, r.message_encoding, r.schema_id, r.metadata)
            elif isinstance(r, Message):
                w.add_message(r.channel_id, r.log_time, r.data, r.publish_time, r.sequence)
            elif isinstance(r, Metadata):
                w.add_metadata(r.name, r.metadata)
        w.finish()
    return dst


@pytest.fixture(scope="module")
def logs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, tuple[Path, pa.Table]]:
    """A protobuf log and a ROS 2 (CDR) MCAP, uncompressed, and their clean conversions."""
    root = tmp_path_factory.mktemp("lying-logs")
    table = staggered_cars(3, 30, stagger=4, step_m=2.5, speed=25.0, rate=10.0)
    pb = uncompressed(mcap_writer.write(table, root / "pb0.mcap", "mcap"), root / "pb.mcap")
    bag = rosbag_writer.write(table, root / "r2", "ros2", storage="mcap")
    cdr = uncompressed(next(bag.glob("*.mcap")), root / "cdr.mcap")
    return {kind: (p, mcap_reader.read(p)) for kind, p in (("pb", pb), ("cdr", cdr))}


def chunks(d: bytes) -> list[int]:
    return [o for o, op, _ in mcap_record_spans(d) if op == OP_CHUNK]


def message_times(d: bytes, chunk: int, channels: set[int] | None = None) -> list[int]:
    """The log times of the messages of an uncompressed chunk (on ``channels``: every channel)."""
    start, recs = chunk_records(d, chunk)
    heads = [struct.unpack_from("<HIQ", d, start + o + 9) for o, op, _ in recs if op == 0x05]
    return [t for cid, _seq, t in heads if channels is None or cid in channels]


def _summary_channel(d: bytearray) -> tuple[int, str]:
    """The summary's copy of a channel given another topic of the same length."""
    recs = mcap_record_spans(bytes(d))
    data_end = next(o for o, op, _ in recs if op == 0x0F)
    at = next(o for o, op, _ in recs if op == 0x04 and o > data_end)
    (n,) = struct.unpack_from("<I", d, at + 9 + 4)
    d[at + 9 + 8 + n - 1] ^= 0x01  # the topic's last character
    return at, "is not the data section's"


def _s(text: str | bytes) -> bytes:
    raw = text.encode() if isinstance(text, str) else text
    return struct.pack("<I", len(raw)) + raw


def _record(op: int, body: bytes) -> bytes:
    return bytes([op]) + struct.pack("<Q", len(body)) + body


def chunk_layout(path: Path) -> list[tuple[int, int, set[int]]]:
    """(offset, length, log times of its messages) of every chunk, from the mcap library's summary."""
    from mcap.data_stream import ReadDataStream
    from mcap.reader import make_reader
    from mcap.records import Chunk, Message
    from mcap.stream_reader import breakup_chunk

    with path.open("rb") as f:
        summary = make_reader(f).get_summary()
        assert summary is not None
        out = []
        for ci in summary.chunk_indexes:
            f.seek(ci.chunk_start_offset + 9)
            chunk = Chunk.read(ReadDataStream(f))
            times = {r.log_time for r in breakup_chunk(chunk) if isinstance(r, Message)}
            out.append((ci.chunk_start_offset, ci.chunk_length, times))
    return out


def rewrite_mcap(
    clean: Path,
    bad: Path,
    edit: Callable[[int, int, int, bytes], bytes | None] | None = None,
    log_time_of: Callable[[int, int], int] | None = None,
    **writer_options: Any,
) -> None:
    """``clean`` rewritten to ``bad`` by the mcap library (valid CRCs; ``writer_options`` for its
    Writer), every message's data passed through ``edit(index, number of messages, log_time,
    data)`` (None: unchanged) and its log time through ``log_time_of(index, log_time)``."""
    from mcap.reader import make_reader
    from mcap.writer import Writer

    with clean.open("rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None
        messages = [(ch.id, m.log_time, m.publish_time, m.data) for _s, ch, m in reader.iter_messages()]
    with bad.open("wb") as f:
        w = Writer(f, **writer_options)
        w.start()
        sids = {i: w.register_schema(s.name, s.encoding, s.data) for i, s in summary.schemas.items()}
        cids = {
            i: w.register_channel(c.topic, c.message_encoding, sids[c.schema_id], c.metadata)
            for i, c in summary.channels.items()
        }
        for k, (cid, log_time, publish_time, data) in enumerate(messages):
            edited = None if edit is None else edit(k, len(messages), log_time, data)
            new_time = log_time if log_time_of is None else log_time_of(k, log_time)
            w.add_message(cids[cid], new_time, data if edited is None else edited, publish_time)
        w.finish()


# ------------------------------------------------------------------ MCAP logs of JSON SceneUpdates


def _entity(track: int, x: float, sec: int = 0, nsec: int = 0) -> dict[str, object]:
    return {
        "timestamp": {"sec": sec, "nsec": nsec},
        "frame_id": "map",
        "id": str(track),
        "metadata": [{"key": "class", "value": "car"}],
        "cubes": [
            {
                "pose": {"position": {"x": x, "y": 0.0, "z": 0.0}, "orientation": {"w": 1.0}},
                "size": {"x": 4.5, "y": 1.8, "z": 1.5},
            }
        ],
    }


def json_log(
    path: Path,
    messages: list[tuple[str, int, list[dict[str, object]]]],
    metadata: dict[str, str] | None = None,
) -> Path:
    """An MCAP of JSON SceneUpdates: (topic, log time ns, entities) per message."""
    from mcap.writer import Writer

    schema = (REPO / "io_adapters/data/foxglove/jsonschema/SceneUpdate.json").read_bytes()
    with path.open("wb") as f:
        w = Writer(f)
        w.start()
        sid = w.register_schema("foxglove.SceneUpdate", "jsonschema", schema)
        channels: dict[str, int] = {}
        for topic, t, entities in messages:
            if topic not in channels:
                channels[topic] = w.register_channel(topic, "json", sid)
            data = json.dumps({"entities": entities}).encode()
            w.add_message(channels[topic], log_time=t, data=data, publish_time=t)
        if metadata is not None:
            w.add_metadata("lanecast", metadata)
        w.finish()
    return path


def straight_messages(topic: str = "/objects", n: int = 20) -> list[tuple[str, int, list[dict[str, object]]]]:
    return [(topic, (i + 1) * 100_000_000, [_entity(1, 2.0 * i), _entity(2, 50 + 2.0 * i)]) for i in range(n)]


# ----------------------------------------------------- the logs and ROS 1 bags of the damage tests


RATE = 25.0


@pytest.fixture(scope="module")
def table() -> pa.Table:
    """4 cars × 60 frames at 25 Hz (frames 0..74)."""
    return staggered_cars(4, 60, stagger=5, step_m=1.2, speed=30.0, rate=RATE)


@pytest.fixture(scope="module")
def log(tmp_path_factory: pytest.TempPathFactory, table: pa.Table) -> Path:
    """The table as an MCAP with many small chunks."""
    return mcap_writer.write(table, tmp_path_factory.mktemp("log") / "log.mcap", "mcap", chunk_size=3000)


def _ros1_records(
    data: bytes, pos: int = 13, stop: int | None = None
) -> list[tuple[int, dict[str, bytes], int, int]]:
    """(offset, header fields, data offset, data length) of every record of a ROS 1 bag (or of an
    uncompressed chunk's records data[pos:stop])."""
    out = []
    while pos < (len(data) if stop is None else stop):
        (header_len,) = struct.unpack_from("<I", data, pos)
        fields, q = {}, pos + 4
        while q < pos + 4 + header_len:
            (n,) = struct.unpack_from("<I", data, q)
            name, _, value = data[q + 4 : q + 4 + n].partition(b"=")
            fields[name.decode()] = value
            q += 4 + n
        (data_len,) = struct.unpack_from("<I", data, q)
        out.append((pos, fields, q + 4, data_len))
        pos = q + 4 + data_len
    return out


def _small_chunks_ros1_bag(table: pa.Table, path: Path) -> Path:
    """lanecast's ROS 1 bag of ``table`` rewritten by rosbags into uncompressed chunks of ~4 kB."""
    from rosbags.rosbag1 import Reader, Writer

    from lanecast.io_adapters.logs.rosbag import writer as rosbag_writer

    src = rosbag_writer.write(table, path.with_name("src.bag"), "ros1")
    with Reader(src) as r:
        w = Writer(path)
        w.chunk_threshold = 4096
        with w:
            conns = {
                c.id: w.add_connection(c.topic, c.msgtype, msgdef=c.msgdef.data, md5sum=c.digest)
                for c in r.connections
            }
            for c, t, raw in r.messages():
                w.write(conns[c.id], t, raw)
    return path


def _ros1_damage(kind: str, data: bytearray) -> tuple[int, str]:
    """Damage ``data`` (a ROS 1 bag) in place: (the offset of the record the error must name, its text)."""
    recs = _ros1_records(bytes(data))
    ops = [(off, f, d, n) for off, f, d, n in recs]
    chunks = [r for r in ops if r[1]["op"] == b"\x05"]
    if kind == "chunk info listing a listed chunk":
        info = [r for r in ops if r[1]["op"] == b"\x06"][1]
        at = data.index(b"chunk_pos=", info[0]) + len(b"chunk_pos=")
        data[at : at + 8] = struct.pack("<Q", chunks[0][0])
        return info[0], f"points at the chunk at offset {chunks[0][0]}, which another one lists"
    if kind == "index data past its chunk":
        index = next(r for r in ops if r[1]["op"] == b"\x04" and r[0] > chunks[1][0])
        struct.pack_into("<I", data, index[2] + 8, 10**8)
        return index[0], "lists a message at offset 100000000 of a chunk of"
    if kind == "connection without message definition":
        conn = next(r for r in ops if r[1]["op"] == b"\x07" and r[0] > chunks[-1][0])
        at = data.index(b"message_definition=", conn[2])
        data[at : at + 1] = b"x"
        return conn[0], "has no message_definition field"
    if kind in ("connection definition that does not parse", "connection md5sum not its definition's"):
        conn = next(
            r
            for r in ops
            if r[1]["op"] == b"\x07" and r[0] > chunks[-1][0] and b"[]" in data[r[2] : r[2] + r[3]]
        )
        if kind.endswith("parse"):
            at = data.index(b"[]", data.index(b"message_definition=", conn[2]))
            data[at : at + 2] = b"[["
            return conn[0], "cannot be parsed"
        at = data.index(b"md5sum=", conn[2]) + len(b"md5sum=")
        data[at : at + 1] = b"0" if data[at : at + 1] != b"0" else b"1"
        return conn[0], "is not that of its message definition"
    if kind == "a record of another kind in the index":
        conn = next(r for r in ops if r[1]["op"] == b"\x07" and r[0] > chunks[-1][0])
        at = data.index(b"op=\x07", conn[0]) + 3
        data[at : at + 1] = b"\x02"
        return conn[0], "a record of op 0x02 in the index"
    if kind == "index data listing no message record":
        index = next(r for r in ops if r[1]["op"] == b"\x04" and r[0] > chunks[1][0])
        struct.pack_into("<I", data, index[2] + 8, 3)  # the first message's offset: inside a record
        return index[0], "lists a message at offset 3 of its chunk, where no message record starts"
    if kind == "a chunk info record deleted":
        info = [r for r in ops if r[1]["op"] == b"\x06"][1]
        del data[info[0] : info[2] + info[3]]
        return ops[0][0], "the bag header states"
    if kind == "chunk info stating more connections than it holds":
        info = [r for r in ops if r[1]["op"] == b"\x06"][1]
        at = data.index(b"count=", info[0]) + len(b"count=")
        data[at : at + 4] = struct.pack("<I", 0xFFFFFFFF)
        return info[0], "a chunk info record states 4294967295 connections in"
    if kind == "index data stating fewer messages than it lists":
        index = next(r for r in ops if r[1]["op"] == b"\x04" and r[0] > chunks[1][0])
        at = data.index(b"count=", index[0]) + len(b"count=")
        data[at : at + 4] = struct.pack("<I", 0)
        return index[0], f"lists 0 messages in {index[3]} bytes (12 bytes each)"
    if kind == "bag header stating no chunks":
        at = data.index(b"chunk_count=", ops[0][0]) + len(b"chunk_count=")
        data[at : at + 4] = struct.pack("<I", 0)
        return ops[0][0], "the bag header states 0 chunks, the index lists"
    if kind == "chunk compressed with an unknown method":
        at = data.index(b"compression=none", chunks[1][0]) + len(b"compression=")
        data[at : at + 4] = b"zzzz"
        return chunks[1][0], "a chunk compressed with 'zzzz', which ROS 1 bags do not use"
    if kind == "message on an undefined connection":
        inner = _ros1_records(bytes(data), chunks[2][2], chunks[2][2] + chunks[2][3])
        msg = next(r for r in inner if r[1]["op"] == b"\x02")
        at = data.index(b"conn=", msg[0]) + len(b"conn=")
        data[at : at + 4] = struct.pack("<I", 77)
        return chunks[2][
            0
        ], f"a message at byte {msg[0] - chunks[2][2]} of the chunk's records is on connection 77"
    header = ops[0]
    at = data.index(b"index_pos=", header[0]) + len(b"index_pos=")
    data[at : at + 8] = struct.pack("<Q", chunks[1][0] + 7)
    return header[0], f"puts the index at offset {chunks[1][0] + 7}, where no record starts"


# ---------------------------------------------------------------------------------- annotated logs


def _prediction_doc() -> dict[str, object]:
    target = {
        "track_id": 4,
        "origin": [0.0, 0.0],
        "x": [1.0, 2.0, 3.0, 4.0, 5.0],
        "y": [0.0] * 5,
        "maneuver": [0] * 5,
        "maneuver_probs": [[0.9, 0.05, 0.05]] * 5,
        "alternatives": [{"prob": 0.1, "x": [1.0] * 5, "y": [0.5] * 5, "maneuver": [1] * 5}],
    }
    return {
        "recording": "r",
        "frame_id": "map",
        "t0_ns": 3_000_000_000,
        "horizon_s": [1, 2, 3, 4, 5],
        "targets": [target],
    }


# -------------------------------------------------------------------------------- highD recordings


HIGHD = TESTS / "data" / "highd"


HIGHD_HEADER = (
    "frame,id,x,y,width,height,xVelocity,yVelocity,xAcceleration,yAcceleration,frontSightDistance,"
    "backSightDistance,dhw,thw,ttc,precedingXVelocity,precedingId,followingId,leftPrecedingId,"
    "leftAlongsideId,leftFollowingId,rightPrecedingId,rightAlongsideId,rightFollowingId,laneId"
)


def _highd(tmp_path: Path, *, velocity: float = 1.0, position: float = 1.0, frame_rate: str = "25") -> Path:
    """A highD recording of two cars, 2.4 s at 30 m/s each way (25 Hz), velocities scaled by
    ``velocity``, positions by ``position``, recordingMeta's frameRate ``frame_rate``."""
    rows = []
    for vid, vx, y, lane in ((1, 30.0, 15.2, 6), (2, -30.0, 5.0, 2)):
        for k in range(60):
            x = (100.0 + vx * k / 25) * position
            rows.append(
                f"{k + 1},{vid},{x:.3f},{y * position:.3f},4.50,2.00,{vx * velocity:.3f},0.00,0.00,0.00,"
                f"0,0,0,0,0,0,0,0,0,0,0,0,0,0,{lane}"
            )
    (tmp_path / "01_tracks.csv").write_text("\n".join([HIGHD_HEADER, *rows]) + "\n")
    meta = (HIGHD / "01_tracksMeta.csv").read_text().splitlines()[0]
    (tmp_path / "01_tracksMeta.csv").write_text(
        f"{meta}\n1,4.50,2.00,1,60,60,Car,2,58.8,30,30,30,0,0,-1,0\n2,4.50,2.00,1,60,60,Car,1,58.8,-30,-30,-30,0,0,-1,0\n"
    )
    recording_meta = (HIGHD / "01_recordingMeta.csv").read_text().splitlines()
    cells = recording_meta[1].split(",")
    cells[1] = frame_rate
    (tmp_path / "01_recordingMeta.csv").write_text("\n".join([recording_meta[0], ",".join(cells)]) + "\n")
    return tmp_path / "01_tracks.csv"


def highd_copy(tmp_path: Path, kind: str = "", edit: Callable[[list[str]], list[str]] | None = None) -> Path:
    """The highD fixture in ``tmp_path/rec`` with ``01_<kind>.csv`` edited line by line."""
    rec = tmp_path / "rec"
    rec.mkdir()
    for src in HIGHD.glob("01_*.csv"):
        shutil.copy(src, rec / src.name)
    if edit is not None:
        path = rec / f"01_{kind}.csv"
        path.write_text("".join(line + "\n" for line in edit(path.read_text().splitlines())))
    return rec


def set_cell(
    column: str, value: str | Callable[[str], str], lines: set[int] | None = None
) -> Callable[[list[str]], list[str]]:
    """An edit setting ``column`` on the given 1-based ``lines`` (every data line by default)."""

    def edit(rows: list[str]) -> list[str]:
        index = rows[0].split(",").index(column)
        out = [rows[0]]
        for number, row in enumerate(rows[1:], start=2):
            cells = row.split(",")
            if lines is None or number in lines:
                cells[index] = value(cells[index]) if callable(value) else value
            out.append(",".join(cells))
        return out

    return edit


def _highd_variant(tmp_path: Path, line: int, column: str, value: str) -> Path:
    """A copy of the highD fixture with one cell of 01_tracks.csv replaced (line 1 = header)."""
    for kind in ("tracks", "tracksMeta", "recordingMeta"):
        (tmp_path / f"01_{kind}.csv").write_bytes((HIGHD / f"01_{kind}.csv").read_bytes())
    path = tmp_path / "01_tracks.csv"
    lines = path.read_text().splitlines()
    header = lines[0].split(",")
    cells = lines[line - 1].split(",")
    cells[header.index(column)] = value
    lines[line - 1] = ",".join(cells)
    path.write_text("\n".join(lines) + "\n")
    return path


# ----------------------------------------------------------------------------------- NGSIM exports


HEADER = (
    "Vehicle_ID,Frame_ID,Total_Frames,Global_Time,Local_X,Local_Y,Global_X,Global_Y,v_length,v_Width,"
    "v_Class,v_Vel,v_Acc,Lane_ID,O_Zone,D_Zone,Int_ID,Section_ID,Direction,Movement,Preceding,Following,"
    "Space_Headway,Time_Headway,Location"
)


EPOCH = 1118846980000  # US-101's first period (ms)


def _rows(
    vehicle: int, frames: range, y0: float, step: float, epoch: int = EPOCH, loc: str = "us-101"
) -> list[str]:
    """CSV-export rows of one vehicle whose Local_Y moves ``step`` ft per frame."""
    return [
        f"{vehicle},{f},{len(frames)},{epoch + 100 * f},18.0,{y0 + step * (f - frames[0]):.3f},"
        f"6451155.641,1873444.255,15.0,6.0,2,40.0,0.0,2,,,,,,,0,0,0.0,0.0,{loc}"
        for f in frames
    ]


def _export(tmp_path: Path, rows: list[str]) -> Path:
    path = tmp_path / "export.csv"
    path.write_text("\n".join([HEADER, *rows]) + "\n")
    return path


US101 = TESTS / "data" / "ngsim" / "us-101" / "trajectories-fixture.txt"


PEACHTREE = TESTS / "data" / "ngsim" / "peachtree_sample.csv"


def _txt_variant(tmp_path: Path, edits: dict[tuple[int, int], str]) -> Path:
    """The US-101 fixture with cells replaced: (1-based line, 0-based field) → text."""
    lines = [line.split() for line in US101.read_text().splitlines()]
    for (line, field), value in edits.items():
        lines[line - 1][field] = value
    path = tmp_path / "us-101" / "trajectories-edit.txt"
    path.parent.mkdir(exist_ok=True)
    path.write_text("\n".join("  ".join(cells) for cells in lines) + "\n")
    return path


def _quoted(source: Path, target: Path, line: int, edit: Callable[[str], str]) -> Path:
    """A copy of ``source`` (its first 200 lines) with ``edit`` applied to ``line`` (1 = header)."""
    lines = source.read_text().splitlines()[:200]
    lines[line - 1] = edit(lines[line - 1])
    target.write_text("\n".join(lines) + "\n")
    return target


# -------------------------------------------------------------------------- track tables (Parquet)


def track_table_copy(tmp_path: Path, edit: Callable[[pa.Table], pa.Table] | None = None) -> Path:
    """The highD fixture as a Parquet track table (``edit``ed, written as is) in ``tmp_path``."""
    from lanecast.io_adapters.formats import registry

    table = registry.read_any([HIGHD])
    path = tmp_path / "table.parquet"
    pq.write_table(table if edit is None else edit(table), path)
    return path


def _set_row(name: str, row: int, value: float) -> Callable[[pa.Table], pa.Table]:
    def edit(table: pa.Table) -> pa.Table:
        values = table.column(name).to_numpy().copy()
        values[row] = value
        index = table.schema.get_field_index(name)
        return table.set_column(
            index, table.schema.field(name), pa.array(values, table.schema.field(name).type)
        )

    return edit


def _parquet(tmp_path: Path) -> tuple[Path, pa.Table]:
    table = mcap_reader.read(json_log(tmp_path / "src.mcap", straight_messages()))
    return track_table.write_parquet(table, tmp_path / "t.parquet"), table


# ----------------------------------------------------------------------- windows datasets, damaged


def windows_copy(tmp_path: Path, damage: Callable[[Path], object]) -> Path:
    """A small windows dataset in ``tmp_path/win``, then ``damage``d."""
    from lanecast.io_adapters.windows_store.dataset import save_windows

    directory = save_windows(synthetic_windows(60), tmp_path / "win")
    damage(directory)
    return directory


def _edit_npy(name: str, edit: Callable[[np.ndarray], np.ndarray]) -> Callable[[Path], None]:
    def damage(directory: Path) -> None:
        path = directory / f"{name}.npy"
        np.save(path, edit(np.load(path)))

    return damage


def _set_first(value: float) -> Callable[[np.ndarray], np.ndarray]:
    def edit(array: np.ndarray) -> np.ndarray:
        array.reshape(-1)[7] = value
        return array

    return edit


# ------------------------------------------------------------------------------------- model cards


def _model_copy(tmp_path: Path, edit: object = None) -> Path:
    from lanecast.models.card import SHIPPED_STEM, WEIGHTS_DIR

    out = tmp_path / "model"
    out.mkdir()
    for suffix in (".safetensors", ".json"):
        (out / f"stcnn{suffix}").write_bytes((WEIGHTS_DIR / f"{SHIPPED_STEM}{suffix}").read_bytes())
    if edit is not None:
        card = json.loads((out / "stcnn.json").read_text())
        edit(card)  # type: ignore[operator]
        (out / "stcnn.json").write_text(json.dumps(card))
    return out


def _set(path: str, value: object) -> object:
    def edit(card: dict[str, object]) -> None:
        *parents, last = path.split(".")
        node = card
        for key in parents:
            node = node[key]  # type: ignore[index, assignment]
        node[last] = value  # type: ignore[index]

    return edit


# ------------------------------------------------------------------------------- command-line runs


def run(args: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str]:
    """Exit status and the last line of stderr (progress lines come before it)."""
    status = main(args)
    err = capsys.readouterr().err.strip()
    assert "Traceback" not in err
    return status, err.splitlines()[-1] if err else ""


def refused(args: list[str], capsys: pytest.CaptureFixture[str], *names: str) -> str:
    """Run a command that must refuse its input: status 2, one error line naming ``names``."""
    status, line = run(args, capsys)
    assert status == 2, line
    assert line.startswith(f"lanecast {args[0]}: error: "), line
    for name in names:
        assert name in line, line
    return line


def no_output(out: Path) -> None:
    assert not out.exists()
    assert not [p for p in out.parent.iterdir() if p.name.startswith(f".{out.name}")]


def convert_refused(source: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str], *names: str) -> str:
    """``lanecast convert SOURCE --out tmp_path/out.parquet`` must refuse its input (see
    :func:`refused`) and leave no output, not even a temporary one."""
    out = tmp_path / "out.parquet"
    line = refused(["convert", str(source), "--out", str(out)], capsys, *names)
    no_output(out)
    return line


def cli(args: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str]:
    status = main(args)
    err = capsys.readouterr().err.strip()
    return status, err


def assert_one_line_error(status: int, err: str, command: str, name: str) -> None:
    assert status == 2
    lines = err.splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"lanecast {command}: error: "), err
    assert name in lines[0]
