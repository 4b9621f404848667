"""Model cards and weights on hostile input: wrong types, NaN, weights of another run, half a model;
refused naming the card or weights file."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
from conftest import _model_copy, _set

from lanecast.io_adapters.errors import InputError
from lanecast.models import card


@pytest.mark.parametrize(("kept", "missing"), [(".json", ".safetensors"), (".safetensors", ".json")])
def test_a_model_directory_with_one_half_of_a_model_names_the_missing_file(
    tmp_path: Path, kept: str, missing: str
) -> None:
    """A model directory holding the card but not the weights (or the reverse: one file copied)
    said "found none" as if it held nothing of a model; now it names the file without its pair."""
    stem = card.SHIPPED_STEM
    shutil.copy(card.WEIGHTS_DIR / f"{stem}{kept}", tmp_path / f"{stem}{kept}")
    with pytest.raises(InputError) as err:
        card.resolve(tmp_path)
    assert err.value.path == str(tmp_path)
    assert f"found {stem}{kept} without {stem}{missing}" in str(err.value)


@pytest.mark.parametrize(
    ("field", "value"),
    [
        ("format_version", "1"),
        ("architecture.config.hidden", 2**40),
        ("architecture.config.conv_channels", [24, -40, 56, 24]),
        ("architecture.config.conv_kernels", [[5, 10], [3], [2, 3], [1, 1]]),
        ("architecture.config.channels", 0),
        ("normalisation.inputs.std", [1.0, 1.0, 0.0, 1.0]),
        ("normalisation.inputs.mean", [1.0, "x", 0.0, 1.0]),
        ("normalisation.future.std", -1.0),
        ("normalisation.future.mean", [1.0, 2.0]),
        ("normalisation", []),
        ("architecture.config.conv_dilations", [[1, 2], [1, 2], [1, 1]]),
        ("training", [1]),
        ("training.config", 3),
        ("training.data.distribution.speed_mps", {"p0.5": "slow", "p99.5": 40.0}),
        ("training.data.distribution.lon_acc_mps2", {"p0.5": 3.0, "p99.5": -3.0}),
        ("windows.neighbour_range_m", -5),
    ],
)
def test_model_card_with_wrong_types_is_refused_naming_the_card(
    tmp_path: Path, field: str, value: object
) -> None:
    from lanecast.models.checkpoint import load_checkpoint

    model = _model_copy(tmp_path, _set(field, value))
    with pytest.raises(InputError) as err:
        load_checkpoint(model)
    assert err.value.path == str(model / "stcnn.json")
    assert err.value.column is not None and err.value.column.startswith(field.split(".")[0])


def test_model_card_nan_is_not_json_and_nan_weights_are_refused(tmp_path: Path) -> None:
    import torch
    from safetensors.torch import load_file, save_file

    from lanecast.models.checkpoint import load_checkpoint

    model = _model_copy(tmp_path)
    card = (model / "stcnn.json").read_text()
    (model / "stcnn.json").write_text(card.replace('"std": [', '"std": [NaN, ', 1))
    with pytest.raises(InputError, match="model card") as err:
        load_checkpoint(model)
    assert err.value.path == str(model / "stcnn.json")
    (model / "stcnn.json").write_text(card)
    state = load_file(str(model / "stcnn.safetensors"))
    name = sorted(state)[0]
    state[name] = state[name].clone()
    state[name].view(-1)[0] = torch.nan
    save_file(state, str(model / "stcnn.safetensors"))
    with pytest.raises(InputError, match=f"tensor '{name}' holds NaN") as err:
        load_checkpoint(model)
    assert err.value.path == str(model / "stcnn.safetensors")


def test_weights_of_another_run_under_a_card_are_refused(tmp_path: Path) -> None:
    """save_checkpoint writes the weights, then the card (two renames): a run stopped between them
    leaves new weights under the old card. The card names its weights' SHA-256, so that pair is
    refused instead of served; a card without the field (written before it) still loads."""
    import torch

    from lanecast.models.card import SHIPPED_STEM, WEIGHTS_DIR, file_sha256
    from lanecast.models.checkpoint import load_checkpoint, save_checkpoint

    net, card = load_checkpoint(None)
    assert card["weights_sha256"] == file_sha256(WEIGHTS_DIR / f"{SHIPPED_STEM}.safetensors")
    first, other = tmp_path / "first", tmp_path / "other"
    save_checkpoint(net, card, first)
    load_checkpoint(first)
    with torch.no_grad():
        next(net.parameters()).add_(0.01)  # another run's weights
    save_checkpoint(net, card, other)
    (first / "stcnn.safetensors").write_bytes((other / "stcnn.safetensors").read_bytes())
    with pytest.raises(InputError, match="not the weights file this card was written with") as err:
        load_checkpoint(first)
    assert err.value.path == str(first / "stcnn.json") and err.value.column == "weights_sha256"
    older = json.loads((first / "stcnn.json").read_text())
    del older["weights_sha256"]
    (first / "stcnn.json").write_text(json.dumps(older))
    reloaded, _ = load_checkpoint(first)
    assert torch.equal(next(reloaded.parameters()), next(net.parameters()))
