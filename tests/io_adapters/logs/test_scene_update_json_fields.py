"""JSON SceneUpdate logs and lanecast's log metadata: a bad field is named, never cast or read twice."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest
from mcap.writer import Writer

from lanecast.io_adapters.errors import LogError
from lanecast.io_adapters.formats import registry
from lanecast.io_adapters.logs.conventions import parse_log_metadata


def _entity(track: int, t_s: float, lane: Any = "2", **overrides: Any) -> dict[str, Any]:
    sec, nsec = int(t_s), round((t_s % 1) * 1e9)
    entity: dict[str, Any] = {
        "timestamp": {"sec": sec, "nsec": nsec},
        "frame_id": "map",
        "id": str(track),
        "metadata": [{"key": "class", "value": "car"}, {"key": "lane_id", "value": lane}],
        "cubes": [
            {
                "pose": {"position": {"x": 25.0 * t_s + 10 * track, "y": 3.5}, "orientation": {"w": 1.0}},
                "size": {"x": 4.5, "y": 1.8, "z": 1.5},
            }
        ],
    }
    entity.update(overrides)
    return entity


def _log(path: Path, entity_of_frame: Any) -> Path:
    """A SceneUpdate (JSON) log of 30 frames at 10 Hz, written with the mcap library alone."""
    with path.open("wb") as fh:
        w = Writer(fh)
        w.start(profile="", library="test")
        schema = w.register_schema("foxglove.SceneUpdate", "jsonschema", b'{"type": "object"}')
        channel = w.register_channel("/objects", "json", schema)
        for i in range(30):
            t_s = 1.0 + i / 10
            doc = {"deletions": [], "entities": [entity_of_frame(i, t_s)]}
            w.add_message(channel, int(t_s * 1e9), json.dumps(doc).encode(), int(t_s * 1e9))
        w.finish()
    return path


def test_a_clean_json_log_reads_with_its_lanes(tmp_path: Path) -> None:
    table = registry.read_any([_log(tmp_path / "ok.mcap", lambda i, t: _entity(1, t))])
    assert table.num_rows == 30
    assert set(table.column("lane_id").to_pylist()) == {2}


@pytest.mark.parametrize("lane", ["1.5", "1e20", "-3e12"])
def test_a_lane_id_that_is_no_integer_lane_is_refused_not_cast(tmp_path: Path, lane: str) -> None:
    log = _log(tmp_path / "lane.mcap", lambda i, t: _entity(1, t, lane=lane if i == 7 else "2"))
    with pytest.raises(LogError) as err:
        registry.read_any([log])
    text = str(err.value)
    assert str(log) in text and "lane_id" in text and f"has lane_id {float(lane):g}" in text, text
    assert "integer lane id" in text


@pytest.mark.parametrize(
    ("edit", "field"),
    [
        (lambda e: {**e, "metadata": "car"}, "entities[0].metadata"),
        (lambda e: {**e, "metadata": [{"key": "vx", "value": "abc"}]}, "entities[0].metadata.vx"),
        (lambda e: {**e, "timestamp": {"sec": "x", "nsec": 0}}, "entities[0].timestamp.sec"),
        (lambda e: {**e, "cubes": ["box"]}, "entities[0].cubes[0]"),
        (lambda e: {**e, "cubes": [{"pose": {"position": {"x": "abc", "y": 0}}}]}, "position.x"),
    ],
)
def test_a_json_field_of_the_wrong_type_is_named(tmp_path: Path, edit: Any, field: str) -> None:
    log = _log(tmp_path / "bad.mcap", lambda i, t: edit(_entity(1, t)) if i == 4 else _entity(1, t))
    with pytest.raises(LogError) as err:
        registry.read_any([log])
    text = str(err.value)
    assert field in text, text
    assert "AttributeError" not in text and "invalid literal" not in text and "could not convert" not in text


def test_log_metadata_naming_one_topic_under_two_recordings_is_refused() -> None:
    spec = {"topic": "/tracked_objects", "frame_rate": 10.0}
    doc = {"recordings": {"north": spec, "south": dict(spec)}}
    with pytest.raises(LogError) as err:
        parse_log_metadata(Path("two.mcap"), json.dumps(doc))
    text = str(err.value)
    assert "recordings.south.topic" in text and "the topic of recording 'north' too" in text, text
    doc["recordings"]["south"]["topic"] = "/tracked_objects/r1"
    parse_log_metadata(Path("two.mcap"), json.dumps(doc))
