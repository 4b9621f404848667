"""MCAP adapter: round trips through SceneUpdate (protobuf, JSON), foreign logs, ROS 2 CDR, frames."""

from __future__ import annotations

import json
import math
import re
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pytest
from conftest import assert_same_table as same_table

from lanecast.io_adapters.contracts import track_table
from lanecast.io_adapters.errors import FrameError, LogError
from lanecast.io_adapters.formats import registry
from lanecast.io_adapters.logs import object_columns as to
from lanecast.io_adapters.logs.foxglove import scene_update_decode as wire
from lanecast.io_adapters.logs.mcap import reader as mcap_reader
from lanecast.io_adapters.logs.mcap import writer as mcap_writer
from lanecast.io_adapters.logs.messages import ros_types

RATE = 25.0


EPOCH = 1_700_000_000_000_000_000  # ns, a log-like absolute time for the second recording


def make_table(
    recordings: tuple[str, ...] = ("rec-a", "rec-b"), n_tracks: int = 3, n_frames: int = 40
) -> pa.Table:
    """A few vehicles for a few seconds per recording; track 1 has no lane, classes include 'van'."""
    cols: dict[str, list[np.ndarray]] = {}
    metas = {}

    def add(name: str, values: np.ndarray | list[str]) -> None:
        cols.setdefault(name, []).append(np.asarray(values))

    for ri, rec in enumerate(recordings):
        offset = EPOCH if ri == 1 else 0
        for k in range(n_tracks):
            f = np.arange(n_frames) + 5 * k + 2
            t = f / RATE
            add("recording", [rec] * n_frames)
            add("track_id", np.full(n_frames, k + 1 + 10 * ri))
            add("frame", f)
            add("time_ns", offset + np.rint(f * 1e9 / RATE).astype(np.int64))
            add("x", 12.5 * k + (22.0 + k) * t + 0.15 * t**2)
            add("y", 3.75 * k + 0.25 * np.sin(t))
            add("heading", 0.01 * np.sin(t) - 0.02 * k)
            add("vx", 22.0 + k + 0.3 * t)
            add("vy", 0.25 * np.cos(t))
            add("ax", np.full(n_frames, 0.3))
            add("ay", -0.25 * np.sin(t))
            add("length", np.full(n_frames, 4.5 + 3 * k))
            add("width", np.full(n_frames, 1.8 + 0.2 * k))
            lane = np.where(np.arange(n_frames) < n_frames // 2, k + 1, k + 2).astype(float)
            add("lane_id", np.full(n_frames, np.nan) if k == 0 else lane)
            add("object_class", [["car", "truck", "van"][k % 3]] * n_frames)
        metas[rec] = track_table.RecordingMeta(RATE, "road" if ri == 0 else "map", ["src.csv"], {"note": rec})
    columns = {k: np.concatenate(v) for k, v in cols.items()}
    table = track_table.build_table(columns, track_table.TableMeta("highd", metas, ["src.csv"]))
    track_table.validate(table)
    return table


def assert_same_table(a: pa.Table, b: pa.Table) -> None:
    """Same rows: positions within 1 mm, ids, frames, times, sizes, classes, lanes, velocities.

    SceneUpdate carries no accelerations: they come back as differences of the velocities (exact
    inside a track for this table's linear vx; within 1e-2 m/s² for its sinusoidal vy, one-sided
    at the track ends).
    """
    same_table(a, b, acceleration_atol=(2e-3, 1e-2))


@pytest.mark.parametrize("encoding", ["protobuf", "json"])
def test_scene_update_round_trip(tmp_path: Path, encoding: str) -> None:
    table = make_table()
    out = mcap_writer.write(table, tmp_path / "log.mcap", "mcap", encoding=encoding, chunk_size=2000)
    assert registry.detect(out) == "mcap"
    back, stats = mcap_reader.read_log(out)
    assert_same_table(table, back)
    assert stats.chunks > 1 and stats.chunks_lost == 0
    meta = track_table.read_meta(back)
    assert meta.source_format == "highd"
    assert meta.recordings["rec-a"].extra["note"] == "rec-a"
    assert meta.recordings["rec-b"].extra["topic"] == "/tracked_objects/rec_b"


def test_single_recording_topic_and_frames_at_own_rate(tmp_path: Path) -> None:
    table = make_table(("only",), n_tracks=2, n_frames=10)
    out = mcap_writer.write(table, tmp_path / "one.mcap", "mcap")
    from mcap.reader import make_reader

    with out.open("rb") as f:
        reader = make_reader(f, validate_crcs=True)
        msgs = [(c.topic, m.log_time, m.publish_time) for _, c, m in reader.iter_messages()]
    # Track 1 spans frames 2..11, track 2 frames 7..16: one message per frame 2..16 at 25 Hz.
    assert [t for t, _, _ in msgs] == ["/tracked_objects"] * 15
    assert [lt for _, lt, _ in msgs] == [round(f * 1e9 / RATE) for f in range(2, 17)]
    assert all(lt == pt for _, lt, pt in msgs)


def test_log_read_independently_by_mcap_library(tmp_path: Path) -> None:
    from mcap.reader import make_reader
    from mcap_protobuf.decoder import DecoderFactory

    table = make_table()
    out = mcap_writer.write(table, tmp_path / "log.mcap", "mcap")
    with out.open("rb") as f:
        reader = make_reader(f, validate_crcs=True, decoder_factories=[DecoderFactory()])
        summary = reader.get_summary()
        assert summary is not None and summary.chunk_indexes
        assert {ci.compression for ci in summary.chunk_indexes} == {"zstd"}
        assert {s.name for s in summary.schemas.values()} == {"foxglove.SceneUpdate"}
        decoded = list(reader.iter_decoded_messages(topics=["/tracked_objects/rec_a"]))
        metadata = {m.name: m.metadata for m in reader.iter_metadata()}
    assert metadata["lanecast"]["source"] == "highd"
    assert json.loads(metadata["lanecast"]["units"])["x"] == "m"
    assert float(metadata["lanecast"]["frame_rate"]) == RATE
    # rec-a: tracks 1..3 starting at frames 2, 7, 12 with 40 frames each → frames 2..51.
    assert len(decoded) == 50
    first = decoded[0].decoded_message
    assert [e.id for e in first.entities] == ["1"]
    e = first.entities[0]
    assert e.frame_id == "road"
    assert e.cubes[0].pose.position.x == pytest.approx(12.5 * 0 + 22.0 * (2 / RATE) + 0.15 * (2 / RATE) ** 2)
    assert e.cubes[0].size.x == pytest.approx(4.5)
    meta = {kv.key: kv.value for kv in e.metadata}
    assert meta["class"] == "car" and "lane_id" not in meta
    assert float(meta["vx"]) == pytest.approx(22.0 + 0.3 * 2 / RATE, abs=1e-5)
    assert e.timestamp.seconds * 10**9 + e.timestamp.nanos == round(2e9 / RATE)


def test_json_messages_follow_foxglove_schema(tmp_path: Path) -> None:
    import jsonschema
    from mcap.reader import make_reader

    out = mcap_writer.write(make_table(), tmp_path / "log.mcap", "mcap", encoding="json")
    with out.open("rb") as f:
        reader = make_reader(f, validate_crcs=True)
        checked = 0
        validator = None
        for i, (schema, channel, message) in enumerate(reader.iter_messages()):
            assert (
                schema is not None and schema.encoding == "jsonschema" and channel.message_encoding == "json"
            )
            if validator is None:
                document = json.loads(schema.data)
                validator = jsonschema.validators.validator_for(document)(document)
            if i % 10 == 0:  # a sample: validation is slow
                validator.validate(json.loads(message.data))
            checked += 1
    assert checked == 100


# ----------------------------------------------------------------------- hand-made foreign logs


def _write_mcap(path: Path, build: object) -> Path:
    from mcap.writer import Writer

    with path.open("wb") as f:
        w = Writer(f)
        w.start()
        build(w)  # type: ignore[operator]
        w.finish()
    return path


def _scene_update(entities: list[dict[str, object]]) -> bytes:
    """A protobuf SceneUpdate from plain dicts (id, t, x, y, yaw, l, w, meta, extra primitives)."""
    from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate

    msg = SceneUpdate()
    for spec in entities:
        e = msg.entities.add()
        e.id = str(spec["id"])
        e.frame_id = str(spec.get("frame", "map"))
        if "t" in spec:
            e.timestamp.seconds, e.timestamp.nanos = divmod(int(spec["t"]), 10**9)  # type: ignore[call-overload]
        for k, v in dict(spec.get("meta", {})).items():  # type: ignore[call-overload]
            e.metadata.add(key=k, value=v)
        if spec.get("text"):
            e.texts.add(text="label")
        c = e.cubes.add()
        c.pose.position.x, c.pose.position.y = spec["x"], spec["y"]  # type: ignore[assignment]
        if "yaw" in spec:  # else no orientation at all
            yaw = float(spec["yaw"])  # type: ignore[arg-type]
            c.pose.orientation.z, c.pose.orientation.w = math.sin(yaw / 2), math.cos(yaw / 2)
        c.size.x, c.size.y, c.size.z = spec["l"], spec["w"], 1.5  # type: ignore[assignment]
        if spec.get("second_cube"):
            e.cubes.add().pose.position.x = 999.0
    return msg.SerializeToString()


def test_foreign_scene_update_velocity_from_differences(tmp_path: Path) -> None:
    """No kinematics in the messages: velocity = Δposition/Δt, heading = quaternion yaw, or the
    direction of the velocity where the cube has no orientation."""
    from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate
    from mcap_protobuf.schema import build_file_descriptor_set

    def build(w: Any) -> None:
        sid = w.register_schema(
            "foxglove.SceneUpdate", "protobuf", build_file_descriptor_set(SceneUpdate).SerializeToString()
        )
        cid = w.register_channel("/perception/scene", "protobuf", sid)
        for i in range(5):  # 10 Hz; car "7" at x = 10 + 20 t, y = -2 + 1 t; "ped-a" standing still
            t = 1_000_000_000 + i * 100_000_000
            data = _scene_update(
                [
                    {
                        "id": 7,
                        "t": t,
                        "x": 10 + 2.0 * i,
                        "y": -2 + 0.1 * i,
                        "yaw": 0.3,
                        "l": 4.0,
                        "w": 2.0,
                        "meta": {"class": "truck"},
                        "text": True,
                        "second_cube": True,
                    },
                    {"id": "ped-a", "x": 5.0, "y": 5.0, "l": 0.5, "w": 0.5},
                    {"id": "bike", "x": 3.0 * i, "y": -3.0 * i, "l": 1.8, "w": 0.6},
                ]
            )
            w.add_message(cid, log_time=t, data=data, publish_time=t)

    path = _write_mcap(tmp_path / "drive.mcap", build)
    table = mcap_reader.read(path)
    meta = track_table.read_meta(table)
    assert list(meta.recordings) == ["drive"]
    rec = meta.recordings["drive"]
    assert rec.frame_rate == 10.0 and rec.coordinate_frame == "map"
    car = table.filter(pa.compute.equal(table.column("track_id"), 7))
    np.testing.assert_array_equal(car.column("frame").to_numpy(), np.arange(5))
    np.testing.assert_allclose(car.column("x").to_numpy(), 10 + 2.0 * np.arange(5))
    np.testing.assert_allclose(car.column("vx").to_numpy(), 20.0, rtol=1e-6)
    np.testing.assert_allclose(car.column("vy").to_numpy(), 1.0, rtol=1e-5)
    np.testing.assert_allclose(car.column("ax").to_numpy(), 0.0, atol=1e-3)
    np.testing.assert_allclose(car.column("heading").to_numpy(), 0.3, rtol=1e-6)
    assert set(car.column("object_class").cast(pa.string()).to_pylist()) == {"truck"}
    assert car.column("lane_id").null_count == 5
    bike = table.filter(pa.compute.equal(table.column("track_id"), to.track_id_of("bike")))
    np.testing.assert_allclose(
        bike.column("heading").to_numpy(), -math.pi / 4, rtol=1e-6
    )  # along (30, -30) m/s
    np.testing.assert_allclose(bike.column("vx").to_numpy(), 30.0, rtol=1e-6)
    ped = table.filter(pa.compute.equal(table.column("track_id"), to.track_id_of("ped-a")))
    assert ped.num_rows == 5 and set(ped.column("object_class").cast(pa.string()).to_pylist()) == {"unknown"}
    # No timestamp on the entity: time = log time.
    np.testing.assert_array_equal(
        ped.column("time_ns").to_numpy(), 1_000_000_000 + np.arange(5) * 100_000_000
    )
    np.testing.assert_allclose(ped.column("vx").to_numpy(), 0.0)


def _ros2_channel(w: Any, topic: str, typename: str) -> int:
    sid = w.register_schema(typename, "ros2msg", ros_types.schema_text(typename).encode())
    return int(w.register_channel(topic, "cdr", sid))


def _tracked_objects(t: int, frame: str, objects: list[tuple[int, float, float, float, float]]) -> bytes:
    """CDR TrackedObjects: (id, x, y, yaw, body vx) per object, 4.5 × 1.8 m cars."""
    store = ros_types.typestore(2)
    m = lambda name, **kw: ros_types.make(store, name, **kw)  # noqa: E731
    objs = []
    for tid, x, y, yaw, v in objects:
        pose = m(
            "geometry_msgs/msg/Pose",
            position=m("geometry_msgs/msg/Point", x=x, y=y, z=0.0),
            orientation=m(
                "geometry_msgs/msg/Quaternion", x=0.0, y=0.0, z=math.sin(yaw / 2), w=math.cos(yaw / 2)
            ),
        )
        kin = m(
            "autoware_perception_msgs/msg/TrackedObjectKinematics",
            orientation_availability=2,
            pose_with_covariance=m("geometry_msgs/msg/PoseWithCovariance", pose=pose),
            twist_with_covariance=m(
                "geometry_msgs/msg/TwistWithCovariance",
                twist=m("geometry_msgs/msg/Twist", linear=m("geometry_msgs/msg/Vector3", x=v, y=0.0, z=0.0)),
            ),
        )
        objs.append(
            m(
                "autoware_perception_msgs/msg/TrackedObject",
                object_id=m("unique_identifier_msgs/msg/UUID", uuid=to.track_id_to_uuid(tid)),
                classification=[
                    m("autoware_perception_msgs/msg/ObjectClassification", label=5, probability=0.9),
                    m("autoware_perception_msgs/msg/ObjectClassification", label=1, probability=0.1),
                ],
                kinematics=kin,
                shape=m(
                    "autoware_perception_msgs/msg/Shape",
                    dimensions=m("geometry_msgs/msg/Vector3", x=4.5, y=1.8, z=1.5),
                ),
            )
        )
    sec, nsec = divmod(t, 10**9)
    header = m(
        "std_msgs/msg/Header", stamp=m("builtin_interfaces/msg/Time", sec=sec, nanosec=nsec), frame_id=frame
    )
    msg = m(ros_types.TRACKED_OBJECTS, header=header, objects=objs)
    return bytes(store.serialize_cdr(msg, ros_types.TRACKED_OBJECTS))


def _ego_pose_msg(kind: str, t: int, x: float, y: float, yaw: float) -> bytes:
    store = ros_types.typestore(2)
    m = lambda name, **kw: ros_types.make(store, name, **kw)  # noqa: E731
    sec, nsec = divmod(t, 10**9)
    stamp = m("builtin_interfaces/msg/Time", sec=sec, nanosec=nsec)
    q = m("geometry_msgs/msg/Quaternion", x=0.0, y=0.0, z=math.sin(yaw / 2), w=math.cos(yaw / 2))
    if kind == "tf":
        tr = m(
            "geometry_msgs/msg/TransformStamped",
            header=m("std_msgs/msg/Header", stamp=stamp, frame_id="map"),
            child_frame_id="base_link",
            transform=m(
                "geometry_msgs/msg/Transform",
                translation=m("geometry_msgs/msg/Vector3", x=x, y=y, z=0.0),
                rotation=q,
            ),
        )
        return bytes(store.serialize_cdr(m(ros_types.TF_MESSAGE, transforms=[tr]), ros_types.TF_MESSAGE))
    odo = m(
        ros_types.ODOMETRY,
        header=m("std_msgs/msg/Header", stamp=stamp, frame_id="odom"),
        child_frame_id="base_link",
        pose=m(
            "geometry_msgs/msg/PoseWithCovariance",
            pose=m(
                "geometry_msgs/msg/Pose",
                position=m("geometry_msgs/msg/Point", x=x, y=y, z=0.0),
                orientation=q,
            ),
        ),
    )
    return bytes(store.serialize_cdr(odo, ros_types.ODOMETRY))


def ego_frame_log(path: Path, ego: str | None) -> Path:
    """Objects in base_link; the ego drives along +y (yaw 90°) at 10 m/s from (100, 50).

    ``ego``: "tf" (/tf map → base_link), "odom" (nav_msgs/Odometry odom → base_link) or None.
    """

    def build(w: Any) -> None:
        objects = _ros2_channel(w, "/perception/objects", ros_types.TRACKED_OBJECTS)
        pose_topic = {"tf": ("/tf", ros_types.TF_MESSAGE), "odom": ("/localization/odom", ros_types.ODOMETRY)}
        poses = _ros2_channel(w, *pose_topic[ego]) if ego else None
        for i in range(6):  # 10 Hz
            t = 5_000_000_000 + i * 100_000_000
            if poses is not None:
                data = _ego_pose_msg(ego, t, 100.0, 50.0 + 1.0 * i, math.pi / 2)  # type: ignore[arg-type]
                w.add_message(poses, log_time=t, data=data, publish_time=t)
            # One car 10 m ahead of the ego, same heading, body speed 12 m/s.
            data = _tracked_objects(t, "base_link", [(42, 10.0 + 0.2 * i, 0.0, 0.0, 12.0)])
            w.add_message(objects, log_time=t, data=data, publish_time=t)

    return _write_mcap(path, build)


@pytest.mark.parametrize("ego", ["tf", "odom"])
def test_ego_frame_objects_moved_into_fixed_frame(tmp_path: Path, ego: str) -> None:
    table = mcap_reader.read(ego_frame_log(tmp_path / "ego.mcap", ego))
    rec = track_table.read_meta(table).recordings["ego"]
    assert rec.coordinate_frame == ("map" if ego == "tf" else "odom")
    i = np.arange(6)
    # Ego at (100, 50 + i) facing +y: a point 10 + 0.2 i ahead is at (100, 60 + 1.2 i).
    np.testing.assert_allclose(table.column("x").to_numpy(), 100.0, atol=1e-9)
    np.testing.assert_allclose(table.column("y").to_numpy(), 60.0 + 1.2 * i, atol=1e-9)
    np.testing.assert_allclose(table.column("heading").to_numpy(), math.pi / 2, rtol=1e-6)
    # Body-frame twist of 12 m/s along the heading (+y).
    np.testing.assert_allclose(table.column("vx").to_numpy(), 0.0, atol=1e-5)
    np.testing.assert_allclose(table.column("vy").to_numpy(), 12.0, rtol=1e-6)
    assert set(table.column("object_class").cast(pa.string()).to_pylist()) == {"motorcycle"}
    np.testing.assert_array_equal(table.column("track_id").to_numpy(), 42)


def test_ego_frame_without_transform_is_a_clear_error(tmp_path: Path) -> None:
    """The error also says where the first such object is (one entity of a frame no transform
    reaches, among thousands, was named by its topic alone: fuzz2 seed 5077)."""
    with pytest.raises(FrameError, match=r"frame 'base_link'.*/tf.*nav_msgs/msg/Odometry") as err:
        mcap_reader.read(ego_frame_log(tmp_path / "ego.mcap", None))
    assert re.search(r"the first of track 42 in the message stamped \d+ ns", str(err.value))


def test_topics_found_by_type_and_picked_by_topic(tmp_path: Path) -> None:
    def build(w: Any) -> None:
        a = _ros2_channel(w, "/objects/front", ros_types.TRACKED_OBJECTS)
        b = _ros2_channel(w, "/objects/rear", ros_types.TRACKED_OBJECTS)
        other = _ros2_channel(w, "/chatter", ros_types.STRING)
        store = ros_types.typestore(2)
        for i in range(3):
            t = 10**9 + i * 50_000_000
            w.add_message(
                a, log_time=t, data=_tracked_objects(t, "map", [(1, float(i), 0.0, 0.0, 1.0)]), publish_time=t
            )
            w.add_message(
                b,
                log_time=t,
                data=_tracked_objects(t, "map", [(2, -float(i), 0.0, 0.0, 1.0)]),
                publish_time=t,
            )
            s = bytes(
                store.serialize_cdr(ros_types.make(store, ros_types.STRING, data="hi"), ros_types.STRING)
            )
            w.add_message(other, log_time=t, data=s, publish_time=t)

    path = _write_mcap(tmp_path / "two.mcap", build)
    both = mcap_reader.read(path)
    assert sorted(track_table.read_meta(both).recordings) == ["two-objects-front", "two-objects-rear"]
    assert track_table.read_meta(both).recordings["two-objects-front"].frame_rate == 20.0
    rear = mcap_reader.read(path, topic="/objects/rear")
    assert list(track_table.read_meta(rear).recordings) == ["two"]
    np.testing.assert_array_equal(rear.column("track_id").to_numpy(), [2, 2, 2])
    np.testing.assert_allclose(rear.column("x").to_numpy(), [0.0, -1.0, -2.0])
    with pytest.raises(LogError, match=r"'/chatter'.*holds no tracked objects"):
        mcap_reader.read(path, topic="/chatter")
    with pytest.raises(LogError, match="'/nope' is not in the log"):
        mcap_reader.read(path, topic="/nope")


def test_convert_cli_round_trip(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from lanecast.workflows.cli import main

    table = make_table()
    src = track_table.write_parquet(table, tmp_path / "tracks.parquet")
    assert main(["convert", str(src), "--to", "mcap", "--out", str(tmp_path / "log.mcap")]) == 0
    assert main(["convert", str(tmp_path / "log.mcap"), "--out", str(tmp_path / "back.parquet")]) == 0
    assert "wrote" in capsys.readouterr().out
    assert_same_table(table, track_table.read_parquet(tmp_path / "back.parquet"))


@pytest.mark.parametrize("encoding", ["protobuf", "json"])
def test_scene_update_in_ego_frame_with_foxglove_transforms(tmp_path: Path, encoding: str) -> None:
    """SceneUpdate in base_link and foxglove.FrameTransforms on /tf: moved into map, vx/vy rotated."""
    from foxglove_schemas_protobuf.FrameTransforms_pb2 import FrameTransforms
    from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate
    from mcap_protobuf.schema import build_file_descriptor_set

    def transforms(t: int, y: float) -> bytes:
        sec, nsec = divmod(t, 10**9)
        tr = {
            "timestamp": {"sec": sec, "nsec": nsec},
            "parent_frame_id": "map",
            "child_frame_id": "base_link",
            "translation": {"x": 100.0, "y": y, "z": 0.0},
            "rotation": {"x": 0.0, "y": 0.0, "z": math.sin(math.pi / 4), "w": math.cos(math.pi / 4)},
        }
        if encoding == "json":
            return json.dumps({"transforms": [tr]}).encode()
        msg = FrameTransforms()
        p = msg.transforms.add()
        p.timestamp.seconds, p.timestamp.nanos = sec, nsec
        p.parent_frame_id, p.child_frame_id = "map", "base_link"
        p.translation.x, p.translation.y = 100.0, y
        p.rotation.z, p.rotation.w = tr["rotation"]["z"], tr["rotation"]["w"]  # type: ignore[index]
        return msg.SerializeToString()

    def build(w: Any) -> None:
        if encoding == "json":
            tf_schema = w.register_schema("foxglove.FrameTransforms", "jsonschema", b"{}")
        else:
            fds = build_file_descriptor_set(FrameTransforms).SerializeToString()
            tf_schema = w.register_schema("foxglove.FrameTransforms", "protobuf", fds)
        scene_fds = build_file_descriptor_set(SceneUpdate).SerializeToString()
        scene = w.register_channel(
            "/scene",
            "protobuf",
            w.register_schema("foxglove.SceneUpdate", "protobuf", scene_fds),
        )
        tf = w.register_channel("/tf", encoding, tf_schema)
        for i in range(4):
            t = 3 * 10**9 + i * 100_000_000
            w.add_message(tf, log_time=t, data=transforms(t, 50.0 + i), publish_time=t)
            entity = {"id": 5, "t": t, "x": 10 + 0.2 * i, "y": 0.0, "yaw": 0.0, "l": 4.0, "w": 2.0,
                      "frame": "base_link", "meta": {"vx": "12.0", "vy": "0.0"}}  # fmt: skip
            w.add_message(scene, log_time=t, data=_scene_update([entity]), publish_time=t)

    table = mcap_reader.read(_write_mcap(tmp_path / "fox.mcap", build))
    assert track_table.read_meta(table).recordings["fox"].coordinate_frame == "map"
    i = np.arange(4)
    np.testing.assert_allclose(table.column("x").to_numpy(), 100.0, atol=1e-9)
    np.testing.assert_allclose(table.column("y").to_numpy(), 60.0 + 1.2 * i, atol=1e-9)
    np.testing.assert_allclose(table.column("heading").to_numpy(), math.pi / 2, rtol=1e-6)
    np.testing.assert_allclose(table.column("vx").to_numpy(), 0.0, atol=1e-5)
    np.testing.assert_allclose(table.column("vy").to_numpy(), 12.0, rtol=1e-6)


def test_vectorised_decoder_matches_protobuf_library_on_odd_layouts() -> None:
    """Valid but unusual encodings: fields out of order, long strings (2-byte lengths), unknown
    primitives, entities without cubes, non-numeric and over-long ids, omitted zeros, deletions."""
    from foxglove_schemas_protobuf.SceneEntity_pb2 import SceneEntity
    from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate

    def entity(i: int) -> bytes:
        head = SceneEntity(id=["17", "car-α", "123456789012345678901", "-4"][i % 4], frame_id="map")
        head.timestamp.seconds = 1_700_000_000 + i
        head.timestamp.nanos = 0 if i % 3 == 0 else 123_456_789 * (i % 7)
        head.metadata.add(key="note", value="x" * (150 if i % 2 else 3))
        head.metadata.add(key="vx", value=["1.5", "-0.25", "1e-05", "300"][i % 4])
        head.metadata.add(key="class", value=["van", "bus"][i % 2])
        tail = SceneEntity()
        tail.arrows.add().shaft_length = 2.0
        cube = tail.cubes.add()
        cube.pose.position.x = [0.0, -12.5, 1e6, 3.25][i % 4]
        cube.pose.position.y = [7.0, 0.0, -0.001, 2.0][i % 4]
        cube.pose.orientation.z = math.sin(0.1 * i)
        cube.pose.orientation.w = math.cos(0.1 * i)
        cube.size.x, cube.size.y = 4.0 + i, 2.0
        tail.cubes.add().size.x = 99.0  # only the first cube counts
        if i % 5 == 4:
            return head.SerializeToString()  # no cube: not an object
        # Cubes and arrows first, then the rest: a valid merge of two serialisations.
        return tail.SerializeToString() + head.SerializeToString()

    messages = []
    for m in range(6):
        body = b"".join(b"\x12" + _varint(len(e)) + e for e in (entity(10 * m + k) for k in range(m + 1)))
        deletion = SceneUpdate()
        deletion.deletions.add().id = "gone"
        messages.append(deletion.SerializeToString() + body)
    buf = np.frombuffer(b"".join(messages), dtype=np.uint8)
    ends = np.cumsum([len(m) for m in messages])
    starts = ends - [len(m) for m in messages]
    block = wire.scene_update_block(buf, starts, ends, np.arange(6) * 1000)

    expected = []
    for data in messages:
        msg = SceneUpdate()
        msg.ParseFromString(data)
        for e in msg.entities:
            if not e.cubes:
                continue
            c = e.cubes[0]
            meta = {kv.key: kv.value for kv in e.metadata}
            q = c.pose.orientation
            expected.append(
                (
                    to.track_id_of(e.id) if not e.id.lstrip("-").isdigit() or len(e.id) > 15 else int(e.id),
                    e.timestamp.seconds * 10**9 + e.timestamp.nanos,
                    c.pose.position.x,
                    c.pose.position.y,
                    math.atan2(2 * q.w * q.z, 1 - 2 * q.z * q.z),
                    c.size.x,
                    float(meta["vx"]),
                    meta["class"],
                )
            )
    got = list(
        zip(
            block["track_id"].tolist(),
            block["time_ns"].tolist(),
            block["x"].tolist(),
            block["y"].tolist(),
            block["yaw"].tolist(),
            block["length"].tolist(),
            block["vx"].tolist(),
            block["classes"].strings().tolist(),
            strict=True,
        )
    )
    assert len(got) == len(expected) == 19  # 21 entities, 2 without a cube
    for g, want in zip(sorted(got, key=lambda r: r[1]), sorted(expected, key=lambda r: r[1]), strict=True):
        assert g[:2] == want[:2] and g[7] == want[7]
        np.testing.assert_allclose(g[2:7], want[2:7], rtol=1e-12, atol=1e-12)
    assert np.isnan(block["lane"]).all() and np.isnan(block["ax"]).all()


def test_cube_layouts_off_the_fixed_offsets_match_protobuf_library() -> None:
    """Cubes the fixed-offset match refuses (size before pose, no position, a 2-byte length, an
    unknown field, a trailing field after the colour) decode like the usual ones, mixed in one block."""
    from foxglove_schemas_protobuf.CubePrimitive_pb2 import CubePrimitive
    from foxglove_schemas_protobuf.SceneEntity_pb2 import SceneEntity

    def cube(i: int) -> bytes:
        c = CubePrimitive()
        if i % 6 != 1:  # i % 6 == 1: no position at all
            c.pose.position.x, c.pose.position.y = 10.0 + i, -2.5 * i
        c.pose.orientation.z, c.pose.orientation.w = math.sin(0.2 * i), math.cos(0.2 * i)
        c.size.x, c.size.y, c.size.z = 4.0 + i, 1.5 + 0.1 * i, 1.5
        c.color.r = 0.5
        pose, size, color = (getattr(c, name).SerializeToString() for name in ("pose", "size", "color"))
        fields = {
            "pose": b"\x0a" + _varint(len(pose)) + pose,
            "size": b"\x12" + _varint(len(size)) + size,
            "color": b"\x1a" + _varint(len(color)) + color,
        }
        if i % 6 == 2:  # size first
            return fields["size"] + fields["pose"] + fields["color"]
        if i % 6 == 3:  # an unknown length-delimited field of 200 bytes: 2-byte length of the cube
            return fields["pose"] + fields["size"] + b"\x7a" + _varint(200) + bytes(200)
        if i % 6 == 4:  # something after the colour
            return fields["pose"] + fields["size"] + fields["color"] + b"\x20\x01"
        return c.SerializeToString()  # the usual layout (i % 6 in (0, 5), and 1 without position)

    entities = []
    for i in range(24):
        head = SceneEntity(id=str(i), frame_id="map")
        head.timestamp.seconds = 100 + i
        raw = head.SerializeToString() + b"\x42" + _varint(len(cube(i))) + cube(i)
        entities.append(raw)
    messages = [b"".join(b"\x12" + _varint(len(e)) + e for e in entities[k : k + 4]) for k in range(0, 24, 4)]
    buf = np.frombuffer(b"".join(messages), dtype=np.uint8)
    ends = np.cumsum([len(m) for m in messages])
    starts = ends - [len(m) for m in messages]
    block = wire.scene_update_block(buf, starts, ends, np.zeros(len(messages), dtype=np.int64))

    got = sorted(
        zip(
            block["track_id"].tolist(),
            block["x"],
            block["y"],
            block["yaw"],
            block["length"],
            block["width"],
            strict=True,
        )
    )
    assert [g[0] for g in got] == list(range(24))
    for i, row in enumerate(got):
        c = CubePrimitive()
        c.ParseFromString(cube(i))
        q = c.pose.orientation
        want = (
            c.pose.position.x,
            c.pose.position.y,
            math.atan2(2 * q.w * q.z, 1 - 2 * q.z * q.z),
            c.size.x,
            c.size.y,
        )
        np.testing.assert_allclose(row[1:], want, rtol=1e-12, atol=1e-12)
    assert got[1][1:3] == (0.0, 0.0)


def _varint(value: int) -> bytes:
    out = bytearray()
    while True:
        byte, value = value & 0x7F, value >> 7
        out.append(byte | (0x80 if value else 0))
        if not value:
            return bytes(out)


def test_varints_of_every_length_decode_exactly() -> None:
    """Varints of 1 to 10 bytes (the one-byte gather, the joined 8-byte word, the 10-byte window)."""
    from lanecast.io_adapters.logs.messages import protobuf_wire

    rng = np.random.default_rng(5)
    edges = [
        0,
        1,
        127,
        128,
        300,
        2**14,
        2**21 - 1,
        2**28 + 5,
        2**35 - 1,
        2**49 + 3,
        2**56 - 1,
        2**56,
        2**63 - 1,
    ]
    values = [*edges, 2**64 - 1, *rng.integers(0, 2**63, 500).tolist(), *rng.integers(0, 2**30, 500).tolist()]
    coded = [_varint(v) for v in values]
    buf = np.frombuffer(b"".join(coded) + bytes(16), dtype=np.uint8)
    pos = np.cumsum([0] + [len(c) for c in coded[:-1]])
    got, after = protobuf_wire.varints(buf, pos)
    assert got.tolist() == values
    assert (after - pos).tolist() == [len(c) for c in coded]


def test_decimal_strings_parse_like_python_float() -> None:
    """The vectorised number parser gives Python's float() for shortest float32 reprs, exponents
    included (those take numpy's own parser)."""
    rng = np.random.default_rng(3)
    values = (rng.standard_normal(5000) * 10.0 ** rng.integers(-7, 7, 5000)).astype(np.float32)
    texts = [*values.astype(str).tolist(), "0", "-0.0", "42", "-17.", ".5", "7e3"]
    raw = "".join(texts).encode()
    ends = np.cumsum([len(t) for t in texts])
    starts = ends - [len(t) for t in texts]
    parsed = wire.parse_floats(np.frombuffer(raw, dtype=np.uint8), starts, ends)
    np.testing.assert_array_equal(parsed, [float(t) for t in texts])
    assert (parsed[: values.size].astype(np.float32) == values).all()


def test_entity_ids_parse_like_track_id_of() -> None:
    """Ids that are plain decimal integers are read digit by digit; any other id (sign, letters,
    spaces, non-ASCII digits, too long) gets what track_id_of gives it."""
    ids = ["1", "42", "-5", "007", "-0", "-", "", "12a", "+3", " 7", "\u0663", "9" * 18, "1" * 19, "car-17"]
    raw = [s.encode() for s in ids]
    buf = np.frombuffer(b"".join(raw) + bytes(wire.PAD), dtype=np.uint8)
    ends = np.cumsum([len(r) for r in raw])
    starts = ends - [len(r) for r in raw]
    got = wire._track_ids(buf, starts, ends).tolist()
    assert got[:5] == [1, 42, -5, 7, 0] and got[11] == 999_999_999_999_999_999
    assert got == [to.track_id_of(s) for s in ids]


def test_a_topic_picked_with_a_foreign_channel_beside_its_object_channel(tmp_path: Path) -> None:
    """Two channels of one topic, a String first and TrackedObjects after: `--topic` refused the
    topic at the String channel ('holds no tracked objects') though the other channel holds the
    objects (read without `--topic`); now both read the objects, and a topic with only the String
    channel is still refused at it."""

    def build(w: Any) -> None:
        chatter = _ros2_channel(w, "/objects", ros_types.STRING)
        objects = _ros2_channel(w, "/objects", ros_types.TRACKED_OBJECTS)
        only = _ros2_channel(w, "/chatter", ros_types.STRING)
        store = ros_types.typestore(2)
        s = bytes(store.serialize_cdr(ros_types.make(store, ros_types.STRING, data="hi"), ros_types.STRING))
        for i in range(3):
            t = 10**9 + i * 50_000_000
            w.add_message(chatter, log_time=t, data=s, publish_time=t)
            w.add_message(only, log_time=t, data=s, publish_time=t)
            objs = _tracked_objects(t, "map", [(1, float(i), 0.0, 0.0, 1.0)])
            w.add_message(objects, log_time=t, data=objs, publish_time=t)

    path = _write_mcap(tmp_path / "shared.mcap", build)
    picked = mcap_reader.read(path, topic="/objects")
    np.testing.assert_allclose(picked.column("x").to_numpy(), [0.0, 1.0, 2.0])
    assert picked.equals(mcap_reader.read(path))
    with pytest.raises(LogError, match=r"topic '/chatter' has schema 'std_msgs/msg/String'") as err:
        mcap_reader.read(path, topic="/chatter")
    assert err.value.offset is not None


def test_a_topic_whose_messages_all_have_one_log_time_is_refused(tmp_path: Path) -> None:
    """A recorder that left every time 0 (log times and header stamps): was read as one frame per
    track, the other rows dropped as duplicates with a warning; now refused, naming the topic and
    the time."""

    def build(w: Any) -> None:
        objects = _ros2_channel(w, "/objects", ros_types.TRACKED_OBJECTS)
        for i in range(5):
            data = _tracked_objects(0, "map", [(1, float(i), 0.0, 0.0, 1.0)])
            w.add_message(objects, log_time=0, data=data, publish_time=10**9 + i * 100_000_000)

    path = _write_mcap(tmp_path / "zero.mcap", build)
    with pytest.raises(LogError, match=r"topic '/objects': all 5 messages are stamped 0 ns") as err:
        mcap_reader.read(path)
    assert err.value.path == str(path)


def test_log_with_numbered_topics_reads_the_same(tmp_path: Path) -> None:
    """Logs written with ``/tracked_objects/r0``, ``r1`` (and any other topic names the metadata
    maps to recordings) read as logs named by recording do."""
    from mcap.reader import make_reader
    from mcap.writer import Writer

    table = make_table()
    named = mcap_writer.write(table, tmp_path / "named.mcap", "mcap")
    renames = {
        "/tracked_objects/rec_a": "/tracked_objects/r0",
        "/tracked_objects/rec_b": "/tracked_objects/r1",
    }
    numbered = tmp_path / "numbered.mcap"
    with named.open("rb") as src, numbered.open("wb") as dst:
        reader = make_reader(src)
        writer = Writer(dst)
        writer.start(profile="", library="lanecast test")
        schemas: dict[int, int] = {}
        channels: dict[int, int] = {}
        for schema, channel, message in reader.iter_messages():
            if channel.id not in channels:
                assert schema is not None
                if schema.id not in schemas:
                    schemas[schema.id] = writer.register_schema(schema.name, schema.encoding, schema.data)
                channels[channel.id] = writer.register_channel(
                    renames[channel.topic], channel.message_encoding, schemas[schema.id]
                )
            writer.add_message(channels[channel.id], message.log_time, message.data, message.publish_time)
        for record in reader.iter_metadata():
            metadata = dict(record.metadata)
            if record.name == "lanecast":
                doc = json.loads(metadata["lanecast"])
                for spec in doc["recordings"].values():
                    spec["topic"] = renames[spec["topic"]]
                metadata["lanecast"] = json.dumps(doc)
            writer.add_metadata(record.name, metadata)
        writer.finish()
    back, _ = mcap_reader.read_log(numbered)
    same_table(table, back)
    assert track_table.read_meta(back).recordings["rec-b"].extra["topic"] == "/tracked_objects/r1"


@pytest.mark.parametrize("threads", ["1", "2"])
def test_decoding_on_threads_gives_the_same_table_and_names_the_damaged_record(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, threads: str
) -> None:
    """SceneUpdates decoded on a pool of threads, batch by batch, while the walk goes on: the table
    is the one a single thread makes, in the log's order, and a message that does not decode is
    still named by the chunk that holds it, whichever batch it falls in."""
    from conftest import rewrite_mcap

    table = make_table(n_tracks=4, n_frames=120)
    clean = mcap_writer.write(table, tmp_path / "log.mcap", "mcap", chunk_size=1500)
    monkeypatch.setattr(wire.SceneUpdateBatch, "LIMIT", 4000)  # many batches in flight
    monkeypatch.setenv("LANECAST_THREADS", "1")
    single = mcap_reader.read(clean)
    monkeypatch.setenv("LANECAST_THREADS", threads)
    back = mcap_reader.read(clean)
    assert back.equals(single) and back.schema.metadata == single.schema.metadata
    assert_same_table(table, back)

    bad = tmp_path / "bad.mcap"
    damaged: list[int] = []

    def edit(k: int, n: int, _log_time: int, data: bytes) -> bytes | None:
        if k != 2 * n // 3:
            return None
        damaged.append(k)
        return data + b"\x12\x50\x1a\x01"  # an entity that runs past the message

    rewrite_mcap(clean, bad, edit)
    assert damaged
    monkeypatch.setenv("LANECAST_THREADS", "1")
    with pytest.raises(LogError, match="SceneUpdate messages cannot be decoded") as single_err:
        mcap_reader.read(bad)
    monkeypatch.setenv("LANECAST_THREADS", threads)
    with pytest.raises(LogError, match="SceneUpdate messages cannot be decoded") as err:
        mcap_reader.read(bad)
    assert err.value.offset is not None and err.value.offset > 0
    assert err.value.offset == single_err.value.offset
