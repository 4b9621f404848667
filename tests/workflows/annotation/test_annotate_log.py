"""Annotating one drive log: byte-for-byte copy, forecasts merged in log time, decodable everywhere.

Logs are real MCAP files / ROS bags written here with the ``mcap`` and ``rosbags`` libraries; the
forecasts are a table built by hand with the columns ``lanecast.workflows.annotation.track_forecasts.forecast_table`` returns.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import jsonschema
import numpy as np
import pyarrow as pa
import pytest
from conftest import S, assert_all_original_records_equal, forecasts_for, make_mcap, records
from mcap.reader import make_reader
from mcap.records import Message
from mcap.writer import Writer

from lanecast.io_adapters.contracts.track_table import RecordingMeta, TableMeta, build_table
from lanecast.io_adapters.contracts.windows import MANEUVER_COLOURS, UNKNOWN_COLOUR
from lanecast.io_adapters.errors import LogError
from lanecast.io_adapters.logs import forecast_messages as fm
from lanecast.workflows.annotation.annotate_log import (
    AnnotateOptions,
    annotate_log,
    choose_encoding,
    forecast_times,
    log_kind,
)


def test_mcap_protobuf_copy_is_byte_for_byte_and_forecasts_decode(tmp_path: Path) -> None:
    src = make_mcap(tmp_path / "drive.mcap")
    src.chmod(0o444)  # the input is opened read-only
    fc = forecasts_for("drive", [1, 2, 3], [1, 2])
    out = tmp_path / "out" / "drive.mcap"
    counts = annotate_log(src, out, AnnotateOptions(every_s=1.0), forecasts=fc)
    assert counts["encoding"] == "protobuf"
    assert (counts["messages"], counts["added"], counts["forecast_frames"]) == (300 + 30 + 43, 6, 3)
    assert not list(out.parent.glob(".*tmp*"))

    channels, added = assert_all_original_records_equal(src, out)
    topics = {c.id: c.topic for c in channels.values()}
    assert [topics[m.channel_id] for m in added] == ["/lanecast/forecast", "/lanecast/prediction"] * 3
    assert [m.log_time for m in added] == [S, S, 2 * S, 2 * S, 3 * S, 3 * S]
    assert all(m.publish_time == m.log_time for m in added)
    # merged after the original messages of the same instant (the /blob tick at exactly t0) and before later ones
    b = records(out)["messages"]
    first = b.index(added[0])
    assert b[first - 1].log_time == S and topics[b[first - 1].channel_id] == "/blob"
    assert b[first + 2].log_time > S

    from mcap_protobuf.decoder import DecoderFactory

    with open(out, "rb") as f:
        decoded = list(
            make_reader(f, decoder_factories=[DecoderFactory()]).iter_decoded_messages(
                topics=[fm.FORECAST_TOPIC]
            )
        )
    scene = decoded[1].decoded_message  # t0 = 2 s
    assert [e.id for e in scene.entities] == ["1", "2"]
    e1 = scene.entities[0]
    assert (e1.timestamp.seconds, e1.timestamp.nanos, e1.frame_id) == (2, 0, "map")
    main = e1.lines[0]
    # origin (21, 3.5) then 5 predicted points 10 m apart, y drifting left by 0.7 m/s
    np.testing.assert_allclose(
        [(p.x, p.y, p.z) for p in main.points],
        [(21, 3.5, 0), (31, 4.2, 0), (41, 4.9, 0), (51, 5.6, 0), (61, 6.3, 0), (71, 7.0, 0)],
    )
    assert (main.color.r, main.color.g, main.color.b, main.color.a) == pytest.approx(
        (*MANEUVER_COLOURS[1], 1.0)
    )  # left: blue, as in the reports
    e2_main = scene.entities[1].lines[0]
    assert (e2_main.color.r, e2_main.color.g, e2_main.color.b) == pytest.approx(
        MANEUVER_COLOURS[0]
    )  # straight: grey
    alt = e1.lines[1]
    assert (alt.color.r, alt.color.g, alt.color.b, alt.color.a) == pytest.approx(
        (*MANEUVER_COLOURS[2], 0.35)
    )  # right, faint
    assert [p.y for p in alt.points] == pytest.approx([3.5, 4.7, 5.4, 6.1, 6.8, 7.5])
    meta = {kv.key: kv.value for kv in e1.metadata}
    assert meta["maneuver"] == "left"
    assert json.loads(meta["maneuver_probs"])[2] == [0.2, 0.7, 0.1]
    assert json.loads(meta["top_k_probs"]) == [0.2, 0.1]
    assert len(e1.lines) == 3  # main + K=2 alternatives


def test_json_log_gets_json_forecasts_valid_against_foxglove_schema(tmp_path: Path) -> None:
    src = make_mcap(tmp_path / "j.mcap", json_only=True, n=120)
    assert choose_encoding("mcap", src) == "json"
    out = tmp_path / "j-out.mcap"
    annotate_log(src, out, forecasts=forecasts_for("j", [2, 5], [1, 2, 3], k=1))
    channels, added = assert_all_original_records_equal(src, out)
    schemas = records(out)["schemas"]
    by_topic: dict[str, list[Message]] = {channels[m.channel_id].topic: [] for m in added}
    for m in added:
        by_topic[channels[m.channel_id].topic].append(m)
    scene_channel = channels[by_topic[fm.FORECAST_TOPIC][0].channel_id]
    foxglove_schema = json.loads(schemas[scene_channel.schema_id].data)
    assert foxglove_schema["title"] == "foxglove.SceneUpdate"
    pred_channel = channels[by_topic[fm.PREDICTION_TOPIC][0].channel_id]
    assert (scene_channel.message_encoding, schemas[pred_channel.schema_id].encoding) == (
        "json",
        "jsonschema",
    )
    pred_schema = json.loads(schemas[pred_channel.schema_id].data)
    for m in by_topic[fm.FORECAST_TOPIC]:
        doc = json.loads(m.data)
        jsonschema.validate(doc, foxglove_schema)
        assert [e["id"] for e in doc["entities"]] == ["1", "2", "3"]
    first = json.loads(by_topic[fm.FORECAST_TOPIC][0].data)["entities"][2]  # track 3 at t0 = 2 s
    assert first["timestamp"] == {"sec": 2, "nsec": 0}
    assert first["lifetime"] == {"sec": 1, "nsec": 0}
    assert [p["x"] for p in first["lines"][0]["points"]] == [23.0, 33.0, 43.0, 53.0, 63.0, 73.0]
    for m in by_topic[fm.PREDICTION_TOPIC]:
        doc = json.loads(m.data)
        jsonschema.validate(doc, pred_schema)
        assert doc["t0_ns"] == m.log_time
    pred = json.loads(by_topic[fm.PREDICTION_TOPIC][1].data)  # t0 = 5 s
    t1 = pred["targets"][0]
    assert (t1["track_id"], t1["origin"], t1["x"][0], t1["maneuver"]) == (
        1,
        [51.0, 3.5],
        61.0,
        [0, 0, 1, 1, 1],
    )
    assert t1["alternatives"][0]["prob"] == pytest.approx(0.2)


def test_ros2_profile_mcap_stays_a_ros2_log_with_cdr_scene_updates(tmp_path: Path) -> None:
    from rosbags.highlevel import AnyReader

    store = fm.ros2_typestore()
    string_def, _ = store.generate_msgdef("std_msgs/msg/String", ros_version=2)
    src = tmp_path / "ros2.mcap"
    with open(src, "wb") as f:
        w = Writer(f, chunk_size=1000)
        w.start(profile="ros2", library="test")
        sid = w.register_schema("std_msgs/msg/String", "ros2msg", string_def.encode())
        cid = w.register_channel("/chatter", "cdr", sid, {"offered_qos_profiles": ""})
        for i in range(60):
            data = bytes(
                store.serialize_cdr(store.types["std_msgs/msg/String"](data=f"m{i}"), "std_msgs/msg/String")
            )
            w.add_message(cid, i * 100_000_000, data, i * 100_000_000, i)
        w.finish()
    assert log_kind(src) == "mcap" and choose_encoding("mcap", src, "json") == "cdr"
    out = tmp_path / "ros2-out.mcap"
    annotate_log(src, out, forecasts=forecasts_for("ros2", [1, 4], [1, 2]))
    channels, added = assert_all_original_records_equal(src, out)
    assert {channels[m.channel_id].message_encoding for m in added} == {"cdr"}
    assert {records(out)["schemas"][c.schema_id].encoding for c in channels.values()} == {"ros2msg"}

    with AnyReader([out]) as reader:
        by_topic: dict[str, list] = {}
        for conn, t, raw in reader.messages():
            by_topic.setdefault(conn.topic, []).append((t, reader.deserialize(raw, conn.msgtype)))
    assert [m.data for _, m in by_topic["/chatter"]] == [f"m{i}" for i in range(60)]
    (t_a, _), (t_b, scene_b) = by_topic[fm.FORECAST_TOPIC]
    assert (t_a, t_b) == (S, 4 * S)
    e = scene_b.entities[0]
    assert (e.id, e.frame_id, e.timestamp.sec, e.timestamp.nanosec) == ("1", "map", 4, 0)
    assert [(p.x, p.y) for p in e.lines[0].points][:2] == [(41.0, 3.5), (51.0, 4.2)]
    assert (e.lines[0].color.g, e.lines[0].type) == (pytest.approx(MANEUVER_COLOURS[1][1]), 0)  # left: blue
    pred = json.loads(by_topic[fm.PREDICTION_TOPIC][1][1].data)
    assert pred["t0_ns"] == 4 * S and pred["targets"][1]["track_id"] == 2


# --------------------------------------------------------------------------------------------- bags


def test_ros2_bag_directory_stays_a_ros2_bag(tmp_path: Path) -> None:
    from rosbags.highlevel import AnyReader
    from rosbags.rosbag2 import Writer as Bag2Writer

    store = fm.ros2_typestore()
    src = tmp_path / "bag2"
    with Bag2Writer(src, version=9) as w:
        c1 = w.add_connection("/chatter", "std_msgs/msg/String", typestore=store)
        c2 = w.add_connection("/odom_x", "std_msgs/msg/Float64", typestore=store)
        for i in range(50):
            t = 20_000_000 + i * 100_000_000
            w.write(
                c1,
                t,
                bytes(
                    store.serialize_cdr(
                        store.types["std_msgs/msg/String"](data=f"s{i}"), "std_msgs/msg/String"
                    )
                ),
            )
            w.write(
                c2,
                t + 1,
                bytes(
                    store.serialize_cdr(
                        store.types["std_msgs/msg/Float64"](data=i * 0.5), "std_msgs/msg/Float64"
                    )
                ),
            )
    out = tmp_path / "out" / "bag2"
    counts = annotate_log(src, out, forecasts=forecasts_for("bag2", [1, 3], [1]))
    assert (counts["kind"], counts["messages"], counts["added"]) == ("ros2", 100, 4)
    assert not list(out.parent.glob(".*tmp*"))

    def read(path: Path) -> list[tuple[str, str, int, bytes]]:
        with AnyReader([path]) as r:
            return [(c.topic, c.msgtype, t, bytes(raw)) for c, t, raw in r.messages()]

    original, annotated = read(src), read(out)
    assert [m for m in annotated if not m[0].startswith("/lanecast")] == original
    times = [m[2] for m in annotated]
    assert times == sorted(times)
    with AnyReader([out]) as r:
        scenes: list[tuple[int, Any]] = [
            (t, r.deserialize(raw, c.msgtype)) for c, t, raw in r.messages() if c.topic == fm.FORECAST_TOPIC
        ]
        assert {c.msgtype for c in r.connections if c.topic.startswith("/lanecast")} == {
            "foxglove_msgs/msg/SceneUpdate",
            "std_msgs/msg/String",
        }
    assert [t for t, _ in scenes] == [S, 3 * S]
    assert [(p.x, p.y) for p in scenes[1][1].entities[0].lines[0].points][-1] == (81.0, 7.0)


def test_ros1_bag_is_annotated_into_mcap(tmp_path: Path) -> None:
    from rosbags.rosbag1 import Writer as Bag1Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS1_NOETIC)
    src = tmp_path / "drive1.bag"
    with Bag1Writer(src) as w:
        conn = w.add_connection("/chatter", "std_msgs/msg/String", typestore=store)
        payloads = [
            bytes(
                store.serialize_ros1(store.types["std_msgs/msg/String"](data=f"r{i}"), "std_msgs/msg/String")
            )
            for i in range(40)
        ]
        for i, p in enumerate(payloads):
            w.write(conn, 10_000_000 + i * 100_000_000, p)
    assert log_kind(src) == "ros1"
    out = tmp_path / "drive1.mcap"
    counts = annotate_log(src, out, forecasts=forecasts_for("drive1", [1, 2], [4]))
    assert (counts["messages"], counts["added"], counts["encoding"]) == (40, 4, "protobuf")
    rec = records(out)
    chatter = next(c for c in rec["channels"].values() if c.topic == "/chatter")
    schema = rec["schemas"][chatter.schema_id]
    assert (schema.name, schema.encoding, chatter.message_encoding) == ("std_msgs/String", "ros1msg", "ros1")
    assert schema.data.decode().strip() == "string data"
    assert chatter.metadata["md5sum"] == "992ce8a1687cec8c8bd883ec73ca41d1"
    msgs = [m for m in rec["messages"] if m.channel_id == chatter.id]
    assert [m.data for m in msgs] == payloads
    assert [m.log_time for m in msgs] == [10_000_000 + i * 100_000_000 for i in range(40)]


# ------------------------------------------------------------------------------------------ errors


def test_truncated_log_is_a_log_error_naming_file_and_offset_and_leaves_no_output(tmp_path: Path) -> None:
    good = make_mcap(tmp_path / "good.mcap", n=400)
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(good.read_bytes()[: good.stat().st_size // 2])
    out = tmp_path / "out" / "bad.mcap"
    with pytest.raises(LogError) as info:
        annotate_log(bad, out, forecasts=forecasts_for("bad", [1], [1]))
    assert "bad.mcap" in str(info.value) and info.value.offset is not None and info.value.offset > 0
    assert not out.exists() and not list(out.parent.glob("*"))
    with pytest.raises(LogError, match="not a drive log"):
        log_kind(Path(__file__))


# ----------------------------------------------------------------------------------- pure functions


def test_dominant_maneuver_is_the_first_lane_change_else_straight() -> None:
    seqs = np.array([[0, 0, 0, 0, 0], [0, 0, 1, 1, 1], [0, 2, 2, 0, 1], [1, 0, 0, 0, 0]])
    assert fm.dominant_maneuver(seqs).tolist() == [0, 1, 2, 1]


def test_origins_are_interpolated_from_the_tracks_when_the_forecasts_lack_them() -> None:
    # track 5 at 0, 0.04, 0.08 s (25 Hz) moving 1 m per frame in x, 0.5 m in y; track 6 one row
    n = 4
    cols = {
        "recording": ["r"] * n,
        "track_id": [5, 5, 5, 6],
        "frame": [0, 1, 2, 0],
        "time_ns": [0, 40_000_000, 80_000_000, 40_000_000],
        "x": [0.0, 1.0, 2.0, 9.0],
        "y": [0.0, 0.5, 1.0, 9.0],
        **{c: [0.0] * n for c in ("heading", "vx", "vy", "ax", "ay", "length", "width")},
        "lane_id": [1] * n,
        "object_class": ["car"] * n,
    }
    tracks = build_table(cols, TableMeta("mcap", {"r": RecordingMeta(25.0, "odom")}))
    fc = forecasts_for("r", [0], [5, 6, 7]).drop_columns(["origin_x", "origin_y"])
    fc = fc.set_column(2, "t0_ns", pa.array([60_000_000, 40_000_000, 0], pa.int64()))
    frames = list(fm.frames_from_table(fc, frame_id={"r": "odom"}, tracks=tracks))
    origin = np.concatenate(
        [f.origin for f in frames]
    )  # frames by t0: track 7 (t0 0), 6 (0.04 s), 5 (0.06 s)
    assert [f.frame_id for f in frames] == ["odom"] * 3
    assert np.isnan(origin[0]).all()  # track 7 is not in the tracks
    assert origin[1].tolist() == [9.0, 9.0]  # exact row
    assert origin[2] == pytest.approx([1.5, 0.75])  # halfway between 0.04 and 0.08 s


def _seeded_model(directory: Path) -> Path:
    """A real (untrained, seeded) ST-CNN checkpoint: the test needs a model, not a good one."""
    import torch

    from lanecast.models.checkpoint import save_checkpoint
    from lanecast.models.stcnn import STCNN

    torch.manual_seed(7)
    norm = {
        "inputs": {"mean": [0.0, 0.0, 25.0, 0.0], "std": [20.0, 3.0, 5.0, 1.0]},
        "future": {"mean": [0.0] * 10, "std": 10.0},
    }
    save_checkpoint(STCNN(), {"normalisation": norm}, directory)
    return directory


def test_forecast_in_annotated_log_matches_batch_prediction(tmp_path: Path) -> None:
    """The forecast written for a vehicle equals what batch prediction gives for the same window,
    and reading the annotated log back gives the original tracks (forecasts are not objects)."""
    from lanecast.io_adapters.formats import registry
    from lanecast.workflows.annotation import track_forecasts as forecast

    model = _seeded_model(tmp_path / "model")
    n_frames, rate = 120, 10.0  # 12 s at 10 Hz, two vehicles side by side
    t = np.arange(n_frames) / rate
    cols = {
        "recording": ["sim"] * (2 * n_frames),
        "track_id": np.repeat([1, 2], n_frames),
        "frame": np.tile(np.arange(n_frames), 2),
        "time_ns": np.tile((t * 1e9).astype(np.int64), 2),
        "x": np.r_[25.0 * t, 10.0 + 22.0 * t],
        "y": np.r_[np.zeros(n_frames), np.full(n_frames, 3.75)],
        "heading": np.zeros(2 * n_frames),
        "vx": np.r_[np.full(n_frames, 25.0), np.full(n_frames, 22.0)],
        "vy": np.zeros(2 * n_frames),
        "ax": np.zeros(2 * n_frames),
        "ay": np.zeros(2 * n_frames),
        "length": np.full(2 * n_frames, 4.5),
        "width": np.full(2 * n_frames, 1.8),
        "lane_id": np.repeat([1, 2], n_frames),
        "object_class": ["car"] * (2 * n_frames),
    }
    table = build_table(cols, TableMeta("sim", {"sim": RecordingMeta(rate, "map")}))
    log = registry.write_any(table, tmp_path / "sim.mcap", "mcap")
    out = tmp_path / "sim-annotated.mcap"
    counts = annotate_log(log, out, AnnotateOptions(model_dir=model, every_s=1.0))
    tracks = registry.read_any([log])
    times = forecast_times(tracks, 1.0)
    assert times.tolist() == [k * S for k in range(12)]  # whole seconds of log time within 0 ... 11.9 s
    batch = forecast.forecast_table(tracks, model, top_k=3, t0_ns=times)
    # both vehicles at every whole second with 3 s of history (t0 = 2.9 s is not a whole second): 3 ... 11 s
    assert sorted(set(batch.column("t0_ns").to_pylist())) == [k * S for k in range(3, 12)]
    assert batch.num_rows == counts["forecast_targets"] == 18
    assert counts["forecast_frames"] == 9  # one SceneUpdate per forecast time, both vehicles in it
    with open(out, "rb") as f:
        docs = [json.loads(m.data) for _, c, m in make_reader(f).iter_messages(topics=[fm.PREDICTION_TOPIC])]
    written = {(tg["track_id"], d["t0_ns"]): tg for d in docs for tg in d["targets"]}
    for row in batch.to_pylist():
        target = written[(row["track_id"], row["t0_ns"])]
        np.testing.assert_allclose(target["x"], row["x"], rtol=0, atol=1e-9)
        np.testing.assert_allclose(target["y"], row["y"], rtol=0, atol=1e-9)
        assert target["maneuver"] == list(row["maneuver"])
        np.testing.assert_allclose(target["maneuver_probs"], row["maneuver_probs"], atol=1e-7)
        # the line starts at the vehicle's centre at t0
        centre = (
            [25.0 * row["t0_ns"] / 1e9, 0.0]
            if row["track_id"] == 1
            else [10 + 22.0 * row["t0_ns"] / 1e9, 3.75]
        )
        np.testing.assert_allclose(target["origin"], centre, atol=1e-6)
    reread = registry.read_any([out])
    assert reread.num_rows == tracks.num_rows
    assert reread.column("x").to_pylist() == tracks.column("x").to_pylist()


@pytest.mark.parametrize("fmt", ["ros2", "ros1"])
def test_bags_written_by_lanecast_are_annotated_end_to_end(tmp_path: Path, fmt: str) -> None:
    """Pass 1 through the registry's bag reader, the model, pass 2 into a ROS 2 bag / an MCAP."""
    from rosbags.highlevel import AnyReader
    from ruamel.yaml import YAML  # rosbags' own YAML library

    from lanecast.io_adapters.formats import registry

    model = _seeded_model(tmp_path / "model")
    n_frames, rate = 80, 10.0
    t = np.arange(n_frames) / rate
    cols = {
        "recording": ["bag"] * n_frames,
        "track_id": np.full(n_frames, 3),
        "frame": np.arange(n_frames),
        "time_ns": (t * 1e9).astype(np.int64) + 5 * S,
        "x": 30.0 * t,
        "y": np.zeros(n_frames),
        **{c: np.zeros(n_frames) for c in ("heading", "vy", "ax", "ay")},
        "vx": np.full(n_frames, 30.0),
        "length": np.full(n_frames, 4.5),
        "width": np.full(n_frames, 1.8),
        "lane_id": np.ones(n_frames, dtype=np.int32),
        "object_class": ["car"] * n_frames,
    }
    table = build_table(cols, TableMeta("bag", {"bag": RecordingMeta(rate, "map")}))
    src = registry.write_any(table, tmp_path / ("bag2" if fmt == "ros2" else "bag1.bag"), fmt)
    out = tmp_path / "out" / ("bag2" if fmt == "ros2" else "bag1.mcap")
    counts = annotate_log(src, out, AnnotateOptions(model_dir=model))
    assert counts["kind"] == fmt and counts["encoding"] == ("cdr" if fmt == "ros2" else "protobuf")
    assert counts["forecast_targets"] == 5  # t0 = 8 s ... 12 s (3 s of history from 5 s, data to 12.9 s)
    if fmt == "ros2":
        with AnyReader([src]) as r:
            original = [(c.topic, ts, bytes(raw)) for c, ts, raw in r.messages()]
        with AnyReader([out]) as r:
            annotated = [(c.topic, ts, bytes(raw)) for c, ts, raw in r.messages()]
            scenes: list[Any] = [
                r.deserialize(raw, c.msgtype) for c, ts, raw in r.messages() if c.topic == fm.FORECAST_TOPIC
            ]
        assert [m for m in annotated if m[0] not in (fm.FORECAST_TOPIC, fm.PREDICTION_TOPIC)] == original
        assert len(scenes) == 5 and scenes[0].entities[0].id == "3"
        custom = [
            YAML(typ="safe").load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"][
                "custom_data"
            ]
            for bag in (src, out)
        ]
        kept = {k: v for k, v in custom[1].items() if not k.startswith("lanecast.forecast.")}
        assert kept == custom[0] and "lanecast" in custom[0]  # metadata.yaml's custom_data kept
        assert custom[1]["lanecast.forecast.model"]  # and the model that made the forecasts named
        assert scenes[0].entities[0].lines[0].points[0].x == pytest.approx(30.0 * 3.0)
    else:
        with open(out, "rb") as f:
            topics = [c.topic for _, c, _ in make_reader(f).iter_messages()]
        assert topics.count(fm.FORECAST_TOPIC) == 5 and topics.count(fm.PREDICTION_TOPIC) == 5
    again = registry.read_any([out])  # ROS 1 messages in MCAP too: lanecast reads its own outputs
    assert again.column("x").to_pylist() == registry.read_any([src]).column("x").to_pylist()
    assert again.column("track_id").to_pylist() == registry.read_any([src]).column("track_id").to_pylist()
    if fmt == "ros1":  # an annotated log is not annotated twice
        with pytest.raises(LogError, match="already has topic"):
            annotate_log(out, tmp_path / "twice.mcap", AnnotateOptions(model_dir=model))
        assert not (tmp_path / "twice.mcap").exists()


