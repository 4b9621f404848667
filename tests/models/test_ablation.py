"""`lanecast ablate`: the paper's variants are what they claim (parameters, what the networks see) and
the command writes ablation.json and the report for two variants trained on a tiny dataset."""

from __future__ import annotations

import json
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch
from conftest import synthetic_windows

from lanecast.io_adapters.contracts.normalisation import NormStats, normalise
from lanecast.io_adapters.contracts.windows import TARGET_ROW
from lanecast.io_adapters.windows_store.dataset import save_windows
from lanecast.models.ablation import (
    SHUFFLED_ROWS,
    InputAblation,
    predict_variant,
    sample_sequences,
    train_variant,
    variant_parameters,
    variants,
)
from lanecast.models.train import TrainConfig
from lanecast.workflows.cli import main

TINY = TrainConfig(epochs=1, batch_size=64, lr=2e-3, threads=1)


@contextmanager
def first_conv_inputs() -> Iterator[list[np.ndarray]]:
    """Every batch that reaches a first convolution (2 or 4 input channels) while the block runs."""
    seen: list[np.ndarray] = []

    def hook(module: torch.nn.Module, args: tuple[Any, ...]) -> None:
        if isinstance(module, torch.nn.Conv2d) and module.in_channels in (2, 4):
            seen.append(args[0].detach().numpy().copy())

    handle = torch.nn.modules.module.register_module_forward_pre_hook(hook)
    try:
        yield seen
    finally:
        handle.remove()


def test_paper_parameter_counts_and_columns() -> None:
    table = variants()
    assert list(table) == [
        "xy_only",
        "no_neighbourhood",
        "shuffled",
        "no_dilation",
        "no_maneuver",
        "sampled_maneuver",
        "full",
    ]
    assert variant_parameters(table["no_dilation"]) == 90_681  # the paper's figure
    assert variant_parameters(table["full"]) == 65_721
    assert table["xy_only"].model.channels == 2


def test_input_ablations_value_by_value() -> None:
    x = np.random.default_rng(0).normal(size=(3, 4, 8, 30)).astype(np.float32)
    alone = InputAblation(target_only=True)(x)
    np.testing.assert_array_equal(alone[:, :, TARGET_ROW], x[:, :, TARGET_ROW])
    assert not np.any(np.delete(alone, TARGET_ROW, axis=2))
    shuffled = InputAblation(rows=SHUFFLED_ROWS)(x)
    for i, source in enumerate(SHUFFLED_ROWS):
        np.testing.assert_array_equal(shuffled[:, :, i], x[:, :, source])
    assert sorted(SHUFFLED_ROWS) == list(range(8)) and all(r != i for i, r in enumerate(SHUFFLED_ROWS))
    np.testing.assert_array_equal(InputAblation(channels=(0, 1))(x), x[:, :2])
    assert InputAblation().is_identity()


@pytest.mark.slow
def test_without_neighbourhood_trains_and_predicts_on_the_target_row_alone() -> None:
    windows = synthetic_windows(200, seed=3)
    variant = variants()["no_neighbourhood"]
    with first_conv_inputs() as seen:
        result = train_variant(windows, variant, TINY)
    assert seen and all(not np.any(np.delete(batch, TARGET_ROW, axis=2)) for batch in seen)
    assert any(np.any(batch[:, :, TARGET_ROW]) for batch in seen)
    # the neighbours cannot matter: moving F far away changes nothing
    moved = np.array(windows.inputs)
    moved[:, 0, 1] += 50.0
    a = predict_variant(result.model, result.card, variant.transform(), windows.inputs, windows.present)
    b = predict_variant(result.model, result.card, variant.transform(), moved, windows.present)
    np.testing.assert_array_equal(a.offsets, b.offsets)


def test_shuffled_sees_the_fixed_permutation() -> None:
    windows = synthetic_windows(120, seed=5)
    variant = variants()["shuffled"]
    with first_conv_inputs() as seen:
        result = train_variant(windows, variant, TINY)
        predict_variant(result.model, result.card, variant.transform(), windows.inputs, windows.present)
    stats_x = normalise(np.asarray(windows.inputs), np.asarray(windows.present), _stats(result.card))
    np.testing.assert_allclose(seen[-1], stats_x[:, :, list(SHUFFLED_ROWS)], rtol=1e-6, atol=1e-6)


def _stats(card: dict[str, Any]) -> NormStats:
    return NormStats.from_dict(card["normalisation"]["inputs"])


def test_sampled_sequences_come_from_training() -> None:
    train = np.array([[0, 0, 0, 0, 0], [0, 1, 1, 1, 0], [2, 2, 0, 0, 0]])
    drawn = sample_sequences(train, 50, seed=1)
    assert drawn.shape == (50, 5)
    assert {tuple(r) for r in drawn} <= {tuple(r) for r in train}
    np.testing.assert_array_equal(drawn, sample_sequences(train, 50, seed=1))


@pytest.mark.slow
def test_ablate_cli_two_variants(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    windows = save_windows(synthetic_windows(300, seed=2), tmp_path / "windows")
    out = tmp_path / "ablation"
    argv = ["ablate", str(windows), "--out", str(out), "--variants", "no_dilation,full"]
    assert main([*argv, "--seeds", "2", "--quick", "--epochs", "1"]) == 0
    doc = json.loads((out / "ablation.json").read_text())
    assert list(doc["variants"]) == ["no_dilation", "full"]  # the paper's column order
    assert doc["seeds"] == [0, 1] and doc["scored_on"]["split"] == "test"
    assert doc["scored_on"]["windows"] == 60  # track ids ending in 8 or 9
    for name, v in doc["variants"].items():
        assert [r["seed"] for r in v["runs"]] == [0, 1]
        assert len(v["mean"]["rmse"]) == len(v["std"]["rmse"]) == 5
        runs = np.array([r["rmse"] for r in v["runs"]])
        np.testing.assert_allclose(v["mean"]["rmse"], runs.mean(axis=0))
        np.testing.assert_allclose(v["std"]["rmse"], runs.std(axis=0, ddof=1))
        assert len(v["paper_rmse"]) == 5 and v["label"]
        assert 0.0 <= v["mean"]["maneuver_macro_f1"] <= 1.0, name
    assert doc["variants"]["no_dilation"]["parameters"] == 90_681
    assert doc["train_config"]["epochs"] == 1
    page = (out / "report.html").read_text()
    assert "Without dilation" in page and "Full approach" in page and " ± " in page
    assert "Table II" in page and (out / "ablation.png").stat().st_size > 1000
    assert "Full approach" in capsys.readouterr().out
    assert main([*argv, "--variants", "nonsense"]) == 2
