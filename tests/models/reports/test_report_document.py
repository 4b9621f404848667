"""The evaluation report a reader trusts: names in words, no raw JSON, the always-straight reference,
per-recording rows, the failure gallery, and scenes drawn with the shared maneuver colours."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from lanecast.io_adapters.contracts.windows import MANEUVER_COLOURS
from lanecast.io_adapters.logs import forecast_messages as fm
from lanecast.models.metrics import summary
from lanecast.models.reports.document import MANEUVER_HEX, Scene, hex_colour, scene_plot, write_report


def scene(kind: str = "example") -> Scene:
    inputs = np.zeros((4, 8, 30), np.float32)
    present = np.zeros((8, 30), bool)
    inputs[0, :, :] = np.arange(30) - 29.0  # 1 m per frame
    inputs[1, 2] = -3.75  # FR on the right
    inputs[0, 2] += 20.0
    inputs[2] = 10.0
    present[[2, 4]] = True
    offsets = np.array([[10, 0], [20, 0.5], [30, 1.5], [40, 3], [50, 3.7]], np.float32)
    probs = np.array([[0.9, 0.1, 0], [0.3, 0.7, 0], [0.1, 0.9, 0], [0.1, 0.9, 0], [0.2, 0.8, 0]])
    return Scene(
        title=f"{kind} scene",
        inputs=inputs,
        present=present,
        future=offsets.copy(),
        offsets=offsets,
        maneuver=np.array([0, 1, 1, 1, 1]),
        alternatives=np.stack([offsets, offsets * [1, 0]]),
        alt_probs=np.array([0.6, 0.3]),
        probs=probs,
        alt_maneuvers=np.array([[0, 1, 1, 1, 1], [0, 0, 0, 0, 0]]),
        kind=kind,
    )


def test_report_in_words_with_reference_and_gallery(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    n = 40
    future = rng.normal(size=(n, 5, 2)).astype(np.float32)
    maneuver = np.zeros((n, 5), np.int64)
    maneuver[:5, 2:] = 1
    pred_m = np.zeros_like(maneuver)
    pred_m[30, 4] = 2  # a false right lane change
    probs = np.full((n, 5, 3), 0.05)
    probs[..., 0] = 0.9
    recording = np.where(np.arange(n) < 20, "rec-a", "rec-b")
    metrics = {
        "stcnn": summary(
            future + 0.1,
            future,
            maneuver,
            np.arange(n),
            predicted_maneuver=pred_m,
            probs=probs,
            recording=recording,
        ),
        "cv": summary(future + 0.5, future, maneuver, np.arange(n), recording=recording),
    }
    meta = {
        "windows": "w/",
        "always_straight": {"maneuver_accuracy": 0.925, "maneuver_macro_f1": 0.48},
        "sources": {"recordings": {"rec-a": {}, "rec-b": {}}, "inputs": ["sim/"]},
    }
    md, page = write_report(tmp_path, metrics, meta, [scene(), scene("failure")])
    text = page.read_text()
    assert "ST-CNN (maneuver-based)" in text and "constant velocity" in text
    assert "always straight (reference)" in text and "0.925" in text
    assert '{"' not in text and "{'" not in text  # no raw JSON or dicts in the header
    assert "2 recording(s): rec-a, rec-b from sim/" in text
    assert "Failure gallery" in text and "failure scene" in text
    assert "<td>rec-a</td>" in text and "<td>rec-b</td>" in text  # per-recording rows
    assert "F1 = 0" in text  # the report says how macro-F1 counts a predicted but absent class
    assert "Per recording" in md.read_text() and (tmp_path / "reliability.png").stat().st_size > 1000


def test_scene_colours_are_the_annotation_colours() -> None:
    assert hex_colour((1.0, 0.0, 0.5)) == "#ff0080"
    assert MANEUVER_HEX == tuple(hex_colour(c) for c in MANEUVER_COLOURS)  # one scheme, from the contract
    np.testing.assert_allclose(fm.COLOURS[:3], MANEUVER_COLOURS)  # ... and in the Foxglove annotation
    png = scene_plot(scene())
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 10_000
