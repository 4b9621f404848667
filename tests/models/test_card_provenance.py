"""Provenance: every output with forecasts names the model, the checksum of its weights and its training data."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

from lanecast.models.card import WEIGHTS_DIR, file_sha256, provenance, provenance_line


def test_the_shipped_model_is_named_with_its_checksum_and_training_data() -> None:
    prov = provenance(None)
    assert prov["model"] == "the shipped model (stcnn-sumo)"
    assert prov["sha256"] == file_sha256(WEIGHTS_DIR / "stcnn-sumo.safetensors")
    assert prov["trained_on"].endswith(
        "simulated recordings (dense, free_flow, lane_drop, on_ramp, signal, stop_and_go, urban, wide)"
    )
    assert provenance_line(prov).startswith(
        f"model: the shipped model (stcnn-sumo) (sha256 {prov['sha256'][:12]})"
    )


def test_a_fine_tuned_model_says_its_windows_and_its_base(tmp_path: Path) -> None:
    model = tmp_path / "runs" / "tuned"
    model.mkdir(parents=True)
    for suffix in (".safetensors", ".json"):
        shutil.copy(WEIGHTS_DIR / f"stcnn-sumo{suffix}", model / f"stcnn{suffix}")
    card = json.loads((model / "stcnn.json").read_text())
    card["training"]["data"] = {"windows": "windows/queue", "init": "shipped model"}
    (model / "stcnn.json").write_text(json.dumps(card))
    prov = provenance(model)
    assert prov["model"] == str(model / "stcnn.json")
    assert prov["trained_on"] == "the windows dataset windows/queue, fine-tuned from shipped model"
