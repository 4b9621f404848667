"""`lanecast annotate --encoding autoware` writes the forecasts as Autoware PredictedObjects (valid CDR,
Autoware's definitions in the log's schema records, paths ordered by probability), and scoring that
recorded topic gives the RMSE per horizon of lanecast's own forecasts on the same objects."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from mcap.reader import make_reader
from predictor_drive_log import PREDICTIONS_TOPIC, write_bag, write_mcap
from rosbags.highlevel import AnyReader
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from lanecast.io_adapters.logs.autoware.predicted_objects import PREDICTED_OBJECTS
from lanecast.io_adapters.logs.autoware.predicted_objects_encode import AUTOWARE_TOPIC
from lanecast.io_adapters.logs.forecast_messages import PREDICTION_TOPIC
from lanecast.io_adapters.logs.messages import ros_types
from lanecast.workflows.cli import main


def annotate(log: Path, out: Path) -> Path:
    assert main(["annotate", str(log), "--out", str(out), "--encoding", "autoware"]) == 0
    (annotated,) = [p for p in out.iterdir() if p.name != "manifest.jsonl"]
    return annotated


def lanecast_documents(log: Path) -> dict[tuple[int, int], dict[str, Any]]:
    """(t0, track id) → the /lanecast/prediction target (an MCAP)."""
    out = {}
    with log.open("rb") as fh:
        for _, _, message in make_reader(fh).iter_messages(topics=[PREDICTION_TOPIC]):
            doc = json.loads(message.data)
            out.update({(doc["t0_ns"], t["track_id"]): t for t in doc["targets"]})
    return out


def test_an_mcap_gets_predicted_objects_with_autowares_definitions(tmp_path: Path) -> None:
    log = annotate(write_mcap(tmp_path / "drive.mcap"), tmp_path / "out")
    targets = lanecast_documents(log)
    with log.open("rb") as fh:
        reader = make_reader(fh)
        summary = reader.get_summary()
        assert summary is not None
        (channel,) = [c for c in summary.channels.values() if c.topic == AUTOWARE_TOPIC]
        schema = summary.schemas[channel.schema_id]
        assert (schema.name, schema.encoding, channel.message_encoding) == (
            PREDICTED_OBJECTS,
            "ros2msg",
            "cdr",
        )
        # decoded by a typestore that knows only ROS 2 and the log's own schema text
        store = get_typestore(Stores.ROS2_HUMBLE)
        store.register(get_types_from_msg(schema.data.decode(), schema.name))
        seen = 0
        for _, _, message in reader.iter_messages(topics=[AUTOWARE_TOPIC]):
            msg = store.deserialize_cdr(message.data, PREDICTED_OBJECTS)
            t0 = msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec
            assert t0 == message.log_time
            for obj in msg.objects:
                track = int.from_bytes(bytes(obj.object_id.uuid[:8]), "little", signed=True)
                target = targets[(t0, track)]
                paths = obj.kinematics.predicted_paths
                conf = [p.confidence for p in paths]
                assert conf == sorted(conf, reverse=True)
                probs = sorted((a["prob"] for a in target["alternatives"]), reverse=True)
                np.testing.assert_allclose(conf, probs, rtol=1e-6)
                best = paths[0]
                assert (best.time_step.sec, best.time_step.nanosec, len(best.path)) == (1, 0, 6)
                xy = np.array([[p.position.x, p.position.y] for p in best.path[1:]])
                np.testing.assert_allclose(xy, np.stack([target["x"], target["y"]], axis=1), atol=1e-3)
                seen += 1
        assert seen == len(targets) > 0


@pytest.mark.parametrize("kind", ["mcap", "ros2"])
def test_scoring_the_recorded_topic_gives_lanecasts_own_rmse(tmp_path: Path, kind: str) -> None:
    src = write_mcap(tmp_path / "drive.mcap") if kind == "mcap" else write_bag(tmp_path / "drive")
    log = annotate(src, tmp_path / "out")
    if kind == "ros2":  # a bag reader with lanecast's types reads the new topic as PredictedObjects
        with AnyReader([log], default_typestore=ros_types.typestore(2)) as reader:
            assert {c.topic: c.msgtype for c in reader.connections}[AUTOWARE_TOPIC] == PREDICTED_OBJECTS
    out = tmp_path / "report"
    assert main(["report", str(log), "--out", str(out), "--predictions"]) == 0
    report = json.loads((out / "metrics.json").read_text())
    # found by schema (both PredictedObjects topics) and by name (lanecast's JSON)
    assert report["predictor_topics"] == sorted([AUTOWARE_TOPIC, PREDICTION_TOPIC, PREDICTIONS_TOPIC])
    for topic, rtol in ((AUTOWARE_TOPIC, 1e-5), (PREDICTION_TOPIC, 1e-3)):  # the JSON holds rounded numbers
        m = report[topic]["metrics"]
        assert m["recorded"]["n"] == m["stcnn"]["n"] == 12
        np.testing.assert_allclose(m["recorded"]["rmse"], m["stcnn"]["rmse"], rtol=rtol)
        np.testing.assert_allclose(m["recorded"]["min_ade"], m["stcnn"]["min_ade"], rtol=rtol)
        np.testing.assert_allclose(m["recorded"]["brier"], m["stcnn"]["brier"], rtol=rtol)