def test_baseline_forecasts_without_maneuvers_are_drawn_in_the_unknown_colour_with_null_probabilities() -> (
    None
):
    fc = forecasts_for("r", [4], [1, 2], k=1)
    nulls5 = pa.nulls(2, pa.list_(pa.int8()))
    fc = fc.set_column(fc.schema.get_field_index("maneuver"), "maneuver", nulls5)
    fc = fc.set_column(
        fc.schema.get_field_index("maneuver_probs"),
        "maneuver_probs",
        pa.nulls(2, pa.list_(pa.list_(pa.float32()))),
    )
    (frame,) = fm.frames_from_table(fc, frame_id="odom")
    scene_json, pred_json = fm.encode_frame(frame, "json")
    scene, pred = json.loads(scene_json), json.loads(pred_json)
    jsonschema.validate(pred, fm.PREDICTION_SCHEMA)
    jsonschema.validate(scene, json.loads(fm.scene_update_jsonschema()))
    assert [t["maneuver_probs"] for t in pred["targets"]] == [None, None]
    assert pred["targets"][0]["maneuver"] == [-1] * 5
    main = scene["entities"][0]["lines"][0]
    assert main["color"] == dict(zip("rgba", (*UNKNOWN_COLOUR, 1.0), strict=True))
    meta = {kv["key"]: kv["value"] for kv in scene["entities"][0]["metadata"]}
    assert (meta["maneuver"], meta["maneuver_probs"]) == ("unknown", "null")
    assert scene["entities"][0]["frame_id"] == "odom"


def test_a_refused_run_and_a_finished_run_leave_no_lock_in_out_dir(tmp_path: Path) -> None:
    """A run that refused to overwrite a user's file in OUT_DIR left `.lanecast-annotate.lock` there;
    now the lock is removed at the end of every run, refused or not."""
    import pyarrow.parquet as pq

    from lanecast.io_adapters.errors import InputError
    from lanecast.workflows.bulk.runner import LOCK, locked, run_bulk

    log = make_mcap(tmp_path / "drive.mcap", n=40)
    pq.write_table(forecasts_for("drive", [1, 2], [1]), tmp_path / "fc.parquet")
    options = AnnotateOptions(forecasts=tmp_path / "fc.parquet")
    out = tmp_path / "out"
    out.mkdir()
    (out / "drive.mcap").write_bytes(b"the user's own file\n")
    with pytest.raises(InputError, match="refusing to overwrite it"):
        run_bulk([log], out, options)
    assert sorted(p.name for p in out.iterdir()) == ["drive.mcap"]
    assert (out / "drive.mcap").read_bytes() == b"the user's own file\n"
    (out / "drive.mcap").unlink()
    result = run_bulk([log], out, options)
    assert len(result.done) == 1 and not (out / LOCK).exists()
    assert sorted(p.name for p in out.iterdir()) == ["drive.mcap", "manifest.jsonl"]
    with locked(out):  # a second run is still kept out while one holds the lock
        with pytest.raises(InputError, match="another `lanecast annotate` run is writing here"):
            with locked(out):
                pass
        assert (out / LOCK).exists()
    assert not (out / LOCK).exists()


def test_a_corrupt_ros1_chunk_copied_with_given_forecasts_names_the_chunk(tmp_path: Path) -> None:
    """Forecasts given (no tracks read first), a ROS 1 bag with a corrupt lz4 chunk: was
    'RuntimeError: LZ4F_decompress failed' naming no file; now the bag and the chunk's offset."""
    from conftest import _ros1_records
    from rosbags.rosbag1 import Writer as Bag1Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS1_NOETIC)
    src = tmp_path / "drive1.bag"
    w = Bag1Writer(src)
    w.set_compression(Bag1Writer.CompressionFormat.LZ4)
    w.chunk_threshold = 2048
    with w:
        conn = w.add_connection("/chatter", "std_msgs/msg/String", typestore=store)
        for i in range(400):
            msg = store.types["std_msgs/msg/String"](data=f"message {i} " * 4)
            w.write(
                conn, 10_000_000 + i * 100_000_000, bytes(store.serialize_ros1(msg, "std_msgs/msg/String"))
            )
    data = bytearray(src.read_bytes())
    chunk = [r for r in _ros1_records(bytes(data)) if r[1]["op"] == b"\x05"][1]
    data[chunk[2] + chunk[3] // 2 : chunk[2] + chunk[3] // 2 + 16] = bytes(16)
    src.write_bytes(bytes(data))
    out = tmp_path / "drive1.mcap"
    with pytest.raises(LogError, match="a corrupt lz4 chunk") as err:
        annotate_log(src, out, forecasts=forecasts_for("drive1", [1, 2], [4]))
    assert err.value.path == str(src) and err.value.offset == chunk[0]
    assert not out.exists()
